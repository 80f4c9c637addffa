"""
Compiled kernels of ST's hot path (numba), and the choice between them and numpy.

Each kernel computes exactly what a numpy function of the core computes, in one pass over its
data instead of a dozen array operations (numpy's cost at 80x60 is the per-operation overhead
and the temporaries, not the arithmetic). The numpy functions stay the reference: the tests
compare every kernel with them (``test/test_kernels.py``).

``kernels`` in STConfig: ``auto`` (the compiled kernels when numba imports, else numpy),
``compiled`` (an error when numba is missing) or ``numpy``. Kernels are compiled on first use
and cached on disk (numba's ``cache=True``: next to this module when that is writable, else
in numba's per-user cache directory, or ``NUMBA_CACHE_DIR``); ``warm_up`` compiles them before
the first real pair.
"""

import functools
import time

import numpy as np

KERNEL_CHOICES = ('auto', 'compiled', 'numpy')


@functools.lru_cache(maxsize=1)
def numba_available():
    """Return the numba version string, or '' when numba cannot be imported."""
    try:
        import numba
    except Exception:     # noqa: B902 - not installed, or a broken llvmlite (OSError)
        return ''
    return numba.__version__


def use_compiled(choice):
    """Whether the compiled kernels run for a ``kernels`` setting (see the module docstring)."""
    if choice == 'numpy':
        return False
    if choice == 'compiled':
        if not numba_available():
            raise ValueError('kernels: compiled needs numba (python3-numba, or pip install '
                             'numba); set kernels to auto or numpy to run without it')
        return True
    if choice == 'auto':
        return bool(numba_available())
    raise ValueError(f'kernels: expected one of {", ".join(KERNEL_CHOICES)}, got {choice!r}')


@functools.lru_cache(maxsize=1)
def _compiled():
    """Return the module of numba kernels (``st_stereo.core._numba_kernels``)."""
    import st_stereo.core._numba_kernels as numba_kernels
    return numba_kernels


def phase_congruency_from_responses(responses, thresholds, angles, epsilon, cutoff, gain):
    """
    Compiled counterpart of the arithmetic of ``phase_congruency_moments`` after its FFTs.

    Returns ``(maximum_moment, minimum_moment)``, shape (n, rows, cols), float32.
    """
    kernels = _compiled()
    n, norient, _, rows, cols = responses.shape
    pc = np.empty((n, norient, rows, cols), dtype=np.float32)
    kernels.orientation_energy(np.ascontiguousarray(responses, dtype=np.complex64),
                               np.ascontiguousarray(thresholds, dtype=np.float32),
                               np.float32(epsilon), np.float32(cutoff), np.float32(gain), pc)
    maximum = np.empty((n, rows, cols), dtype=np.float32)
    minimum = np.empty_like(maximum)
    kernels.moments(pc, np.cos(angles).astype(np.float32), np.sin(angles).astype(np.float32),
                    np.float32(epsilon), maximum, minimum)
    return maximum, minimum


def lades_similarity_volume(left_moments, right_moments, disparities, window, tiny):
    """Compiled counterpart of ``rough_matching.lades_similarity_volume``, (D, rows, cols)."""
    left = np.ascontiguousarray(left_moments, dtype=np.float32)
    right = np.ascontiguousarray(right_moments, dtype=np.float32)
    disparities = np.ascontiguousarray(disparities, dtype=np.int64)
    out = np.empty((len(disparities),) + left.shape, dtype=np.float32)
    _compiled().lades_volume(left, right, disparities, int(window), np.float32(tiny), out)
    return out


def cross_power_spectra(left_spectra, right_spectra, mask):
    """Compiled counterpart of ``subpixel.poc_from_spectra`` before its inverse FFT."""
    right = np.ascontiguousarray(right_spectra, dtype=np.complex128)
    out = np.empty_like(right)
    _compiled().cross_power(np.ascontiguousarray(left_spectra, dtype=np.complex128), right,
                            np.ascontiguousarray(mask, dtype=np.float32), out)
    return out


def shift_phases(omega, shifts):
    """Compiled counterpart of the phase ramps of ``fourier.RowShifter.shift``, (n, F)."""
    shifts = np.ascontiguousarray(shifts, dtype=np.float32).reshape(-1)
    out = np.empty((len(shifts), len(omega)), dtype=np.complex64)
    _compiled().shift_phases(np.ascontiguousarray(omega, dtype=np.float32), shifts, out)
    return out


def deramped_strips(image, y, x, size, margin):
    """
    Compiled strips of ``subpixel.extract_strips`` (float32) and ``RowShifter``'s de-ramping.

    Returns ``(strips, periodic, first, slope)``: (n, size, size + 2 margin) twice, then
    (n, size, 1) twice.
    """
    n, width = len(y), size + 2 * margin
    strips = np.empty((n, size, width), dtype=np.float32)
    periodic = np.empty_like(strips)
    first = np.empty((n, size, 1), dtype=np.float32)
    slope = np.empty_like(first)
    _compiled().deramped_strips(np.ascontiguousarray(image, dtype=np.float64),
                                np.ascontiguousarray(y, np.int64),
                                np.ascontiguousarray(x, np.int64), int(size), int(margin),
                                strips, periodic, first[..., 0], slope[..., 0])
    return strips, periodic, first, slope


def reramped_columns(shifted, first, slope, shifts, columns):
    """Compiled ramp of ``RowShifter.shift`` put back on the ``columns`` slice, float32."""
    shifted = np.ascontiguousarray(shifted, dtype=np.float32)
    start, stop, _ = columns.indices(shifted.shape[-1])
    out = np.empty(shifted.shape[:-1] + (stop - start,), dtype=np.float32)
    _compiled().reramped_columns(shifted, np.ascontiguousarray(first[..., 0]),
                                 np.ascontiguousarray(slope[..., 0]),
                                 np.ascontiguousarray(shifts, np.float32).reshape(-1), start,
                                 out)
    return out


def poc_peak_fits(surfaces, band_ratio):
    """
    Compiled counterpart of the peak search and fit of ``subpixel._poc_offsets``.

    Returns ``(delta, denominator, inside, peak_value, lag)`` per surface.
    """
    surfaces = np.ascontiguousarray(surfaces, dtype=np.float64)
    n = len(surfaces)
    delta, denominator, peak_value = np.empty(n), np.empty(n), np.empty(n)
    inside = np.empty(n, dtype=bool)
    lag = np.empty(n, dtype=np.int64)
    _compiled().poc_peak_fits(surfaces, float(band_ratio), delta, denominator, inside,
                              peak_value, lag)
    return delta, denominator, inside, peak_value, lag


def feature_candidates(volume, candidates, inside, admissible, disparities, y, x, exclusion):
    """
    Compiled best candidate and runner-up of each feature (``rough_matching``).

    Returns ``(best index, best similarity, runner-up similarity)`` per feature (float64
    values of the float32 volume).
    """
    n = len(y)
    best_index = np.empty(n, dtype=np.int64)
    best_value, runner_up = np.empty(n), np.empty(n)
    _compiled().feature_candidates(
        np.ascontiguousarray(volume, dtype=np.float32), np.ascontiguousarray(candidates),
        np.ascontiguousarray(inside), np.ascontiguousarray(admissible),
        np.ascontiguousarray(disparities, dtype=np.int64), np.ascontiguousarray(y, np.int64),
        np.ascontiguousarray(x, np.int64), int(exclusion), best_index, best_value, runner_up)
    return best_index, best_value, runner_up


def left_right_best(volume, valid_left, disparities, y, x_right):
    """Compiled best left disparity of each matched right pixel (``left_right_consistent``)."""
    out = np.empty(len(y), dtype=np.int64)
    _compiled().left_right_best(
        np.ascontiguousarray(volume, dtype=np.float32), np.ascontiguousarray(valid_left),
        np.ascontiguousarray(disparities, dtype=np.int64), np.ascontiguousarray(y, np.int64),
        np.ascontiguousarray(x_right, np.int64), out)
    return out


def continuity_medians(grid, y, x, radius):
    """Compiled neighbour count and median disparity of each match (``continuity_consistent``)."""
    count = np.empty(len(y), dtype=np.int64)
    median = np.empty(len(y))
    _compiled().continuity_medians(np.ascontiguousarray(grid, dtype=np.float64),
                                   np.ascontiguousarray(y, np.int64),
                                   np.ascontiguousarray(x, np.int64), int(radius), count,
                                   median)
    return count, median


def window_ncc(current, previous, y, x, half, offsets_y, offsets_x):
    """
    Compiled zero-mean NCC of each feature's window at every offset (``skew.feature_motion``).

    ``current`` and ``previous`` are the two frames (every window inside both); returns
    (n, len(offsets_y), len(offsets_x)) float64, OpenCV's ``TM_CCOEFF_NORMED`` to a few 1e-6.
    """
    offsets_y = np.ascontiguousarray(offsets_y, dtype=np.int64)
    offsets_x = np.ascontiguousarray(offsets_x, dtype=np.int64)
    y, x = np.ascontiguousarray(y, np.int64), np.ascontiguousarray(x, np.int64)
    if np.shape(current) != np.shape(previous):
        raise ValueError(f'window_ncc: frames of shapes {np.shape(current)} and '
                         f'{np.shape(previous)}')
    rows, cols = np.shape(current)
    if len(y) and (y.min() - half + min(offsets_y.min(), 0) < 0 or
                   y.max() + half + max(offsets_y.max(), 0) >= rows or
                   x.min() - half + min(offsets_x.min(), 0) < 0 or
                   x.max() + half + max(offsets_x.max(), 0) >= cols):
        # The kernel reads without bounds checks (OpenCV raises here too).
        raise ValueError(f'window_ncc: windows of half size {half} at rows {y.min()}..'
                         f'{y.max()}, columns {x.min()}..{x.max()}, offsets '
                         f'{offsets_y.min()}..{offsets_y.max()} x {offsets_x.min()}..'
                         f'{offsets_x.max()} leave the {cols}x{rows} frames')
    out = np.empty((len(y), len(offsets_y), len(offsets_x)))
    _compiled().window_ncc(np.ascontiguousarray(current, dtype=np.float64),
                           np.ascontiguousarray(previous, dtype=np.float64),
                           y, x, int(half), offsets_y, offsets_x, out)
    return out


def blurred_ellipses(params, xs, ys, dx, dy):
    """
    Compiled counterpart of ``calibration.target_refinement.blurred_ellipse``, (n, m).

    Not part of ``warm_up`` (the nodes never fit targets): compiled, or loaded from the cache,
    on the first calibration.
    """
    params = np.ascontiguousarray(params, dtype=np.float64)
    xs = np.ascontiguousarray(xs, dtype=np.float64)
    out = np.empty(xs.shape)
    _compiled().blurred_ellipses(params, xs, np.ascontiguousarray(ys, dtype=np.float64),
                                 np.ascontiguousarray(dx, dtype=np.float64),
                                 np.ascontiguousarray(dy, dtype=np.float64), out)
    return out


def warm_up():
    """Compile (or load) every kernel now; returns the seconds it took."""
    start = time.perf_counter()
    if numba_available():
        phase_congruency_from_responses(np.ones((1, 2, 2, 4, 4), np.complex64),
                                        np.zeros((1, 2), np.float32), np.zeros(2), 1e-4, 0.5,
                                        10.0)
        lades_similarity_volume(np.ones((4, 4)), np.ones((4, 4)), np.arange(2), 3, 1e-12)
        spectra = np.ones((1, 9, 5), np.complex128)
        cross_power_spectra(spectra, spectra, np.ones((9, 5), np.float32))
        poc_peak_fits(np.ones((1, 9, 9)), 1.0)
        shift_phases(np.ones(11, np.float32), np.zeros(1, np.float32))
        strips, _, first, slope = deramped_strips(np.ones((9, 9)), np.array([4]),
                                                  np.array([4]), 9, 6)
        reramped_columns(strips, first, slope, np.zeros(1, np.float32), slice(6, 15))
        volume = np.ones((2, 4, 4), np.float32)
        mask = np.ones((4, 4), dtype=bool)
        index = np.zeros(1, np.int64)
        feature_candidates(volume, mask, mask, np.ones((2, 1, 1), dtype=bool), np.arange(2),
                           index, index, 1)
        left_right_best(volume, mask, np.arange(2), index, index)
        continuity_medians(np.zeros((4, 4)), index, index, 1)
        window_ncc(np.ones((5, 5)), np.ones((5, 5)), np.array([2]), np.array([2]), 1,
                   np.arange(-1, 2), np.arange(-1, 2))
    return time.perf_counter() - start
