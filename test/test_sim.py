"""The simulated rig: exact ground truth, projections, sensor model, sequences."""

import dataclasses
import math

import numpy as np
import pytest

from st_stereo.core.rectification import StereoRectifier
from st_stereo.sim.render import disparity_error, ground_truth, render_temperature
from st_stereo.sim.rig import (distort_normalised, realistic_rig, RigGeometry,
                               undistort_normalised)
from st_stereo.sim.scene import FACES, RoomShell, Scene, ThermalMaterial
from st_stereo.sim.sensor import LeptonSensor, SensorModel
from st_stereo.sim.sequences import (Keyframe, PERSON_LABEL_BASE, PersonScript,
                                     SequenceRenderer, SequenceSpec, standard_sequences)


@pytest.fixture(scope='module')
def textures():
    from st_stereo.sim.sequences import load_textures
    return load_textures()


def plane_scene(textures, depth):
    """Build a room whose far wall is a textured plane ``depth`` metres in front of a level rig."""
    wall = ThermalMaterial(base=25.0, texture=textures['panel'],
                           texture_axes=((1.0, 0.0, 0.0), (0.0, 0.0, -1.0)), texel_m=0.03,
                           texture_kelvin=3.0)
    flat = ThermalMaterial(base=21.0)
    materials = dict.fromkeys(FACES, flat)
    materials['y+'] = wall
    labels = dict.fromkeys(FACES, 1)
    labels['y+'] = 2
    return Scene(RoomShell((-6.0, -1.0, -3.0), (6.0, depth, 6.0), materials, labels), [], {})


def test_fronto_parallel_plane_renders_the_expected_disparity_everywhere(textures):
    rig = RigGeometry(tilt_deg=0.0, mount_height_m=1.5)
    depth = 3.5
    scene = plane_scene(textures, depth)
    truth = ground_truth(scene, rig)
    expected = rig.fx_baseline / depth
    assert np.abs(truth.disparity - expected).max() < 1e-9
    assert np.abs(truth.depth - depth).max() < 1e-9
    assert truth.visible_right.all()
    # Image content: the right pixel (u, v) sees exactly what the left sees at (u + d, v) ...
    left_camera, right_camera = rig.cameras()
    right = render_temperature(scene, right_camera)
    left_at_d = render_temperature(scene, left_camera, offset_px=(expected, 0.0))
    assert np.abs(left_at_d - right).max() < 1e-9
    # ... and a disparity off by 0.01 px would be visible (the check is sensitive enough).
    for error in (-0.01, 0.01):
        off = render_temperature(scene, left_camera, offset_px=(expected + error, 0.0))
        assert np.abs(off - right).max() > 0.01


def test_ground_truth_disparity_is_fx_baseline_over_rectified_depth():
    rig = realistic_rig()
    sequence = standard_sequences()['walk_across']
    renderer = SequenceRenderer(dataclasses.replace(sequence, rig=rig), noise=False)
    scene, _ = renderer.scene(1.0)
    truth = ground_truth(scene, rig)
    np.testing.assert_allclose(truth.disparity * truth.depth, rig.fx_baseline, rtol=1e-12)
    assert (truth.disparity_min <= truth.disparity + 1e-12).all()
    assert (truth.disparity_max >= truth.disparity - 1e-12).all()
    # A matched point projected from the rectified left to the rectified right lands on the
    # same row at u - d: check it through the rig's rectified rays.
    v, u = 30, 40
    origin, direction = rig.rectified_rays([[u, v]])
    hit = scene.cast(origin, direction, with_temperature=False)
    _, right = rig.cameras()
    _, r2, _, p2 = rig.rectification()
    # Through P_right in the rectified left frame (what the matcher assumes) ...
    projected = p2 @ np.append(rig.to_rectified_left(hit.points)[0], 1.0)
    assert projected[0] / projected[2] == pytest.approx(u - truth.disparity[v, u], abs=1e-9)
    assert projected[1] / projected[2] == pytest.approx(v, abs=1e-9)
    # ... and through the right camera's own pose and R2 (what the renderer does).
    in_right = right.to_camera(hit.points)[0] @ r2.T
    assert p2[0, 0] * in_right[0] / in_right[2] + p2[0, 2] == pytest.approx(
        u - truth.disparity[v, u], abs=1e-9)


@pytest.mark.parametrize('rig', [RigGeometry(), realistic_rig()], ids=['ideal', 'realistic'])
def test_a_persons_head_projects_where_it_is_rendered_in_both_images(textures, rig):
    script = PersonScript((Keyframe(0.0, 0.3, 3.0), Keyframe(5.0, 0.3, 3.0)))
    spec = SequenceSpec('one', 'a person standing', (script,), duration_s=1.0, rig=rig)
    renderer = SequenceRenderer(spec, textures=textures, noise=False)
    scene, heads = renderer.scene(0.0)
    for camera in rig.cameras():
        pixel = camera.project(heads)[0]
        # The ray through the projected pixel hits the head, and passes within 1 mm of its
        # centre's line of sight.
        ray = camera.pixel_rays(pixel[None])[0]
        hit = scene.cast(camera.centre, ray[None], with_temperature=False)
        assert hit.label[0] == PERSON_LABEL_BASE
        to_head = heads[0] - camera.centre
        miss = np.linalg.norm(np.cross(to_head, ray / np.linalg.norm(ray)))
        assert miss < 1e-3
        # The rendered image is warm (head, not 21 C room) where the head projects.
        temperature = render_temperature(scene, camera)
        col, row = np.rint(pixel).astype(int)
        assert temperature[row, col] > 26.0
    # In the rectified frame the head's disparity is fx B / Z.
    rectified = rig.to_rectified_left(heads)[0]
    _, right = rig.calibrations()
    rectifier = StereoRectifier(*rig.calibrations())
    assert rectifier.model.disparity_of_depth(rectified[2]) == pytest.approx(
        rig.fx_baseline / rectified[2], rel=1e-12)
    assert right.projection[0, 3] == pytest.approx(-rig.fx_baseline, rel=1e-12)


def test_undistortion_inverts_distortion_and_refuses_what_it_cannot_invert():
    points = np.random.default_rng(0).uniform(-0.5, 0.5, (500, 2))
    distortion = np.array([-0.12, 0.03, 0.0, 0.0, 0.0])
    back = undistort_normalised(distort_normalised(points, distortion), distortion)
    np.testing.assert_allclose(back, points, atol=1e-12)
    with pytest.raises(ValueError, match='did not converge'):
        undistort_normalised(np.array([[3.0, 3.0]]), [-2.0, 0.0, 0.0, 0.0, 0.0])


def test_rectifying_the_realistic_rig_puts_a_point_on_the_same_row_in_both_images():
    rig = realistic_rig()
    rectifier = StereoRectifier(*rig.calibrations())
    left, right = rig.cameras()
    point = np.array([[0.4, 3.2, 1.1]])
    rows = []
    for camera, maps in ((left, rectifier.left_maps), (right, rectifier.right_maps)):
        raw = camera.project(point)[0]
        # Find the rectified pixel whose map points at the raw projection.
        distance = np.hypot(maps[0] - raw[0], maps[1] - raw[1])
        rows.append(np.unravel_index(np.argmin(distance), distance.shape)[0])
    assert rows[0] == rows[1]


def test_sensor_noise_drift_and_flat_field_corrections():
    model = SensorModel(seed=3, ffc_first_s=2.0, ffc_period_s=5.0, drift_counts_per_s=10.0)
    sensor = LeptonSensor(model, (60, 80))
    scene = np.full((60, 80), 30.0)
    clean = sensor.frame(scene, 0.0, noise=False).astype(float)
    # 30 C is 10 K above the reference: about 350 counts above 8000 at the centre.
    assert 8300 < clean[30, 40] < 8400
    assert clean[0, 0] < clean[30, 40]                    # vignetting
    frames = np.array([sensor.frame(scene, 0.0).astype(float) for _ in range(200)])
    temporal = frames.std(axis=0).mean()
    assert temporal == pytest.approx(0.05 * model.counts_per_kelvin, rel=0.15)
    before = sensor.frame(scene, 1.9).astype(float) - clean
    after = sensor.frame(scene, 2.1).astype(float) - clean
    assert before.mean() > after.mean() + 15              # the FFC removed 19 s x 10 counts
    assert model.ffc_index(1.9) == 0 and model.ffc_index(2.1) == 1
    assert model.ffc_index(7.5) == 2
    assert model.seconds_since_ffc(7.5) == pytest.approx(0.5)
    hot = sensor.frame(np.full((60, 80), 500.0), 0.0)
    assert hot.max() == 2 ** 14 - 1                      # 14-bit saturation


def test_sequences_are_deterministic_and_people_stay_in_the_evaluated_range(textures):
    spec = standard_sequences()['two_people']
    first = SequenceRenderer(spec, textures=textures).frame(1.0)
    second = SequenceRenderer(spec, textures=textures).frame(1.0)
    np.testing.assert_array_equal(first['left'], second['left'])
    np.testing.assert_array_equal(first['right'], second['right'])
    assert first['left'].dtype == np.uint16
    for name in ('walk_across', 'two_people', 'sit_down'):
        spec = standard_sequences()[name]
        renderer = SequenceRenderer(spec, textures=textures)
        for t in spec.frame_times[::20]:
            scene, heads = renderer.scene(t)
            depths = spec.rig.to_rectified_left(heads)[:, 2]
            assert ((depths > 2.3) & (depths < 4.7)).all(), (name, t, depths)


def test_disparity_error_is_zero_inside_the_pixel_range_and_nan_when_hidden():
    rig = RigGeometry(tilt_deg=0.0, mount_height_m=1.5)
    truth = ground_truth(plane_scene({'panel': np.zeros((4, 4))}, 3.0), rig)
    d = rig.fx_baseline / 3.0
    truth.visible_right[10, 10] = False
    error = disparity_error(truth, np.array([20, 20, 10]), np.array([20, 20, 10]),
                            np.array([d, d + 0.5, d]))
    assert error[0] == 0.0
    assert error[1] == pytest.approx(0.5, abs=1e-9)
    assert math.isnan(error[2])


def test_sim_commands_list_render_and_refuse_unknown_sequences(tmp_path, capsys):
    from st_stereo.cli import main
    assert main(['sim', 'list']) == 0
    assert 'walk_across' in capsys.readouterr().out
    assert main(['sim', 'render', '--sequence', 'sit_down', '--time', '5',
                 '--out', str(tmp_path / 'frame')]) == 0
    data = np.load(tmp_path / 'frame.npz')
    assert data['left'].shape == (60, 80) and data['left'].dtype == np.uint16
    assert (tmp_path / 'frame.png').stat().st_size > 1000
    assert main(['sim', 'record', '--sequence', 'nope', '--out', str(tmp_path / 'x')]) == 2
    assert "unknown sequence 'nope'" in capsys.readouterr().err
