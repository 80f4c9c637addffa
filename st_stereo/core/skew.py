"""
Camera skew: two free-running cameras expose a pair at different instants.

A Lepton 2 has no sync input; the right image of a pair is taken ``skew_s = t_right - t_left``
after the left one (up to half a unique frame period, ~57 ms, either sign). A feature moving in
the rectified image with horizontal velocity ``v_x`` (px/s) is then seen by the right camera
``v_x * skew_s`` further along, and the measured disparity ``d' = x_L(t_L) - x_R(t_R)`` is off by
that much:

    d = d' + v_x * skew_s                                              (skew correction)

``v_x`` is measured by tracking each feature's window from a camera's previous unique frame to
its current one (a backward difference: no added latency): an integer zero-mean NCC search,
then a parabola through the NCC at the best column and its neighbours. The camera is the one
whose two frames bracket the other camera's instant, so that the displacement over the skew
is interpolated within the measured interval, never extrapolated beyond it: the left camera
when the right one exposed first (``skew_s < 0``: ``t_R`` lies between the left camera's
previous frame and its current one), the right camera when it exposed after the left one
(``skew_s > 0``: ``t_L`` lies between the right camera's two frames; the feature is tracked
at its right pixel ``x_L - d'``). Measured on the tuning sequences, people faster than 25 px/s,
skew +40 ms: median abs error 0.468 px with the left camera's velocity, 0.378 px with the
right camera's (docs/skew.md). When the bracketing camera has no usable previous frame (not
known, more than ``max_period_s`` old, another shape, frozen by an FFC) the other one serves,
extrapolating, and the pair is counted as ``pairs_extrapolated``.
With ``skew_velocity`` ``poc`` (an option, not the default: below) the track only finds the
moving features and places a second search: each moving feature's disparity is measured again
by the matcher's own sub-pixel POC with the bracketing camera's previous frame in place of its
current one (``poc_velocity``), and the difference of the two disparities over the period is
the velocity. ``d' + v_x skew_s`` is then the disparity interpolated in time between two
correspondences of the same Hann-weighted window, which the NCC's integer search and parabola
only approximate. Measured on the tuning sequences, moving people, published matches: median
abs error 0.282 -> 0.241 px (10-25 px/s) and 0.326 -> 0.291 px (over 25 px/s) at +55 ms, p90
0.799 -> 0.679 and 0.804 -> 0.707 px (docs/skew.md). A moving feature the POC does not find
again is dropped with ``skew_drop_untracked`` (``rejected_skew_poc``). Not the default: with
it the people stage lost walk_across's walker to a warm screen (precision 100 -> 63.7 %,
docs/skew.md), a tracker fragility that these slightly different points set off.
Features that do not move (their window did not change beyond the noise, or best offset 0 and
a sub-pixel shift below ``static_px``) get no correction at all, so a static scene keeps
exactly the same disparities. Windows that did not change are not tracked at all (the search
is most of the cost, and in a room most features are static).
"""

import dataclasses

import cv2
import numpy as np

import st_stereo.core.kernels as compiled_kernels
from st_stereo.core.matcher import fill_invalid
from st_stereo.core.subpixel import refine_subpixel_poc
from st_stereo.core.triangulation import triangulate


NOISE_PERCENTILE = 5.0      # of the frame difference's local spread: the noise level
# A POC velocity farther than this many pixels per period from the NCC track's is refused.
POC_MAX_DISAGREEMENT_PX = 1.0


@dataclasses.dataclass
class FeatureMotion:
    """Horizontal image velocity of each feature, from a camera's previous frame."""

    velocity_x: np.ndarray      # px/s in the rectified image (0 where static or untracked)
    moving: np.ndarray          # bool: a correction applies
    changed: np.ndarray         # bool: the window changed beyond the noise (so it was tracked)
    tracked: np.ndarray         # bool: changed, and its track is good (NCC >= min_ncc, ...)
    ncc: np.ndarray             # best NCC of the track (nan where not searched)


def feature_motion(previous_left, left, x, y, period_s, window=9, search_x=8, search_y=3,
                   min_ncc=0.5, static_px=0.25, change_noise=2.0, kernels='auto'):
    """
    Measure each feature's horizontal image velocity between two frames of one camera.

    Parameters
    ----------
    previous_left, left : ndarray, shape (rows, cols)
        A camera's previous unique rectified frame and the current one (the names are the
        left camera's, which served alone before ``bracketing_motion``).
    x, y : ndarray of int, shape (n,)
        Feature pixels in ``left``.
    period_s : float
        Time between the two frames, seconds (> 0).
    window : int
        Side of the tracked window (odd).
    search_x, search_y : int
        Integer search range, pixels (``search_x / period_s`` is the fastest motion tracked).
    min_ncc : float
        A track whose best zero-mean NCC is below this is not trusted (no correction).
    static_px : float
        A feature whose displacement between the frames is below this is static.
    change_noise : float
        A feature is static unless the standard deviation of the frame difference over its
        window exceeds this many times the noise level (the 5th percentile of that standard
        deviation over the frame; about 0.87 sigma for pure noise). Pure noise over 81 pixels
        exceeds 1.74 sigma with a probability far below 1e-15 (chi-square, 80 degrees of
        freedom), so a static scene keeps every disparity exactly.
    kernels : str
        ``STConfig.kernels``: the NCC search compiled or OpenCV's (``window_ncc``).

    Returns
    -------
    FeatureMotion

    """
    if period_s <= 0:
        raise ValueError(f'period_s: expected > 0 s, got {period_s}')
    previous = np.asarray(previous_left, dtype=np.float64)
    current = np.asarray(left, dtype=np.float64)
    if previous.shape != current.shape:
        raise ValueError(f'previous_left: expected shape {current.shape}, got {previous.shape}')
    x, y = np.asarray(x, dtype=np.int64), np.asarray(y, dtype=np.int64)
    n = len(x)
    half = window // 2
    reach_x, reach_y = half + search_x + 1, half + search_y
    # A window that did not change beyond the noise has not moved, whatever its track says.
    changed = changed_windows(previous, current, x, y, window, change_noise)
    # Windows may leave the image: both frames are extended by edge replication (a feature
    # near the border is still tracked, on the part of its window inside the image). Raw
    # 14-bit counts sit near 8000 with a texture of a few counts: the frame means are taken
    # off before the float32 NCC, or float32 rounding swamps the texture.
    pad = ((reach_y, reach_y), (reach_x, reach_x))
    current = np.pad(current - current.mean(), pad, mode='edge')
    previous = np.pad(previous - previous.mean(), pad, mode='edge')
    velocity = np.zeros(n)
    moving = np.zeros(n, dtype=bool)
    tracked = np.zeros(n, dtype=bool)
    best_ncc = np.full(n, np.nan)
    index = np.flatnonzero(changed)
    if len(index):
        xi, yi = x[index] + reach_x, y[index] + reach_y
        offsets_x = np.arange(-search_x - 1, search_x + 2)
        offsets_y = np.arange(-search_y, search_y + 1)
        ncc = window_ncc(current, previous, yi, xi, half, offsets_y, offsets_x, kernels)
        # The best integer offset within the search range (the outer columns only serve the
        # parabola), then the sub-pixel column.
        inner = ncc[:, :, 1:-1]
        flat = inner.reshape(len(index), -1).argmax(axis=1)
        row, col = np.divmod(flat, inner.shape[2])
        col += 1
        k = np.arange(len(index))
        peak = ncc[k, row, col]
        left_value, right_value = ncc[k, row, col - 1], ncc[k, row, col + 1]
        curvature = left_value - 2.0 * peak + right_value
        sub = np.where(curvature < -1e-12,
                       0.5 * (left_value - right_value) / np.where(curvature < -1e-12,
                                                                   curvature, -1.0), 0.0)
        # The feature was at x + offset in the previous frame: it moved by -(offset).
        shift = -(offsets_x[col] + np.clip(sub, -0.5, 0.5))
        # A peak on the edge of the search range may lie beyond it: not a track (along x the
        # outer columns tell; along y there are none).
        beyond_x = (np.abs(offsets_x[col]) == search_x) & \
            (np.maximum(left_value, right_value) > peak)
        good = (peak >= min_ncc) & ~beyond_x & (np.abs(offsets_y[row]) < search_y)
        static = (offsets_x[col] == 0) & (offsets_y[row] == 0) & (np.abs(shift) < static_px)
        tracked[index] = good
        best_ncc[index] = peak
        moves = good & ~static
        moving[index] = moves
        velocity[index] = np.where(moves, shift / period_s, 0.0)
    return FeatureMotion(velocity, moving, changed, tracked, best_ncc)


def window_ncc(current, previous, y, x, half, offsets_y, offsets_x, kernels='auto'):
    """
    Zero-mean NCC of each feature's window against another frame at every offset.

    ``ncc[k, a, b]`` correlates ``current``'s window of side ``2 half + 1`` centred on
    ``(y[k], x[k])`` with ``previous``'s centred on ``(y[k] + offsets_y[a], x[k] +
    offsets_x[b])`` (every window inside both frames; ``offsets`` consecutive integers). The
    reference (``kernels`` numpy) is OpenCV's ``TM_CCOEFF_NORMED`` over one small search
    region per feature, in float32; the compiled kernel (``kernels.window_ncc``) computes the
    same in float64, its cross sums shared between neighbouring features, with OpenCV's
    handling of flat windows (a flat template correlates 1, a flat window 0).
    """
    if compiled_kernels.use_compiled(kernels):
        return compiled_kernels.window_ncc(current, previous, y, x, half, offsets_y, offsets_x)
    current32, previous32 = current.astype(np.float32), previous.astype(np.float32)
    ncc = np.empty((len(y), len(offsets_y), len(offsets_x)))
    top, bottom = -offsets_y[0], offsets_y[-1]
    before, after = -offsets_x[0], offsets_x[-1]
    for k, (fy, fx) in enumerate(zip(np.asarray(y).tolist(), np.asarray(x).tolist())):
        template = current32[fy - half:fy + half + 1, fx - half:fx + half + 1]
        region = previous32[fy - half - top:fy + half + bottom + 1,
                            fx - half - before:fx + half + after + 1]
        ncc[k] = cv2.matchTemplate(region, template, cv2.TM_CCOEFF_NORMED)
    return np.nan_to_num(ncc, nan=-1.0)        # a flat window correlates with nothing


def changed_windows(previous, current, x, y, window=9, change_noise=2.0):
    """
    Whether each feature's window changed between two frames of one camera beyond the noise.

    The spread (standard deviation) of the frame difference over the ``window x window``
    square at each feature, against ``change_noise`` times the frame's noise level, taken as
    the 5th percentile of that spread over the frame's pixels that change at all (its
    flattest or static parts: sensor noise alone; a border without data never changes).
    Features outside the image have not changed (False). Give frames whose pixels without
    data are filled (``matcher.fill_invalid``): windows that straddle a border of 0 have a
    lower spread than the noise, and pull the level down (a review: with a 3-px border the
    level fell from 2.4 to 1.3 counts and 70 % of a static scene's windows "changed").
    """
    previous = np.asarray(previous, dtype=np.float64)
    current = np.asarray(current, dtype=np.float64)
    x, y = np.asarray(x, dtype=np.int64), np.asarray(y, dtype=np.int64)
    size = 2 * (window // 2) + 1
    difference = current - previous
    mean = cv2.boxFilter(difference, -1, (size, size), borderType=cv2.BORDER_REPLICATE)
    mean_square = cv2.boxFilter(difference ** 2, -1, (size, size),
                                borderType=cv2.BORDER_REPLICATE)
    spread_map = np.sqrt(np.maximum(mean_square - mean ** 2, 0.0))
    # Pixels without data (a rectified image's border, 0 in both frames) do not change at
    # all: left in, a border of 5 % or more would make the noise level zero and every window
    # with real noise 'changed'.
    with_data = spread_map[spread_map > 0]
    noise = max(float(np.percentile(with_data, NOISE_PERCENTILE)), 1e-9) \
        if with_data.size else 1e-9
    rows, cols = current.shape
    inside = (x >= 0) & (x < cols) & (y >= 0) & (y < rows)
    changed = np.zeros(len(x), dtype=bool)
    changed[inside] = spread_map[y[inside], x[inside]] > change_noise * noise
    return changed


def poc_velocity(frames, camera, left, right, x_left, y, disparity, velocity_x, config,
                 max_disagreement_px=POC_MAX_DISAGREEMENT_PX):
    """
    Re-measure moving features' horizontal velocity by POC across a camera's two frames.

    The disparity of the same feature is measured twice by the matcher's own sub-pixel POC
    (``refine_subpixel_poc``, the pair's ``config``): against the pair (``disparity``, ``d``)
    and with one image taken from the camera's previous frame (``d_prev``), one period ``T``
    earlier. For a rigid motion ``v`` along the rows:

    - ``camera == 'right'``: the left window at ``(y, x_left)`` against the right camera's
      previous frame, searched from ``rint(d + v T)``: ``d_prev = d + v T``;
    - ``camera == 'left'``: the left camera's previous frame's window at the feature's
      previous pixel ``rint(x_left - v T)``, against the pair's right image, searched from its
      right pixel ``x_left - d``: ``d_prev = d - v T`` (whatever the window's integer column,
      with the disparity locally constant).

    So ``v = +-(d_prev - d) / T``, and ``d + v skew`` is the disparity interpolated in time
    between the two measured correspondences: the same Hann-weighted window, located by the
    same estimator, as the disparity it corrects (the NCC track's velocity, ``velocity_x``,
    only places the search). The POC runs on the images given (the intensities) whatever
    ``poc_source``: with ``poc_source`` moments, on a rigid motion of 23.7 px/s at +-45 ms,
    the corrected median error is 0.015 px with these velocities, 0.022-0.027 px with
    velocities measured on the feature images M, 0.034-0.039 px with the NCC's. ``d_prev``
    pairs two instants and may be negative (fast motion at a small disparity): it is not
    clamped. Returns the velocities, nan where either window leaves the image, the POC
    rejected the window, or the two velocities disagree by more than
    ``max_disagreement_px / T`` (the POC locked on something else). ``SkewCompensator``
    passes its images with the pixels without data filled from their nearest data, as the
    matcher's own POC sees them.
    """
    x_left = np.asarray(x_left, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    disparity = np.asarray(disparity, dtype=np.float64)
    velocity_x = np.asarray(velocity_x, dtype=np.float64)
    period = frames.period_s
    rows, cols = np.shape(left)
    half = config.poc_window // 2
    out = np.full(len(x_left), np.nan)
    if not len(x_left):
        return out
    if camera == 'right':
        window_x = x_left
        first, second = left, frames.previous
        start = np.rint(disparity + velocity_x * period).astype(np.int64)
        sign = 1.0
    else:
        window_x = np.rint(x_left - velocity_x * period).astype(np.int64)
        first, second = frames.previous, right
        start = np.rint(window_x - (x_left - disparity)).astype(np.int64)
        sign = -1.0
    second_x = window_x - start
    inside = (window_x >= half) & (window_x < cols - half) & (y >= half) & \
        (y < rows - half) & (second_x >= half) & (second_x < cols - half)
    index = np.flatnonzero(inside)
    if not len(index):
        return out
    refined = refine_subpixel_poc(first, second, y[index], window_x[index], start[index],
                                  config)
    # start + correction, not refined.disparity: that one is clamped at 0 (a stereo disparity
    # cannot be negative; this cross-time one can).
    velocity = sign * (start[index] + refined.correction - disparity[index]) / period
    trusted = refined.accepted & \
        (np.abs(velocity - velocity_x[index]) * period <= max_disagreement_px)
    out[index[trusted]] = velocity[trusted]
    return out


def skew_corrected_disparity(disparity, velocity_x, skew_s):
    """
    Return ``disparity + velocity_x * skew_s`` (see the module docstring).

    ``skew_s`` is ``t_right - t_left`` of the pair, seconds; static features (velocity 0) keep
    their disparity exactly.
    """
    return np.asarray(disparity, dtype=np.float64) + np.asarray(velocity_x) * float(skew_s)


SKEW_COUNT_KEYS = ('pairs_skew_compensated', 'pairs_without_skew', 'pairs_without_previous',
                   'pairs_calibration_changed', 'pairs_in_ffc', 'pairs_tracked_on_right',
                   'pairs_extrapolated', 'features_moving', 'features_untracked',
                   'rejected_skew_range', 'rejected_skew_untracked',
                   'rejected_skew_disagreement', 'rejected_skew_poc',
                   'features_checked_on_both', 'features_poc_velocity')


@dataclasses.dataclass
class CameraFrames:
    """One camera's previous and current rectified frames and the time between them."""

    previous: np.ndarray
    current: np.ndarray
    period_s: float


def bracketing_motion(x_left, y, disparity, skew_s, left_frames, right_frames=None,
                      kernels='auto'):
    """
    Measure the features' motion on the camera whose frames bracket the other's instant.

    ``skew_s > 0`` (the right camera exposed after the left one) with ``right_frames``: each
    feature is tracked at its right pixel ``rint(x_left - disparity)`` (``disparity`` as the
    matcher gives it, principal-point offset included) on the right camera's frames; otherwise
    on the left camera's, at ``x_left`` (see the module docstring). Either may be None (not
    known, or frozen by an FFC): the other serves, extrapolating.

    Returns
    -------
    (FeatureMotion, str): the motion and the camera tracked (``'left'`` or ``'right'``).

    """
    if right_frames is not None and (skew_s > 0 or left_frames is None):
        return camera_motion(right_frames, 'right', x_left, y, disparity, kernels), 'right'
    if left_frames is None:
        raise ValueError('bracketing_motion: neither camera has two frames')
    return camera_motion(left_frames, 'left', x_left, y, disparity, kernels), 'left'


def camera_motion(frames, camera, x_left, y, disparity, kernels='auto'):
    """
    Track the features on one camera's frames (``feature_motion``).

    On the left camera at ``x_left``; on the right one at the right pixel
    ``rint(x_left - disparity)``, clipped to the image.
    """
    x = np.asarray(x_left)
    if camera == 'right':
        cols = np.shape(frames.current)[1]
        x = np.clip(np.rint(x - np.asarray(disparity)), 0, cols - 1)
    return feature_motion(frames.previous, frames.current, x.astype(np.int64), y,
                          frames.period_s, kernels=kernels)


def cameras_disagree(motion, other, skew_s, tolerance_px):
    """
    Flag the moving features whose displacement over the skew the two cameras disagree on.

    ``motion`` is the bracketing camera's (``bracketing_motion``), ``other`` the other
    camera's motion of the features ``motion.moving`` selects (same order). A feature is
    flagged when both tracked it and ``|v_x - v_x_other| |skew_s| > tolerance_px``: the
    correction ``v_x skew_s`` is then uncertain by more than the tolerance (a body part that
    deforms, an occlusion boundary that slides, a window mixing two surfaces). Measured on
    walk_across (skew +40 ms): 61 % of the moving matches with a disagreement above 16 px/s
    (0.64 px) were 3-D outliers, 2.6 % of those below 2 px/s (docs/skew.md).
    """
    flagged = np.zeros(len(motion.moving), dtype=bool)
    index = np.flatnonzero(motion.moving)
    difference = np.abs(motion.velocity_x[index] - other.velocity_x) * abs(float(skew_s))
    flagged[index] = other.tracked & (difference > tolerance_px)
    return flagged


def compensation_options(config):
    """
    Return ``SkewCompensator.correct``'s keyword options from an STConfig.

    ``skew_drop_untracked``, ``skew_agreement_px`` and ``kernels`` as they are;
    ``poc_config`` is the config itself when ``skew_velocity`` is ``poc`` (its POC parameters
    re-measure the velocities, ``poc_velocity``), else None (the NCC track's velocities).
    """
    return {'drop_untracked': config.skew_drop_untracked,
            'agreement_px': config.skew_agreement_px, 'kernels': config.kernels,
            'poc_config': config if config.skew_velocity == 'poc' else None}


class SkewCompensator:
    """
    Correct each pair's disparities for its camera skew, frame after frame (one pair kept).

    ``correct`` is called once per pair, in order, with the pair's rectified left image (and,
    when given, its rectified right image), the left acquisition time and the skew
    (``t_right - t_left``; both None when the pair does not say, and then the next pair has no
    previous time either): it measures the features' motion against the previous pair's
    images (``bracketing_motion``: the right camera's when the right one exposed later, the
    left camera's when it exposed first; each at most ``max_period_s`` older), corrects their
    disparities, re-triangulates, drops matches the correction takes outside the admissible
    disparities, and remembers the images. A camera in FFC (``ffc``, from ``pair_info``) in this
    pair or the previous one is not tracked (its frames are frozen, older than their stamp, or
    the first after the freeze, at another level); the other one serves, extrapolating. A
    pair whose stereo model is another object than the previous pair's (a new calibration: the
    previous images were rectified differently) is not corrected. Counts of every case
    accumulate in ``counts``.
    """

    def __init__(self, max_period_s=0.25):
        self.max_period_s = max_period_s
        self.previous = None
        self.previous_time = None
        self.previous_right = None
        self.previous_right_time = None
        self.previous_model = None
        self.previous_ffc = (False, False)
        self.counts = dict.fromkeys(SKEW_COUNT_KEYS, 0)

    def remember(self, left, left_time_s, right=None, skew_s=None, model=None,
                 ffc=(False, False), left_valid=None, right_valid=None):
        """
        Keep a pair's images as the previous ones (``correct`` does it for every pair).

        ``left_valid`` / ``right_valid``: the pixels with data (a rectified image's border has
        none), as ``correct`` takes them.
        """
        self.previous, self.previous_time = fill_invalid(np.asarray(left), left_valid), \
            left_time_s
        known = right is not None and left_time_s is not None and skew_s is not None
        self.previous_right = fill_invalid(np.asarray(right), right_valid) if known else None
        self.previous_right_time = left_time_s + skew_s if known else None
        self.previous_model = model
        self.previous_ffc = tuple(bool(flag) for flag in ffc)

    def _frames(self, previous, previous_time, current, time_s):
        period = None if previous_time is None or time_s is None else time_s - previous_time
        if previous is None or current is None or previous.shape != np.shape(current) or \
                not period or not 0.0 < period <= self.max_period_s:
            return None
        return CameraFrames(previous, np.asarray(current), period)

    def correct(self, result, left, left_time_s, skew_s, model=None, bounds=None, right=None,
                ffc=(False, False), drop_untracked=True, agreement_px=0.5, poc_config=None,
                kernels='auto', left_valid=None, right_valid=None):
        """
        Return ``result`` with skew-corrected disparities and points (or unchanged).

        With ``drop_untracked``, a match whose window changed beyond the noise but could not be
        tracked (``FeatureMotion.changed & ~tracked``) is dropped and counted
        (``rejected_skew_untracked``): it moves at an unknown velocity, so its disparity carries
        an unknown ``v_x skew_s``. Measured on walk_across (skew +40 ms, stride 4): 195 of 3266
        matches, 31.8 % of them 3-D outliers against 6.9 % over all (docs/skew.md).

        With ``agreement_px`` > 0 and both cameras' frames usable, the moving features are
        also tracked on the other camera and a match whose two displacements over the skew
        differ by more than ``agreement_px`` is dropped and counted
        (``rejected_skew_disagreement``; ``cameras_disagree``).

        With ``poc_config`` (an STConfig: ``compensation_options`` passes it when
        ``skew_velocity`` is ``poc``) and ``right``, the moving features' velocities are
        measured again by POC (``poc_velocity``, counted as ``features_poc_velocity``); one the
        POC does not find again keeps its NCC velocity, or, with ``drop_untracked``, is dropped
        and counted (``rejected_skew_poc``). Without ``right`` the NCC velocities serve. The
        two-camera check compares the NCC velocities (a drop is counted under its first
        reason only). ``kernels`` chooses the NCC search's implementation (``window_ncc``).

        ``left_valid`` / ``right_valid`` (bool, the images' shape; None: every pixel has data)
        mark the pixels with data, as ``StereoMatcher.match`` takes them: the others (a
        rectified image's border, 0) are filled from their nearest pixel with data before
        anything is tracked, as the matcher fills them, in this pair and in the one kept for
        the next. Left at 0, the border is a step of the frame's whole level (some 8000
        counts) next to a few counts of texture: a window whose search reached it locked on
        the step (a review: up to 94 px/s off, 5 px of disparity at 57 ms of skew).
        """
        left = fill_invalid(np.asarray(left), left_valid)
        if right is not None:
            right = fill_invalid(np.asarray(right), right_valid)
        left_frames = self._frames(self.previous, self.previous_time, left, left_time_s)
        right_frames = None
        if skew_s is not None and left_time_s is not None:
            right_frames = self._frames(self.previous_right, self.previous_right_time, right,
                                        left_time_s + skew_s)
        recalibrated = model is not None and self.previous_model is not None and \
            model is not self.previous_model
        frozen = [now or before for now, before in zip(ffc, self.previous_ffc)]
        self.remember(left, left_time_s, right, skew_s, model, ffc)
        if skew_s is None or left_time_s is None:
            self.counts['pairs_without_skew'] += 1
            return result
        if recalibrated:
            self.counts['pairs_calibration_changed'] += 1
            return result
        if left_frames is None and right_frames is None:
            self.counts['pairs_without_previous'] += 1
            return result
        if not len(result) or skew_s == 0.0:
            self.counts['pairs_skew_compensated'] += 1
            return result
        left_frames = None if frozen[0] else left_frames
        right_frames = None if frozen[1] else right_frames
        if left_frames is None and right_frames is None:
            self.counts['pairs_in_ffc'] += 1
            return result
        self.counts['pairs_skew_compensated'] += 1
        motion, camera = bracketing_motion(result.x_left, result.y, result.disparity, skew_s,
                                           left_frames, right_frames, kernels)
        self.counts['pairs_tracked_on_right'] += int(camera == 'right')
        self.counts['pairs_extrapolated'] += int((camera == 'right') != (skew_s > 0))
        self.counts['features_moving'] += int(motion.moving.sum())
        self.counts['features_untracked'] += int((motion.changed & ~motion.tracked).sum())
        untracked = motion.changed & ~motion.tracked if drop_untracked else \
            np.zeros(len(result), dtype=bool)
        if not motion.moving.any() and not untracked.any():
            return result
        velocity = motion.velocity_x
        keep = ~untracked
        self.counts['rejected_skew_untracked'] += int(untracked.sum())
        if poc_config is not None and right is not None and motion.moving.any():
            frames = right_frames if camera == 'right' else left_frames
            moving = np.flatnonzero(motion.moving)
            measured = poc_velocity(frames, camera, left, right, result.x_left[moving],
                                    result.y[moving], result.disparity[moving],
                                    velocity[moving], poc_config)
            found = np.isfinite(measured)
            self.counts['features_poc_velocity'] += int(found.sum())
            velocity = velocity.copy()
            velocity[moving[found]] = measured[found]
            if drop_untracked:
                self.counts['rejected_skew_poc'] += int((~found).sum())
                keep[moving[~found]] = False
        disparity = skew_corrected_disparity(result.disparity, velocity, skew_s)
        other_frames = left_frames if camera == 'right' else right_frames
        if agreement_px > 0 and other_frames is not None and motion.moving.any():
            moving = motion.moving
            other = camera_motion(other_frames, 'left' if camera == 'right' else 'right',
                                  result.x_left[moving], result.y[moving],
                                  result.disparity[moving], kernels)
            self.counts['features_checked_on_both'] += int(other.tracked.sum())
            disagree = cameras_disagree(motion, other, skew_s, agreement_px)
            self.counts['rejected_skew_disagreement'] += int((keep & disagree).sum())
            keep &= ~disagree
        if bounds is not None:
            inside = (disparity >= bounds[0]) & (disparity <= bounds[1])
            self.counts['rejected_skew_range'] += int((keep & ~inside).sum())
            keep &= inside
        if model is None:               # no geometry: no points (not the uncorrected ones)
            return dataclasses.replace(result.select(keep, disparity), points=None)
        return result.select(keep, disparity,
                             triangulate(model, result.x_point, result.y_point, disparity))
