"""
Sub-pixel peers of ST, run on the same windows around the same rough matches.

Each peer refines integer matches ``(y, x_left, d_int)`` from raw-intensity windows and
returns sub-pixel disparities (NaN where it fails). Conventions were measured on synthetic
Fourier shifts (right window ``R(u) = L(u + r)``): both OpenCV functions return ``-r`` and
scikit-image's column shift returns ``+r``.
"""

import cv2
import numpy as np
from skimage.registration import phase_cross_correlation

from st_stereo.core.subpixel import extract_windows


def _even_offsets(image, y, x, size):
    """
    Top-left corners of (W+1)-sided windows around (y, x).

    The extra pixel goes after the centre, or before it where it would leave the image.
    OpenCV's phase correlation is biased by half a pixel on odd sizes, so it runs on even ones.
    """
    half = size // 2
    rows, cols = image.shape
    start_y = np.where(y + half + 1 < rows, y - half, y - half - 1)
    start_x = np.where(x + half + 1 < cols, x - half, x - half - 1)
    return start_y, start_x


def _even_windows(image, start_y, start_x, size):
    offsets = np.arange(size + 1)
    return image[(start_y[:, None] + offsets)[:, :, None],
                 (start_x[:, None] + offsets)[:, None, :]]


def _even_pairs(left, right, y, x_left, x_right, size):
    """Left and right (W+1) windows with the same placement relative to their centres."""
    ly, lx = _even_offsets(left, y, x_left, size)
    ry, rx = _even_offsets(right, y, x_right, size)
    # Use one common placement per pair: the one that fits both windows.
    start_y = np.minimum(ly, ry)
    dx = np.minimum(lx - x_left, rx - x_right)
    return (_even_windows(left, start_y, x_left + dx, size),
            _even_windows(right, start_y, x_right + dx, size))


def opencv_phase_correlate(left, right, y, x_left, d_int, size):
    """Run cv2.phaseCorrelate (Hann window, 5x5 weighted centroid) on (W+1)-sided windows."""
    taper = cv2.createHanningWindow((size + 1, size + 1), cv2.CV_64F)
    lw, rw = _even_pairs(left, right, y, x_left, x_left - d_int, size)
    shifts = np.empty(len(lw))
    for i in range(len(lw)):
        # Copies: opencv-python 5 writes the windowed values back into non-contiguous views.
        (sx, _), _ = cv2.phaseCorrelate(np.ascontiguousarray(lw[i]),
                                        np.ascontiguousarray(rw[i]), taper)
        shifts[i] = sx
    return d_int - shifts


def _mean_removed_tapered(windows):
    windows = windows - windows.mean(axis=(-2, -1), keepdims=True)
    size = windows.shape[-1]
    return windows * cv2.createHanningWindow((size, size), cv2.CV_64F)


def opencv_phase_correlate_iterative(left, right, y, x_left, d_int, size):
    """Run cv2.phaseCorrelateIterative (OpenCV 5) on mean-removed, Hann-tapered (W+1) windows."""
    lw, rw = _even_pairs(left, right, y, x_left, x_left - d_int, size)
    lw, rw = _mean_removed_tapered(lw), _mean_removed_tapered(rw)
    shifts = np.empty(len(lw))
    for i in range(len(lw)):
        try:
            sx, _ = cv2.phaseCorrelateIterative(np.ascontiguousarray(lw[i]),
                                                np.ascontiguousarray(rw[i]))
        except cv2.error:
            sx = np.nan
        shifts[i] = sx
    return d_int - shifts


def skimage_upsampled(left, right, y, x_left, d_int, size):
    """Run skimage phase_cross_correlation (upsampled DFT, factor 100) on Hann-windowed inputs."""
    x_right = x_left - d_int
    lw = _mean_removed_tapered(extract_windows(left, y, x_left, size))
    rw = _mean_removed_tapered(extract_windows(right, y, x_right, size))
    out = np.empty(len(y))
    for i in range(len(y)):
        shift = phase_cross_correlation(lw[i], rw[i], upsample_factor=100,
                                        normalization='phase')[0]
        out[i] = d_int[i] + shift[1]
    return out


def sad_parabola(left, right, y, x_left, d_int, size):
    """
    Parabola through the SAD costs of W x W windows at the best integer disparity +- 1.

    The integer disparity is re-chosen in ``d_int +- 1`` (as block matchers do), then
    ``d = d* + (C(-1) - C(+1)) / (2 (C(-1) - 2 C(0) + C(+1)))``. Windows have their mean
    removed (zero-mean SAD), the fair form for two cameras with different offsets: block
    matchers prefilter for the same reason (OpenCV StereoBM normalises, SGBM uses a Sobel
    prefilter).
    """
    half = size // 2
    cols = right.shape[1]
    left_windows = extract_windows(left, y, x_left, size)
    left_windows = left_windows - left_windows.mean(axis=(1, 2), keepdims=True)
    steps = np.arange(-2, 3)
    costs = np.full((len(y), len(steps)), np.inf)
    for j, step in enumerate(steps):
        x_right = x_left - d_int - step
        ok = (x_right - half >= 0) & (x_right + half < cols)
        rw = extract_windows(right, y[ok], x_right[ok], size)
        rw = rw - rw.mean(axis=(1, 2), keepdims=True)
        costs[ok, j] = np.abs(left_windows[ok] - rw).sum(axis=(1, 2))
    inner = costs[:, 1:4]
    best = inner.argmin(axis=1) + 1
    rows = np.arange(len(y))
    c_minus, c_zero, c_plus = (costs[rows, best - 1], costs[rows, best],
                               costs[rows, best + 1])
    curvature = c_minus - 2.0 * c_zero + c_plus
    with np.errstate(invalid='ignore', divide='ignore'):
        offset = np.where(curvature > 0, (c_minus - c_plus) / (2.0 * curvature), np.nan)
    return d_int + steps[best] + offset


PEERS = {
    'opencv_phaseCorrelate': opencv_phase_correlate,
    'opencv_phaseCorrelateIterative': opencv_phase_correlate_iterative,
    'skimage_upsampled_dft': skimage_upsampled,
    'sad_parabola': sad_parabola,
}
