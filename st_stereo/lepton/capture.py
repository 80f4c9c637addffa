"""
Raw VoSPI captures: the bytes exactly as read, with host timestamps, and their replay.

Format (little-endian): magic ``STLEPCAP``, version (u16), header length (u32), a JSON header
(packet_bytes, telemetry, spi_hz, ...), then records: ``b'R'`` + time (f64) + length (u32) +
bytes for a read, ``b'I'`` + time (f64) + seconds (f64) for an idle. A plain file of
concatenated SPI bytes (no header, no stamps), as other tools write, replays too: its times are
synthesised from the byte position at the given SPI clock.
"""

import json
import math
import os
import re
import struct

import numpy as np

from st_stereo.lepton.assembler import TELEMETRY_MODES
from st_stereo.lepton.packets import packet_crc, RAW14_PACKET_BYTES, RGB888_PACKET_BYTES
from st_stereo.lepton.reader import EndOfStream, LeptonReader
from st_stereo.lepton.telemetry import parse_telemetry_row_a

MAGIC = b'STLEPCAP'
VERSION = 1
READ_RECORD = struct.Struct('<cdI')
IDLE_RECORD = struct.Struct('<cdd')


class CaptureError(ValueError):
    """A capture file is missing, truncated, garbage, or in an unsupported mode."""


class CaptureWriter:
    """Append reads and idles of a transport to a capture file."""

    def __init__(self, path, header):
        self.path = os.fspath(path)
        self._stream = open(self.path, 'wb')
        text = json.dumps(dict(header)).encode('utf-8')
        self._stream.write(MAGIC + struct.pack('<HI', VERSION, len(text)) + text)

    def read(self, stamp, data):
        """Record one read."""
        self._stream.write(READ_RECORD.pack(b'R', stamp, len(data)) + data)

    def idle(self, stamp, seconds):
        """Record an idle period: a resync or a pause."""
        self._stream.write(IDLE_RECORD.pack(b'I', stamp, seconds))

    def close(self):
        """Flush and close."""
        self._stream.close()


class RecordingTransport:
    """Wrap a transport and record every read and idle of it, unchanged."""

    def __init__(self, inner, writer):
        self.inner = inner
        self.writer = writer
        self.packet_bytes = inner.packet_bytes
        self.max_read_bytes = inner.max_read_bytes
        self.seconds_per_byte = inner.seconds_per_byte

    def now(self):
        """Time of the wrapped transport."""
        return self.inner.now()

    def read(self, nbytes):
        """Read through and record."""
        stamp = self.inner.now()
        data = self.inner.read(nbytes)
        self.writer.read(stamp, data)
        return data

    def idle(self, seconds):
        """Idle through and record."""
        self.writer.idle(self.inner.now(), seconds)
        self.inner.idle(seconds)

    def wait(self, seconds):
        """Pause through and record as an idle."""
        self.writer.idle(self.inner.now(), seconds)
        self.inner.wait(seconds)


class PlainByteWriter:
    """A RecordingTransport sink writing only the bytes read, concatenated (as other tools do)."""

    def __init__(self, path):
        self.path = path
        self.chunks = []

    def read(self, stamp, data):
        """Keep the bytes of one read."""
        self.chunks.append(data)

    def idle(self, stamp, seconds):
        """Plain captures keep no timing."""

    def close(self):
        """Write the bytes to the file."""
        with open(self.path, 'wb') as stream:
            stream.write(b''.join(self.chunks))


def record_camera(camera, path, seconds, telemetry='off', plain=False, source='st_stereo'):
    """
    Read ``seconds`` of a camera (a simulator's clock) with the reader, writing a capture.

    ``plain``: the bytes only (``PlainByteWriter``), else this package's record format with
    its header. Returns the reader's counters.
    """
    writer = PlainByteWriter(path) if plain else CaptureWriter(
        path, {'packet_bytes': camera.packet_bytes, 'telemetry': telemetry, 'spi_hz': 20e6,
               'source': source})
    reader = LeptonReader(RecordingTransport(camera, writer), telemetry=telemetry,
                          frame_gap_wait=not plain)
    try:
        while camera.now() < seconds:
            reader.read_frame(timeout_s=1.0)
    finally:
        writer.close()
    return reader.counters.as_dict()


def read_capture(path):
    """
    Load a capture: (header dict, byte stream, per-byte-offset read times, damaged bytes).

    A file without the magic is taken as plain concatenated SPI bytes (header {}, no times).
    Records damaged by lost or extra bytes are passed over: parsing resumes at the next offset
    where two plausible records follow each other (or one ends the file), and a truncated last
    record is dropped; every byte passed over is counted in ``damaged bytes``.

    Raises
    ------
    CaptureError
        Missing file, bad header (see ``header_settings``), or no intact record at all.

    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise CaptureError(f'{path}: no such capture file')
    with open(path, 'rb') as stream:
        return parse_capture(stream.read(), path)


def parse_capture(blob, path='<capture>'):
    """Parse the bytes of a capture as ``read_capture`` does; errors name ``path``."""
    if not blob.startswith(MAGIC):
        return {}, blob, None, 0
    offset = len(MAGIC)
    if len(blob) < offset + 6:
        raise CaptureError(f'{path}: truncated header')
    version, length = struct.unpack_from('<HI', blob, offset)
    if version != VERSION:
        raise CaptureError(f'{path}: capture version {version}, this reader knows {VERSION}')
    offset += 6
    try:
        header = json.loads(blob[offset:offset + length].decode('utf-8'))
    except (ValueError, RecursionError):     # also UnicodeDecodeError, JSONDecodeError,
        # and the int() of a number of more than 4300 digits
        raise CaptureError(f'{path}: unreadable capture header') from None
    if not isinstance(header, dict):
        raise CaptureError(f'{path}: capture header: expected a JSON object, got '
                           f'{type(header).__name__}')
    header_settings(path, header)
    offset += length
    chunks, starts, offsets = [], [], []
    total = damaged = 0
    last_stamp = None
    first_problem = None
    while offset < len(blob):
        record = _plausible_record(blob, offset, last_stamp)
        # A plausible record is kept when the next one chains to it, or when the damage is
        # after it: no chained record starts inside it.
        if record is not None and (record[2] == len(blob) or _plausible_record(
                blob, record[2], record[1]) is not None or
                _next_record(blob, offset + 1, last_stamp, record[2]) >= record[2]):
            kind, last_stamp, end = record
            if kind == b'R':
                chunks.append(blob[offset + READ_RECORD.size:end])
                starts.append(last_stamp)
                offsets.append(total)
                total += end - offset - READ_RECORD.size
            offset = end
            continue
        if first_problem is None:
            first_problem = _record_problem(blob, offset)
        resume = _next_record(blob, offset + 1, last_stamp)
        damaged += resume - offset
        offset = resume
    if not chunks:
        raise CaptureError(f'{path}: no intact read record'
                           + (f' ({first_problem})' if first_problem else ''))
    return header, b''.join(chunks), (np.array(offsets), np.array(starts)), damaged


MAX_RECORD_BYTES = 1 << 24      # far above any SPI read (the reader reads a frame at most)
MAX_IDLE_S = 3600.0


def _plausible_record(blob, offset, last_stamp):
    """Return (kind, stamp, end offset) of a well-formed record at ``offset``, else None."""
    kind = blob[offset:offset + 1]
    if kind == b'R':
        if offset + READ_RECORD.size > len(blob):
            return None
        _, stamp, size = READ_RECORD.unpack_from(blob, offset)
        end = offset + READ_RECORD.size + size
        if not 0 < size <= MAX_RECORD_BYTES or end > len(blob):
            return None
    elif kind == b'I':
        if offset + IDLE_RECORD.size > len(blob):
            return None
        _, stamp, seconds = IDLE_RECORD.unpack_from(blob, offset)
        end = offset + IDLE_RECORD.size
        if not 0.0 <= seconds <= MAX_IDLE_S:        # also false for NaN
            return None
    else:
        return None
    if not math.isfinite(stamp) or last_stamp is not None and \
            not last_stamp - 1.0 <= stamp <= last_stamp + MAX_IDLE_S:
        return None
    return kind, stamp, end


def _record_problem(blob, offset):
    kind = blob[offset:offset + 1]
    if kind not in (b'R', b'I'):
        return f'unknown record type {kind!r} at byte {offset}'
    record = READ_RECORD if kind == b'R' else IDLE_RECORD
    if offset + record.size > len(blob):
        return f'truncated {"read" if kind == b"R" else "idle"} record at byte {offset}'
    if kind == b'R':
        size = READ_RECORD.unpack_from(blob, offset)[2]
        present = len(blob) - offset - READ_RECORD.size
        if size > present:
            return (f'truncated read record at byte {offset} ({size} bytes announced, '
                    f'{present} present)')
    return f'implausible record at byte {offset}'


_RECORD_KIND = re.compile(b'[RI]')


def _next_record(blob, offset, last_stamp, limit=None):
    """Offset of the next place before ``limit`` where plausible records chain, else limit."""
    limit = len(blob) if limit is None else min(limit, len(blob))
    while True:
        found = _RECORD_KIND.search(blob, offset, limit)
        if found is None:
            return limit
        offset = found.start()
        record = _plausible_record(blob, offset, last_stamp)
        if record is not None and (record[2] == len(blob) or _plausible_record(
                blob, record[2], record[1]) is not None):
            return offset
        offset += 1


def valid_packet_starts(data, start=0, stop=None, packet_bytes=RAW14_PACKET_BYTES):
    """
    Byte offsets in ``[start, stop)`` where a video packet with a valid CRC begins.

    Any alignment; discards (no CRC) and packet numbers >= 63 are not counted, nor is a packet
    whose CRC field is 0: a window of zeros has a trivially valid CRC (CRC-16/XMODEM of zeros
    is 0), zero-filled discards hold such windows at every offset, and a discard followed by
    a packet 0 (ID 0x0000) holds one 2 bytes before the real packet 0. A real packet has CRC 0
    once in 65,536; a search for packet boundaries then takes the next packet. Candidates are
    found with numpy; only they are CRC-checked.
    """
    last = len(data) - packet_bytes
    stop = last + 1 if stop is None else min(stop, last + 1)
    if stop <= start:
        return np.zeros(0, dtype=np.int64)
    view = memoryview(data)
    head = np.frombuffer(view[start:stop + 3], dtype=np.uint8)
    count = stop - start
    candidates = np.flatnonzero(((head[:count] & 0x0F) == 0) & (head[1:count + 1] < 63) &
                                ((head[2:count + 2] | head[3:count + 3]) != 0)) + start
    return np.array([offset for offset in candidates.tolist()
                     if packet_crc(view[offset:offset + packet_bytes]) ==
                     ((data[offset + 2] << 8) | data[offset + 3])], dtype=np.int64)


def next_valid_packet(data, position, packet_bytes=RAW14_PACKET_BYTES):
    """
    Byte offset >= ``position`` of the next video packet with a valid CRC (any alignment).

    Returns ``len(data)`` when there is none (see ``valid_packet_starts``). This is how a
    decoder finds packet boundaries again after lost or extra bytes, as a live reader does
    after a resync. Searched in blocks that double in size (the next packet is usually near).
    """
    start, block = position, 4 * packet_bytes
    while start <= len(data) - packet_bytes:
        found = valid_packet_starts(data, start, start + block, packet_bytes)
        if len(found):
            return int(found[0])
        start, block = start + block, min(2 * block, 1 << 20)
    return len(data)


DETECT_BYTES = 4 << 20      # 4 MB from the first packet (over 400 frames) decide the mode


def detect_telemetry_mode(data, packet_bytes=RAW14_PACKET_BYTES):
    """
    Telemetry mode of a stream: 'off' (60 packets a frame), 'header' or 'footer' (63).

    Every CRC-valid packet that continues a sequence (the one a packet length before it is
    valid and numbered one less) counts, at whatever byte alignment: lost or extra bytes may
    shift the stream at any point. Packets numbered 60-62 mean telemetry; then row A holds a
    frame counter that never decreases from frame to frame: the mode is the one whose
    candidate row A (packet 0 or packet 60) behaves so.

    Raises
    ------
    CaptureError
        When the stream holds no valid video packet at all, or too few frames to tell a
        telemetry header from a footer.

    """
    first = next_valid_packet(data, 0, packet_bytes)
    if first >= len(data):
        raise CaptureError('no valid Lepton packet found (not a VoSPI Raw14 stream?)')
    starts = valid_packet_starts(data, first, first + DETECT_BYTES, packet_bytes)
    numbers = np.array([((data[s] << 8) | data[s + 1]) & 0x0FFF for s in starts.tolist()],
                       dtype=np.int64)
    index = dict(zip(starts.tolist(), numbers.tolist()))
    follows = np.array([index.get(start - packet_bytes, -2) == number - 1
                        for start, number in zip(starts.tolist(), numbers.tolist())], dtype=bool)
    if not (follows & (numbers >= 60)).any():
        return 'off'
    scores = {}
    for mode, row in (('header', 0), ('footer', 60)):
        rows = starts[(numbers == row) & (follows if row else True)].tolist()
        counters = [parse_telemetry_row_a(data[s + 4:s + packet_bytes]).frame_counter
                    for s in rows]
        steps = np.diff(counters) if len(counters) > 1 else np.zeros(0)
        scores[mode] = float(np.mean((steps >= 0) & (steps <= 3))) if len(steps) else 0.0
    if scores['header'] == scores['footer']:
        raise CaptureError('telemetry is on, but too few frames to tell a header from a footer: '
                           'give the mode (--telemetry header or footer)')
    return max(scores, key=scores.get)


class ReplayTransport:
    """Replay a byte stream through the reader; stamps from the recorded read times."""

    def __init__(self, data, times=None, spi_hz=20e6, packet_bytes=RAW14_PACKET_BYTES,
                 start_offset=0):
        self.data = data
        self.position = start_offset
        self.times = times
        self.packet_bytes = packet_bytes
        self.max_read_bytes = 1 << 20
        self.seconds_per_byte = 8.0 / spi_hz
        self._clock = 0.0
        self.skipped_bytes = 0           # bytes never read: passed over to find boundaries
        self._search_from = 0            # the next search starts past the last packet found
        self._read_up_to = start_offset  # end of the furthest read (re-reads are not skips)
        self._record_starts = set(times[0].tolist()) if times is not None else None

    def now(self):
        """Time of the byte about to be read (recorded, or synthesised)."""
        if self.times is None:
            return self.position * self.seconds_per_byte + self._clock
        offsets, starts = self.times
        index = int(np.searchsorted(offsets, self.position, side='right')) - 1
        if index < 0:
            return float(starts[0]) + self._clock
        return float(starts[index] + (self.position - offsets[index]) * self.seconds_per_byte
                     ) + self._clock

    def _record_end(self):
        offsets = self.times[0]
        index = int(np.searchsorted(offsets, self.position, side='right'))
        return int(offsets[index]) if index < len(offsets) else len(self.data)

    def read(self, nbytes):
        """Return the next bytes of the stream, never across a recorded read; fewer at the end."""
        end = self.position + nbytes
        if self.times is not None:
            end = min(end, self._record_end())
        chunk = self.data[self.position:end]
        self.position += len(chunk)
        self._read_up_to = max(self._read_up_to, self.position)
        return chunk

    def unread(self, nbytes):
        """
        Take back the last ``nbytes`` read (the reader did not use them).

        Plain byte files only: a capture with recorded reads replays the live reader exactly
        (it dropped those bytes too, and resumed where the next recorded read starts).
        """
        if self.times is None:
            self.position -= min(nbytes, self.position)

    def idle(self, seconds):
        """
        Skip to where the live reader resumed after a resync or pause.

        A recording holds what followed the idle; the bytes of the current read that the live
        reader dropped when it resynchronised are skipped, as they were live. For synthesised
        times only the clock moves on.
        """
        if self.times is not None:
            if self.position not in self._record_starts:
                self.position = self._record_end()
            return
        self._clock += seconds
        # Plain bytes: lost or extra bytes shift every packet after them: resume at the next
        # packet with a valid CRC, whatever its byte offset (every byte skipped counted).
        # The search may start a little before bytes already read (see ``unread``), never at
        # or before the packet the last search found: every search moves on.
        start = max(self.position, self._search_from)
        found = next_valid_packet(self.data, start, self.packet_bytes)   # end when none
        self.skipped_bytes += max(found - max(start, self._read_up_to), 0)
        self.position = found
        self._search_from = found + 1

    def wait(self, seconds):
        """As ``idle``."""
        self.idle(seconds)


def header_settings(path, header):
    """
    Check a capture header's fields: {'telemetry': mode or None, 'spi_hz': Hz}.

    CaptureError names the file, the field, what was expected and what was found; RGB888 and
    packet sizes other than Raw14's are refused.
    """
    packet_bytes = header.get('packet_bytes', RAW14_PACKET_BYTES)
    if packet_bytes == RGB888_PACKET_BYTES or header.get('format') == 'rgb888':
        raise CaptureError(f'{path}: RGB888 video (244-byte packets) is not supported: set the '
                           f'camera to Raw14')
    if packet_bytes != RAW14_PACKET_BYTES:
        raise CaptureError(f'{path}: header field packet_bytes: only Raw14 '
                           f'({RAW14_PACKET_BYTES}) is supported, got {packet_bytes!r}')
    telemetry = header.get('telemetry')
    if telemetry is not None and telemetry not in TELEMETRY_MODES:
        raise CaptureError(f'{path}: header field telemetry: expected one of '
                           f'{", ".join(TELEMETRY_MODES)}, got {telemetry!r}')
    spi_hz = header.get('spi_hz', 20e6)
    if isinstance(spi_hz, bool) or not isinstance(spi_hz, (int, float)) or \
            not 1e5 <= spi_hz <= 1e8:
        raise CaptureError(f'{path}: header field spi_hz: expected a clock of 0.1 to 100 MHz, '
                           f'got {spi_hz!r}')
    return {'telemetry': telemetry, 'spi_hz': float(spi_hz)}


def decode_capture(path, telemetry=None, spi_hz=None):
    """
    Decode every unique frame of a capture (ours or plain SPI bytes).

    Returns
    -------
    frames : list of LeptonFrame
    counters : dict
    telemetry : str
        The mode used (given, from the header, or detected).

    """
    return decode_parsed_capture(read_capture(path), path, telemetry, spi_hz)


def replay_reader(capture, path='<capture>', telemetry=None, spi_hz=None):
    """
    Return ``(reader, transport, mode)`` replaying a parsed capture (``parse_capture``).

    The telemetry mode is ``telemetry`` when given, else the header's, else detected from the
    data; a plain byte file starts at its first CRC-valid packet.
    """
    header, data, times, _ = capture
    settings = header_settings(path, header)
    if len(data) < RAW14_PACKET_BYTES:
        raise CaptureError(f'{path}: {len(data)} bytes: shorter than one packet')
    try:
        mode = telemetry or settings['telemetry'] or detect_telemetry_mode(data)
    except CaptureError as error:
        raise CaptureError(f'{path}: {error}') from None
    start = 0 if times is not None else next_valid_packet(data, 0)
    transport = ReplayTransport(data, times, spi_hz or settings['spi_hz'], start_offset=start)
    reader = LeptonReader(transport, telemetry=mode, frame_gap_wait=False, no_video_s=1e9)
    return reader, transport, mode


def decode_parsed_capture(capture, path='<capture>', telemetry=None, spi_hz=None):
    """Decode a parsed capture (``parse_capture``'s result) as ``decode_capture`` does."""
    reader, transport, mode = replay_reader(capture, path, telemetry, spi_hz)
    frames = []
    try:
        while True:
            frame = reader.read_frame(timeout_s=1e9)
            if frame is None:
                break
            frames.append(frame)
    except EndOfStream:
        pass
    counters = reader.counters.as_dict()
    counters['bytes_skipped_realigning'] = transport.skipped_bytes
    counters['capture_bytes_damaged'] = capture[3]
    return frames, counters, mode


def save_frames_npz(path, frames, counters, telemetry_mode):
    """Write decoded frames, stamps, telemetry fields and counters to an .npz file."""
    pixels = np.stack([f.pixels for f in frames]) if frames else np.zeros((0, 60, 80),
                                                                          np.uint16)
    fields = {'frames': pixels, 'stamps': np.array([f.stamp for f in frames]),
              'ffc_in_progress': np.array([f.ffc_in_progress for f in frames]),
              'counters': np.array(json.dumps(counters)),
              'telemetry_mode': np.array(telemetry_mode)}
    if frames and frames[0].telemetry is not None:
        fields['frame_counter'] = np.array([f.telemetry.frame_counter for f in frames])
        fields['fpa_temperature_k'] = np.array([f.telemetry.fpa_temperature_k for f in frames])
        fields['ffc_state'] = np.array([f.telemetry.ffc_state for f in frames])
    np.savez_compressed(path, **fields)
