"""
Reading rosbag2 bags with ``rosbags``, with the workarounds that real bags need.

One place for ``bag_play``, the driver's ``source:=bag`` and ``st-stereo calibrate --bag``.

- ``bag_messages``: rosbags (0.11) pairs each storage file's connections with the bag's
  ``metadata.yaml`` connections by topic, type *and* the stored offered QoS. Older rosbag2
  versions stored the QoS differently in the two places (the Foxy-era MCAP talker bag:
  deadline 0 in ``metadata.yaml``, infinite in the MCAP channel), so rosbags matched nothing
  and yielded no message at all. rosbag2 itself matches by topic and type; so does this.
  (Worth offering upstream: the QoS text is not part of a connection's identity.)
- ``normalized_msgtype``: ``pkg/msg/Name``, also for the old ``pkg/Name`` spelling.
"""

import importlib


def normalized_msgtype(msgtype):
    """
    Return ``pkg/msg/Name`` for a recorded type name (``pkg/Name`` is the old spelling).

    ValueError for anything else.
    """
    parts = msgtype.split('/')
    if len(parts) == 2 and all(parts):
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3 and all(parts):
        return msgtype
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
    storages = getattr(reader.storage, 'storages', None)
    if storages is None:
        yield from reader.messages(connections=wanted)
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
