"""Model fits of blurred target features: sub-pixel centres without pixel locking."""

import numpy as np
import pytest
from scipy import ndimage
from st_stereo.core.calibration.target_refinement import (
    blurred_ellipse, blurred_saddle, compiled_blurred_ellipse, ellipse_matrix,
    refine_chessboard_corners, refine_circle_centres)

OVERSAMPLE = 12


def render(inside, shape=(30, 40), blur_px=0.55, low=8000.0, high=8350.0):
    """Area-integrate ``inside(x, y)`` over each pixel after a Gaussian blur (sensor-like)."""
    rows, cols = shape
    offsets = (np.arange(OVERSAMPLE) + 0.5) / OVERSAMPLE - 0.5
    y = (np.arange(rows)[:, None] + offsets[None]).ravel()
    x = (np.arange(cols)[:, None] + offsets[None]).ravel()
    fine = np.where(inside(x[None, :], y[:, None]), high, low)
    fine = ndimage.gaussian_filter(fine, blur_px * OVERSAMPLE, mode='nearest')
    return fine.reshape(rows, OVERSAMPLE, cols, OVERSAMPLE).mean(axis=(1, 3))


def circle_grid(centre, spacing, radius, count=(3, 3), squash=1.0):
    """Centres (n, 2) of a grid and its rendered image (ellipses squashed along y)."""
    gy, gx = np.mgrid[0:count[1], 0:count[0]]
    centres = np.column_stack([centre[0] + gx.ravel() * spacing,
                               centre[1] + gy.ravel() * spacing * squash])

    def inside(x, y):
        hit = np.zeros(np.broadcast(x, y).shape, bool)
        for cx, cy in centres:
            hit |= (x - cx) ** 2 + ((y - cy) / squash) ** 2 <= radius ** 2
        return hit
    return centres, render(inside)


@pytest.mark.parametrize('squash', [1.0, 0.6], ids=['round', 'tilted'])
def test_circle_centres_follow_sub_pixel_shifts_without_locking(squash):
    errors = []
    for shift in np.linspace(0.0, 0.9, 10):
        truth, image = circle_grid((10.0 + shift, 9.0 + shift * 0.7), 6.0, 1.6, squash=squash)
        rough = truth + np.array([0.3, -0.25])           # as from the upsampled detector
        fitted = refine_circle_centres(image, rough, warm=True)
        assert fitted.valid.all()
        errors.append(fitted.points - truth)
    errors = np.abs(np.concatenate(errors))
    assert errors.max() < 0.02


def test_cold_holes_fit_as_well_as_warm_dots():
    truth, image = circle_grid((10.3, 9.6), 6.0, 1.6)
    inverted = 16350.0 - image
    fitted = refine_circle_centres(inverted, truth + 0.3, warm=False)
    assert fitted.valid.all()
    assert np.abs(fitted.points - truth).max() < 0.02


def test_chessboard_corners_follow_sub_pixel_shifts_and_rotation():
    errors = []
    for shift in np.linspace(0.0, 0.9, 10):
        angle = np.radians(12.0)
        origin = np.array([12.0 + shift, 8.0 + 0.5 * shift])
        u = np.array([np.cos(angle), np.sin(angle)]) * 5.0
        v = np.array([-np.sin(angle), np.cos(angle)]) * 5.0
        basis = np.linalg.inv(np.column_stack([u, v]))

        def inside(x, y):
            a = basis[0, 0] * (x - origin[0]) + basis[0, 1] * (y - origin[1])
            b = basis[1, 0] * (x - origin[0]) + basis[1, 1] * (y - origin[1])
            return (np.floor(a) + np.floor(b)) % 2 == 0
        image = render(inside)
        grid = np.array([origin + i * u + j * v for j in range(1, 4) for i in range(1, 4)])
        fitted = refine_chessboard_corners(image, grid + np.array([0.2, 0.3]), (3, 3))
        assert fitted.valid.all()
        errors.append(fitted.points - grid)
    assert np.abs(np.concatenate(errors)).max() < 0.02


def test_ellipse_parameters_always_give_a_positive_definite_matrix():
    rng = np.random.default_rng(3)
    params = np.zeros((200, 8))
    params[:, 2:5] = rng.uniform(-3, 3, (200, 3))
    eigenvalues = np.linalg.eigvalsh(ellipse_matrix(params))
    assert (eigenvalues > 0).all()
    # log_r is the geometric mean radius: det Q = r^-4.
    np.testing.assert_allclose(np.linalg.det(ellipse_matrix(params)),
                               np.exp(-4 * params[:, 2]), rtol=1e-9)
    values = blurred_ellipse(np.array([[5.0, 5.0, np.log(3.0), 0, 0, np.log(0.5), 100, 10]]),
                             np.array([[5.0, 20.0]]), np.array([[5.0, 5.0]]))
    np.testing.assert_allclose(values, [[110.0, 10.0]], atol=1e-3)


def test_the_compiled_ellipse_model_is_the_numpy_reference():
    # Would catch the kernel drifting from the reference (a formula or a sum changed in one).
    rng = np.random.default_rng(5)
    count, pixels = 40, 81
    params = np.column_stack([rng.uniform(0, 8, count), rng.uniform(0, 8, count),
                              rng.uniform(-0.7, 2.0, count), rng.uniform(-1.1, 1.1, count),
                              rng.uniform(-1.1, 1.1, count), rng.uniform(-1.6, 0.9, count),
                              rng.uniform(-50, 200, count), rng.uniform(0, 1e4, count)])
    xs = rng.integers(0, 9, (count, pixels)).astype(float)
    ys = rng.integers(0, 9, (count, pixels)).astype(float)
    np.testing.assert_allclose(compiled_blurred_ellipse(params, xs, ys),
                               blurred_ellipse(params, xs, ys), rtol=1e-13, atol=0)
    truth, image = circle_grid((10.3, 9.6), 6.0, 1.6, squash=0.7)
    fits = [refine_circle_centres(image, truth + 0.3, warm=True, kernels_choice=choice)
            for choice in ('numpy', 'compiled')]
    assert fits[0].valid.all() and fits[1].valid.all()
    np.testing.assert_allclose(fits[1].points, fits[0].points, rtol=0, atol=1e-9)


@pytest.mark.parametrize('model', [blurred_ellipse, blurred_saddle], ids=['ellipse', 'saddle'])
def test_the_gain_and_offset_columns_are_the_models_derivatives(model):
    # fit_batch takes the last two Jacobian columns from the model's values instead of two
    # more evaluations: they must be what a difference of the model gives, for any gain
    # (one too near zero to divide by included) and with zero weights in the window.
    from st_stereo.core.calibration.target_refinement import (_gain_offset_columns,
                                                              feature_windows)
    rng = np.random.default_rng(4)
    count = 5
    centres = rng.uniform(6, 12, (count, 2))
    xs, ys, _ = feature_windows(centres, 4, (20, 20))
    size = 8 if model is blurred_ellipse else 7
    p = np.zeros((count, size))
    p[:, :2] = centres
    if model is blurred_ellipse:
        p[:, 2:6] = [np.log(2.0), 0.2, -0.1, np.log(0.6)]
    else:
        p[:, 2:5] = [0.3, 1.8, np.log(0.6)]
    p[:, -2] = [300.0, -120.0, 1e-9, 0.0, 45.0]
    p[:, -1] = rng.uniform(7000, 9000, count)
    data = rng.uniform(7000, 9000, xs.shape)
    weights = (rng.uniform(size=xs.shape) > 0.2).astype(np.float64)
    r = (model(p, xs, ys) - data) * weights
    jacobian = np.full(r.shape + (size,), np.nan)
    _gain_offset_columns(jacobian, p, r, data, weights, model, xs, ys)
    for column in (size - 2, size - 1):
        shifted = p.copy()
        shifted[:, column] += 1.0
        expected = (model(shifted, xs, ys) - model(p, xs, ys)) * weights
        np.testing.assert_allclose(jacobian[:, :, column], expected, rtol=1e-6, atol=1e-6)
