"""
The node suite with real rclpy (Fast DDS on loopback): end to end, diagnostics, bad input.

ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a per-run ROS_DOMAIN_ID come from .ci/dev.py.
"""

import os
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from ros_helpers import GatedMatch, ideal_camera_info, keep_statuses, spin_until, \
    subscribe_replay_topics
from scipy import ndimage
from sensor_msgs.msg import Image, PointCloud2
from st_stereo.core.calibration.files import CalibrationError
from st_stereo.nodes.conversions import image_to_msg, point_cloud_array
from st_stereo.nodes.driver_node import DriverNode
from st_stereo.nodes.matcher_node import MatcherNode
from st_stereo.nodes.rectifier_node import RectifierNode
from std_msgs.msg import Header

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


class Collector(Node):
    def __init__(self, context):
        super().__init__('collector', context=context, namespace='stereo')
        self.clouds, self.statuses = [], {}
        self.create_subscription(PointCloud2, 'points2', self.clouds.append,
                                 qos_profile_sensor_data)
        self.create_subscription(DiagnosticArray, '/diagnostics',
                                 lambda msg: keep_statuses(self.statuses, msg), 10)


@pytest.mark.timeout(180)
@pytest.mark.timeout(120)
def test_a_camera_with_agc_on_is_a_warning_naming_it(ros, monkeypatch):
    # With AGC on a Lepton sends 8-bit values in the 16-bit words: not the 14-bit counts
    # everything downstream assumes. Its telemetry says so; the driver says it too.
    import functools
    import st_stereo.lepton.simulator as simulator
    monkeypatch.setattr(simulator, 'LeptonSimulator',
                        functools.partial(simulator.LeptonSimulator, agc=True))
    context, executor, add = ros
    statuses = {}

    def keep(msg):
        for status in msg.status:
            statuses[status.name] = (status.level, status.message,
                                     {kv.key: kv.value for kv in status.values})

    add(Node('statuses', context=context)).create_subscription(DiagnosticArray, '/diagnostics',
                                                               keep, 10)
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('duration', value=3.0), Parameter('telemetry', value='footer')]))
    spin_until(executor, lambda: 'AGC' in statuses.get(
        'stereo/lepton_driver: left camera', (0, '', {}))[2], 30.0)
    level, message, values = statuses['stereo/lepton_driver: left camera']
    assert values['AGC'] == 'on' and level == DiagnosticStatus.WARN
    assert message.startswith('AGC on: 8-bit values') and '0x0100' in message
    assert driver.published > 0


def test_simulated_rig_end_to_end(ros):
    context, executor, add = ros
    # Subscribers first: the driver publishes from the moment it exists.
    add(RectifierNode(context=context))
    # The temporal check (off by default) on: the node runs it on every pair after the first.
    add(MatcherNode(context=context, parameter_overrides=[
        Parameter('temporal_tolerance_px', value=0.3)]))
    collector = add(Collector(context))
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('duration', value=6.0), Parameter('sim_depth', value=3.5),
        Parameter('telemetry', value='footer')]))
    spin_until(executor, driver.finished.is_set, 90.0)
    spin_until(executor, lambda: False, 1.5)          # drain the last pair and diagnostics
    clouds = collector.clouds
    assert len(clouds) >= 30, f'{len(clouds)} point clouds'
    # No pair lost in transit (behaviour, not a rate: the machine may be loaded; the rate is
    # measured by st-stereo rig-bench and the strict rig tests).
    assert len({(c.header.stamp.sec, c.header.stamp.nanosec) for c in clouds}) >= \
        driver.published - 1
    depths = [np.nanmedian(point_cloud_array(c)[:, 2]) for c in clouds]
    assert np.median(depths) == pytest.approx(3.5, rel=0.01)
    first = clouds[0]
    assert [f.name for f in first.fields][:3] == ['x', 'y', 'z']
    assert first.header.frame_id == 'stereo_left_optical_frame'
    pairs = collector.statuses['stereo/lepton_driver: stereo pairs']
    for key in ('Actual frequency (Hz)', 'Events in window', 'Target frequency (Hz)',
                'pair skew max (ms)', 'frames dropped (left unmatched)'):
        assert key in pairs
    camera = collector.statuses['stereo/lepton_driver: left camera']
    for key in ('crc_errors', 'gaps', 'resyncs', 'FPA temperature (K)', 'FFC state'):
        assert key in camera
    assert camera['AGC'] == 'off'
    matching = collector.statuses['stereo/matcher: ST matching']
    for key in ('features', 'matches', 'rejected_left_right', 'rejected_subpixel_range',
                'time total (ms)', 'latency from stamp, node clock, median (ms)',
                'time from arrival to points2, median (ms)', 'Actual frequency (Hz)'):
        assert key in matching
    # The driver's pair_info gives each pair's skew; the simulated plane does not move.
    assert int(matching['skew pairs_skew_compensated']) > 0
    assert int(matching['skew features_moving']) == 0
    # Pairs are checked against the one before them (a static plane: its features static).
    assert int(matching['temporal pairs_checked']) > 0
    assert int(matching['temporal features_static']) > 0


def test_parameters_out_of_range_are_rejected_with_the_reason(ros):
    context, _, add = ros
    matcher = add(MatcherNode(context=context))
    result = matcher.set_parameters([Parameter('poc_window', value=8)])[0]
    assert not result.successful and 'poc_window' in result.reason   # the descriptor's step
    # 5 was in the declared range, but its peak fit rejected every match (a review).
    result = matcher.set_parameters([Parameter('poc_window', value=5)])[0]
    assert not result.successful and 'poc_window' in result.reason
    result = matcher.set_parameters([Parameter('disparity_min', value=50)])[0]
    assert not result.successful and 'disparity_min' in result.reason
    assert matcher.set_parameters([Parameter('gamma', value=0.3)])[0].successful
    assert matcher.config.gamma == 0.3
    for name in ('target_frequency', 'pair_info_wait'):
        result = matcher.set_parameters([Parameter(name, value=float('inf'))])[0]
        assert not result.successful and f'{name}: expected a finite number' in result.reason


@pytest.mark.parametrize('name, value', [('target_frequency', 0.0),
                                         ('target_frequency', float('nan')),
                                         ('pair_info_wait', -0.1),
                                         ('pair_info_wait', float('inf'))])
def test_a_matcher_started_with_a_rate_or_wait_that_is_not_one_names_it(ros, name, value):
    context, _, _ = ros
    with pytest.raises(ValueError, match=f'{name}: expected a finite number above 0'):
        MatcherNode(context=context, parameter_overrides=[Parameter(name, value=value)])


def test_invalid_calibration_names_file_and_field(ros, tmp_path):
    context, _, _ = ros
    bad = tmp_path / 'left.yaml'
    bad.write_text('image_width: 80\nimage_height: 60\ndistortion_model: plumb_bob\n')
    with pytest.raises(CalibrationError, match=f'{bad}: missing field .camera_matrix.'):
        DriverNode(context=context, parameter_overrides=[
            Parameter('left.camera_info_url', value=f'file://{bad}')])


def _info(width, height, tx):
    return ideal_camera_info(tx, width=width, height=height)


def test_mismatched_image_and_info_are_dropped_counted_and_reported(ros):
    context, executor, add = ros
    matcher = add(MatcherNode(context=context))
    header = Header(frame_id='left')
    image = image_to_msg(np.full((60, 80), 8000, np.uint16), header)
    # The camera_info says 160x120: an error diagnostic, the pair dropped and counted.
    matcher.sync.add(0, image)
    matcher.sync.add(1, image)
    matcher.sync.add(2, _info(160, 120, 0.0))
    matcher.sync.add(3, _info(160, 120, -46.3))
    # The worker thread matches (keep_latest): wait for it, not for a fixed time.
    spin_until(executor, lambda: matcher.counts['dropped_bad_input'] == 1, 30.0)
    assert matcher.counts['dropped_bad_input'] == 1
    assert 'camera_info says 160x120' in matcher.last_error
    # ... and the node keeps running: a good pair goes through.
    header.stamp.sec = 1
    image = image_to_msg(np.full((60, 80), 8000, np.uint16), header)
    for index, msg in enumerate((image, image, _info(80, 60, 0.0), _info(80, 60, -46.3))):
        msg.header = header
        matcher.sync.add(index, msg)
    spin_until(executor, lambda: matcher.counts['matched'] == 1, 30.0)
    assert matcher.counts['matched'] == 1


def test_wrong_encoding_is_dropped_and_counted(ros):
    context, _, add = ros
    rectifier = add(RectifierNode(context=context))
    header = Header(frame_id='left')
    image = image_to_msg(np.zeros((60, 80), np.uint8), header, 'mono8')
    for index, msg in enumerate((image, image, _info(80, 60, 0.0), _info(80, 60, -46.3))):
        msg.header = header
        rectifier.sync.add(index, msg)
    assert rectifier.counts['dropped_bad_input'] == 1
    assert 'expected mono16 or 16UC1, got mono8' in rectifier.last_error


def _image_as(pixels, header, encoding, pad_bytes=0, big_endian=False):
    """Return an Image of counts as another driver writes it: encoding, padding, order."""
    msg = Image(header=header, height=pixels.shape[0], width=pixels.shape[1],
                encoding=encoding, is_bigendian=int(big_endian))
    rows = pixels.astype('>u2' if big_endian else '<u2').view(np.uint8)
    rows = np.concatenate([rows, np.full((rows.shape[0], pad_bytes), 0xAB, np.uint8)], axis=1)
    msg.step = rows.shape[1]
    msg.data = rows.tobytes()
    return msg


VARIANTS = [('mono16', 0, False), ('16UC1', 0, False), ('16UC1', 6, False),
            ('mono16', 2, True)]


class RectifiedImages(Node):
    def __init__(self, context):
        super().__init__('rectified_images', context=context, namespace='stereo')
        self.images = []
        self.create_subscription(Image, 'left/image_rect', self.images.append,
                                 qos_profile_sensor_data)


def _counts_pair(sec, encoding, pad, big, border=0):
    rng = np.random.default_rng(5)
    texture = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (60, 80)), 1.0)
    texture = np.rint(8000 + 800 * texture).astype(np.uint16)
    left, right = texture.copy(), np.roll(texture, -9, axis=1)      # about 3 m
    left[:, :border] = right[:, :border] = 0          # pixels without data (rectified)
    header = Header(frame_id='left')
    header.stamp.sec = sec
    messages = [_image_as(left, header, encoding, pad, big),
                _image_as(right, header, encoding, pad, big),
                _info(80, 60, 0.0), _info(80, 60, -46.3)]
    for msg in messages:
        msg.header = header
    return messages


def test_counts_as_libuvc_camera_writes_them_are_rectified_alike(ros):
    # libuvc_camera publishes a PureThermal board's Y16 stream as 16UC1 (the same bytes as
    # mono16); sensor_msgs/Image also allows padded rows and big-endian data. The rectifier
    # refused 16UC1 ('expected mono16') and padded rows: the same counts, the same image.
    context, executor, add = ros
    rectifier = add(RectifierNode(context=context))
    collector = add(RectifiedImages(context))
    spin_until(executor, lambda: False, 1.0)          # discovery
    for sec, variant in enumerate(VARIANTS, start=1):
        for index, msg in enumerate(_counts_pair(sec, *variant)):
            rectifier.sync.add(index, msg)
        spin_until(executor, lambda: len(collector.images) == sec, 30.0)
    assert rectifier.counts['dropped_bad_input'] == 0
    assert len(collector.images) == len(VARIANTS)
    assert {msg.encoding for msg in collector.images} == {'mono16'}
    assert len({bytes(msg.data) for msg in collector.images}) == 1


def test_rectified_counts_in_16uc1_are_matched_as_mono16_with_their_border(ros):
    # image_proc keeps its input's encoding: a 16UC1 camera gives 16UC1 rectified images,
    # whose 0 is a pixel without data as in mono16 (a 12-column border here).
    context, executor, add = ros
    matcher = add(MatcherNode(context=context, parameter_overrides=[
        Parameter('keep_latest', value=False)]))
    collector = add(Collector(context))
    spin_until(executor, lambda: False, 1.0)          # discovery
    for sec, variant in enumerate(VARIANTS, start=1):
        _feed(matcher, _counts_pair(sec, *variant, border=12))
        spin_until(executor, lambda: len(collector.clouds) == sec, 30.0)
    assert matcher.counts['dropped_bad_input'] == 0
    assert len(collector.clouds) == len(VARIANTS)
    first = point_cloud_array(collector.clouds[0])
    assert len(first) > 20
    assert np.median(first[:, 2]) == pytest.approx(46.3 / 9, rel=0.01)
    for cloud in collector.clouds[1:]:
        assert np.array_equal(point_cloud_array(cloud), first)


def test_image_messages_round_trip():
    from st_stereo.nodes.conversions import msg_to_image
    pixels = np.arange(4800, dtype=np.uint16).reshape(60, 80)
    msg = image_to_msg(pixels, Header())
    assert msg.step == 160 and msg.encoding == 'mono16'
    assert np.array_equal(msg_to_image(msg), pixels)
    msg.step = 100
    with pytest.raises(ValueError, match='image step: expected at least 160'):
        msg_to_image(msg)
    msg.step = 162                                  # padded rows: the data must hold them
    with pytest.raises(ValueError, match='image data: expected 9720 bytes, got 9600'):
        msg_to_image(msg)
    padded = _image_as(pixels, Header(), '16UC1', pad_bytes=4, big_endian=True)
    assert np.array_equal(msg_to_image(padded, 'mono16'), pixels)
    with pytest.raises(ValueError, match='expected 32FC1, got 16UC1'):
        msg_to_image(padded, '32FC1')


def test_cloud_layout(ros):
    from st_stereo.nodes.conversions import point_cloud
    cloud = point_cloud(Header(), np.ones((3, 3)), np.ones(3), np.ones(3), np.ones(3))
    assert (cloud.height, cloud.width, cloud.point_step, cloud.row_step) == (1, 3, 36, 108)
    assert [f.offset for f in cloud.fields][:3] == [0, 4, 8] and cloud.is_dense
    assert [f.name for f in cloud.fields][-3:] == ['confidence', 'u', 'v']
    assert np.isnan(point_cloud_array(cloud)[:, -2:]).all()        # no pixels given
    values = point_cloud_array(point_cloud(Header(), np.ones((2, 3)), np.ones(2), np.ones(2),
                                           np.ones(2), np.array([0.25, 0.75]),
                                           (np.array([10.0, 11.0]), np.array([20.0, 21.0]))))
    assert values[:, -3].tolist() == [0.25, 0.75]
    assert values[:, -2:].tolist() == [[10.0, 20.0], [11.0, 21.0]]


def call_service(executor, client, request, timeout_s=30.0):
    """Call a ROS service through its client and return the response (spinning meanwhile)."""
    assert client.wait_for_service(timeout_sec=timeout_s), f'{client.srv_name}: no service'
    future = client.call_async(request)
    spin_until(executor, future.done, timeout_s)
    assert future.done(), f'{client.srv_name}: no response in {timeout_s} s'
    return future.result()


@pytest.mark.timeout(180)
def test_services_trigger_ffc_and_set_camera_info(ros, tmp_path):
    # Through the driver's ROS services, as a user's `ros2 service call` reaches them: a
    # service left unregistered, renamed, or answering with the wrong type fails here.
    from sensor_msgs.srv import SetCameraInfo
    from st_stereo.core.calibration.files import (calibration_from_camera_info,
                                                  load_calibration, save_calibration)
    from std_srvs.srv import Trigger
    context, executor, add = ros
    target = tmp_path / 'left.yaml'
    save_calibration(calibration_from_camera_info(_info(80, 60, 0.0), 'left'), target)
    assert load_calibration(target).camera_matrix[0, 0] != 85.0
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('left.camera_info_url', value=f'file://{target}')]))
    client_node = add(Node('service_client', context=context, namespace='stereo'))
    ffc = client_node.create_client(Trigger, 'trigger_ffc')
    response = call_service(executor, ffc, Trigger.Request())
    assert response.success and 'FFC started' in response.message
    # SetCameraInfo writes camera_calibration YAML to the camera_info_url and is used at once.
    set_info = client_node.create_client(SetCameraInfo, 'left/set_camera_info')
    request = SetCameraInfo.Request()
    request.camera_info = _info(80, 60, 0.0)
    request.camera_info.k[0] = 85.0
    response = call_service(executor, set_info, request)
    assert response.success, response.status_message
    assert load_calibration(target).camera_matrix[0, 0] == 85.0
    assert driver.calibrations[0].camera_matrix[0, 0] == 85.0
    request.camera_info.width = 160
    response = call_service(executor, set_info, request)
    assert not response.success and '160x60' in response.status_message
    assert driver.calibrations[0].camera_matrix[0, 0] == 85.0


@pytest.mark.timeout(180)
def test_driver_replays_plain_byte_captures_in_the_mode_their_data_show(ros, tmp_path):
    # Plain SPI bytes of cameras with a telemetry header, cut mid-packet: the telemetry
    # parameter (default off) does not apply to a capture; the mode is detected, and every
    # published image is a frame the camera sent (the default 'off' made them all corrupt).
    from st_stereo.lepton.capture import decode_capture
    from st_stereo.lepton.cli import simulate_capture
    paths, sent = [], set()
    for side, seed in (('left', 1), ('right', 2)):
        full = tmp_path / f'{side}_full.bin'
        simulate_capture(full, 3.0, 'header', None, seed=seed, plain=True)
        frames, _, mode = decode_capture(full)
        assert mode == 'header'
        sent |= {frame.pixels.tobytes() for frame in frames}
        cut = tmp_path / f'{side}.bin'
        cut.write_bytes(full.read_bytes()[57:])
        paths.append(cut)
    context, executor, add = ros
    images = []
    listener = add(Node('images', context=context, namespace='stereo'))
    listener.create_subscription(Image, 'left/image_raw', images.append, 50)
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('source', value='capture'), Parameter('left_capture', value=str(paths[0])),
        Parameter('right_capture', value=str(paths[1]))]))
    spin_until(executor, driver.finished.is_set, 60.0)
    spin_until(executor, lambda: False, 1.0)
    assert len(images) >= 5
    pixels = [np.frombuffer(bytes(m.data), '<u2').reshape(m.height, m.width).tobytes()
              for m in images]
    assert all(p in sent for p in pixels)


@pytest.mark.timeout(180)
def test_driver_flags_every_pair_whose_image_an_ffc_moved(ros, tmp_path, monkeypatch):
    # Captures of two cameras: the right one runs FFCs (frozen frames, then its level jumps
    # by 25 counts), the left one has CRC errors, and the driver drops a frame whose
    # acquisition time is then unknown: 7 of the right camera's 11 FFC-flagged frames find no
    # partner (without the driver's PairFfcFlags the second FFC's pair goes out unflagged).
    # Whatever was paired, a published right image whose level moved from the previous
    # published one must come with 'right ffc' True in pair_info (the skew compensation must
    # not compare the two). Recorded at the publish call: no DDS queue can lose a message.
    from rclpy.publisher import Publisher
    from st_stereo.lepton.cli import simulate_capture
    from st_stereo.lepton.simulator import FaultPlan
    paths = [tmp_path / 'left.bin', tmp_path / 'right.bin']
    simulate_capture(paths[0], 20.0, 'footer', FaultPlan({'crc': 0.2}), seed=1)
    simulate_capture(paths[1], 20.0, 'footer', FaultPlan({'ffc_freeze': 0.1}), seed=2)
    published = []
    publish = Publisher.publish

    def record(self, msg):
        published.append((self.topic_name, msg))
        return publish(self, msg)
    monkeypatch.setattr(Publisher, 'publish', record)
    context, executor, add = ros
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('source', value='capture'), Parameter('left_capture', value=str(paths[0])),
        Parameter('right_capture', value=str(paths[1])),
        Parameter('replay_rate', value=0.0)]))     # as fast as read: 20 s of capture
    spin_until(executor, driver.finished.is_set, 90.0)

    def stamp(msg):
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    levels = {stamp(msg): np.frombuffer(bytes(msg.data), '<u2').mean()
              for topic, msg in published if topic.endswith('right/image_raw')}
    flags = {stamp(msg): {kv.key: kv.value for kv in msg.status[0].values}['right ffc']
             for topic, msg in published if topic.endswith('/pair_info')}
    assert len(levels) > 40 and set(levels) == set(flags)
    order = sorted(levels)
    moved = [b for a, b in zip(order, order[1:]) if abs(levels[b] - levels[a]) > 12.0]
    assert moved, 'no FFC moved a published image: the case tests nothing'
    assert [flags[s] for s in moved] == ['True'] * len(moved)


def _textured_pair(stamp_sec):
    rng = np.random.default_rng(stamp_sec)
    texture = 7800 + 400 * rng.random((60, 80))
    header = Header(frame_id='left')
    header.stamp.sec = stamp_sec
    messages = [image_to_msg(texture.astype(np.uint16), header),
                image_to_msg(np.roll(texture, -5, axis=1).astype(np.uint16), header),
                _info(80, 60, 0.0), _info(80, 60, -46.3)]
    for msg in messages:
        msg.header = header
    return messages


def _feed(matcher, messages):
    for index, msg in enumerate(messages):
        matcher.sync.add(index, msg)


def test_a_slow_matcher_drops_stale_pairs_counted_and_publishes_the_newest(ros):
    # Would catch: pairs queued behind a slow match (latency growing by a period per pair),
    # a replaced pair not counted, the newest pair lost instead of the stale ones.
    context, executor, add = ros
    matcher = add(MatcherNode(context=context))
    collector = add(Collector(context))
    gated = GatedMatch(matcher.matcher.match)
    matcher.matcher.match = gated
    spin_until(executor, lambda: False, 1.0)          # discovery
    _feed(matcher, _textured_pair(1))
    assert gated.entered.wait(30.0)                   # pair 1 is being matched ...
    for sec in (2, 3, 4):                             # ... while three more arrive
        _feed(matcher, _textured_pair(sec))
    assert matcher.counts['dropped_stale'] == 2       # 2 and 3 replaced; 4 waits
    gated.gate.set()
    # The cloud goes out before the worker counts it: wait for both.
    spin_until(executor, lambda: len(collector.clouds) == 2 and
               matcher.counts['matched'] == 2, 30.0)
    assert [c.header.stamp.sec for c in collector.clouds] == [1, 4]
    counts = matcher.counts
    assert (counts['pairs'], counts['matched'], counts['dropped_stale']) == (4, 2, 2)

    def stale_in_diagnostics():
        return collector.statuses.get('stereo/matcher: ST matching', {}) \
            .get('pairs dropped_stale')

    spin_until(executor, lambda: stale_in_diagnostics() == '2', 10.0)    # 1 Hz diagnostics
    assert stale_in_diagnostics() == '2'


def test_without_keep_latest_every_pair_is_matched_in_order(ros):
    context, executor, add = ros
    matcher = add(MatcherNode(context=context, parameter_overrides=[
        Parameter('keep_latest', value=False)]))
    collector = add(Collector(context))
    spin_until(executor, lambda: False, 1.0)
    for sec in (1, 2, 3):
        _feed(matcher, _textured_pair(sec))
        assert matcher.counts['matched'] == sec       # matched inside the callback
    spin_until(executor, lambda: len(collector.clouds) == 3, 30.0)
    assert [c.header.stamp.sec for c in collector.clouds] == [1, 2, 3]
    assert matcher.counts['dropped_stale'] == 0


def test_an_unexpected_error_in_the_worker_is_counted_and_the_next_pair_matched(ros):
    # Would catch: the worker thread dying on an exception (every later pair lost, unseen).
    context, executor, add = ros
    matcher = add(MatcherNode(context=context))
    original = matcher.matcher.match
    calls = []

    def failing_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError('simulated failure')
        return original(*args, **kwargs)

    matcher.matcher.match = failing_once
    _feed(matcher, _textured_pair(1))
    spin_until(executor, lambda: matcher.counts['dropped_internal_error'] == 1, 30.0)
    assert 'RuntimeError: simulated failure' in matcher.last_error
    _feed(matcher, _textured_pair(2))
    spin_until(executor, lambda: matcher.counts['matched'] == 1, 30.0)
    assert matcher.counts['matched'] == 1 and matcher.last_error == ''


def test_latest_slot_keeps_the_newest_item_and_counts_the_replaced():
    from st_stereo.nodes.runtime import LatestSlot
    slot = LatestSlot()
    assert slot.take(timeout=0.01) is None            # nothing yet
    # Idle consumer: two items handed over at once are both kept, in order; a third
    # pushes the oldest out (counted).
    assert slot.put('a') == 0 and slot.put('b') == 0
    assert slot.put('c') == 1
    assert slot.take() == 'b'                         # now busy with 'b'
    # Busy consumer: a newer item replaces the one waiting.
    assert slot.put('d') == 1 and slot.put('e') == 1  # 'c', then 'd' replaced
    assert (slot.take(), slot.replaced) == ('e', 3)
    assert slot.take(timeout=0.01) is None            # emptied
    slot.put('f')
    assert slot.close() == 1                          # 'f' was still waiting: dropped
    assert slot.take() is None                        # closed: returns at once


def test_a_runtime_error_is_the_shutdown_only_once_the_context_is_shut_down():
    # CI once saw stereo_pipeline exit 1 after a clean Ctrl-C: the signal handler shut the
    # context down while the executor was taking a message, and the take raised RuntimeError.
    import rclpy
    from st_stereo.nodes.runtime import until_shutdown
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(RuntimeError, match='while running'):
            with until_shutdown(context):
                raise RuntimeError('a failure while running')
        rclpy.shutdown(context=context)
        with until_shutdown(context):
            raise RuntimeError("Unable to convert call argument '0' to Python object")
    finally:
        rclpy.try_shutdown(context=context)


def test_node_processes_spin_on_the_events_executor_unless_told_otherwise(ros, monkeypatch):
    context = ros[0]
    from rclpy.executors import SingleThreadedExecutor
    from st_stereo.nodes.runtime import EXECUTOR_VARIABLE, node_executor
    monkeypatch.delenv(EXECUTOR_VARIABLE, raising=False)
    try:
        from rclpy.experimental import EventsExecutor  # noqa: F401
        expected = 'EventsExecutor'
    except ImportError:                                 # an rclpy without it falls back
        expected = 'SingleThreadedExecutor'
    assert type(node_executor(context)).__name__ == expected
    monkeypatch.setenv(EXECUTOR_VARIABLE, 'single')
    assert isinstance(node_executor(context), SingleThreadedExecutor)
    monkeypatch.setenv(EXECUTOR_VARIABLE, 'fast')
    with pytest.raises(ValueError, match='ST_STEREO_EXECUTOR: expected one of events, '
                                         'single, got .fast.'):
        node_executor(context)


@pytest.mark.parametrize('signal_name', ['SIGINT', 'SIGTERM'])
def test_a_node_process_ends_cleanly_on_a_signal(signal_name):
    # The events executor's spin() never returned after a signal's shutdown (rclpy 7.1.6):
    # the process hung until killed, and launch would have waited for it.
    import signal
    import subprocess
    import sys
    import time
    process = subprocess.Popen(
        [sys.executable, '-c', 'import sys; from st_stereo.nodes.rectifier_node import main; '
         'sys.exit(main())'], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(3.0)                                 # imported and spinning
        assert process.poll() is None
        process.send_signal(getattr(signal, signal_name))
        assert process.wait(timeout=15) == 0, process.stderr.read()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


SIGNAL_MID_PAIR = """
import json, os, signal, sys, time
import rclpy
from rclpy.parameter import Parameter
from st_stereo.nodes import runtime
from st_stereo.nodes.driver_node import DriverNode

counts = {'left': 0, 'right': 0, 'pair_info': 0}


def counted(name, publish):
    def wrapped(msg):
        if name == 'right' and counts['right'] == 4:    # Ctrl-C between a pair's images
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)
        publish(msg)
        counts[name] += 1
    return wrapped


def build():
    driver = DriverNode(parameter_overrides=[Parameter('source', value='sim')])
    for index, name in enumerate(('left', 'right')):
        driver.image_pubs[index].publish = counted(name, driver.image_pubs[index].publish)
    driver.pair_info_pub.publish = counted('pair_info', driver.pair_info_pub.publish)
    return [driver]


if sys.argv[1] == 'orderly':
    code = runtime.run_nodes(build)
else:                                  # rclpy's own signal handler, as before 2026-12-07
    rclpy.init()
    executor = runtime.node_executor()
    nodes = build()
    executor.add_node(nodes[0])
    try:
        runtime.spin_until_shutdown(executor)
    finally:
        nodes[0].destroy_node()
        rclpy.try_shutdown()
    code = 0
print(json.dumps(counts))
sys.exit(code)
"""


def test_ctrl_c_between_the_images_of_a_pair_lets_the_driver_finish_the_pair(tmp_path):
    # rclpy's handler shuts the context down inside the signal: the driver's thread, between
    # the left and the right image, then failed the rest of the pair (a subscriber or a bag
    # got a left image without its right one: seen in CI, 2026-12-06). run_nodes turns the
    # signal into a stop request and destroys the nodes (joining the driver's thread) before
    # shutting the context down. The control runs the same process with rclpy's handler.
    import json
    import subprocess
    import sys
    script = tmp_path / 'signal_mid_pair.py'
    script.write_text(SIGNAL_MID_PAIR)
    counts = {}
    for mode in ('orderly', 'rclpy'):
        result = subprocess.run([sys.executable, str(script), mode], capture_output=True,
                                text=True, timeout=60)
        assert result.returncode == 0, result.stderr[-2000:]
        assert 'Traceback' not in result.stderr, result.stderr[-2000:]
        counts[mode] = json.loads(result.stdout.strip().splitlines()[-1])
    assert counts['orderly']['left'] >= 5
    assert counts['orderly']['left'] == counts['orderly']['right'] == \
        counts['orderly']['pair_info'], counts
    # The control: the same signal with rclpy's handler loses the pair's right image.
    assert counts['rclpy']['right'] == counts['rclpy']['left'] - 1, counts


SLOW_TO_STOP = """
import sys, time
from rclpy.node import Node
from st_stereo.nodes import runtime


class SlowToStop(Node):
    def destroy_node(self):
        print('stopping', flush=True)
        time.sleep(3.0)
        print('stopped', flush=True)
        return super().destroy_node()


def build():
    print('spinning', flush=True)
    return [SlowToStop('slow_to_stop')]


sys.exit(runtime.run_nodes(build))
"""


@pytest.mark.parametrize('second_after_s, code', [(0.1, 0), (1.6, 130)],
                         ids=['same-request', 'forced'])
def test_a_second_signal_forces_the_stop_only_after_the_repeat_window(
        tmp_path, second_after_s, code):
    # launch and a terminal may both signal a process at once: the same request. A second
    # Ctrl-C later means do not wait: exit 130, said on standard error.
    import signal
    import subprocess
    import sys
    import time
    script = tmp_path / 'slow_to_stop.py'
    script.write_text(SLOW_TO_STOP)
    process = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == 'spinning'
        time.sleep(0.5)
        process.send_signal(signal.SIGINT)
        assert process.stdout.readline().strip() == 'stopping'
        time.sleep(second_after_s)
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == code, err[-2000:]
    assert 'Traceback' not in err, err[-2000:]
    assert ('stopped' in out) == (code == 0)
    assert ('stopped by a second signal' in err) == (code != 0)


def test_a_camera_info_opencv_or_rectification_cannot_use_is_dropped_and_named(ros):
    # An independent review: a distortion vector of the wrong length killed the rectifier
    # process (cv2.error), and NaN or absurd values rectified to blank images under an OK
    # status; a K changed alone kept the old maps.
    context, _, add = ros
    rectifier = add(RectifierNode(context=context))
    rng = np.random.default_rng(0)
    texture = rng.normal(8000.0, 30.0, (60, 80))
    header = Header(frame_id='left')
    left = image_to_msg(texture.astype(np.uint16), header)
    right = image_to_msg(np.roll(texture, -5, axis=1).astype(np.uint16), header)
    published = []
    rectifier.image_pubs[0].publish = published.append

    def pair(left_info):
        rectifier._on_pair(left, right, left_info, _info(80, 60, -46.3))

    cases = [({'distortion_model': 'equidistant'}, 'for equidistant must hold 4 values, got 5'),
             ({'d': [0.0] * 3}, 'for plumb_bob must hold 5 values, got 3'),
             ({'k': [84.0, 0, 40.0, 0, float('nan'), 30.0, 0, 0, 1]},
              'camera_matrix.data holds non-finite values'),
             ({'r': [0.0] * 9}, 'rectification_matrix R is not a rotation'),
             ({'d': [1e6, 0, 0, 0, 0]}, 'the calibration maps 0 of 4800 rectified pixels')]
    for dropped, (change, message) in enumerate(cases, start=1):
        info = _info(80, 60, 0.0)
        for field, value in change.items():
            setattr(info, field, value)
        pair(info)
        assert rectifier.counts['dropped_bad_input'] == dropped, change
        assert message in rectifier.last_error, rectifier.last_error
    assert not published
    pair(_info(80, 60, 0.0))
    assert rectifier.last_error == '' and len(published) == 1
    wider = _info(80, 60, 0.0)
    wider.k = [120.0, 0.0, 40.0, 0.0, 120.0, 30.0, 0.0, 0.0, 1.0]
    pair(wider)                                   # K alone changed: new maps
    assert len(published) == 2 and bytes(published[1].data) != bytes(published[0].data)
    resized = _info(80, 60, 0.0)
    resized.width = 81
    pair(resized)
    assert 'left is 81x60 but right is 80x60' in rectifier.last_error


def test_pairs_the_exact_stamp_sync_drops_are_an_error_naming_it(ros):
    # The review: with the right stream stamped 1 ns later than the left one every pair was
    # dropped while the rectifier said OK "rectifying" and the matcher "No events recorded.".
    context, _, add = ros
    rectifier = add(RectifierNode(context=context))
    published = []
    rectifier.diagnostics_pub.publish = published.append
    rectifier._publish_diagnostics()                 # the watch's first look
    for sec in range(1, 16):
        left, right = Header(frame_id='left'), Header(frame_id='right')
        left.stamp.sec, right.stamp.sec, right.stamp.nanosec = sec, sec, 1
        rectifier.sync.add(0, image_to_msg(np.full((60, 80), 8000, np.uint16), left))
        rectifier.sync.add(1, image_to_msg(np.full((60, 80), 8000, np.uint16), right))
        rectifier.sync.add(2, _info(80, 60, 0.0))
    assert rectifier.counts['pairs'] == 0 and sum(rectifier.sync.dropped) > 0
    rectifier._publish_diagnostics()
    status = published[-1].status[0]
    assert status.level == DiagnosticStatus.ERROR
    assert status.message.startswith('no pair in the last period: ')
    assert 'dropped by the exact-stamp sync of left/image_raw, right/image_raw, ' \
        'left/camera_info, right/camera_info (their stamps must be equal)' in status.message


def test_counts_above_14_bits_are_rectified_and_said(ros):
    # A radiometric Lepton in TLinear mode (which PureThermal firmware may restore) gives
    # centikelvin, about 30,000 at room temperature: rectified, but the count parameters
    # downstream assume raw counts, and nothing said so.
    context, _, add = ros
    rectifier = add(RectifierNode(context=context))
    for sec, level in ((1, 29_500), (2, 8_000)):
        for index, msg in enumerate(_counts_pair(sec, '16UC1', 0, False)):
            if index < 2:
                pixels = np.frombuffer(bytes(msg.data), '<u2').astype(int) - 8000 + level
                msg.data = pixels.astype('<u2').tobytes()
            rectifier.sync.add(index, msg)
        status = rectifier.status()
        if sec == 1:
            assert status.level == DiagnosticStatus.WARN
            assert status.message.startswith('left and right image_raw above 16383: not 14-bit '
                                             'raw counts (a radiometric Lepton in TLinear')
    assert rectifier.counts['rectified'] == 2 and rectifier.counts['pairs_above_14_bits'] == 1
    assert status.level == DiagnosticStatus.OK         # the state is the latest pair's


@pytest.mark.timeout(120)
@pytest.mark.parametrize('rate', [1.0, 2.0])
def test_a_capture_replays_at_its_recorded_pace_times_replay_rate(ros, tmp_path, rate):
    # Captures were replayed as fast as they were decoded (a 3 s capture in well under a
    # second, a consumer with keep_latest then dropping most pairs). Pacing can only make
    # the replay slower than its recorded span: the check is a lower bound.
    from st_stereo.lepton.capture import decode_capture
    from st_stereo.lepton.cli import simulate_capture
    paths = [tmp_path / 'left.bin', tmp_path / 'right.bin']
    for path, seed in zip(paths, (1, 2)):
        simulate_capture(path, 3.0, 'footer', None, seed=seed)
    frames = decode_capture(paths[0])[0]
    span = frames[-1].stamp - frames[0].stamp
    assert span > 2.5
    context, executor, add = ros
    arrivals = []
    listener = add(Node('images', context=context, namespace='stereo'))
    subscribe_replay_topics(listener)
    listener.create_subscription(Image, 'left/image_raw',
                                 lambda msg: arrivals.append(time.monotonic()), 50)
    driver = add(DriverNode(context=context, parameter_overrides=[
        Parameter('source', value='capture'), Parameter('left_capture', value=str(paths[0])),
        Parameter('right_capture', value=str(paths[1])), Parameter('replay_rate', value=rate)]))
    spin_until(executor, driver.finished.is_set, 60.0)
    spin_until(executor, lambda: False, 0.5)
    assert len(arrivals) >= 0.8 * len(frames) and driver.published == len(arrivals)
    # The last pair is released once the wall clock reaches its recorded time / rate.
    assert arrivals[-1] - arrivals[0] >= 0.9 * span / rate - 2 * 0.1136
