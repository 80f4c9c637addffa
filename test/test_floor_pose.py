"""
st-stereo rig-pose: the rig's height, tilt and roll from a target lying on the floor.

The geometry is checked against exact projections; the whole tool against targets rendered
on the simulated rooms' floors through the realistic rig (barrel distortion, a misaligned
right camera, Lepton blur and noise) mounted at a known height, tilt and roll, and the pose it
writes against the transform the people stage builds from it.
"""

import dataclasses
import pathlib

import cv2
import numpy as np
import pytest
from st_stereo.cli import main
from st_stereo.core.calibration.files import load_calibration, save_calibration
from st_stereo.core.calibration.target_refinement import Refinement
from st_stereo.core.calibration.targets import CalibrationTarget, find_target, grid_reseeded
from st_stereo.core.floor_pose import combine_views, floor_of_target, floor_view, \
    FloorPoseError, FloorView, target_pose, tilt_roll_of_up
from st_stereo.core.people import rectified_to_world, world_from_rectified
from st_stereo.core.rig_pose import load_rig_pose, rig_pose_yaml, rig_to_optical_rotation, \
    RigPose, stereo_extrinsics
from st_stereo.sim.recording import write_pairs_bag
from st_stereo.sim.rig import realistic_rig
from st_stereo.sim.targets import floor_target_pose, render_floor_target_pairs
from st_stereo.tools.rig_pose import estimate, FloorTargetViews, pose_yaml, report_text, \
    RigPoseInputError

CIRCLES = CalibrationTarget('circles', 4, 5, 0.25)
TARGET_ARGS = ['--target', 'circles', '--rows', '4', '--cols', '5', '--spacing', '0.25']


@pytest.mark.parametrize('tilt', [5.0, 30.0, 50.0, 80.0])
@pytest.mark.parametrize('roll', [-10.0, 0.0, 7.0])
def test_tilt_and_roll_of_the_floor_normal_invert_the_rig_rotation(tilt, roll):
    pose = RigPose(tilt_deg=tilt, roll_deg=roll)
    up = rig_to_optical_rotation(pose).T @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(tilt_roll_of_up(3.0 * up), (tilt, roll), atol=1e-9)
    with pytest.raises(FloorPoseError, match='non-zero'):
        tilt_roll_of_up([0.0, 0.0, 0.0])


def test_the_floor_lies_below_the_camera_whichever_way_the_target_faces():
    # A target 2 m below the camera along the optical axis, its normal along the axis.
    for normal_sign in (1.0, -1.0):
        rotation = np.diag([1.0, normal_sign, normal_sign])
        up, height = floor_of_target(rotation, [0.1, 0.2, 2.0], thickness_m=0.01)
        np.testing.assert_allclose(up, [0.0, 0.0, -1.0])
        assert height == pytest.approx(2.01)


def exact_views(rig, target, floor_xy, yaw_deg=0.0):
    """Exact projections of a floor target's points into both raw cameras, and the truth."""
    origin, rotation = floor_target_pose(target, floor_xy, yaw_deg, 0.0)
    world = origin + target.object_points().astype(np.float64) @ rotation.T
    left, right = rig.cameras()
    return left.project(world), right.project(world), world


@pytest.mark.parametrize('seen', ['both', 'left', 'right'])
def test_an_exact_view_gives_the_exact_pose(seen):
    rig = dataclasses.replace(realistic_rig(), mount_height_m=2.6, tilt_deg=35.0, roll_deg=3.0)
    left_points, right_points, world = exact_views(rig, CIRCLES, (-0.3, 2.3), 20.0)
    left, right = rig.calibrations()
    rotation, translation, rms = target_pose(
        CIRCLES.object_points(), None if seen == 'right' else left_points,
        None if seen == 'left' else right_points, left, right)
    camera = rig.cameras()[0]
    np.testing.assert_allclose(CIRCLES.object_points() @ rotation.T + translation,
                               camera.to_camera(world), atol=1e-6)
    assert (rms[0] is None) == (seen == 'right') and (rms[1] is None) == (seen == 'left')
    up, height = floor_of_target(rotation, translation)
    truth = rig.rig_pose()
    assert height == pytest.approx(truth.height_m, abs=1e-6)
    np.testing.assert_allclose(tilt_roll_of_up(up), (truth.tilt_deg, truth.roll_deg), atol=1e-5)
    with pytest.raises(FloorPoseError, match='neither camera'):
        target_pose(CIRCLES.object_points(), None, None, left, right)


@pytest.mark.parametrize('flip', ['rows', 'columns', 'both'])
def test_the_cameras_may_number_the_grid_differently(flip):
    # Seen with a grid turned 45 degrees on the floor: the right image's rows reversed.
    rig = dataclasses.replace(realistic_rig(), mount_height_m=2.6, tilt_deg=60.0, roll_deg=0.5)
    left_points, right_points, _ = exact_views(rig, CIRCLES, (-0.2, 1.4), 45.0)
    grid = right_points.reshape(CIRCLES.rows, CIRCLES.cols, 2)
    grid = {'rows': grid[::-1], 'columns': grid[:, ::-1], 'both': grid[::-1, ::-1]}[flip]
    result = floor_view('v', CIRCLES, left_points, grid.reshape(-1, 2), *rig.calibrations())
    truth = rig.rig_pose()
    assert max(result.rms_left_px, result.rms_right_px) < 1e-6
    assert result.height_m == pytest.approx(truth.height_m, abs=1e-6)
    assert (result.tilt_deg, result.roll_deg) == pytest.approx((truth.tilt_deg, truth.roll_deg),
                                                               abs=1e-5)


def test_stereo_extrinsics_of_a_rolled_rig_do_not_change():
    # The rig's bar rolls with its cameras: the calibration does not depend on the mount.
    level, rolled = realistic_rig(), dataclasses.replace(realistic_rig(), roll_deg=6.0,
                                                         tilt_deg=30.0, mount_height_m=2.4)
    for a, b in zip(stereo_extrinsics(*level.calibrations()),
                    stereo_extrinsics(*rolled.calibrations())):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_a_rolled_rigs_true_pose_is_what_the_people_stage_uses():
    rig = dataclasses.replace(realistic_rig(), tilt_deg=33.0, roll_deg=-4.0)
    pose = rig.rig_pose()
    assert pose.roll_deg == pytest.approx(-4.0) and pose.tilt_deg == pytest.approx(57.0)
    world = np.array([[0.3, 2.5, 0.0], [-0.8, 3.9, 1.7], [1.2, 1.8, 0.4]])
    transform = world_from_rectified(pose, rig.rectification()[0])
    np.testing.assert_allclose(rectified_to_world(rig.to_rectified_left(world), transform),
                               world, atol=1e-9)


def view(height, tilt=50.0, roll=0.0, right=0.03):
    up = rig_to_optical_rotation(RigPose(tilt_deg=tilt, roll_deg=roll)).T @ [0.0, 0.0, 1.0]
    return FloorView('v', height, tilt, roll, 0.03, right, tuple(up), 1.0)


def test_views_combine_by_their_median():
    floor = combine_views([view(2.90), view(2.91), view(3.50), view(2.905)])
    assert floor.height_m == pytest.approx(2.9075) and floor.views == 4
    assert floor.roll_determined
    assert floor.spread['height_m'][1] > 3.4
    assert not combine_views([view(2.9, tilt=1.0)]).roll_determined
    with pytest.raises(FloorPoseError, match='no view'):
        combine_views([])


def test_points_a_fit_lost_are_reseeded_from_the_grid():
    model = CIRCLES.object_points()[:, :2].astype(np.float64)
    homography = np.array([[40.0, 5.0, 20.0], [-3.0, 30.0, 25.0], [0.01, 0.02, 1.0]])
    truth = cv2.perspectiveTransform(model.reshape(-1, 1, 2), homography).reshape(-1, 2)
    fitted = truth.copy()
    valid = np.ones(len(truth), dtype=bool)
    valid[[3, 7, 8]] = False
    fitted[~valid] += 1.4           # where the lost fits ended
    refined = Refinement(fitted, np.zeros((len(truth), 7)), np.zeros(len(truth)), valid)
    np.testing.assert_allclose(grid_reseeded(CIRCLES, refined), truth, atol=1e-6)


def test_points_opencv_misplaced_on_a_foreshortened_floor_target_are_fitted_again():
    # Rendered: a 4x5 grid 2.4 m ahead on the floor; OpenCV's rough positions of a row are
    # more than a pixel off in the right images, the fits fail there ('fit failed'); from the
    # grid's homography through the other points they are found to a few hundredths of a px.
    rig = realistic_rig()
    pairs = render_floor_target_pairs(rig, CIRCLES, (0.0, 2.4), count=2)
    _, _, world = exact_views(rig, CIRCLES, (0.0, 2.4))
    world[:, 2] = 0.005                                     # the target's surface
    failed = 0
    for camera, image in zip(rig.cameras() * 2, [image for pair in pairs for image in pair]):
        failed += find_target(image, CIRCLES)[1] == 'fit failed'
        detection, reason = find_target(image, CIRCLES, reseed=True)
        assert reason is None
        true = camera.project(world)
        nearest = np.linalg.norm(detection.points[:, None] - true[None], axis=2).min(axis=1)
        assert nearest.max() < 0.1
    assert failed >= 2               # both right images, here


def render_session(tmp_path, capsys, *extra):
    out = tmp_path / 'session'
    assert main(['sim', 'floor-target', '--out', str(out), '--pairs', '4', *extra]) == 0
    capsys.readouterr()
    return out


def test_rig_pose_finds_a_rolled_rig_from_a_rendered_floor_target(tmp_path, capsys):
    # The figures: height within 2 cm, tilt and roll within 0.5 deg of the truth.
    out = render_session(tmp_path, capsys, '--rig-height', '2.7', '--rig-tilt', '44',
                         '--rig-roll', '-3', '--at', '-0.2', '2.0', '--yaw', '20',
                         '--room', 'meeting_room')
    base = tmp_path / 'base.yaml'
    base.write_text(rig_pose_yaml(RigPose(world_frame='room', x_m=1.5, y_m=-2.0,
                                          yaw_deg=30.0, height_m=9.0)))
    fitted = tmp_path / 'rig_pose.yaml'
    assert main(['rig-pose', '--images', str(out), '--calibration', str(out), *TARGET_ARGS,
                 '--thickness', '0.005', '--base', str(base), '--out', str(fitted),
                 '--quiet']) == 0
    printed = capsys.readouterr().out
    assert 'target seen by both cameras in 4' in printed and '| height_m |' in printed
    pose, truth = load_rig_pose(fitted), load_rig_pose(out / 'true_rig_pose.yaml')
    assert abs(pose.height_m - truth.height_m) <= 0.02
    assert abs(pose.tilt_deg - truth.tilt_deg) <= 0.5
    assert abs(pose.roll_deg - truth.roll_deg) <= 0.5
    assert (pose.world_frame, pose.x_m, pose.y_m, pose.yaw_deg) == ('room', 1.5, -2.0, 30.0)
    # The people stage's transform from the fitted pose puts the true floor at z = 0 and
    # the vertical where it is (compared in the rig's own horizontal frame).
    rig = dataclasses.replace(realistic_rig(), mount_height_m=2.7, tilt_deg=44.0,
                              roll_deg=-3.0)
    floor = np.array([[x, y, 0.0] for x in (-1.0, 0.0, 1.0) for y in (1.5, 2.5, 4.0)])
    rectified = rig.to_rectified_left(floor)
    heights = rectified_to_world(rectified, world_from_rectified(
        pose, rig.rectification()[0]))[:, 2]
    assert np.abs(heights).max() <= 0.03


def test_rig_pose_says_what_is_wrong(tmp_path, capsys):
    out = render_session(tmp_path, capsys)
    fitted = str(tmp_path / 'rig_pose.yaml')
    cases = [
        (['--images', str(out), *TARGET_ARGS, '--out', fitted], 'stereo calibration is needed'),
        (['--images', str(out), '--calibration', str(tmp_path), *TARGET_ARGS, '--out', fitted],
         'left.yaml'),
        (['--images', str(out), '--calibration', str(out), '--target', 'circles', '--rows', '4',
          '--cols', '6', '--spacing', '0.25', '--out', fitted],
         'not found in any of 4 pairs: not found'),
        (['--images', str(out), '--calibration', str(out), '--target', 'circles', '--rows', '4',
          '--cols', '5', '--spacing', '0.24', '--out', fitted],
         'larger than --spacing 0.24 m says'),
        (['--images', str(out), '--calibration', str(out), *TARGET_ARGS, '--max-rms', '0',
          '--out', fitted], '--max-rms: expected a positive number'),
        (['--images', str(out), '--calibration', str(out), '--target', 'circles', '--rows', '4',
          '--cols', '5', '--spacing', '0.25', '--thickness', '-1', '--out', fitted],
         '--thickness'),
        (['--calibration', str(out), *TARGET_ARGS, '--out', fitted], 'exactly one input'),
        (['--images', str(out), '--calibration', str(out), *TARGET_ARGS, '--base',
          str(out / 'turned.yaml'), '--out', fitted], 'tilt_deg -50.0 is negative'),
    ]
    (out / 'turned.yaml').write_text(rig_pose_yaml(RigPose(yaw_deg=270.0, tilt_deg=-50.0,
                                                           roll_deg=180.0)))
    for arguments, message in cases:
        assert main(['rig-pose', '--quiet', *arguments]) == 2
        assert message in capsys.readouterr().err
    small = tmp_path / 'small'
    (small / 'left').mkdir(parents=True)
    (small / 'right').mkdir()
    for side in ('left', 'right'):
        cv2.imwrite(str(small / side / '000.png'), np.zeros((30, 40), np.uint16))
    assert main(['rig-pose', '--quiet', '--images', str(small), '--calibration', str(out),
                 *TARGET_ARGS, '--out', fitted]) == 2
    assert 'the left image is 40x30 but its calibration is for 80x60' in capsys.readouterr().err


def test_a_nearly_straight_down_rig_keeps_its_measured_roll():
    # 1.5 deg from straight down the roll is still the tilt's direction: written as measured.
    rig = dataclasses.replace(realistic_rig(), tilt_deg=88.5, roll_deg=90.0)
    left, right = rig.calibrations()
    left_points, right_points, _ = exact_views(rig, CIRCLES, (-0.3, 0.0))
    views = FloorTargetViews(CIRCLES, left, right)
    views.views.append(floor_view('v', CIRCLES, left_points, right_points, left, right))
    pose, floor = estimate(views, RigPose(yaw_deg=15.0))
    truth = rig.rig_pose()
    assert (pose.tilt_deg, pose.roll_deg) == pytest.approx((truth.tilt_deg, truth.roll_deg),
                                                           abs=2e-3)
    assert pose.tilt_deg == pytest.approx(1.5, abs=2e-3) and pose.yaw_deg == 15.0
    assert pose.height_m == pytest.approx(truth.height_m, abs=1e-4)
    assert not floor.roll_determined and 'poorly determined' in pose_yaml(pose, floor, 'test')


def test_a_roll_near_180_degrees_is_not_averaged_to_0():
    # A camera mounted upside down: views either side of +-180 deg.
    views = []
    for roll in (179.95, -179.97, 179.98, -179.94):
        up = rig_to_optical_rotation(RigPose(tilt_deg=50.0, roll_deg=roll)).T @ [0, 0, 1.0]
        views.append(FloorView('v', 2.9, 50.0, roll, 0.03, 0.03, tuple(up), 1.0))
    floor = combine_views(views)
    assert abs(abs(floor.roll_deg) - 180.0) < 0.05 and floor.tilt_deg == pytest.approx(50.0)
    low, high = floor.spread['roll_deg']
    assert high - low < 0.15       # the views span 0.12 deg, not 360


def test_one_camera_views_need_to_be_asked_for():
    rig = realistic_rig()
    left, right = rig.calibrations()
    left_points, _, _ = exact_views(rig, CIRCLES, (-0.3, 2.4))
    views = FloorTargetViews(CIRCLES, left, right)
    views.views.append(floor_view('v', CIRCLES, left_points, None, left, right))
    with pytest.raises(RigPoseInputError, match='--allow-one-camera'):
        estimate(views, RigPose())
    pose, _ = estimate(views, RigPose(), allow_one_camera=True)
    assert pose.height_m == pytest.approx(rig.rig_pose().height_m, abs=1e-3)
    report = report_text(views, pose, combine_views(views.views))
    assert 'no pair showed the target to both cameras' in report


def test_a_fisheye_calibration_is_refused_by_name(tmp_path, capsys):
    out = render_session(tmp_path, capsys)
    fisheye = dataclasses.replace(load_calibration(out / 'left.yaml'),
                                  distortion_model='equidistant',
                                  distortion=np.array([-0.05, 0.01, 0.0, 0.0]))
    save_calibration(fisheye, out / 'left.yaml')
    assert main(['rig-pose', '--quiet', '--images', str(out), '--calibration', str(out),
                 *TARGET_ARGS, '--out', str(tmp_path / 'pose.yaml')]) == 2
    assert "distortion_model 'equidistant' is not supported" in capsys.readouterr().err


def test_a_bag_stamping_each_camera_apart_is_paired_by_nearest_stamp(tmp_path, capsys):
    rig = dataclasses.replace(realistic_rig(), roll_deg=2.0)
    pairs = render_floor_target_pairs(rig, CIRCLES, (0.0, 2.4), count=4)
    bag = write_pairs_bag(pairs, tmp_path / 'bag', right_offset_s=0.02)
    calibration = tmp_path / 'calibration'
    calibration.mkdir()
    for side, camera in zip(('left', 'right'), rig.calibrations()):
        save_calibration(camera, calibration / f'{side}.yaml')
    out = tmp_path / 'pose.yaml'
    arguments = ['rig-pose', '--quiet', '--bag', str(bag), '--calibration', str(calibration),
                 *TARGET_ARGS, '--thickness', '0.005', '--out', str(out)]
    assert main(arguments) == 0
    assert 'seen by both cameras in 4' in capsys.readouterr().out
    assert load_rig_pose(out).roll_deg == pytest.approx(2.0, abs=0.5)
    assert main(arguments + ['--max-pair-delta', '0.01']) == 2
    assert 'no pairs in the input (4 left and 4 right images, none within 0.01 s' in \
        capsys.readouterr().err


def test_a_bag_ros2_bag_record_wrote_without_images_is_named_with_its_topics(tmp_path, capsys):
    # Written by `ros2 bag record` itself (../shared/data/rosbag2, MCAP, metadata v4): no
    # camera topics, and the error lists the ones it has.
    bag = pathlib.Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'rosbag2' / \
        'talker_mcap_v4'
    out = render_session(tmp_path, capsys)
    assert main(['rig-pose', '--quiet', '--bag', str(bag), '--calibration', str(out),
                 *TARGET_ARGS, '--out', str(tmp_path / 'pose.yaml')]) == 2
    error = capsys.readouterr().err
    assert 'expected topics ending in left/image_raw and right/image_raw' in error
    assert "'/topic'" in error and "'/rosout'" in error
    assert not (tmp_path / 'pose.yaml').exists()
