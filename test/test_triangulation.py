"""Triangulation: round trips, the Q matrix, the default rig, bad models."""

import numpy as np
import pytest

from st_stereo.core.triangulation import project, StereoModel, triangulate


def test_round_trip_points_to_pixels_and_back(rng):
    model = StereoModel(fx=83.9, fy=84.5, cx=39.5, cy=29.5, baseline=0.55, cx_right=40.5)
    points = np.column_stack((rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50),
                              rng.uniform(2.0, 5.0, 50)))
    u, v, d = project(model, points)
    assert np.allclose(triangulate(model, u, v, d), points)


def test_q_matrix_gives_the_same_points():
    model = StereoModel(fx=80.0, fy=81.0, cx=40.0, cy=30.0, baseline=0.5, cx_right=41.0)
    u, v, d = np.array([10.0, 60.0]), np.array([5.0, 50.0]), np.array([12.5, 20.0])
    homogeneous = model.reprojection_matrix() @ np.vstack((u, v, d, np.ones(2)))
    assert np.allclose((homogeneous[:3] / homogeneous[3]).T, triangulate(model, u, v, d))


def test_default_rig_matches_the_papers_depth_figures():
    model = StereoModel.default_lepton_rig()
    assert model.fx == pytest.approx(83.9, abs=0.05)
    assert model.fx * model.baseline == pytest.approx(46.3)
    d = model.disparity_of_depth(3.35)
    z_far, z_near = model.depth(d - 1.0), model.depth(d + 1.0)
    assert z_near == pytest.approx(3.108, abs=0.02) and z_far == pytest.approx(3.59, abs=0.03)


def test_rep103_axes_right_down_forward():
    model = StereoModel(fx=100.0, fy=100.0, cx=50.0, cy=50.0, baseline=0.5)
    point = triangulate(model, np.array([70.0]), np.array([80.0]), np.array([10.0]))[0]
    assert point[0] > 0 and point[1] > 0 and point[2] == pytest.approx(5.0)


def test_zero_disparity_is_at_infinity_not_a_crash():
    model = StereoModel.default_lepton_rig()
    assert np.isnan(triangulate(model, np.array([1.0]), np.array([1.0]), np.array([0.0]))).all()


def test_from_projection_matrices():
    left = [[80.0, 0, 40.0, 0], [0, 80.0, 30.0, 0], [0, 0, 1, 0]]
    right = [[80.0, 0, 40.0, -80.0 * 0.55], [0, 80.0, 30.0, 0], [0, 0, 1, 0]]
    model = StereoModel.from_projection_matrices(left, right)
    assert model.baseline == pytest.approx(0.55) and model.fx == 80.0


@pytest.mark.parametrize('field, value', [('fx', 0.0), ('baseline', -0.5), ('fy', np.nan)])
def test_invalid_models_are_rejected(field, value):
    kwargs = {'fx': 80.0, 'fy': 80.0, 'cx': 40.0, 'cy': 30.0, 'baseline': 0.5}
    kwargs[field] = value
    with pytest.raises(ValueError, match=field):
        StereoModel(**kwargs)


def test_right_camera_first_is_rejected():
    left = [[80.0, 0, 40.0, 0], [0, 80.0, 30.0, 0], [0, 0, 1, 0]]
    right = [[80.0, 0, 40.0, 44.0], [0, 80.0, 30.0, 0], [0, 0, 1, 0]]
    with pytest.raises(ValueError, match='P\\[0,3\\]'):
        StereoModel.from_projection_matrices(left, right)


@pytest.mark.parametrize('index, value, name', [(0, 90.0, 'fx'), (5, 90.0, 'fy'),
                                                (6, 31.0, 'cy')])
def test_two_projections_not_of_one_rectified_pair_are_refused(index, value, name):
    # A review: a right P whose rows do not align with the left's (a raw camera_info given to
    # the matcher) was triangulated as if rectified.
    left = [83.9, 0.0, 39.5, 0.0, 0.0, 83.9, 29.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    right = [83.9, 0.0, 41.0, -46.0, 0.0, 83.9, 29.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert StereoModel.from_projection_matrices(left, right).cx_right == 41.0
    right[index] = value
    with pytest.raises(ValueError, match=f'right projection: {name} .*not the P of one '
                                         f'rectified pair'):
        StereoModel.from_projection_matrices(left, right)
