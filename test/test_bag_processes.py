"""
A bag of two free-running cameras replayed through the node processes on the wall clock.

What the in-process tests share with the code: one executor, a pair handed on within one
process. Here the driver (``source:=bag``), the rectifier and the matcher are three processes
started as ``ros2 run`` starts them, talking over Fast DDS on loopback, paced by the wall
clock; the bag is what two independent camera drivers would record (each camera its own
stamps, the right one starting a second later, 16UC1 as libuvc_camera writes a PureThermal
board's Y16) and the scene moves, so a pair's skew shows in its disparity unless corrected.
"""

import ctypes
import os
import signal
import subprocess
import sys

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from ros_helpers import ideal_camera_info, keep_statuses, ros_nodes, spin_until
from rosbag2_layouts import Topic, write_bag
from sensor_msgs.msg import Image, PointCloud2
from st_stereo.nodes.conversions import point_cloud_array
from std_msgs.msg import Header

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

FOCAL_BASELINE = 46.3          # fx B of ideal_camera_info's right P (px m)
ROOM_DISPARITY = 9.0           # px: the room's back, 5.14 m away, still
BODY_DISPARITY = 14.0          # px: a warm body 3.31 m away, walking along the rows
SPEED = 20.0                   # px/s: 0.6 px of false disparity per 30 ms of skew
BODY_COLUMNS, BODY_ROWS = 16.0, (12, 48)
LEFT_PERIOD, RIGHT_PERIOD = 0.1136, 0.1139
RIGHT_LATER = 1.051            # s: the right camera's first frame after the left one's


def texture(x, y, seed):
    """Return smooth, aperiodic thermal detail (counts about 0) at real pixel positions."""
    rng = np.random.default_rng(seed)
    out = np.zeros(np.broadcast(x, y).shape)
    for _ in range(40):
        wavelength = rng.uniform(5.0, 25.0)
        angle = rng.uniform(0.0, np.pi)
        phase = rng.uniform(0.0, 2 * np.pi)
        out += rng.uniform(10.0, 30.0) * np.cos(
            2 * np.pi * (x * np.cos(angle) + y * np.sin(angle)) / wavelength + phase)
    return out


def camera_image(seconds, right):
    """
    Return what a camera sees ``seconds`` after the recording's start.

    The still room and the body walking in front of it, its left edge at ``6 + SPEED
    (seconds - 1)`` in the left image; the right camera sees each at its own disparity. Edge
    pixels are mixed by the part of them the body covers (an optical image, no jagged edge).
    """
    y, x = np.mgrid[0:60, 0:80].astype(float)
    room = 8000.0 + texture(x + right * ROOM_DISPARITY, y, 7)
    left_edge = 6.0 + SPEED * (seconds - 1.0) - right * BODY_DISPARITY
    covered = np.clip(x + 0.5 - left_edge, 0.0, 1.0) * \
        np.clip(left_edge + BODY_COLUMNS - (x - 0.5), 0.0, 1.0)
    covered[:BODY_ROWS[0]] = covered[BODY_ROWS[1]:] = 0.0
    body = 8600.0 + texture(x - left_edge, y, 8)
    return np.rint(room + covered * (body - room)).astype(np.uint16)


def _stamp(seconds):
    ns = int(round(seconds * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _image_16uc1(pixels, stamp_s, frame_id):
    return Image(header=Header(stamp=_stamp(stamp_s), frame_id=frame_id), height=60, width=80,
                 encoding='16UC1', is_bigendian=0, step=160, data=pixels.tobytes())


def write_two_camera_bag(bag, start_s):
    """Write the two cameras' topics; return their stamps (seconds)."""
    left = [start_s + LEFT_PERIOD * i for i in range(36)]
    right = [start_s + RIGHT_LATER + RIGHT_PERIOD * i for i in range(22)]
    topics = []
    for side, stamps, tx in (('left', left, 0.0), ('right', right, -FOCAL_BASELINE)):
        frame_id = f'thermal_{side}'
        images = [_image_16uc1(camera_image(t - start_s, side == 'right'), t, frame_id)
                  for t in stamps]
        infos = [ideal_camera_info(tx, Header(stamp=_stamp(t), frame_id=frame_id))
                 for t in stamps]
        topics += [Topic(f'/thermal/{side}/image_raw', 'sensor_msgs/msg/Image', images),
                   Topic(f'/thermal/{side}/camera_info', 'sensor_msgs/msg/CameraInfo', infos)]
    write_bag(bag, 5, 'sqlite3', topics)       # the Humble layout
    return left, right


def expected_pairs(left, right, max_delta=0.05):
    """Return the nearest-stamp pairs within ``max_delta`` (left, right), worked out here."""
    pairs = []
    for r in right:
        nearest = min(left, key=lambda t: abs(t - r))
        if abs(nearest - r) <= max_delta:
            pairs.append((nearest, r))
    return pairs


class Listener(Node):
    def __init__(self, context):
        super().__init__('listener', context=context)
        reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.clouds, self.pair_infos, self.statuses, self.messages = {}, {}, {}, {}
        self.create_subscription(PointCloud2, '/stereo/points2', self._cloud,
                                 qos_profile_sensor_data)
        self.create_subscription(DiagnosticArray, '/stereo/pair_info', self._pair_info,
                                 reliable)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._diagnostics, 50)
        # A second subscriber of the raw images (the rectifier is the first): with the
        # matcher the second of camera_info, the driver waits for all three (replay_wait).
        self.raw_images = {'left': 0, 'right': 0}
        for side in self.raw_images:
            self.create_subscription(Image, f'/stereo/{side}/image_raw',
                                     lambda msg, side=side: self._count(side), reliable)

    def _count(self, side):
        self.raw_images[side] += 1

    def _diagnostics(self, msg):
        keep_statuses(self.statuses, msg)
        self.messages.update({status.name: status.message for status in msg.status})

    def _cloud(self, msg):
        self.clouds[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg

    def _pair_info(self, msg):
        values = {kv.key: kv.value for kv in msg.status[0].values}
        self.pair_infos[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = values

    def driver_finished(self):
        return any(name.endswith('lepton_driver: stereo pairs') and
                   message.startswith('finished') for name, message in self.messages.items())


def _interrupt_when_the_test_dies():
    # Linux prctl(PR_SET_PDEATHSIG, SIGINT): a pytest killed by SIGTERM (a CI timeout) left
    # the three node processes running, the driver never exiting (it stays up after its
    # bag), and on the same ROS_DOMAIN_ID they would have taken the next run's messages.
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGINT)


def _node_process(module, *parameters):
    command = [sys.executable, '-c',
               f'import sys; from st_stereo.nodes.{module} import main; sys.exit(main())',
               '--ros-args'] + [arg for p in parameters for arg in ('-p', p)]
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, preexec_fn=_interrupt_when_the_test_dies)


def _stop(processes):
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    codes = []
    for process in processes:
        try:
            codes.append(process.wait(timeout=20))
        except subprocess.TimeoutExpired:
            process.kill()
            codes.append(process.wait())
    return codes


@pytest.mark.timeout(240)
def test_two_free_running_cameras_recorded_apart_replay_through_the_processes(tmp_path):
    start_s = 1_714_557_600.25
    bag = tmp_path / 'two_cameras'
    left, right = write_two_camera_bag(bag, start_s)
    pairs = expected_pairs(left, right)
    assert len(pairs) == len(right) == 22                 # every right frame has a partner
    skews = [r - lt for lt, r in pairs]
    assert min(skews) > 0.02                             # each pair 25-35 ms apart
    processes = []
    with ros_nodes() as (context, executor, add):
        listener = add(Listener(context))
        try:
            processes += [_node_process('rectifier_node'), _node_process('matcher_node')]

            def downstream_up():
                names = ' '.join(listener.statuses)
                return 'rectifier' in names and 'matcher' in names
            spin_until(executor, downstream_up, 60.0)
            assert downstream_up(), 'the rectifier and matcher did not start'
            processes.append(_node_process('driver_node', 'source:=bag', f'bag:={bag}',
                                           'replay_subscribers:=2'))
            spin_until(executor, listener.driver_finished, 90.0)
            assert listener.driver_finished(), listener.messages
            spin_until(executor, lambda: len(listener.clouds) >= len(pairs), 5.0)
            spin_until(executor, lambda: False, 1.5)      # the matcher's 1 Hz diagnostics
        finally:
            codes = _stop(processes)
    errors = [process.stderr.read() for process in processes]
    assert codes == [0, 0, 0], errors
    # The driver paired the two cameras as worked out from the stamps: the right camera's
    # late start costs the left camera's first second, nothing else; and it waited for its
    # consumers (a new process's publishers are discovered within a second or so; the first
    # pair went out 1.05 s after the start and was lost to them before replay_wait).
    finished = next(message for name, message in listener.messages.items()
                    if name.endswith('lepton_driver: stereo pairs'))
    assert finished == f'finished: {len(pairs)} pairs published'
    assert listener.raw_images == {'left': len(pairs), 'right': len(pairs)}
    expected = {}
    for lt, r in pairs:
        midpoint = (int(round(lt * 1e9)) + int(round(r * 1e9))) // 2
        expected[divmod(midpoint, 1_000_000_000)] = (lt, r)
    assert set(listener.pair_infos) == set(expected)
    for key, values in listener.pair_infos.items():
        lt, r = expected[key]                       # the pair's stamp: the midpoint, exact
        assert float(values['left acquisition stamp']) == pytest.approx(lt, abs=1e-6)
        assert float(values['right acquisition stamp']) == pytest.approx(r, abs=1e-6)
        assert float(values['skew (ms)']) == pytest.approx(1e3 * (r - lt), abs=1e-3)
    # Every pair's cloud: the room at its depth, the body at its own although it moved 0.6 px
    # between the two cameras' instants (the first pair has no previous pair to measure the
    # motion on: published uncorrected, counted).
    matcher = next(s for n, s in listener.statuses.items() if n.endswith('matcher: ST matching'))
    assert int(matcher['pairs pairs']) == len(pairs)
    assert len(listener.clouds) + int(matcher['pairs dropped_stale']) == len(pairs)
    assert len(listener.clouds) >= len(pairs) - 2
    assert set(listener.clouds) <= set(expected)
    assert int(matcher['skew pairs_without_previous']) == 1
    room, body = (FOCAL_BASELINE / d for d in (ROOM_DISPARITY, BODY_DISPARITY))
    uncorrected = FOCAL_BASELINE / (BODY_DISPARITY - SPEED * min(skews))
    assert uncorrected / body > 1.04                       # what the skew alone would do
    first = min(listener.clouds)
    body_depths = []
    for key, cloud in listener.clouds.items():
        z = point_cloud_array(cloud)[:, 2]
        near = z < (room + body) / 2
        assert near.sum() >= 10 and (~near).sum() >= 30, key
        # Room points beside the body's edges take some of its disparity (issue 12): the
        # room's median moves by up to 1.2 % in the pairs where the body stands mid-view.
        assert np.median(z[~near]) == pytest.approx(room, rel=0.02), key
        if key != first:
            body_depths.append(np.median(z[near]))
    # Measured: 3.25-3.38 m per pair (the body's 70-140 points), 3.32 m over the pairs;
    # uncorrected, 3.44 m (the first pair's).
    assert np.median(body_depths) == pytest.approx(body, rel=0.01)
    assert max(abs(np.array(body_depths) / body - 1)) < 0.03
