"""The raw image streams of a rosbag2, read with ``rosbags`` alone (no ROS installation)."""

import pathlib

SIDES = ('left', 'right')


def raw_image_messages(path):
    """
    Yield ``(side, stamp_ns, msg)`` for the topics ending in left/image_raw and right/image_raw.

    ``msg`` is a rosbags sensor_msgs/Image (fields as in ROS); messages come in bag order. A
    missing bag or a bag without both topics raises a ValueError naming what was found.
    """
    from rosbags.typesys import get_typestore, Stores

    from st_stereo.bag_reading import bag_messages, open_bag
    path = pathlib.Path(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    reader = open_bag(path)
    try:
        wanted = {c.id: side for c in reader.connections for side in SIDES
                  if c.topic.endswith(f'{side}/image_raw')}
        if set(wanted.values()) != set(SIDES):
            raise ValueError(f'{path}: expected topics ending in left/image_raw and '
                             f'right/image_raw, found {sorted(reader.topics)}')
        for connection, _, data in bag_messages(
                reader, [c for c in reader.connections if c.id in wanted]):
            msg = typestore.deserialize_cdr(data, connection.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            yield wanted[connection.id], stamp, msg
    finally:
        reader.close()
