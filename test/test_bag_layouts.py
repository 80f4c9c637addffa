"""
Bags in the layout ``ros2 bag record`` wrote on each distribution replay through bag_play.

The bags are written by ``rosbag2_layouts`` (no rosbags): metadata versions 4 to 9, sqlite3
and MCAP, split, file- and message-compressed, old type names, uninstalled types and each
version's shape of the offered QoS (issue 13).
"""

import time

import pytest
import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import new_context, ros_nodes
from rosbag2_layouts import Offered, Topic, write_bag
from sensor_msgs.msg import Image
from st_stereo.nodes.bags import BagPlayer, play_main
from std_msgs.msg import String

VERSIONS = (4, 5, 6, 7, 8, 9)
STORAGES = ('sqlite3', 'mcap')
BAG = 'rosbag2_2024_05_01-12_00_00'
CLASSES = {'std_msgs/msg/String': String, 'sensor_msgs/msg/Image': Image}


def chatter(count=10, msgtype='std_msgs/msg/String', offered=None):
    return Topic('/chatter', msgtype, [String(data=f'Hello World: {i}') for i in range(count)],
                 [Offered()] if offered is None else offered)


def camera(count=3):
    images = []
    for index in range(count):
        image = Image(height=2, width=3, encoding='mono16', step=6,
                      data=bytes(range(index, index + 12)))
        image.header.frame_id = 'cam_left'
        image.header.stamp.sec = 1_714_557_600 + index
        images.append(image)
    return Topic('/stereo/left/image_raw', 'sensor_msgs/msg/Image', images)


def replay(bag, expected, timeout_s=15.0):
    """
    Play ``bag`` with BagPlayer to real rclpy subscribers; return (received, player).

    ``expected`` maps each subscribed topic to the messages it must get; the subscribers are
    reliable, like the recorded publishers. Playback starts once every publisher and
    subscription have matched, and ends when all expected messages arrived (or the timeout).
    """
    with ros_nodes() as (context, executor, add):
        listener = add(Node('layout_listener', context=context))
        received = {topic: [] for topic in expected}
        subscriptions = [
            listener.create_subscription(type(messages[0]), topic,
                                         lambda msg, t=topic: received[t].append(msg),
                                         QoSProfile(depth=100,
                                                    reliability=ReliabilityPolicy.RELIABLE))
            for topic, messages in expected.items()]
        player = add(BagPlayer(bag, rate=10.0, context=context))   # 10 ms apart
        publishers = {p.topic_name: p for p in player.publishers_by_id.values()}
        try:
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline and not (
                    all(s.get_publisher_count() for s in subscriptions) and
                    all(publishers[t].get_subscription_count() for t in expected
                        if t in publishers)):
                executor.spin_once(timeout_sec=0.02)
            player.play(spin=lambda s: executor.spin_once(timeout_sec=s))
            while time.monotonic() < deadline and any(
                    len(received[t]) < len(m) for t, m in expected.items()):
                executor.spin_once(timeout_sec=0.02)
            executor.spin_once(timeout_sec=0.05)        # nothing more may come
            return received, player
        finally:
            player.close()


def expect(topics):
    return {t.name: t.messages for t in topics if t.messages}


@pytest.mark.parametrize('storage', STORAGES)
@pytest.mark.parametrize('version', VERSIONS)
def test_each_version_and_storage_replays_every_message(tmp_path, version, storage):
    topics = [chatter(), camera()]
    order = write_bag(tmp_path / BAG, version, storage, topics)
    received, player = replay(tmp_path / BAG, expect(topics))
    assert received == expect(topics)
    assert player.published == len(order) == 13 and player.skipped == []


@pytest.mark.parametrize('storage', STORAGES)
def test_split_bags_replay_whole_and_in_order(tmp_path, storage):
    topics = [chatter(12)]
    write_bag(tmp_path / BAG, 9, storage, topics, files=3)
    assert len(list((tmp_path / BAG).glob(f'{BAG}_*'))) == 3
    received, player = replay(tmp_path / BAG, expect(topics))
    assert [m.data for m in received['/chatter']] == [f'Hello World: {i}' for i in range(12)]


@pytest.mark.parametrize('version, storage, compression, files', [
    (4, 'sqlite3', 'file', 1),          # Foxy: compression already in rosbag2 0.2.5+
    (4, 'sqlite3', 'message', 1),
    (5, 'mcap', 'message', 1),          # Humble's MCAP plugin still took message mode
    (5, 'mcap', 'file', 2),
    (9, 'sqlite3', 'file', 2),
    (9, 'sqlite3', 'message', 1),
    (9, 'mcap', 'file', 1),
])
def test_compressed_bags_replay(tmp_path, version, storage, compression, files):
    topics = [chatter(), camera()]
    write_bag(tmp_path / BAG, version, storage, topics, files=files, compression=compression)
    suffix = {'file': '.zstd', 'message': '.db3' if storage == 'sqlite3' else '.mcap'}
    assert all(p.name.endswith(suffix[compression]) for p in (tmp_path / BAG).glob(f'{BAG}_*'))
    received, player = replay(tmp_path / BAG, expect(topics))
    assert received == expect(topics) and player.skipped == []


@pytest.mark.parametrize('storage', STORAGES)
def test_old_type_names_in_metadata_and_storage_replay(tmp_path, storage):
    # std_msgs/String (no /msg/) in metadata.yaml and in the topics table / MCAP schema name.
    topics = [chatter(msgtype='std_msgs/String')]
    write_bag(tmp_path / BAG, 4, storage, topics)
    received, player = replay(tmp_path / BAG, expect(topics))
    assert received == expect(topics) and player.skipped == []


@pytest.mark.parametrize('version, storage', [(4, 'sqlite3'), (9, 'sqlite3'), (8, 'mcap')])
def test_uninstalled_type_is_skipped_naming_topic_type_and_package(
        tmp_path, capsys, version, storage):
    from std_msgs.msg import Int32     # stands for acme_msgs/msg/Thing's bytes
    thing = Topic('/acme/thing', 'acme_msgs/msg/Thing', [Int32(data=i) for i in range(4)])
    topics = [chatter(), thing]
    write_bag(tmp_path / BAG, version, storage, topics)
    received, player = replay(tmp_path / BAG, {'/chatter': topics[0].messages})
    assert received == {'/chatter': topics[0].messages}
    reason = ('message type acme_msgs/msg/Thing: not installed (install the ROS package '
              'acme_msgs, e.g. ros-jazzy-acme-msgs)')
    assert player.skipped == [('/acme/thing', reason)] and player.published == 10
    assert play_main([str(tmp_path / BAG), '--rate', '100']) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == [f'bag_play: skipping /acme/thing: {reason}']


@pytest.mark.parametrize('storage', STORAGES)
def test_nothing_playable_exits_non_zero(tmp_path, capsys, storage):
    from std_msgs.msg import Int32
    thing = Topic('/acme/thing', 'acme_msgs/msg/Thing', [Int32(data=i) for i in range(4)])
    write_bag(tmp_path / BAG, 9, storage, [thing])
    assert play_main([str(tmp_path / BAG)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == ['bag_play: skipping /acme/thing: message type acme_msgs/msg/Thing: not '
                   'installed (install the ROS package acme_msgs, e.g. ros-jazzy-acme-msgs)',
                   f'bag_play: {tmp_path / BAG}: no topic can be played']


@pytest.mark.parametrize('storage', STORAGES)
def test_a_topic_whose_definition_rosbag2_left_empty_replays(tmp_path, storage):
    # rosbag2 (Iron on) stores encoding '' and no text when it cannot find a type's .msg
    # ("Message definition will be left empty in bag"), e.g. for service event topics.
    image = camera()
    image.definition_found = False
    topics = [chatter(), image]
    write_bag(tmp_path / BAG, 9, storage, topics)
    received, player = replay(tmp_path / BAG, expect(topics))
    assert received == expect(topics) and player.skipped == []


RELIABLE, BEST_EFFORT = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT
VOLATILE, TRANSIENT_LOCAL = DurabilityPolicy.VOLATILE, DurabilityPolicy.TRANSIENT_LOCAL


@pytest.mark.parametrize('version, offered, reliability, durability', [
    # YAML text in a string, integers, Fast-DDS's Foxy infinities (2147483647 s 4294967295 ns)
    (4, [Offered(reliability=1, durability=1)], RELIABLE, TRANSIENT_LOCAL),
    (4, [Offered(reliability=2, durability=2)], BEST_EFFORT, VOLATILE),
    # the same shape with RMW_DURATION_INFINITE (9223372036 s 854775807 ns), Humble and Iron
    (5, [Offered(reliability=2, durability=1)], BEST_EFFORT, TRANSIENT_LOCAL),
    (8, [Offered(reliability=1, durability=1, lifespan_s=10)], RELIABLE, TRANSIENT_LOCAL),
    # the empty string: no publisher seen (rosbag2's default offer: reliable, volatile)
    (4, [], RELIABLE, VOLATILE),
    (8, [], RELIABLE, VOLATILE),
    # version 9: a YAML sequence in metadata.yaml, policies by name
    (9, [Offered(reliability=2, durability=1)], BEST_EFFORT, TRANSIENT_LOCAL),
    (9, [Offered(reliability=1, durability=2)], RELIABLE, VOLATILE),
    (9, [], RELIABLE, VOLATILE),
    # several publishers: the same offer is kept; differing offers fall back to rosbag2's
    # default offer (Rosbag2QoS::adapt_offer_to_recorded_offers)
    (4, [Offered(reliability=1, durability=1)] * 2, RELIABLE, TRANSIENT_LOCAL),
    (9, [Offered(reliability=2, durability=1), Offered(reliability=1, durability=2)],
     RELIABLE, VOLATILE),
])
def test_bag_play_offers_the_recorded_reliability_and_durability(
        tmp_path, version, offered, reliability, durability):
    write_bag(tmp_path / BAG, version, 'sqlite3', [chatter(offered=offered)])
    context, executor = new_context()
    listener = Node('qos_listener', context=context)
    player = BagPlayer(tmp_path / BAG, rate=100.0, context=context)
    for node in (listener, player):
        executor.add_node(node)
    try:
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not listener.get_publishers_info_by_topic(
                '/chatter'):
            executor.spin_once(timeout_sec=0.02)
        (info,) = listener.get_publishers_info_by_topic('/chatter')
        assert (info.qos_profile.reliability, info.qos_profile.durability) == \
            (reliability, durability)
        if (reliability, durability) == (RELIABLE, TRANSIENT_LOCAL):
            # Latched as recorded: a subscriber that joins after playback gets the messages
            # (DDS resends history to late joiners only on reliable writers).
            player.play(spin=lambda s: executor.spin_once(timeout_sec=s))
            late = []
            listener.create_subscription(String, '/chatter', lambda msg: late.append(msg.data),
                                         QoSProfile(depth=10, durability=TRANSIENT_LOCAL))
            while time.monotonic() < deadline and len(late) < 10:
                executor.spin_once(timeout_sec=0.02)
            assert late == [f'Hello World: {i}' for i in range(10)]
    finally:
        player.close()
        for node in (listener, player):
            node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize('version', [8, 9])
def test_an_empty_sqlite3_bag_opens_and_holds_no_message(tmp_path, version):
    # A review: an empty Iron/Jazzy sqlite3 bag was "not enough values to unpack" (the
    # message_definitions filter stayed on the cursor rosbags' next query used).
    # rosbags' writer: the fixture writes recordings with messages.
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    from st_stereo.bag_reading import bag_messages, open_bag
    bag = tmp_path / 'empty'
    with Writer(bag, version=version, storage_plugin=StoragePlugin.SQLITE3) as writer:
        writer.add_connection('/chatter', 'std_msgs/msg/String',
                              typestore=get_typestore(Stores.ROS2_JAZZY))
    reader = open_bag(bag)
    try:
        assert list(bag_messages(reader)) == [] and reader.message_count == 0
    finally:
        reader.close()
