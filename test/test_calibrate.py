"""
st-stereo calibrate: target detection at 80x60, stereo calibration, YAML out, bad input.

The sessions are rendered through the realistic simulated rig (barrel distortion, a rotated
right camera with a 0.6 % longer focal length, Lepton blur and noise), so every recovered
number is checked against the truth it was rendered with.
"""

import json
import os

import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import ros_nodes, spin_for, spin_until_finished
from sensor_msgs.msg import Image
from st_stereo.cli import main
from st_stereo.core.calibration.files import load_calibration
from st_stereo.core.calibration.targets import (CalibrationInputError, CalibrationTarget,
                                                detect_target, find_target, grid_numberings,
                                                stereo_numbering)
from st_stereo.core.rectification import StereoRectifier
from st_stereo.nodes.conversions import msg_to_image
from st_stereo.nodes.driver_node import DriverNode
from st_stereo.nodes.rectifier_node import RectifierNode
from st_stereo.sim.recording import write_pairs_bag
from st_stereo.sim.render import render_temperature
from st_stereo.sim.rig import realistic_rig, rotation_xyz
from st_stereo.sim.sensor import LeptonSensor, SensorModel
from st_stereo.sim.targets import calibration_scene, PatternMaterial, render_calibration_pairs, \
    target_poses
from st_stereo.tools.calibrate import calibrate, Collector

os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

CIRCLES = CalibrationTarget('circles', 5, 7, 0.1)
CHESSBOARD = CalibrationTarget('chessboard', 5, 7, 0.09)
TARGET_ARGS = ['--target', 'circles', '--rows', '5', '--cols', '7', '--spacing', '0.1']


def test_target_object_points_follow_opencv_conventions():
    points = CalibrationTarget('acircles', 4, 3, 0.1).object_points()
    assert points.shape == (12, 3)
    # Asymmetric: odd rows are offset by half the spacing, rows are half a spacing apart.
    np.testing.assert_allclose(points[:4, :2], [[0, 0], [0.1, 0], [0.2, 0], [0.05, 0.05]])
    assert CHESSBOARD.pattern_size == (7, 5)
    for bad, message in ((('hexagons', 4, 5, 0.1), 'kind must be one of'),
                         (('circles', 4, 4, 0.1), 'no defined orientation'),
                         (('chessboard', 1, 5, 0.1), 'at least 2 x 2'),
                         (('circles', 4, 5, 0.0), 'spacing must be positive')):
        with pytest.raises(CalibrationInputError, match=message):
            CalibrationTarget(*bad)


@pytest.mark.parametrize('target,warm', [(CIRCLES, True), (CIRCLES, False),
                                         (CHESSBOARD, True)],
                         ids=['warm-dots', 'cold-holes', 'chessboard'])
def test_targets_are_found_to_a_few_hundredths_of_a_pixel_at_80x60(target, warm):
    rig = realistic_rig()
    pairs, poses = render_calibration_pairs(rig, target, 10, seed=4, warm_features=warm,
                                            supersample=4)
    errors, found = [], 0
    for pair, (origin, rotation) in zip(pairs, poses):
        for image, camera in zip(pair, rig.cameras()):
            detection = detect_target(image, target)
            if detection is None:
                continue
            found += 1
            if target.kind != 'chessboard':     # an inverted chessboard is still a chessboard
                assert detection.warm_features == warm        # polarity found automatically
            truth = camera.project(origin + target.object_points().astype(float) @ rotation.T)
            errors.append(np.linalg.norm(detection.points - truth, axis=1))
    assert found >= 8
    errors = np.concatenate(errors)
    # The true projection of a circle's centre is not its blob's centre under perspective;
    # the difference (<= 0.05 px here) is part of this error.
    assert np.median(errors) < 0.05
    assert np.percentile(errors, 95) < 0.12
    assert errors.max() < 0.3


def _render_one(rig, target, pose):
    sensor = LeptonSensor(SensorModel(seed=3, ffc_period_s=0.0), (rig.height, rig.width))
    return sensor.frame(render_temperature(calibration_scene(target, pose), rig.cameras()[0], 3),
                        0.0)


@pytest.mark.parametrize('flip', ['rows', 'columns', 'half turn'])
def test_the_right_cameras_grid_is_numbered_as_the_left_one(flip):
    left = CIRCLES.object_points()[:, :2].astype(np.float64) * 300.0 + [10.0, 8.0]
    left = left @ np.array([[0.8, 0.6], [-0.6, 0.8]]).T      # turned 37 degrees in the image
    grid = (left + [-6.0, 0.3]).reshape(CIRCLES.rows, CIRCLES.cols, 2)
    grid = {'rows': grid[::-1], 'columns': grid[:, ::-1], 'half turn': grid[::-1, ::-1]}[flip]
    np.testing.assert_allclose(stereo_numbering(CIRCLES, left, grid.reshape(-1, 2)),
                               left + [-6.0, 0.3])


@pytest.mark.parametrize('target,flip', [(CalibrationTarget('acircles', 4, 7, 0.1), 'half turn'),
                                         (CalibrationTarget('acircles', 5, 5, 0.1), 'rows')],
                         ids=['acircles-4x7', 'acircles-5x5'])
def test_an_asymmetric_grid_is_renumbered_only_by_its_own_symmetry(target, flip):
    # An asymmetric grid allows fewer numberings: even rows the half turn, odd rows reversed.
    left = target.object_points()[:, :2].astype(np.float64) * 300.0 + [10.0, 8.0]
    grid = (left + [-6.0, 0.3]).reshape(target.rows, target.cols, 2)
    grid = {'rows': grid[::-1], 'half turn': grid[::-1, ::-1]}[flip]
    assert len(grid_numberings(target, grid.reshape(-1, 2))) == 2
    np.testing.assert_allclose(stereo_numbering(target, left, grid.reshape(-1, 2)),
                               left + [-6.0, 0.3], atol=1e-9)


def test_a_chessboard_turned_far_in_its_plane_is_numbered_alike_in_both_images():
    # Rendered: turned 105 degrees, the right image's detector numbered it from another
    # corner; a stereo view so numbered would pull stereoCalibrate's R and T off.
    rig = realistic_rig()
    cameras = rig.cameras()
    x0, y0, x1, y1 = PatternMaterial(CHESSBOARD).extent()
    rotation = cameras[0].rotation.T @ rotation_xyz(105, 0, 0) @ rotation_xyz(0, 20, 0)
    origin = cameras[0].centre + cameras[0].rotation[2] * 1.6 - \
        rotation @ [(x0 + x1) / 2, (y0 + y1) / 2, 0.0]
    scene = calibration_scene(CHESSBOARD, (origin, rotation))
    frames = [LeptonSensor(SensorModel(seed=seed, ffc_period_s=0.0), (60, 80)).frame(
        render_temperature(scene, camera, 4), 0.0, True)
        for seed, camera in zip((1, 2), cameras)]
    left, right = Collector(CHESSBOARD).add('turned', *frames)
    world = origin + CHESSBOARD.object_points().astype(np.float64) @ rotation.T
    numbering = []
    for camera, detection in zip(cameras, (left, right)):
        true = camera.project(world)
        nearest = np.linalg.norm(detection.points[:, None] - true[None], axis=2).argmin(axis=1)
        np.testing.assert_allclose(detection.points, true[nearest], atol=0.3)
        numbering.append(nearest)
    # Either corner may come first (the grid is symmetric), but the same in both images.
    np.testing.assert_array_equal(numbering[0], numbering[1])


def test_rejected_images_say_why():
    rig = realistic_rig()
    flat = np.full((60, 80), 8000, np.uint16)
    assert find_target(flat, CIRCLES) == (None, 'not found')
    # 3.2 m away the circles are ~2.6 px apart: blobs merge, refused as too small.
    far = target_poses(rig, CIRCLES, 1, seed=2, distance=(3.2, 3.3), max_tilt_deg=5.0)[0]
    assert find_target(_render_one(rig, CIRCLES, far), CIRCLES) == (None, 'too small')
    near = target_poses(rig, CIRCLES, 1, seed=2, distance=(1.2, 1.3), max_tilt_deg=5.0)[0]
    detection, reason = find_target(_render_one(rig, CIRCLES, near), CIRCLES)
    assert reason is None and detection.points.shape == (35, 2)


# A session of 40 pairs (users collect 30-60): 10 with the target in both views. 60 pairs
# gave the same recovery (intrinsics within 0.6 % either way) in half again the time.
SESSION_PAIRS = 40


@pytest.fixture(scope='module')
def circle_session(tmp_path_factory):
    """Record a session as a rosbag2 and calibrate it with ``calibrate --bag``."""
    rig = realistic_rig()
    pairs, _ = render_calibration_pairs(rig, CIRCLES, SESSION_PAIRS, seed=1, supersample=4)
    out = tmp_path_factory.mktemp('calibration')
    write_pairs_bag(pairs, out / 'bag')
    code = main(['calibrate', '--bag', str(out / 'bag')] + TARGET_ARGS +
                ['--out', str(out / 'result'), '--quiet'])
    assert code == 0
    return rig, out, pairs


def test_calibration_recovers_the_rig(circle_session):
    rig, out, _ = circle_session
    report = json.loads((out / 'result' / 'calibration_report.json').read_text())
    assert report['pairs']['pairs'] == SESSION_PAIRS
    assert report['baseline_m'] == pytest.approx(rig.baseline_m, rel=0.02)
    assert report['rectified_vertical_disparity_px']['median'] <= 0.1
    assert report['rms_px']['left'] < 0.1 and report['rms_px']['right'] < 0.1
    for side, camera in zip(('left', 'right'), rig.cameras()):
        k = camera.camera_matrix
        for name, (i, j) in (('fx', (0, 0)), ('fy', (1, 1)), ('cx', (0, 2)), ('cy', (1, 2))):
            assert report[side][name] == pytest.approx(k[i, j], rel=0.01), (side, name)
    # Every image is accounted for: found, or rejected with a reason.
    for side in ('left', 'right'):
        found = report['pairs']['both'] + report['pairs'][f'{side}_only']
        assert found + sum(report['rejected_images'][side].values()) == SESSION_PAIRS
    assert (out / 'result' / 'calibration.png').stat().st_size > 1000
    assert 'coverage' in (out / 'result' / 'calibration_report.txt').read_text()


def test_calibrated_yaml_rectifies_target_rows_onto_equal_rows(circle_session):
    rig, out, pairs = circle_session
    left = load_calibration(out / 'result' / 'left.yaml')
    right = load_calibration(out / 'result' / 'right.yaml')
    assert left.distortion_model == 'plumb_bob' and len(left.distortion) == 5
    assert right.projection[0, 3] < 0
    rectifier = StereoRectifier(left, right)
    differences = []
    for raw_left, raw_right in pairs[:16]:     # the fit is 0.2 s an image: 16 pairs are enough
        found = [detect_target(image, CIRCLES)
                 for image in rectifier.rectify(raw_left, raw_right)]
        if found[0] and found[1]:
            differences.append(found[0].points[:, 1] - found[1].points[:, 1])
    assert len(differences) >= 3
    assert np.median(np.abs(np.concatenate(differences))) < 0.1


class RectifiedPairs(Node):
    def __init__(self, context):
        super().__init__('rectified_pairs', context=context, namespace='stereo')
        self.images = {'left': {}, 'right': {}}
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        for side in ('left', 'right'):
            self.create_subscription(
                Image, f'{side}/image_rect',
                lambda msg, side=side: self.images[side].__setitem__(
                    (msg.header.stamp.sec, msg.header.stamp.nanosec),
                    msg_to_image(msg, 'mono16')), qos)


@pytest.mark.timeout(180)
def test_round_trip_through_the_driver_and_rectifier_nodes(circle_session):
    """Calibrate -> YAML -> driver (bag source) loads it -> rectifier node -> equal rows."""
    _, out, _ = circle_session
    urls = [Parameter(f'{side}.camera_info_url', value=f'file://{out}/result/{side}.yaml')
            for side in ('left', 'right')]
    with ros_nodes() as (context, executor, add):
        received = add(RectifiedPairs(context)).images
        add(RectifierNode(context=context))
        spin_for(executor, 1.0)             # discovery before the first pair
        driver = add(DriverNode(context=context, parameter_overrides=[
            Parameter('source', value='bag'), Parameter('bag', value=str(out / 'bag'))] + urls))
        spin_until_finished(executor, driver, 60.0)
        spin_for(executor, 1.5)
    stamps = sorted(set(received['left']) & set(received['right']))
    assert driver.published == SESSION_PAIRS and len(stamps) >= SESSION_PAIRS - 4
    differences = []
    for stamp in stamps:
        found = [detect_target(received[side][stamp], CIRCLES) for side in ('left', 'right')]
        if found[0] and found[1]:
            differences.append(found[0].points[:, 1] - found[1].points[:, 1])
    assert len(differences) >= 3        # 4 of the 40 pairs (35 points each)
    assert np.median(np.abs(np.concatenate(differences))) < 0.1


def test_bad_input_is_refused_with_the_reason(tmp_path, capsys):
    empty = tmp_path / 'empty'
    empty.mkdir()
    assert main(['calibrate', '--images', str(empty)] + TARGET_ARGS +
                ['--out', str(tmp_path / 'o')]) == 2
    assert 'no pairs' in capsys.readouterr().err
    flat = np.full((60, 80), 8000, np.uint16)
    collector = Collector(CIRCLES)
    for _ in range(3):
        collector.add('flat', flat, flat)
    assert collector.rejected['left']['not found'] == 3
    with pytest.raises(CalibrationInputError, match='target never found in 3 pairs'):
        calibrate(collector)
    with pytest.raises(CalibrationInputError, match='left is 80x60 but right is 160x120'):
        collector.add('mixed', flat, np.zeros((120, 160), np.uint16))
    with pytest.raises(CalibrationInputError, match='earlier ones 80x60'):
        collector.add('bigger', np.zeros((120, 160)), np.zeros((120, 160)))
    # The target seen in one place only: not enough coverage to calibrate.
    rig = realistic_rig()
    pose = target_poses(rig, CIRCLES, 1, seed=2, distance=(2.0, 2.1), max_tilt_deg=5.0)[0]
    seen = _render_one(rig, CIRCLES, pose)
    corner = Collector(CIRCLES)
    for _ in range(4):
        corner.add('same', seen, seen)
    with pytest.raises(CalibrationInputError, match='too little coverage'):
        calibrate(corner)
    missing = tmp_path / 'nobag'
    assert main(['calibrate', '--bag', str(missing)] + TARGET_ARGS +
                ['--out', str(tmp_path / 'o')]) == 2
    assert 'no such bag' in capsys.readouterr().err


def test_sim_calibration_writes_a_bag_that_calibrate_reads(tmp_path, capsys):
    from st_stereo.tools.calibrate import pairs_from_bag
    out = tmp_path / 'session'
    assert main(['sim', 'calibration', '--pairs', '3', '--bag', '--out', str(out)]) == 0
    assert 'true calibration' in capsys.readouterr().out
    pairs = list(pairs_from_bag(out / 'bag'))
    assert len(pairs) == 3 and pairs[0][1].shape == (60, 80) and pairs[0][1].dtype == np.uint16
    assert load_calibration(out / 'true_left.yaml').width == 80
    # A second run refuses to overwrite the bag unless told to.
    assert main(['sim', 'calibration', '--pairs', '3', '--bag', '--out', str(out)]) == 2
    assert 'exists' in capsys.readouterr().err


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_a_bag_of_16uc1_padded_big_endian_counts_is_read_as_its_counts(tmp_path, storage):
    # libuvc_camera writes a PureThermal board's Y16 as 16UC1; sensor_msgs/Image allows padded
    # rows and big-endian data. The tool refused 16UC1 and ignored is_bigendian.
    from builtin_interfaces.msg import Time
    from rosbag2_layouts import Topic, write_bag
    from st_stereo.tools.calibrate import pairs_from_bag
    from std_msgs.msg import Header
    counts = {side: np.arange(4800, dtype=np.uint16).reshape(60, 80) + offset
              for side, offset in (('left', 7000), ('right', 7100))}

    def image(side, sec):
        rows = counts[side].astype('>u2').view(np.uint8)
        rows = np.concatenate([rows, np.zeros((60, 4), np.uint8)], axis=1)
        return Image(header=Header(stamp=Time(sec=sec), frame_id=side), height=60, width=80,
                     encoding='16UC1', is_bigendian=1, step=164, data=rows.tobytes())
    bag = tmp_path / 'uvc'
    write_bag(bag, 9, storage, [Topic(f'/stereo/{side}/image_raw', 'sensor_msgs/msg/Image',
                                      [image(side, sec) for sec in (1, 2)])
                                for side in ('left', 'right')])
    pairs = list(pairs_from_bag(bag))
    assert len(pairs) == 2
    for _, left, right in pairs:
        assert np.array_equal(left, counts['left']) and np.array_equal(right, counts['right'])
