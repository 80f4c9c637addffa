"""
The nodes behave as ROS users expect (real rclpy, Fast DDS on loopback).

Rectified streams under image_proc's names, each in its camera's frame; a bag replayed on its
own /clock with use_sim_time gives the same point clouds as on the wall clock; read-only
parameters are refused through the parameter service with the reason; the matcher leaves
ERROR after a good pair; deprecated parameter names still work.
"""

import dataclasses
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import qos_profile_sensor_data
from ros_helpers import RectifiedPairs, replay_through_matcher, spin_for, \
    spin_until_finished
from sensor_msgs.msg import Image, PointCloud2
from st_stereo.nodes.driver_node import DriverNode
from st_stereo.nodes.matcher_node import MatcherNode
from st_stereo.nodes.rectifier_node import RectifierNode
from st_stereo.sim.recording import write_recording
from st_stereo.sim.sequences import SequenceRenderer, standard_sequences


class Streams(Node):
    """Collects the rectified streams, the point clouds and the diagnostics."""

    def __init__(self, context):
        super().__init__('streams', context=context, namespace='stereo')
        self.got = {'left/image_rect': [], 'right/image_rect': [], 'points2': []}
        for topic, kind in (('left/image_rect', Image), ('right/image_rect', Image),
                            ('points2', PointCloud2)):
            self.create_subscription(kind, topic, self.got[topic].append,
                                     qos_profile_sensor_data)
        self.statuses = []
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)

    def _on_diagnostics(self, msg):
        self.statuses += list(msg.status)


@pytest.mark.timeout(120)
def test_rectified_streams_keep_image_procs_names_and_each_cameras_frame(ros):
    context, executor, add = ros
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('duration', value=2.0),
        Parameter('left.frame_id', value='rig_a_left_optical'),
        Parameter('right.frame_id', value='rig_a_right_optical')]))
    add(RectifierNode(context=context))
    add(MatcherNode(context=context))
    streams = add(Streams(context))
    spin_until_finished(executor, driver, 60.0)
    spin_for(executor, 1.0)
    left, right, clouds = (streams.got[t] for t in ('left/image_rect', 'right/image_rect',
                                                    'points2'))
    assert len(left) >= 5 and len(right) >= 5
    assert {m.header.frame_id for m in left} == {'rig_a_left_optical'}
    assert {m.header.frame_id for m in right} == {'rig_a_right_optical'}
    # The matcher pairs image_rect with the raw camera_info (its P is the rectified
    # geometry), as stereo_image_proc's disparity node does; its outputs are in the left frame.
    assert len(clouds) >= 5 and {m.header.frame_id for m in clouds} == {'rig_a_left_optical'}
    stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in left}
    assert {(m.header.stamp.sec, m.header.stamp.nanosec) for m in clouds} <= stamps


def test_deprecated_per_camera_names_still_set_the_new_parameters(ros):
    context, _, add = ros
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('duration', value=0.5), Parameter('left_frame_id', value='old_left'),
        Parameter('right.frame_id', value='new_right'),
        Parameter('right_frame_id', value='old_right')]))
    # The old name alone is used; with both, the new name wins (both warn at start-up). The
    # value in use is the new parameter's, as `ros2 param get` shows it.
    assert driver.frame_ids == ['old_left', 'new_right']
    assert driver.get_parameter('left.frame_id').value == 'old_left'


@pytest.mark.timeout(120)
def test_a_parameter_of_the_wrong_type_is_one_line_and_exit_2():
    import os
    import subprocess
    import sys
    done = subprocess.run(
        [sys.executable, '-c', 'import sys; from st_stereo.nodes.driver_node import main; '
         'sys.exit(main())', '--ros-args', '-p', 'sim_depth:=3'],
        capture_output=True, text=True, timeout=100, env=dict(os.environ))
    assert done.returncode == 2, done.stderr
    assert 'cannot start: parameter sim_depth: expected a float (a number with a decimal ' \
        'point, e.g. 3.0 rather than 3)' in done.stderr
    assert 'Traceback' not in done.stderr


def _set(executor, client, parameters):
    future = client.set_parameters(parameters)
    deadline = time.monotonic() + 10.0
    while not future.done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert future.done(), 'no answer from the parameter service'
    return future.result().results


@pytest.mark.timeout(120)
def test_read_only_parameters_are_refused_through_the_parameter_service(ros):
    context, executor, add = ros
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('duration', value=30.0)]))
    caller = add(Node('caller', context=context))
    client = AsyncParameterClient(caller, '/stereo/lepton_driver')
    deadline = time.monotonic() + 10.0
    while not client.services_are_ready() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    refused = _set(executor, client, [Parameter('source', value='spi')])[0]
    assert not refused.successful and 'read-only' in refused.reason
    assert driver.get_parameter('source').value == 'sim'
    future = client.describe_parameters(['source', 'max_pair_delta'])
    while not future.done():
        executor.spin_once(timeout_sec=0.05)
    source, delta = future.result().descriptors
    assert source.read_only and 'start-up' in source.additional_constraints
    assert not delta.read_only
    # A live one takes effect at once, and a bad value is refused with the reason.
    assert _set(executor, client, [Parameter('max_pair_delta', value=0.05)])[0].successful
    assert driver.pairing.max_delta == 0.05
    bad = _set(executor, client, [Parameter('max_pair_delta', value=0.5)])[0]
    assert not bad.successful and 'max_pair_delta: expected 0 < seconds <= 0.1' in bad.reason


def _matcher_levels(streams):
    return [status.level for status in streams.statuses
            if status.name == 'stereo/matcher: ST matching']


@pytest.mark.timeout(120)
def test_the_matcher_leaves_error_after_a_good_pair(ros, people_80x60):
    context, executor, add = ros
    matcher = add(MatcherNode(context=context))
    source = add(RectifiedPairs(context))
    streams = add(Streams(context))
    texture = (7800 + (people_80x60 - people_80x60.min()) * 800 / np.ptp(people_80x60))
    spin_for(executor, 1.0)
    image = texture.astype(np.uint16)
    source.publish_images(1, image, image, (160, 120))          # info and image disagree
    spin_for(executor, 2.5)
    assert matcher.counts['dropped_bad_input'] == 1
    assert _matcher_levels(streams)[-1] == DiagnosticStatus.ERROR
    source.publish_images(2, image, image)
    spin_for(executor, 2.5)
    assert matcher.counts['matched'] == 1
    assert _matcher_levels(streams)[-1] != DiagnosticStatus.ERROR
    last = next(s for s in reversed(streams.statuses) if s.name == 'stereo/matcher: ST matching')
    values = {kv.key: kv.value for kv in last.values}
    assert 'camera_info says 160x120' in values['last dropped pair']  # still said, not ERROR


@pytest.mark.timeout(120)
def test_each_rigs_diagnostics_are_named_by_its_namespace(ros, people_80x60):
    # Several rigs on one machine publish on the one /diagnostics: named only by the node
    # ('matcher: ST matching'), the rigs' statuses could not be told apart, and a monitor of
    # one rig took another's counts.
    from st_stereo.nodes.pipeline import SuiteMonitor
    context, executor, add = ros
    for rig in ('rig1', 'rig2'):
        add(MatcherNode(context=context, namespace=rig))
    monitors = {rig: add(SuiteMonitor(watch_raw=True, context=context, namespace=rig))
                for rig in ('rig1', 'rig2')}
    source = add(RectifiedPairs(context, namespace='rig1'))
    names = set()

    def keep_names(msg):
        names.update(status.name for status in msg.status)

    add(Node('names', context=context)).create_subscription(DiagnosticArray, '/diagnostics',
                                                            keep_names, 10)
    spin_for(executor, 1.0)
    image = (7800 + (people_80x60 - people_80x60.min()) * 800 /
             np.ptp(people_80x60)).astype(np.uint16)
    source.publish_images(1, image, image, (160, 120))          # rig1 only, a bad pair
    spin_for(executor, 2.5)
    assert {'rig1/matcher: ST matching', 'rig2/matcher: ST matching'} <= names
    assert monitors['rig1'].matcher_values['pairs dropped_bad_input'] == '1'
    assert monitors['rig2'].matcher_values['pairs dropped_bad_input'] == '0'


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory):
    spec = dataclasses.replace(standard_sequences()['walk_across'], duration_s=1.5)
    out = tmp_path_factory.mktemp('clock') / 'walk'
    write_recording(SequenceRenderer(spec, supersample=2), out)
    return out / 'bag'


@pytest.mark.timeout(240)
def test_a_replay_on_the_bags_clock_gives_the_same_point_clouds(short_bag):
    wall, _, wall_matcher = replay_through_matcher(short_bag, use_sim_time=False)
    sim, _, sim_matcher = replay_through_matcher(short_bag, use_sim_time=True)
    assert len(wall) >= 12 and set(sim) == set(wall)
    assert all(sim[stamp] == wall[stamp] for stamp in wall)
    compensated = [m.skew.counts['pairs_skew_compensated'] for m in (wall_matcher, sim_matcher)]
    assert compensated[0] == compensated[1] > 0
    # On the wall clock the recorded stamps are years old: no latency from them (counted);
    # on the bag's /clock they are the node's time, and the latency is measured.
    assert wall_matcher.counts['stamps_not_on_node_clock'] == len(wall)
    assert not wall_matcher.latencies
    assert sim_matcher.latencies and max(sim_matcher.latencies) < 5.0
