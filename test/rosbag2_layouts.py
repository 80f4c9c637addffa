"""
rosbag2 bags in the on-disk layout ``ros2 bag record`` wrote, one per metadata version (tests).

Written WITHOUT rosbags (whose reader is under test): ``metadata.yaml`` text as rosbag2's
yaml-cpp emitter wrote it, sqlite3 files with the stdlib ``sqlite3`` and the tables rosbag2's
sqlite3 plugin created, MCAP files with the official ``mcap`` package and the records
rosbag2_storage_mcap wrote, message bytes from ``rclpy.serialization.serialize_message``,
compression with ``zstandard`` (rosbag2_compression_zstd: one zstd frame per message or file).

Sources each layout follows (ros2/rosbag2 unless named):

- ``metadata.yaml``: ``rosbag2_storage/include/rosbag2_storage/yaml.hpp`` (``encode``: key
  names and order; ``decode``: which version added what: 5 ``files``, 6 ``custom_data``,
  7 ``type_description_hash``, 8 ``ros_distro``, 9 ``offered_qos_profiles`` as a YAML sequence
  with policy names). Version 4 follows a bag rosbag2 itself wrote then
  (``rosbag2_cpp/test/rosbag2_cpp/reindex_test_bags/target_metadata/*/metadata.yaml``, 2020:
  ``relative_file_paths`` right after ``storage_identifier``, the QoS as YAML text in a
  string, Fast-DDS's Foxy "infinite" 2147483647 s 4294967295 ns).
- QoS text: ``rosbag2_storage/src/rosbag2_storage/qos.cpp`` (``serialize_rclcpp_qos_vector``:
  ``YAML::Dump`` of the profiles; integers before version 9, ``rmw_qos_*_policy_to_str``
  names from 9; durations ``{sec, nsec}``; the Foxy infinities it still translates on read).
- sqlite3: ``rosbag2_storage_sqlite3/src/rosbag2_storage_sqlite3/sqlite_storage.cpp``
  (``initialize``; ``read_db_schema_version``: schema 2 = ``topics.offered_qos_profiles``
  without a ``schema`` table, 3 = ``schema`` and ``metadata`` tables (#1156, backported to
  Humble 0.15.4), 4 = ``message_definitions`` and ``topics.type_description_hash``
  (0.22.0, Iron); the ``metadata`` table filled by ``update_metadata`` from Iron 0.22.2).
- MCAP: ``rosbag2_storage_mcap/src/mcap_storage.cpp`` (profile ``ros2``; one schema per type:
  name = the type, encoding ``ros2msg``; one channel per topic, encoding ``cdr``, metadata
  ``offered_qos_profiles`` and from 0.22.0 ``topic_type_hash``; log and publish time = the
  receive time; from 0.19 a metadata record ``rosbag2`` with ``serialized_metadata``, and in
  Iron 0.22.2 one with ``ROS_DISTRO``; zstd chunks before 0.5.0, uncompressed after).
- Compression: ``rosbag2_compression/src/rosbag2_compression/sequential_compression_writer.cpp``
  (``compression_format: zstd``, ``compression_mode: FILE`` or ``MESSAGE``; in FILE mode each
  closed storage file becomes ``<file>.zstd`` and the file list names the compressed file).
"""

import dataclasses
import json
import sqlite3

from mcap.writer import CompressionType, Writer as McapWriter
from rclpy.serialization import serialize_message
import zstandard

# Which distribution wrote each metadata version by default (docs/bags.md has the sources).
DISTRO = {4: 'foxy', 5: 'humble', 6: 'rolling', 7: 'rolling', 8: 'iron', 9: 'jazzy'}

# rmw's "infinite" duration as the recorder stored it: Fast-DDS on Foxy, and
# RMW_DURATION_INFINITE from Galactic on (qos.cpp lists both).
FOXY_INFINITE = (2147483647, 4294967295)
INFINITE = (9223372036, 854775807)

# rmw enum values (integers before version 9) and their rmw_qos_*_policy_to_str names (9).
HISTORY = {3: 'unknown', 1: 'keep_last', 2: 'keep_all', 0: 'system_default'}
RELIABILITY = {1: 'reliable', 2: 'best_effort', 0: 'system_default', 3: 'unknown'}
DURABILITY = {1: 'transient_local', 2: 'volatile', 0: 'system_default', 3: 'unknown'}
LIVELINESS = {1: 'automatic', 3: 'manual_by_topic', 0: 'system_default', 4: 'unknown'}

# Message definitions as rosbag2 stores them (the .msg text, dependencies after a separator
# line and "MSG: <type>"); comments left out here, their text is not read by any player.
DEFINITIONS = {
    'std_msgs/msg/String': 'string data\n',
    'sensor_msgs/msg/Image': (
        'std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n'
        'uint8 is_bigendian\nuint32 step\nuint8[] data\n' + '=' * 80 +
        '\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n' + '=' * 80 +
        '\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n'),
    'sensor_msgs/msg/CameraInfo': (
        'std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n'
        'float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n'
        'uint32 binning_y\nRegionOfInterest roi\n' + '=' * 80 +
        '\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n' + '=' * 80 +
        '\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n' + '=' * 80 +
        '\nMSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\n'
        'uint32 height\nuint32 width\nbool do_rectify\n'),
    'acme_msgs/msg/Thing': 'int32 value\n',
}
# RIHS01 type hashes as rclpy (Jazzy) reports them for the publishers of these types.
TYPE_HASHES = {
    'std_msgs/msg/String':
        'RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18',
    'sensor_msgs/msg/Image':
        'RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47',
    'sensor_msgs/msg/CameraInfo':
        'RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275',
    'acme_msgs/msg/Thing':
        'RIHS01_' + '0' * 64,
}


@dataclasses.dataclass
class Offered:
    """One offered QoS profile as the recorder discovered it (no history or depth)."""

    reliability: int = 1          # reliable
    durability: int = 2           # volatile
    lifespan_s: int = None        # None: infinite
    history: int = 3              # unknown: discovery does not carry it
    depth: int = 0


@dataclasses.dataclass
class Topic:
    """A recorded topic: its name, type as written, messages (rclpy) and offered QoS."""

    name: str
    msgtype: str
    messages: list
    offered: list = dataclasses.field(default_factory=lambda: [Offered()])
    definition_found: bool = True   # False: rosbag2 left the definition empty

    @property
    def full_type(self):
        parts = self.msgtype.split('/')
        return self.msgtype if len(parts) == 3 else f'{parts[0]}/msg/{parts[1]}'


# --- the QoS text ---------------------------------------------------------------------------
def _qos_profiles(topic, version):
    """Return the offered profiles as yaml-cpp nodes (dicts) of ``version``."""
    infinite = FOXY_INFINITE if version == 4 else INFINITE
    profiles = []
    for offered in topic.offered:
        lifespan = infinite if offered.lifespan_s is None else (offered.lifespan_s, 0)

        def policy(value, names):
            return names[value] if version >= 9 else value
        profiles.append({
            'history': policy(offered.history, HISTORY),
            'depth': offered.depth,
            'reliability': policy(offered.reliability, RELIABILITY),
            'durability': policy(offered.durability, DURABILITY),
            'deadline': {'sec': infinite[0], 'nsec': infinite[1]},
            'lifespan': {'sec': lifespan[0], 'nsec': lifespan[1]},
            'liveliness': policy(1, LIVELINESS),
            'liveliness_lease_duration': {'sec': infinite[0], 'nsec': infinite[1]},
            'avoid_ros_namespace_conventions': False,
        })
    return profiles


def qos_text(topic, version):
    """Return the QoS as ``serialize_rclcpp_qos_vector`` wrote it (YAML::Dump, no newline)."""
    profiles = _qos_profiles(topic, version)
    if not profiles:
        return '[]' if version >= 9 else ''
    return '\n'.join(_block(profile, 0, sequence_item=True) for profile in profiles)


# --- a small yaml-cpp style block emitter ------------------------------------------------
def _scalar(value):
    if value is True or value is False:
        return 'true' if value else 'false'
    if value is None:
        return '~'
    if isinstance(value, int):
        return str(value)
    if value == '' or '\n' in value:
        return json.dumps(value)        # yaml-cpp double-quotes these, with \n escapes
    return value


def _block(node, indent, sequence_item=False):
    """Emit a dict as yaml-cpp does (2 spaces a level, sequences indented under keys)."""
    lines = []
    pad = ' ' * indent
    first = True
    for key, value in node.items():
        lead = (pad + '- ') if sequence_item and first else (pad + '  ' if sequence_item
                                                             else pad)
        first = False
        inner = len(lead)
        if isinstance(value, dict) and value:
            lines.append(f'{lead}{key}:')
            lines.append(_block(value, inner + 2))
        elif isinstance(value, dict):
            lines.append(f'{lead}{key}: ~')
        elif isinstance(value, list) and value:
            lines.append(f'{lead}{key}:')
            for item in value:
                if isinstance(item, dict):
                    lines.append(_block(item, inner + 2, sequence_item=True))
                else:
                    lines.append(f'{" " * (inner + 2)}- {_scalar(item)}')
        elif isinstance(value, list):
            lines.append(f'{lead}{key}: []')
        else:
            lines.append(f'{lead}{key}: {_scalar(value)}')
    return '\n'.join(lines)


# --- metadata -----------------------------------------------------------------------------
def bag_metadata(version, storage, topics, counts, files, compression, custom_data=None):
    """Return the BagMetadata node (a dict in yaml-cpp ``encode`` key order) of a version."""
    stamps = [f['start'] for f in files]
    ends = [f['start'] + f['duration'] for f in files]
    start, end = min(stamps), max(ends)
    topic_nodes = []
    for topic in topics:
        meta = {'name': topic.name, 'type': topic.msgtype, 'serialization_format': 'cdr'}
        if version >= 9:
            meta['offered_qos_profiles'] = _qos_profiles(topic, version)
        else:
            meta['offered_qos_profiles'] = qos_text(topic, version)
        if version >= 7:
            meta['type_description_hash'] = TYPE_HASHES[topic.full_type]
        topic_nodes.append({'topic_metadata': meta, 'message_count': counts[topic.name]})
    mode, fmt = {None: ('', ''), 'file': ('FILE', 'zstd'),
                 'message': ('MESSAGE', 'zstd')}[compression]
    paths = [f['path'] for f in files]
    node = {'version': version, 'storage_identifier': storage}
    if version == 4:       # the Foxy-era encoder: file paths second, no per-file list
        node['relative_file_paths'] = paths
    node.update({'duration': {'nanoseconds': end - start},
                 'starting_time': {'nanoseconds_since_epoch': start},
                 'message_count': sum(counts.values()),
                 'topics_with_message_count': topic_nodes,
                 'compression_format': fmt, 'compression_mode': mode})
    if version >= 5:
        node['relative_file_paths'] = paths
        node['files'] = [{'path': f['path'],
                          'starting_time': {'nanoseconds_since_epoch': f['start']},
                          'duration': {'nanoseconds': f['duration']},
                          'message_count': f['count']} for f in files]
    if version >= 6:
        node['custom_data'] = dict(custom_data or {})
    if version >= 8:
        node['ros_distro'] = DISTRO[version]
    return node


def metadata_yaml(node):
    """Return ``metadata.yaml`` as MetadataIo::write_metadata wrote it."""
    return _block({'rosbag2_bagfile_information': node}, 0) + '\n'


# --- storage files ------------------------------------------------------------------------
def sqlite_schema_version(version):
    """Return the sqlite3 schema rosbag2 created alongside a metadata version."""
    return {4: 2, 5: 3, 6: 3, 7: 4, 8: 4, 9: 4}[version]


def write_sqlite(path, version, topics, rows, metadata_node):
    """Write one ``.db3`` as rosbag2_storage_sqlite3 (or _default_plugins) created it."""
    schema = sqlite_schema_version(version)
    db = sqlite3.connect(path)
    if schema >= 3:
        db.execute('CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,'
                   'ros_distro TEXT NOT NULL);')
        db.execute('CREATE TABLE metadata(id INTEGER PRIMARY KEY,'
                   'metadata_version INTEGER NOT NULL,metadata TEXT NOT NULL);')
    columns = ('id INTEGER PRIMARY KEY,name TEXT NOT NULL,type TEXT NOT NULL,'
               'serialization_format TEXT NOT NULL,offered_qos_profiles TEXT NOT NULL')
    if schema >= 4:
        columns += ',type_description_hash TEXT NOT NULL'
    db.execute(f'CREATE TABLE topics({columns});')
    if schema >= 4:
        db.execute('CREATE TABLE message_definitions(id INTEGER PRIMARY KEY,'
                   'topic_type TEXT NOT NULL,encoding TEXT NOT NULL,'
                   'encoded_message_definition TEXT NOT NULL,'
                   'type_description_hash TEXT NOT NULL);')
    db.execute('CREATE TABLE messages(id INTEGER PRIMARY KEY,topic_id INTEGER NOT NULL,'
               'timestamp INTEGER NOT NULL, data BLOB NOT NULL);')
    db.execute('CREATE INDEX timestamp_idx ON messages (timestamp ASC);')
    if schema >= 3:
        db.execute('INSERT INTO schema (schema_version, ros_distro) VALUES (?, ?)',
                   (schema, DISTRO[version]))
    ids = {}
    for topic in topics:
        values = [topic.name, topic.msgtype, 'cdr', qos_text(topic, version)]
        if schema >= 4:
            values.append(TYPE_HASHES[topic.full_type])
            found = topic.definition_found
            db.execute('INSERT INTO message_definitions (topic_type, encoding, '
                       'encoded_message_definition, type_description_hash) VALUES (?, ?, ?, ?)',
                       (topic.msgtype, 'ros2msg' if found else '',
                        DEFINITIONS[topic.full_type] if found else '',
                        TYPE_HASHES[topic.full_type]))
        marks = ', '.join('?' * len(values))
        names = 'name, type, serialization_format, offered_qos_profiles' + (
            ', type_description_hash' if schema >= 4 else '')
        ids[topic.name] = db.execute(f'INSERT INTO topics ({names}) VALUES ({marks})',
                                     values).lastrowid
    db.executemany('INSERT INTO messages (timestamp, topic_id, data) VALUES (?, ?, ?);',
                   [(stamp, ids[name], data) for name, stamp, data in rows])
    if version >= 8:       # update_metadata: the bag's metadata, YAML::Dump without the key
        db.execute('INSERT INTO metadata (metadata_version, metadata) VALUES (?, ?)',
                   (version, _block(metadata_node, 0)))
    db.commit()
    db.close()


def write_mcap(path, version, topics, rows, metadata_node):
    """Write one ``.mcap`` as rosbag2_storage_mcap wrote it for that distribution."""
    with open(path, 'wb') as stream:
        writer = McapWriter(stream, compression=CompressionType.ZSTD if version <= 4
                            else CompressionType.NONE)
        writer.start(profile='ros2', library='libmcap')
        if version == 8:          # Iron 0.22.2: ROS_DISTRO record written at open
            writer.add_metadata('rosbag2', {'ROS_DISTRO': DISTRO[version]})
        schemas, channels = {}, {}
        for topic in topics:
            if topic.msgtype not in schemas:
                found = topic.definition_found
                schemas[topic.msgtype] = writer.register_schema(
                    name=topic.msgtype, encoding='ros2msg' if found else '',
                    data=DEFINITIONS[topic.full_type].encode() if found else b'')
            metadata = {'offered_qos_profiles': qos_text(topic, version)}
            if version >= 7:
                metadata['topic_type_hash'] = TYPE_HASHES[topic.full_type]
            channels[topic.name] = writer.register_channel(
                topic=topic.name, message_encoding='cdr', schema_id=schemas[topic.msgtype],
                metadata=metadata)
        for name, stamp, data in rows:
            writer.add_message(channel_id=channels[name], log_time=stamp, data=data,
                               publish_time=stamp, sequence=0)
        if version >= 6:          # update_metadata (the merged plugin, rosbag2 0.19 on)
            writer.add_metadata('rosbag2',
                                {'serialized_metadata': _block(metadata_node, 0)})
        writer.finish()


# --- a whole bag --------------------------------------------------------------------------
def write_bag(bag, version, storage, topics, files=1, compression=None, custom_data=None,
              start_ns=1_714_557_600_000_000_000, period_ns=100_000_000):
    """
    Write a bag directory as ``ros2 bag record`` of that version left it.

    Messages of all topics are interleaved in time (topic order within one step) and split
    evenly over ``files`` storage files. Returns ``[(topic, timestamp, message)]`` in bag
    order.
    """
    bag.mkdir(parents=True)
    order = []
    for step in range(max(len(t.messages) for t in topics)):
        for topic in topics:
            if step < len(topic.messages):
                order.append((topic.name, start_ns + len(order) * period_ns,
                              topic.messages[step]))
    per_file = -(-len(order) // files)
    chunks = [order[i:i + per_file] for i in range(0, len(order), per_file)]
    extension = '.db3' if storage == 'sqlite3' else '.mcap'
    infos, raw_rows = [], []
    for index, chunk in enumerate(chunks):
        rows = []
        for name, stamp, msg in chunk:
            data = serialize_message(msg)
            if compression == 'message':
                data = zstandard.ZstdCompressor().compress(data)
            rows.append((name, stamp, data))
        raw_rows.append(rows)
        path = f'{bag.name}_{index}{extension}' + ('.zstd' if compression == 'file' else '')
        infos.append({'path': path, 'start': chunk[0][1],
                      'duration': chunk[-1][1] - chunk[0][1], 'count': len(chunk)})
    counts = {t.name: len(t.messages) for t in topics}
    node = bag_metadata(version, storage, topics, counts, infos, compression, custom_data)
    for info, rows in zip(infos, raw_rows):
        target = bag / info['path'].removesuffix('.zstd')
        write = write_sqlite if storage == 'sqlite3' else write_mcap
        write(target, version, topics, rows, node)
        if compression == 'file':     # the closed file, compressed whole, original removed
            compressed = zstandard.ZstdCompressor().compress(target.read_bytes())
            (bag / info['path']).write_bytes(compressed)
            target.unlink()
    (bag / 'metadata.yaml').write_text(metadata_yaml(node))
    return order
