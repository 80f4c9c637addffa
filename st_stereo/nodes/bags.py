"""
``bag_record`` and ``bag_play``: rosbag2 without the ros2 CLI, through ``rosbags``.

Recording subscribes in raw mode (the CDR bytes, identical to rclpy's) and writes MCAP
(metadata version 9, as Jazzy does), optionally zstd-compressed per message or per file.
Playback reads every rosbag2 layout ``ros2 bag record`` wrote (sqlite3 or MCAP, metadata
versions 4 to 9, split, compressed; see docs/bags.md) and publishes every topic's recorded
bytes unchanged, with its recorded type and QoS (reliability and durability, as ros2 bag
play adapts them), at the recorded pace (``rate`` times faster or slower), optionally
publishing ``/clock``.
"""

import argparse
import pathlib
import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.utilities import remove_ros_args
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock
from st_stereo.bag_reading import bag_messages, BagError, message_class, open_bag
from st_stereo.nodes.runtime import until_shutdown, with_default_namespace

COMPRESSION_MODES = ('none', 'file', 'message')
# The raw pair and the driver's pair_info (both acquisition stamps of each pair: the matcher's
# camera skew correction needs them on replay too).
RAW_PAIR_TOPICS = ('left/image_raw', 'right/image_raw', 'left/camera_info',
                   'right/camera_info', 'pair_info')


def offered_qos(profile):
    """Return the rosbags Qos of an rclpy QoSProfile a publisher offers (as rosbag2 stores)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)

    def duration(value):
        seconds, nanoseconds = divmod(int(value.nanoseconds), 1_000_000_000)
        return QosTime(sec=seconds, nsec=nanoseconds)
    return Qos(history=QosHistory(int(profile.history)), depth=int(profile.depth),
               reliability=QosReliability(int(profile.reliability)),
               durability=QosDurability(int(profile.durability)),
               deadline=duration(profile.deadline), lifespan=duration(profile.lifespan),
               liveliness=QosLiveliness(int(profile.liveliness)),
               liveliness_lease_duration=duration(profile.liveliness_lease_duration),
               avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


def qos_from_recorded(profiles):
    """
    Return the rclpy QoSProfile of the offered QoS recorded in a bag.

    Reliable with depth 10 when nothing was recorded, and, as ``ros2 bag play`` does
    (rosbag2_storage qos.cpp, ``adapt_offer_to_recorded_offers``), when the recorded
    publishers did not all offer the same reliability, durability, deadline and liveliness.
    """
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)

    def compatibility(profile):
        return tuple(getattr(getattr(profile, key, None), 'value', getattr(profile, key, None))
                     for key in ('reliability', 'durability', 'deadline', 'liveliness',
                                 'liveliness_lease_duration'))
    if profiles and len({compatibility(p) for p in profiles}) == 1:
        recorded = profiles[0]
        reliability = getattr(recorded.reliability, 'value', recorded.reliability)
        durability = getattr(recorded.durability, 'value', recorded.durability)
        if reliability == 2:
            qos.reliability = ReliabilityPolicy.BEST_EFFORT
        if durability == 1:
            qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
        qos.history = HistoryPolicy.KEEP_LAST
        qos.depth = max(int(getattr(recorded, 'depth', 0) or 10), 1)
    return qos


class BagRecorder(Node):
    """Record topics (raw bytes and each publisher's offered QoS) into an MCAP rosbag2."""

    def __init__(self, path, topics, compression_mode='none', **kwargs):
        super().__init__('bag_record', **with_default_namespace(kwargs))
        self.path = pathlib.Path(path)
        if self.path.exists():
            raise FileExistsError(f'{self.path}: the bag already exists')
        if compression_mode not in COMPRESSION_MODES:
            raise ValueError(f'compression mode: expected one of {", ".join(COMPRESSION_MODES)}'
                             f', got {compression_mode!r}')
        self.topics = [self.resolve_topic_name(t) for t in topics]
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        if compression_mode != 'none':
            # As ros2 bag record --compression-mode file|message --compression-format zstd.
            self.writer.set_compression(CompressionMode[compression_mode.upper()],
                                        CompressionFormat.ZSTD)
        self.writer.open()
        self.connections = {}
        self.counts = dict.fromkeys(self.topics, 0)
        self._subscribed = set()
        self.create_timer(0.2, self._discover)
        self._discover()

    def _discover(self):
        types = dict(self.get_topic_names_and_types())
        for topic in self.topics:
            if topic in self._subscribed or topic not in types:
                continue
            msgtype = types[topic][0]
            # Each publisher's offered QoS, as ros2 bag record stores it, so that bag_play
            # republishes the topic with it.
            offered = [offered_qos(info.qos_profile)
                       for info in self.get_publishers_info_by_topic(topic)]
            self.connections[topic] = self.writer.add_connection(
                topic, msgtype, typestore=self.typestore, offered_qos_profiles=offered)
            self.create_subscription(message_class(msgtype), topic,
                                     lambda data, t=topic: self._write(t, data),
                                     QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE),
                                     raw=True)
            self._subscribed.add(topic)

    def _write(self, topic, data):
        self.writer.write(self.connections[topic], self.get_clock().now().nanoseconds, data)
        self.counts[topic] += 1

    def close(self):
        """Finish the bag (metadata written)."""
        self.writer.close()


class BagPlayer(Node):
    """Publish the messages of a rosbag2 with their recorded bytes, types and QoS."""

    def __init__(self, path, rate=1.0, publish_clock=False, topics=None, **kwargs):
        super().__init__('bag_play', **kwargs)
        if rate <= 0:
            raise ValueError(f'rate must be positive, got {rate}')
        self.path = pathlib.Path(path)
        self.reader = open_bag(self.path)
        self.rate = rate
        self.publishers_by_id = {}
        self.skipped = []            # (topic, reason) of topics that cannot be played
        for connection in self.reader.connections:
            if topics and connection.topic not in topics:
                continue
            try:
                cls = message_class(connection.msgtype)
            except (ImportError, ValueError) as error:
                self.skipped.append((connection.topic, str(error)))
                continue
            profiles = getattr(connection.ext, 'offered_qos_profiles', [])
            self.publishers_by_id[connection.id] = self.create_publisher(
                cls, connection.topic, qos_from_recorded(profiles))
        self.clock_pub = self.create_publisher(Clock, '/clock', 10) if publish_clock else None
        self.published = 0

    def play(self, stop=None, spin=None, step=None):
        """
        Publish every message at the recorded pace; returns the number published.

        With ``step`` (a callable), the pace is ignored: ``step()`` is called before each
        message and playback goes on when it returns (stepping through a bag).
        """
        connections = [c for c in self.reader.connections if c.id in self.publishers_by_id]
        start_wall = time.monotonic()
        start_bag = None
        for connection, timestamp, data in bag_messages(self.reader, connections):
            if stop is not None and stop():
                break
            if start_bag is None:
                start_bag = timestamp
            if step is not None:
                step()
            due = start_wall + (timestamp - start_bag) * 1e-9 / self.rate
            while step is None:
                wait = due - time.monotonic()
                if wait <= 0:
                    break
                if spin is not None:
                    spin(min(wait, 0.01))
                else:
                    time.sleep(min(wait, 0.01))
            if self.clock_pub is not None:
                clock = Clock()
                clock.clock.sec, clock.clock.nanosec = divmod(timestamp, 1_000_000_000)
                self.clock_pub.publish(clock)
            self.publishers_by_id[connection.id].publish(bytes(data))
            self.published += 1
        return self.published

    def close(self):
        """Close the bag."""
        self.reader.close()


def record_main(argv=None):
    """``bag_record OUTPUT [TOPIC ...]``: record until Ctrl-C (default: the raw pair)."""
    parser = argparse.ArgumentParser(prog='bag_record', description=record_main.__doc__)
    parser.add_argument('output', help='bag directory to create')
    parser.add_argument('topics', nargs='*', default=list(RAW_PAIR_TOPICS))
    parser.add_argument('--compression-mode', choices=COMPRESSION_MODES, default='none',
                        help='zstd-compress each message or each closed file (none)')
    # ROS arguments (``--ros-args ...``, which launch adds) go to rclpy, the rest to argparse.
    full = ['bag_record', *(sys.argv[1:] if argv is None else argv)]
    args = parser.parse_args(remove_ros_args(full)[1:])
    rclpy.init(args=full)
    node = BagRecorder(args.output, args.topics, args.compression_mode)
    try:
        with until_shutdown():
            rclpy.spin(node)
    finally:
        node.close()
        print(dict(node.counts))
        node.destroy_node()
        rclpy.try_shutdown()


def play_main(argv=None):
    """``bag_play BAG [--rate R] [--clock]``: publish a bag's messages as recorded."""
    parser = argparse.ArgumentParser(prog='bag_play', description=play_main.__doc__)
    parser.add_argument('bag')
    parser.add_argument('--rate', type=float, default=1.0, help='playback speed factor')
    parser.add_argument('--clock', action='store_true', help='publish /clock')
    parser.add_argument('--step', action='store_true',
                        help='publish one message per line read on standard input')
    parser.add_argument('--topics', nargs='*', help='only these topics')
    parser.add_argument('--delay', type=float, default=0.5,
                        help='seconds to wait before the first message, for subscribers to '
                             'connect (a launch file starting everything at once: a few)')
    # ROS arguments (``--ros-args ...``, which launch adds) go to rclpy, the rest to argparse.
    full = ['bag_play', *(sys.argv[1:] if argv is None else argv)]
    args = parser.parse_args(remove_ros_args(full)[1:])
    rclpy.init(args=full)
    try:
        node = BagPlayer(args.bag, args.rate, args.clock, args.topics)
    except (BagError, OSError, ValueError) as error:
        print(f'bag_play: {error}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    status = 0
    try:
        with until_shutdown():
            for note in node.reader.notes:
                print(f'bag_play: {note}', file=sys.stderr)
            for topic, reason in node.skipped:
                print(f'bag_play: skipping {topic}: {reason}', file=sys.stderr)
            if not node.publishers_by_id:
                print(f'bag_play: {args.bag}: no topic can be played', file=sys.stderr)
                return 1
            time.sleep(max(0.0, args.delay))      # let subscribers discover the publishers
            step = (lambda: sys.stdin.readline()) if args.step else None
            count = node.play(spin=lambda s: rclpy.spin_once(node, timeout_sec=s), step=step)
            print(f'published {count} messages from {args.bag}')
            expected = sum(c.msgcount for c in node.reader.connections
                           if c.id in node.publishers_by_id)
            if count == 0 and expected:
                print(f'bag_play: {args.bag}: the metadata lists {expected} messages of the '
                      f'playable topics but none could be read', file=sys.stderr)
                status = 1
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return status
