"""
Reading rosbag2 bags with ``rosbags``, with the workarounds that real bags need.

One place for ``bag_play``, the driver's ``source:=bag`` and ``st-stereo calibrate --bag``.

- ``bag_messages``: rosbags (0.11) pairs each storage file's connections with the bag's
  ``metadata.yaml`` connections by topic, type *and* the stored offered QoS. Older rosbag2
  versions stored the QoS differently in the two places (the Foxy-era MCAP talker bag:
  deadline 0 in ``metadata.yaml``, infinite in the MCAP channel), so rosbags matched nothing
  and yielded no message at all. rosbag2 itself matches by topic and type; so does this.
  (Worth offering upstream: the QoS text is not part of a connection's identity.)
- ``open_bag``, sqlite3 bags of Iron and later: rosbag2 stores a type whose ``.msg`` it could
  not find (e.g. a service event type) with encoding ``''`` and no text in the
  ``message_definitions`` table ("Message definition will be left empty in bag"). rosbags
  (0.11) maps only ``ros2msg``/``ros2idl`` there and fails the whole bag with ``KeyError: ''``
  (its MCAP reader accepts ``''``). ``_Sqlite3Reader`` hides those rows from that one query:
  they hold no definition, so the type reads as "no definition", as in MCAP.
- ``normalized_msgtype``: ``pkg/msg/Name``, also for the old ``pkg/Name`` spelling.
- ``open_bag``: a damaged or foreign bag is one ``BagError`` line naming the file, the line
  where the parser stopped (when it says) and what is wrong, never a traceback.
- ``open_bag``, recordings that did not end (power cut, ``kill -9``, a copy cut short): an
  MCAP file without its footer is read up to its last complete record, as rosbag2's MCAP
  plugin reads one (the mcap library's fallback scan); rosbags (0.11) refused the whole file
  ("File end magic is invalid"). A bag directory without ``metadata.yaml`` (rosbag2 writes it
  when the recording ends) and with one storage file is read from that file, as
  ``ros2 bag play FILE`` does. Each is said in the reader's ``notes`` (``bag_notes``).
"""

import importlib
import pathlib
import re
import struct


_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*')     # a package, msg/srv/action, or a type


class BagError(ValueError):
    """A bag cannot be read; the message names the file and the problem."""


def open_bag(path):
    """Open a rosbag2 directory (or storage file) with rosbags; BagError when it cannot."""
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f'{path}: no such bag')
    notes = []
    if path.is_dir() and not _has_metadata(path):
        path = _lone_storage_file(path)
        notes.append(f'{path.parent}: no metadata.yaml, or an empty one (a recording that '
                     f'did not end, or a copy without it): reading {path.name} alone')
    path, logged = _with_write_ahead_logs_applied(path)
    notes += logged
    metadata = path / 'metadata.yaml' if path.is_dir() else path
    try:
        reader = _reader_class()(path)
        reader.open()
    except Exception as error:      # noqa: B902 - rosbags and its YAML parser raise many kinds
        hint = ' (a recording that did not end: reading its complete records needs rosbags ' \
            '0.11.6 or later)' if 'end magic' in str(error) else ''
        raise BagError(f'{metadata}: {_one_line(error)}{hint}') from None
    storages = getattr(reader.storage, 'storages', None) or [reader.storage]
    notes += [storage.cut_short_note for storage in storages
              if getattr(storage, 'cut_short_note', None)]
    reader.notes = notes
    problem = _metadata_shape_problem(metadata) if path.is_dir() else None
    if problem:
        _close_quietly(reader)
        raise BagError(f'{metadata}: {problem}')
    for connection in reader.connections:
        try:
            if not isinstance(connection.topic, str) or not connection.topic:
                raise ValueError(f'expected a topic name, got {connection.topic!r}')
            normalized_msgtype(connection.msgtype)
        except ValueError as error:
            _close_quietly(reader)
            raise BagError(f'{metadata}: topic {connection.topic}: {error}') from None
    return reader


def bag_notes(path):
    """Return what ``open_bag`` had to work around in a bag (see the module docstring)."""
    reader = open_bag(path)
    try:
        return list(reader.notes)
    finally:
        _close_quietly(reader)


STORAGE_SUFFIXES = ('.mcap', '.db3')
_ZSTD_MAGIC = b'\x28\xb5\x2f\xfd'


_WAL_COPIES = {}        # (bag, its databases' and logs' sizes and times) -> applied copy


def _with_write_ahead_logs_applied(path):
    """
    Return ``(path to read, notes)``: a copy with each database's write-ahead log applied.

    rosbag2's ``resilient`` sqlite3 preset writes in WAL mode; a recording that did not end
    leaves messages in ``<file>.db3-wal`` that the database itself does not hold yet, and
    rosbags opens databases immutable, which ignores the log: they were lost without a word.
    The bag (a directory, or one .db3 file) is copied to a temporary directory, kept until
    the process ends and shared by every opening of the same files, where SQLite applies the
    log; the user's files are not written.
    """
    import atexit
    import shutil
    import sqlite3
    import tempfile
    databases = sorted(path.glob('*.db3')) if path.is_dir() else \
        [path] if path.suffix == '.db3' else []
    logged = [db for db in databases if _nonempty(db.with_name(db.name + '-wal'))]
    if not logged:
        return path, []
    key = (str(path.resolve()),) + tuple(
        (f.name, f.stat().st_size, f.stat().st_mtime_ns) for db in logged
        for f in (db, db.with_name(db.name + '-wal')))
    if key not in _WAL_COPIES:
        folder = pathlib.Path(tempfile.mkdtemp(prefix='st_stereo_bag_'))
        atexit.register(shutil.rmtree, folder, True)
        copy = folder / path.name
        if path.is_dir():
            shutil.copytree(path, copy, ignore=shutil.ignore_patterns('*-shm'))
        else:
            shutil.copy2(path, copy)
            shutil.copy2(path.with_name(path.name + '-wal'), folder / (path.name + '-wal'))
        for db in logged:
            target = copy / db.name if path.is_dir() else copy
            connection = sqlite3.connect(target)
            try:
                connection.execute('PRAGMA wal_checkpoint(TRUNCATE)')
            finally:
                connection.close()
        _WAL_COPIES[key] = copy
    notes = [f"{db}: a write-ahead log (rosbag2's resilient preset, a recording that did not "
             f'end) holds messages the database does not yet: read from a copy with it applied'
             for db in logged]
    return _WAL_COPIES[key], notes


def _nonempty(file):
    return file.exists() and file.stat().st_size > 0


def _has_metadata(directory):
    # rosbag2 writes metadata.yaml when the recording ends: a crash while writing it can
    # leave it empty, which is no more than a missing one.
    return _nonempty(directory / 'metadata.yaml')


def _lone_storage_file(directory):
    """Return the one storage file of a bag directory without metadata.yaml (else BagError)."""
    files = sorted(p for p in directory.iterdir() if p.suffix in STORAGE_SUFFIXES)
    # rosbag2's file compression compresses each file of a split recording as it is closed.
    compressed = sorted(p for p in directory.iterdir()
                        if any(p.name.endswith(f'{suffix}.zstd') for suffix in STORAGE_SUFFIXES))
    if len(files) == 1 and not compressed:
        return files[0]
    if not files and not compressed:
        raise BagError(f'{directory}: no metadata.yaml and no storage file (.mcap, .db3): '
                       f'not a rosbag2 directory')
    names = ', '.join(p.name for p in files + compressed)
    unzip = ' (decompress the .zstd files first: zstd -d)' if compressed else ''
    raise BagError(f'{directory}: no metadata.yaml and {len(files) + len(compressed)} storage '
                   f'files ({names}): `ros2 bag reindex {directory}` writes it{unzip}; or give '
                   f'one of the files')


# MCAP opcodes (mcap.dev/spec), to name the record a file was cut in.
_MCAP_RECORDS = {0x01: 'header', 0x02: 'footer', 0x03: 'schema', 0x04: 'channel',
                 0x05: 'message', 0x06: 'chunk', 0x07: 'message index', 0x08: 'chunk index',
                 0x09: 'attachment', 0x0A: 'attachment index', 0x0B: 'statistics',
                 0x0C: 'metadata', 0x0D: 'metadata index', 0x0E: 'summary offset',
                 0x0F: 'data end'}
_MCAP_DATA_END = 0x0F


def data_extent(stream, size, block=1 << 16):
    """
    Return the offset after the last non-zero byte of a ``size``-byte file.

    A file system can leave the blocks a crash did not write as zeros, up to the file's
    recorded size: what lies in that run of zeros was never written.
    """
    end = size
    while end > 0:
        start = max(0, end - block)
        stream.seek(start)
        data = stream.read(end - start).rstrip(b'\0')
        if data:
            return start + len(data)
        end = start
    return 0


def _chunk_check(record, decompress):
    """
    Return ``(whole, checked)`` of a chunk record's content.

    ``whole``: it decompresses, checks and holds whole records; ``checked``: compressed or
    with a checksum, so that ``whole`` also shows no byte of it is missing (an uncompressed
    chunk without a checksum, rosbag2's default, shows nothing of the kind).
    """
    try:
        (_, _, size, crc), offset = struct.unpack_from('<QQQI', record, 0), 28
        (length,) = struct.unpack_from('<I', record, offset)
        compression = record[offset + 4:offset + 4 + length].decode()
        offset += 4 + length
        (compressed,) = struct.unpack_from('<Q', record, offset)
        data = record[offset + 8:offset + 8 + compressed]
        if len(data) != compressed:
            return False, False
        raw = decompress(bytes(data), compression, size, crc)
    except Exception:               # noqa: B902 - any failure: not a chunk that can be read
        return False, False
    checked = bool(compression) or bool(crc)
    position = 0
    while position < len(raw):
        if position + 9 > len(raw):
            return False, checked
        opcode, length = raw[position], int.from_bytes(raw[position + 1:position + 9], 'little')
        if opcode not in (0x03, 0x04, 0x05) or (opcode == 0x05 and length < 22) or \
                position + 9 + length > len(raw):
            return False, checked
        position += 9 + length
    return True, checked


def complete_records_end(stream, start, size, decompress=None):
    """
    Return ``(end, cut)`` of an MCAP data section read from ``start`` of a ``size``-byte file.

    ``end``: the offset after the last complete top-level record (records are an opcode, a
    little-endian uint64 length, then that many bytes), before a ``data end`` record or zero
    bytes, or before a record that cannot be whole: an unknown opcode, a message record
    shorter than its fixed fields, or (with ``decompress``, rosbags' chunk decoder) a chunk
    that does not decompress, fails its checksum or holds a broken record. A file system can
    leave the blocks a crash did not write as zeros up to the file's recorded size
    (``data_extent``): a record reaching into that run of zeros is taken as not written,
    unless it is a chunk whose compression or checksum shows it whole (an lz4 chunk ends in
    four zero bytes; a message ending in zeros, e.g. a camera_info's ``do_rectify`` false,
    before the run is left out: one message, never a corrupt one). ``cut``: the name of the
    record left out at ``end``, or None when the data section ends there.
    """
    extent = min(size, data_extent(stream, size))
    position = start
    while position + 9 <= size:
        stream.seek(position)
        head = stream.read(9)
        opcode, length = head[0], int.from_bytes(head[1:9], 'little')
        if opcode == 0 or opcode == _MCAP_DATA_END:
            return position, None
        name = _MCAP_RECORDS.get(opcode)
        end = position + 9 + length
        if name is None or end > size:
            return position, name or f'unknown record 0x{opcode:02x}'
        if opcode == 0x05 and length < 22:
            return position, 'message'
        if opcode == 0x06 and decompress is not None:
            whole, checked = _chunk_check(stream.read(length), decompress)
            if not whole or (end > extent and not checked):
                return position, 'chunk'
        elif end > extent:
            return position, name
        position = end
    return position, None if position == size else 'record header'


# Fields rosbags (0.11) takes as they are: a damaged metadata.yaml can make ``files`` a string
# that opens but breaks ``Reader.close`` (AttributeError; found by .ci/fuzz.py).
_LIST_FIELDS = ('relative_file_paths', 'files', 'topics_with_message_count')


def _metadata_shape_problem(metadata):
    """Return what is wrong with the shape of a metadata.yaml rosbags opened, or None."""
    import yaml
    try:
        document = yaml.safe_load(pathlib.Path(metadata).read_text(encoding='utf-8'))
        info = document['rosbag2_bagfile_information']
    except Exception:               # noqa: B902 - rosbags read it; a difference is no shape
        return None
    if not isinstance(info, dict):
        return None
    for field in _LIST_FIELDS:
        value = info.get(field)
        if value is not None and not isinstance(value, list):
            return f'field {field}: expected a list, got {type(value).__name__} {value!r:.40}'
        if field == 'files' and value and not all(isinstance(item, dict) for item in value):
            return 'field files: expected a list of mappings (path, starting_time, ...)'
    return None


def _close_quietly(reader):
    try:
        reader.close()
    except Exception:               # noqa: B902 - the bag is refused anyway; closing is cleanup
        pass


_DEFINITIONS_QUERY = 'FROM message_definitions'


def _skip_empty_definitions(cursor, statement, bindings):
    # Execution tracer of the connection rosbags' Sqlite3Reader._open makes: on its query of
    # message_definitions only, drop the rows rosbag2 left without a definition.
    # Any other query on the same cursor gets its rows untouched: rosbags asks MIN/MAX of the
    # timestamps on it next, whose one row of an empty bag, (None, None, 0), the definitions'
    # filter dropped ("not enough values to unpack" on an empty Iron/Jazzy sqlite3 bag).
    cursor.row_trace = (lambda _, row: row if row[1] else None) \
        if _DEFINITIONS_QUERY in statement else None
    return True


def _reader_class():
    """Return rosbags' Reader with the sqlite3 and MCAP readers of the module docstring."""
    import apsw
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.rosbag2.reader import DirectoryReader
    from rosbags.rosbag2 import storage_mcap
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    class _Sqlite3Reader(Sqlite3Reader):
        def _open(self):
            def hook(connection):
                connection.exec_trace = _skip_empty_definitions
            apsw.connection_hooks.append(hook)
            try:
                super()._open()
            finally:
                apsw.connection_hooks.remove(hook)

    class _McapReader(McapReader):
        cut_short_note = None

        def _open(self):
            try:
                super()._open()
            except (ReaderError, OSError) as error:
                # A file cut before its footer could be whole (37 bytes) fails the seek.
                short = isinstance(error, OSError) and self.data_start and \
                    self.bio.seek(0, 2) < self.data_start + 37
                if 'end magic' not in str(error) and not short:
                    raise
                self._open_cut_short()

        def _open_cut_short(self):
            # No footer: read the complete records of the data section, in file order (the
            # summary with the chunk index is written last, so it is gone too).
            size = self.bio.seek(0, 2)
            self.data_end, cut = complete_records_end(self.bio, self.data_start, size,
                                                      storage_mcap.decompress)
            self.meta_scan()
            counts = self.statistics.channel_message_counts
            self.connections = [c._replace(msgcount=counts.get(c.id, 0))
                                for c in self.connections]
            count = self.statistics.message_count
            self.metadata = self.metadata._replace(
                duration=self.statistics.end_time - self.statistics.start_time + 1
                if count else 0,
                start_time=self.statistics.start_time if count else 2 ** 63 - 1,
                end_time=self.statistics.end_time + 1 if count else 0, message_count=count)
            lost = f'; bytes {self.data_end} to {size} (an incomplete {cut} record) not read' \
                if cut else ''
            self.cut_short_note = (
                f'{self.path}: no MCAP footer (a recording that did not end, or a copy cut '
                f'short): {count} messages read from its complete records{lost}')

        def messages(self, *args, **kwargs):
            # Without a chunk index (a file cut short, or written unchunked: rosbag2's
            # fastwrite preset) rosbags scans, but refuses messages out of time order, which
            # a recorder writing in callback order produces; rosbag2's reader yields them in
            # file order, and so does this.
            if self.chunks:
                yield from super().messages(*args, **kwargs)
                return
            yield from self.messages_scan(*args, **kwargs)

    class _DirectoryReader(DirectoryReader):
        STORAGE_PLUGINS = {**DirectoryReader.STORAGE_PLUGINS, 'sqlite3': _Sqlite3Reader,
                           'mcap': _McapReader}

    class _Reader(Reader):
        STORAGE_PLUGINS = {**Reader.STORAGE_PLUGINS, 'dir': _DirectoryReader,
                           '.db3': _Sqlite3Reader, '.mcap': _McapReader}
    return _Reader


def _one_line(error):
    mark = getattr(error, 'problem_mark', None) or getattr(
        getattr(error, '__cause__', None), 'problem_mark', None)
    where = f'line {mark.line + 1}: ' if mark is not None else ''
    cause = error.__cause__ or error.__context__
    text = str(error) or type(error).__name__
    if cause is not None and str(cause) not in text:
        text += f' ({type(cause).__name__}: {cause})'
    return where + ' '.join(text.split())


def normalized_msgtype(msgtype):
    """
    Return ``pkg/msg/Name`` for a recorded type name (``pkg/Name`` is the old spelling).

    ValueError for anything else.
    """
    if not isinstance(msgtype, str):      # e.g. a number in a damaged metadata.yaml
        raise ValueError(f'message type {msgtype!r}: expected pkg/msg/Name or pkg/Name, got '
                         f'a {type(msgtype).__name__}')
    parts = msgtype.split('/')
    # Each part a name (found by .ci/fuzz.py: '.pkg/msg/X' was a relative import, TypeError).
    if len(parts) in (2, 3) and all(_NAME.fullmatch(part) for part in parts):
        return msgtype if len(parts) == 3 else f'{parts[0]}/msg/{parts[1]}'
    raise ValueError(f'message type {msgtype!r}: expected pkg/msg/Name or pkg/Name')


def message_class(msgtype):
    """Return the rclpy class of a message type; ImportError names the package to install."""
    package, kind, name = normalized_msgtype(msgtype).split('/')
    try:
        return getattr(importlib.import_module(f'{package}.{kind}'), name)
    except (ImportError, AttributeError):
        raise ImportError(f'message type {msgtype}: not installed (install the ROS package '
                          f'{package}, e.g. ros-jazzy-{package.replace("_", "-")})') from None


def bag_messages(reader, connections=None):
    """
    Yield ``(connection, timestamp_ns, data)`` of an open rosbags ``Reader``, in bag order.

    ``connections`` (the reader's, default all) selects topics; storage-file connections are
    matched to them by topic and type (see the module docstring); message-compressed bags are
    decompressed. Readers of a single storage file are read as rosbags does.
    """
    wanted = list(connections) if connections is not None else list(reader.connections)
    if not wanted:                  # rosbags reads an empty selection as every connection
        return
    storages = getattr(reader.storage, 'storages', None)
    if storages is None:
        # A storage file read alone (no metadata.yaml) does not say whether rosbag2
        # compressed each message: a zstd frame is not CDR (which starts 00 00 or 00 01).
        decompress = None
        for connection, timestamp, data in reader.messages(connections=wanted):
            if bytes(data[:4]) == _ZSTD_MAGIC:
                decompress = decompress or _zstd_decompress()
                data = decompress(bytes(data))
            yield connection, timestamp, data
        return
    decompress = _zstd_decompress() if reader.compression_mode == 'message' else None
    for storage in storages:
        matched = {}
        for stored in storage.connections:
            for connection in wanted:
                if connection.topic == stored.topic and \
                        normalized_msgtype(connection.msgtype) == \
                        normalized_msgtype(stored.msgtype):
                    matched[stored.id] = connection
                    break
        stored_connections = [c for c in storage.connections if c.id in matched]
        if not stored_connections:
            continue
        for stored, timestamp, data in storage.messages(stored_connections):
            yield matched[stored.id], timestamp, decompress(data) if decompress else data


def _zstd_decompress():
    # The zstd module rosbags itself uses (the standard library's from Python 3.14).
    try:
        from compression import zstd
    except ImportError:
        from backports import zstd
    return zstd.decompress
