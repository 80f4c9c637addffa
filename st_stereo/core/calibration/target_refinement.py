"""
Sub-pixel localisation of calibration-target features by fitting a blurred, pixel-integrated model.

At 80x60 a target circle is three or four pixels across and blurred (Lepton optics: a Gaussian
of about 0.55 px on top of the pixel's own area), and a chessboard square is five. An intensity
centroid of such a blob needs a window that truncates its tails and a background that its own
tails raise; measured on rendered targets it is off by 0.06 px rms per coordinate, which at this
resolution moves the principal point by about 1 %. Fitting a model of what the sensor saw removes
most of that (0.025 px rms on the same images; see ``docs/calibration.md``).

Two models, both point-symmetric about the feature, so a mismatch in the exact edge profile
(curvature, blur shape) does not move the fitted centre:

- blob (circle of a circle grid, seen as an ellipse): ``b + a * Phi(d / w)`` where ``Phi`` is the
  normal CDF (a Gaussian-blurred edge of width ``w``) and ``d`` the signed distance to the
  ellipse ``(x - c)^T Q (x - c) = 1``, approximated to first order as ``(1 - s) / |grad s|``
  with ``s = sqrt((x - c)^T Q (x - c))``; parameters ``cx, cy, log_r, e1, e2, log_w, a, b``
  (``ellipse_matrix`` builds ``Q``; logs keep radius and width positive).
- saddle (inner chessboard corner): ``m + a * (2 Phi(d1 / w) - 1) * (2 Phi(d2 / w) - 1)`` with
  ``d1``, ``d2`` the signed distances to the two edges through the corner at angles ``t1``,
  ``t2``; parameters ``cx, cy, t1, t2, log_w, a, m``.

Each pixel's value is the model's mean over ``SUBSAMPLES`` x ``SUBSAMPLES`` points of the pixel
(the sensor integrates over its area). All features of an image are fitted at once by a batched
Levenberg-Marquardt with a forward-difference Jacobian (analytic for the gain and offset),
within bounds. A circle is first fitted
on the pixels nearer to it than half way to its nearest neighbour, then twice more on its whole
window with the neighbouring blobs' fitted tails subtracted.
"""

import dataclasses

import numpy as np
from scipy.special import ndtr

from st_stereo.core import kernels

SUBSAMPLES = 3
_OFFSETS = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES - 0.5
SUBSAMPLE_DX, SUBSAMPLE_DY = (a.ravel() for a in np.meshgrid(_OFFSETS, _OFFSETS))
BLOB_STEPS = np.array([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-3, 1e-3])
SADDLE_STEPS = np.array([1e-4, 1e-4, 1e-5, 1e-5, 1e-4, 1e-3, 1e-3])
START_EDGE_WIDTH_PX = 0.6
CENTRE_TOLERANCE_PX = 1e-4
# Bounds: edge width 0.2-2.5 px, blob radius 0.5-8 px, elongation up to 3:1 (tilted 70 deg).
BLOB_BOUNDS = np.array([
    [-np.inf, -np.inf, np.log(0.5), -1.1, -1.1, np.log(0.2), -np.inf, -np.inf],
    [np.inf, np.inf, np.log(8.0), 1.1, 1.1, np.log(2.5), np.inf, np.inf]])
SADDLE_BOUNDS = np.array([
    [-np.inf, -np.inf, -np.inf, -np.inf, np.log(0.2), -np.inf, -np.inf],
    [np.inf, np.inf, np.inf, np.inf, np.log(2.5), np.inf, np.inf]])


def _subsample_offsets(xs, ys, params):
    """Subsample positions relative to each feature's centre: (n, m, s) arrays."""
    x = xs[:, :, None] + SUBSAMPLE_DX - params[:, 0, None, None]
    y = ys[:, :, None] + SUBSAMPLE_DY - params[:, 1, None, None]
    return x, y


def ellipse_matrix(params):
    """
    Return ``Q`` (n, 2, 2) of ``(x - c)^T Q (x - c) = 1`` from the blob parameters (n, 8).

    ``Q = exp(-2 log_r) expm([[e1, e2], [e2, -e1]])``: positive definite for any values, with
    ``r`` the geometric mean radius and ``e1, e2`` the elongation.
    """
    log_r, e1, e2 = params[:, 2], params[:, 3], params[:, 4]
    k = np.hypot(e1, e2)
    sinhc = np.where(k > 1e-8, np.sinh(k) / np.maximum(k, 1e-8), 1.0)
    scale = np.exp(-2.0 * log_r)
    q11 = scale * (np.cosh(k) + sinhc * e1)
    q22 = scale * (np.cosh(k) - sinhc * e1)
    q12 = scale * sinhc * e2
    return np.stack([np.stack([q11, q12], -1), np.stack([q12, q22], -1)], -2)


def blurred_ellipse(params, xs, ys):
    """
    Pixel values (n, m) of blurred ellipses ``params`` (n, 8) at pixel centres ``xs, ys``.

    Parameters per row: ``cx, cy, log_r, e1, e2, log_w, a, b`` (module docstring and
    ``ellipse_matrix``).
    """
    x, y = _subsample_offsets(xs, ys, params)
    q = ellipse_matrix(params)
    q11, q12, q22 = (q[:, i, j, None, None] for i, j in ((0, 0), (0, 1), (1, 1)))
    width = np.exp(params[:, 5, None, None])
    gx = q11 * x + q12 * y
    gy = q12 * x + q22 * y
    s = np.sqrt(np.maximum(x * gx + y * gy, 1e-12))
    gradient = np.sqrt(gx * gx + gy * gy) / s
    distance = (1.0 - s) / np.maximum(gradient, 1e-6)
    edge = ndtr(distance / width).mean(axis=2)
    return params[:, 7, None] + params[:, 6, None] * edge


def compiled_blurred_ellipse(params, xs, ys):
    """``blurred_ellipse`` by the compiled kernel (equal to about 1e-15 relative)."""
    return kernels.blurred_ellipses(params, xs, ys, SUBSAMPLE_DX, SUBSAMPLE_DY)


def ellipse_model(choice='auto'):
    """
    Return the blurred-ellipse model the fits use for a ``kernels`` choice (``STConfig``'s).

    The fit evaluates it seven times per step for every circle of every image; compiled, a
    60-pair calibration takes about a third of the time.
    """
    return compiled_blurred_ellipse if kernels.use_compiled(choice) else blurred_ellipse


def blurred_saddle(params, xs, ys):
    """
    Pixel values (n, m) of blurred chessboard corners ``params`` (n, 7) at ``xs, ys``.

    Parameters per row: ``cx, cy, t1, t2, log_w, a, m`` (module docstring).
    """
    x, y = _subsample_offsets(xs, ys, params)
    t1, t2 = params[:, 2, None, None], params[:, 3, None, None]
    width = np.exp(params[:, 4, None, None])
    d1 = -np.sin(t1) * x + np.cos(t1) * y
    d2 = -np.sin(t2) * x + np.cos(t2) * y
    product = ((2.0 * ndtr(d1 / width) - 1.0) * (2.0 * ndtr(d2 / width) - 1.0)).mean(axis=2)
    return params[:, 6, None] + params[:, 5, None] * product


def fit_batch(model, params, xs, ys, data, weights, steps, bounds, max_shift_px=1.5,
              iterations=40, tolerance=1e-7, gain_offset=False):
    """
    Levenberg-Marquardt fit of ``model`` to every row of ``data`` at once.

    ``params`` (n, k) are the start values (the first two: the feature's centre), ``xs, ys,
    data, weights`` (n, m) the pixel centres, values and weights of each feature's window,
    ``steps`` (k,) the relative forward-difference steps, ``bounds`` (2, k) or (2, n, k) the
    lowest and highest values of each parameter (the centre's are ignored: it is kept within
    ``max_shift_px`` of its start). A feature stops when a step lowers its cost by less than
    ``tolerance`` (relative) and moves its centre by less than ``CENTRE_TOLERANCE_PX``, or when
    its damping has grown past any useful step. ``gain_offset``: the last two parameters are
    a gain ``a`` and an offset ``b`` of the model, ``b + a * shape(p)`` (both models here): their
    Jacobian columns are ``shape = (model - b) / a`` and 1, taken from the model's values
    instead of two more evaluations (a forward difference of a linear parameter is the same
    to rounding). Returns the fitted parameters and the weighted residual rms per feature.
    """
    params = np.array(params, dtype=np.float64)
    lower = np.broadcast_to(np.asarray(bounds[0], dtype=np.float64), params.shape).copy()
    upper = np.broadcast_to(np.asarray(bounds[1], dtype=np.float64), params.shape).copy()
    lower[:, :2], upper[:, :2] = params[:, :2] - max_shift_px, params[:, :2] + max_shift_px
    params = np.clip(params, lower, upper)
    count, size = params.shape
    damping = np.full(count, 1e-2)
    identity = np.eye(size)

    def residuals(p, rows):
        return (model(p, xs[rows], ys[rows]) - data[rows]) * weights[rows]
    residual = residuals(params, slice(None))
    cost = np.einsum('nm,nm->n', residual, residual)
    active = np.arange(count)
    numeric = range(size - 2) if gain_offset else range(size)
    for _ in range(iterations):
        if not len(active):
            break
        p, r = params[active], residual[active]
        jacobian = np.empty(r.shape + (size,))
        for i in numeric:
            shifted = p.copy()
            shifted[:, i] += steps[i] * np.maximum(1.0, np.abs(p[:, i]))
            jacobian[:, :, i] = (residuals(shifted, active) - r) / \
                (shifted[:, i] - p[:, i])[:, None]
        if gain_offset:
            _gain_offset_columns(jacobian, p, r, data[active], weights[active], model, xs[active],
                                 ys[active])
        normal = np.einsum('nmi,nmj->nij', jacobian, jacobian)
        gradient = np.einsum('nmi,nm->ni', jacobian, r)
        scale = np.einsum('nii->ni', normal) + 1e-12
        damped = normal + damping[active, None, None] * scale[:, :, None] * identity
        delta = -_solve(damped, gradient)
        trial = np.clip(p + np.where(np.isfinite(delta), delta, 0.0), lower[active],
                        upper[active])
        trial_residual = residuals(trial, active)
        trial_cost = np.einsum('nm,nm->n', trial_residual, trial_residual)
        better = trial_cost < cost[active]
        gain = np.where(better, cost[active] - trial_cost, 0.0)
        improved = active[better]
        params[improved] = trial[better]
        residual[improved] = trial_residual[better]
        cost[improved] = trial_cost[better]
        damping[active] = np.clip(np.where(better, damping[active] * 0.3,
                                           damping[active] * 10.0), 1e-9, 1e9)
        moved = np.abs(trial[:, :2] - p[:, :2]).max(axis=1)
        done = (better & (gain <= tolerance * np.maximum(cost[active], 1e-30)) &
                (moved < CENTRE_TOLERANCE_PX)) | (damping[active] >= 1e6)
        active = active[~done]
    used = np.maximum(weights.astype(bool).sum(axis=1), 1)
    return params, np.sqrt(cost / used)


def _gain_offset_columns(jacobian, p, r, data, weights, model, xs, ys):
    """
    Fill the last two Jacobian columns of ``b + a * shape(p)``: ``w shape`` and ``w``.

    The model's values are ``r / w + data`` where the weight ``w`` is not zero; where it is,
    the column is 0 whatever the shape. A gain too near zero to divide by gets its shape from
    one evaluation with ``a = 1, b = 0``.
    """
    gain, offset = p[:, -2, None], p[:, -1, None]
    weighted = weights != 0
    values = np.divide(r, weights, out=np.zeros_like(r), where=weighted) + data
    small = np.abs(gain[:, 0]) < 1e-6
    shape = (values - offset) / np.where(small[:, None], 1.0, gain)
    if small.any():
        unit = p[small].copy()
        unit[:, -2], unit[:, -1] = 1.0, 0.0
        shape[small] = model(unit, xs[small], ys[small])
    jacobian[:, :, -2] = shape * weights
    jacobian[:, :, -1] = weights


def _solve(matrices, vectors):
    """Solve each (k, k) system; if one is singular, all get least-squares solutions."""
    try:
        return np.linalg.solve(matrices, vectors[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        return np.stack([np.linalg.lstsq(m, v, rcond=None)[0] for m, v in zip(matrices, vectors)])


def feature_windows(centres, half, shape):
    """Square windows of ``2 half + 1`` pixels around each centre: xs, ys, inside (n, m)."""
    offsets_y, offsets_x = np.mgrid[-half:half + 1, -half:half + 1]
    xs = np.rint(centres[:, 0])[:, None] + offsets_x.ravel()[None]
    ys = np.rint(centres[:, 1])[:, None] + offsets_y.ravel()[None]
    inside = (xs >= 0) & (xs < shape[1]) & (ys >= 0) & (ys < shape[0])
    return xs, ys, inside


def _window_values(image, xs, ys):
    rows, cols = image.shape
    return image[np.clip(ys, 0, rows - 1).astype(int), np.clip(xs, 0, cols - 1).astype(int)]


@dataclasses.dataclass
class Refinement:
    """Fitted feature positions (n, 2), the fitted parameters and each fit's residual rms."""

    points: np.ndarray
    params: np.ndarray
    residual_rms: np.ndarray
    valid: np.ndarray           # fit converged to a sensible feature near its start


def _blob_start(values, xs, ys, centres, inside):
    """Start parameters of the ellipse fit: round blob of the size seen above half height."""
    count = len(centres)
    params = np.zeros((count, 8))
    params[:, :2] = centres
    distance = np.hypot(xs - centres[:, :1], ys - centres[:, 1:])
    half = int(np.sqrt(xs.shape[1])) // 2
    for k in range(count):
        ring = values[k][inside[k] & (distance[k] > half - 1)]
        background = np.median(ring) if len(ring) else values[k][inside[k]].min()
        peak = values[k][inside[k] & (distance[k] <= 1.5)].max(initial=background)
        area = np.count_nonzero(inside[k] & (values[k] > (background + peak) / 2))
        params[k, 2] = np.log(max(np.sqrt(area / np.pi), 0.8))
        params[k, 5] = np.log(START_EDGE_WIDTH_PX)
        params[k, 6] = peak - background
        params[k, 7] = background
    return params


def _neighbour_tails(params, xs, ys, reach, model=blurred_ellipse):
    """Sum over each window of the other blobs' fitted excess over their background."""
    centres = params[:, :2]
    distance = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    owner, other = np.nonzero((distance < reach) & ~np.eye(len(centres), dtype=bool))
    tails = np.zeros(xs.shape)
    if len(owner):
        excess = params[other].copy()
        excess[:, 7] = 0.0
        np.add.at(tails, owner, model(excess, xs[owner], ys[owner]))
    return tails


def refine_circle_centres(image, centres, warm, max_shift_px=1.0, kernels_choice='auto'):
    """
    Fit blurred ellipses to the blobs of a circle grid around rough ``centres`` (n, 2).

    ``warm``: the blobs are warmer than the plate (else colder). Returns a Refinement; a fit is
    invalid if it moved more than ``max_shift_px`` from its start or did not end as a blob
    (positive-definite ellipse, positive contrast and edge width). ``kernels_choice``: the
    model's implementation (``ellipse_model``).
    """
    model = ellipse_model(kernels_choice)
    values_sign = 1.0 if warm else -1.0
    image = np.asarray(image, dtype=np.float64) * values_sign
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    spacing = np.sort(np.linalg.norm(centres[:, None] - centres[None], axis=2), axis=1)[:, 1]
    half = int(np.clip(np.ceil(np.median(spacing) * 0.6), 3, 8))
    xs, ys, inside = feature_windows(centres, half, image.shape)
    values = _window_values(image, xs, ys)
    params = _blob_start(values, xs, ys, centres, inside)
    # Circles of a grid do not overlap: radius at most half the spacing to the nearest one.
    bounds = np.repeat(BLOB_BOUNDS[:, None, :], len(centres), axis=1)
    bounds[1, :, 2] = np.log(np.maximum(0.5 * spacing, 0.8))
    params[:, 2] = np.minimum(params[:, 2], bounds[1, :, 2])
    # First each blob alone, on the pixels nearer to it than half way to its nearest neighbour;
    # then on the whole window with the neighbours' fitted tails subtracted (twice).
    own = np.hypot(xs - centres[:, :1], ys - centres[:, 1:]) <= 0.5 * spacing[:, None] + 0.5
    params, rms = fit_batch(model, params, xs, ys, values,
                            (inside & own).astype(np.float64), BLOB_STEPS, bounds,
                            gain_offset=True)
    for _ in range(2):
        tails = _neighbour_tails(params, xs, ys, 4.0 * half, model)
        params, rms = fit_batch(model, params, xs, ys, values - tails,
                                inside.astype(np.float64), BLOB_STEPS, bounds,
                                gain_offset=True)
    valid = (np.linalg.norm(params[:, :2] - centres, axis=1) <= max_shift_px) & \
        (params[:, 6] > 0) & np.all(np.isfinite(params), axis=1)
    return Refinement(points=params[:, :2].copy(), params=params, residual_rms=rms, valid=valid)


def refine_chessboard_corners(image, corners, pattern_size, max_shift_px=1.0):
    """
    Fit blurred saddles to the inner corners of a chessboard around rough ``corners`` (n, 2).

    ``pattern_size`` is (corners per row, rows), the order of ``corners``. The start angles of
    the two edges come from the directions to the neighbouring corners along the row and the
    column; the window reaches half way to the nearest neighbouring corner.
    """
    image = np.asarray(image, dtype=np.float64)
    corners = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    cols, rows = pattern_size
    grid = corners.reshape(rows, cols, 2)
    along_row = np.gradient(grid, axis=1).reshape(-1, 2)
    along_col = np.gradient(grid, axis=0).reshape(-1, 2)
    spacing = np.minimum(np.linalg.norm(along_row, axis=1), np.linalg.norm(along_col, axis=1))
    half = int(np.clip(np.floor(np.median(spacing) * 0.6), 2, 8))
    xs, ys, inside = feature_windows(corners, half, image.shape)
    reach = np.hypot(xs - corners[:, :1], ys - corners[:, 1:])
    weights = (inside & (reach <= 0.6 * spacing[:, None] + 0.5)).astype(np.float64)
    values = _window_values(image, xs, ys)
    params = np.zeros((len(corners), 7))
    params[:, :2] = corners
    params[:, 2] = np.arctan2(along_row[:, 1], along_row[:, 0])
    params[:, 3] = np.arctan2(along_col[:, 1], along_col[:, 0])
    params[:, 4] = np.log(START_EDGE_WIDTH_PX)
    # Contrast and mean level: linear least squares given the start geometry.
    shape = params.copy()
    shape[:, 5], shape[:, 6] = 1.0, 0.0
    basis = blurred_saddle(shape, xs, ys)
    for k in range(len(corners)):
        used = weights[k] > 0
        design = np.column_stack([basis[k][used], np.ones(used.sum())])
        (params[k, 5], params[k, 6]), *_ = np.linalg.lstsq(design, values[k][used], rcond=None)
    params, rms = fit_batch(blurred_saddle, params, xs, ys, values, weights, SADDLE_STEPS,
                            SADDLE_BOUNDS, gain_offset=True)
    valid = (np.linalg.norm(params[:, :2] - corners, axis=1) <= max_shift_px) & \
        (np.abs(np.sin(params[:, 2] - params[:, 3])) > 0.2) & \
        np.all(np.isfinite(params), axis=1)
    return Refinement(points=params[:, :2].copy(), params=params, residual_rms=rms, valid=valid)
