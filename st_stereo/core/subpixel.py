"""
Sub-pixel refinement of rough matches by phase-only correlation (paper section 2.4).

For every rough match, a W x W window of the left image and of the right image around the
matched pixels are compared by phase-only correlation (POC, paper eqs. 10-11); the peak of the
POC function is located to a fraction of a pixel with Nagashima's least-squares estimator on
the sinc peak model (eqs. 12-17). All windows of a frame go through one batched FFT.

The paper's estimator fits the peak once. ``recentred`` goes further: it shifts the right
window by the current estimate (a Fourier shift of a wider strip), fits the small residual
again, and repeats. Near zero shift the windowed POC is symmetric, so the model error of the
sinc fit vanishes and the estimate converges on the true shift.

Sign convention: for a rectified pair, ``x_right = x_left - d`` with ``d >= 0``. If the right
window is the left one moved left by ``s`` (``R(u) = L(u + s)``), the POC
``fftshift(real(ifft2(F_R conj(F_L) / |.|)))`` peaks at ``-s``; in the peak model
``r(x) = alpha sin(pi V (x + delta) / N) / (pi (x + delta))`` that is ``delta = s``, so the
refined disparity is ``d_int + delta``.
"""

import dataclasses
import functools

import numpy as np
import scipy.fft as sfft

from st_stereo.core.fourier import RowShifter
import st_stereo.core.kernels as kernels

SUBPIXEL_REJECTION_KEYS = ('subpixel_degenerate', 'subpixel_edge', 'subpixel_range')

# Strip margin on each side of the right window used by the recentred estimator.
RECENTRE_MARGIN = 6


@functools.lru_cache(maxsize=16)
def half_sample_hann(size):
    """
    Half-sample Hann window ``0.5 - 0.5 cos(2 pi (n + 1/2) / N)``, 2-D outer product.

    Symmetric about the window centre and non-zero at both ends, unlike ``np.hanning``.
    """
    n = np.arange(size)
    w = 0.5 - 0.5 * np.cos(2.0 * np.pi * (n + 0.5) / size)
    window = np.outer(w, w)
    window.setflags(write=False)
    return window


def band_half_width(window, band):
    """
    Half-width K of the POC pass band, V = 2K + 1.

    ``full`` keeps every frequency (V = W); ``takita`` keeps ``K = floor(floor(W / 2) / 2)``
    (Takita 2003: V = 5 at W = 9).
    """
    if band == 'full':
        return window // 2
    if band == 'takita':
        return (window // 2) // 2
    raise ValueError(f'poc_band: expected full or takita, got {band!r}')


@functools.lru_cache(maxsize=16)
def _band_mask(window, half_width):
    # Layout of rfft2 spectra: full axis -2, half axis -1.
    rows = np.abs(sfft.fftfreq(window) * window) <= half_width
    cols = np.abs(sfft.rfftfreq(window) * window) <= half_width
    mask = np.outer(rows, cols).astype(np.float32)
    mask.setflags(write=False)
    return mask


def window_spectra(windows, hann=True):
    """
    2-D spectra of windows after mean removal and (optionally) the half-sample Hann taper.

    Removing the mean first makes the POC blind to an offset between the cameras; the gain
    cancels in the normalisation of eq. 10.
    """
    windows = np.asarray(windows, dtype=np.float32)
    windows = windows - windows.mean(axis=(-2, -1), keepdims=True)
    if hann:
        windows = windows * half_sample_hann(windows.shape[-1])
    # Real windows: the half spectrum (rfft2) carries everything, at half the cost.
    return sfft.rfft2(windows, workers=1)


def poc_from_spectra(left_spectra, right_spectra, band='full', compiled=False):
    """
    POC surfaces ``real(ifft2(R))``, ``R = F_R conj(F_L) / |.|`` (eqs. 10-11), zero lag first.

    The spectra are rfft2 half spectra of real windows; the surface is real (unshifted:
    lag ``k`` at index ``k mod W``). ``compiled``: ``R`` by the numba kernel (the same
    arithmetic, ``st_stereo.core.kernels``).
    """
    size = left_spectra.shape[-2]
    half = band_half_width(size, band)
    if compiled:
        mask = _band_mask(size, half)
        cross = kernels.cross_power_spectra(left_spectra, right_spectra, mask)
        return sfft.irfft2(cross, s=(size, size), workers=1)
    cross = right_spectra * np.conj(left_spectra)
    cross /= np.maximum(np.abs(cross), np.float32(1e-20))
    if half < size // 2:
        cross *= _band_mask(size, half)
    return sfft.irfft2(cross, s=(size, size), workers=1)


def phase_only_correlation(left_windows, right_windows, band='full', hann=True):
    """
    Batched phase-only correlation of window pairs (paper eqs. 10-11).

    ``R = F_R conj(F_L) / |F_R conj(F_L)|``, optionally restricted to ``|k| <= K`` (Takita),
    ``r = fftshift(real(ifft2(R)))``. Each window has its mean removed and, optionally, a
    half-sample Hann window applied first.

    Parameters
    ----------
    left_windows, right_windows : ndarray, shape (n, W, W)
        Window pairs.
    band : {'full', 'takita'}
        Pass band (see ``band_half_width``).
    hann : bool
        Apply the half-sample Hann window.

    Returns
    -------
    ndarray, shape (n, W, W)
        POC surfaces, zero lag at index ``W // 2``.

    """
    surface = poc_from_spectra(window_spectra(left_windows, hann),
                               window_spectra(right_windows, hann), band)
    return sfft.fftshift(surface, axes=(-2, -1))


def nagashima_peak_offset(profiles, peak, band_ratio):
    """
    Sub-pixel offset of a sinc peak by least squares over six samples (paper eqs. 14-17).

    With ``c_d = cos(pi V d / N)``,
    ``u(p, d) = r(p - d) + r(p + d) - 2 c_d r(p)`` and
    ``v(p, d) = 2 p c_d r(p) - (p - d) r(p - d) - (p + d) r(p + d)`` satisfy ``v = delta u``
    for the peak model of eq. 13; ``delta = sum(u v) / sum(u^2)`` over
    ``p in {p_hat - 1, p_hat, p_hat + 1}``, ``d in {1, 2}`` (chi = 6). The paper's eq. 16 is a
    typo for this ordinary least squares in one unknown (Nagashima 2006).

    Parameters
    ----------
    profiles : ndarray, shape (n, N)
        POC samples along x, zero lag at index ``N // 2``.
    peak : ndarray of int, shape (n,)
        Index of the highest sample; must satisfy ``3 <= peak <= N - 4``.
    band_ratio : float
        ``V / N``.

    Returns
    -------
    delta : ndarray, shape (n,)
        Offset such that the model peaks at ``x = -delta`` (lag relative to zero).
    denominator : ndarray, shape (n,)
        ``sum(u^2)``; near zero means the fit is degenerate.

    """
    n, size = profiles.shape
    centre = size // 2
    rows = np.arange(n)[:, None]
    p = np.array([-1, -1, 0, 0, 1, 1])[None, :] + peak[:, None]
    d = np.array([1, 2, 1, 2, 1, 2])[None, :]
    cos_d = np.cos(np.pi * band_ratio * d)
    r_p = profiles[rows, p]
    r_minus = profiles[rows, p - d]
    r_plus = profiles[rows, p + d]
    lag = (p - centre).astype(np.float64)
    u = r_minus + r_plus - 2.0 * cos_d * r_p
    v = 2.0 * lag * cos_d * r_p - (lag - d) * r_minus - (lag + d) * r_plus
    denominator = (u * u).sum(axis=1)
    numerator = (u * v).sum(axis=1)
    delta = numerator / np.where(denominator > 0, denominator, 1.0)
    return delta, denominator


@dataclasses.dataclass
class SubpixelResult:
    """Refined disparities for a batch of rough matches."""

    disparity: np.ndarray    # d_int + delta, pixels
    correction: np.ndarray   # delta, pixels
    peak_value: np.ndarray   # POC peak height, 0..1
    accepted: np.ndarray     # bool per match
    rejected: dict           # rejection counts by reason
    clamped_to_zero: int = 0  # accepted estimates slightly below zero, set to 0


def extract_windows(image, y, x, size):
    """
    Gather ``size x size`` windows of an image centred at integer (y, x), shape (n, W, W).

    Every window must lie inside the image (a negative index would wrap round silently).
    """
    half = size // 2
    if len(y) and (min(np.min(y), np.min(x)) < half or np.max(y) >= image.shape[0] - half
                   or np.max(x) >= image.shape[1] - half):
        raise ValueError(f'extract_windows: a {size}x{size} window leaves the '
                         f'{image.shape[1]}x{image.shape[0]} image')
    blocks = np.lib.stride_tricks.sliding_window_view(image, (size, size))
    return blocks[y - half, x - half]


def extract_strips(image, y, x, size, margin):
    """
    Gather strips ``size`` rows by ``size + 2 margin`` columns centred at (y, x).

    Columns outside the image are filled by symmetric reflection.
    """
    half = size // 2
    reach = half + margin
    padded = np.pad(image, ((0, 0), (reach, reach)), mode='symmetric')
    blocks = np.lib.stride_tricks.sliding_window_view(padded, (size, size + 2 * margin))
    return blocks[y - half, x - half - margin + reach]


def _poc_offsets(left_spectra, right_windows, config):
    # Compiled for the double-precision spectra of Hann-windowed windows (the default); the
    # single-precision ones of poc_hann=False keep numpy's float32 arithmetic.
    compiled = kernels.use_compiled(config.kernels) and left_spectra.dtype == np.complex128
    surfaces = poc_from_spectra(left_spectra, window_spectra(right_windows, config.poc_hann),
                                config.poc_band, compiled)
    n, size, _ = surfaces.shape
    band_ratio = (2 * band_half_width(size, config.poc_band) + 1) / size
    if compiled:
        return kernels.poc_peak_fits(surfaces, band_ratio)
    half = size // 2
    flat_peak = surfaces.reshape(n, -1).argmax(axis=1)
    peak_row, peak_col = np.divmod(flat_peak, size)
    # Unshifted surfaces: reorder the peak row so that lag 0 sits at index W // 2.
    centred = (np.arange(size) - half) % size
    profiles = surfaces[np.arange(n)[:, None], peak_row[:, None], centred[None, :]]
    peak_col = (peak_col + half) % size
    peak_value = profiles[np.arange(n), peak_col]
    inside = (peak_col >= 3) & (peak_col <= size - 4)
    safe_peak = np.where(inside, peak_col, size // 2)
    delta, denominator = nagashima_peak_offset(profiles, safe_peak, band_ratio)
    lag = peak_col - half          # integer lag of the peak; the model's delta is about -lag
    return delta, denominator, inside, peak_value, lag


def refine_subpixel_poc(left_image, right_image, y, x_left, disparity, config):
    """
    Refine integer matches to sub-pixel disparities with POC (paper section 2.4).

    Parameters
    ----------
    left_image, right_image : ndarray, shape (rows, cols)
        Images the POC runs on (M by default, or intensity).
    y, x_left, disparity : ndarray of int, shape (n,)
        Rough matches; the left window must fit in the image.
    config : STConfig
        ``poc_window``, ``poc_band``, ``poc_hann``, ``poc_estimator``, ``poc_iterations``,
        ``poc_max_shift``.

    Returns
    -------
    SubpixelResult
        A rejected match (degenerate fit, peak at the window edge, correction beyond
        ``poc_max_shift``) is counted by reason and flagged, never dropped silently.

    """
    size = config.poc_window
    n = len(y)
    rejected = dict.fromkeys(SUBPIXEL_REJECTION_KEYS, 0)
    if n == 0:
        empty = np.zeros(0)
        return SubpixelResult(empty, empty, empty, np.zeros(0, dtype=bool), rejected)
    left_image = np.asarray(left_image, dtype=np.float64)
    right_image = np.asarray(right_image, dtype=np.float64)
    x_right = x_left - disparity
    left_spectra = window_spectra(extract_windows(left_image, y, x_left, size), config.poc_hann)
    iterations = 1 if config.poc_estimator == 'nagashima' else config.poc_iterations
    if iterations == 1:
        right_windows = extract_windows(right_image, y, x_right, size)
        delta, denominator, inside, peak_value, _ = _poc_offsets(left_spectra, right_windows,
                                                                 config)
        total = delta
    else:
        if kernels.use_compiled(config.kernels):
            strips, *deramped = kernels.deramped_strips(right_image, y, x_right, size,
                                                        RECENTRE_MARGIN)
            shifter = RowShifter(strips, np.float32, True, deramped)
        else:
            strips = extract_strips(right_image, y, x_right, size, RECENTRE_MARGIN)
            shifter = RowShifter(strips, np.float32)
        centre = slice(RECENTRE_MARGIN, RECENTRE_MARGIN + size)
        total = np.zeros(n)
        for iteration in range(iterations):
            # out(u) = strip(u - total): undo the estimated shift, leaving the residual.
            if iteration == 0:
                # Contiguous, as the numpy path's float32 copy is (the windows' mean then
                # sums in the same order).
                right_windows = np.ascontiguousarray(strips[:, :, centre], dtype=np.float32)
            else:
                right_windows = shifter.shift(-total, centre)
            delta, denominator, inside, peak_value, lag = _poc_offsets(
                left_spectra, right_windows, config)
            # A peak too near the window edge for the fit: re-centre by its integer lag
            # first (the strip allows it) and fit on the next iteration.
            delta = np.where(inside, np.where(denominator > 1e-12, delta, 0.0), -lag)
            total = np.clip(total + delta, -2.0 * config.poc_max_shift,
                            2.0 * config.poc_max_shift)
    degenerate = inside & ~(denominator > 1e-12)
    edge = ~inside
    out_of_range = inside & ~degenerate & (np.abs(total) > config.poc_max_shift)
    accepted = ~(degenerate | edge | out_of_range)
    # A disparity cannot be negative: an estimate within poc_max_shift below zero is a point at
    # (or near) infinity and is clamped to 0, the closest feasible value, and counted.
    refined = disparity + total
    negative = accepted & (refined < 0)
    refined = np.where(negative, 0.0, refined)
    rejected['subpixel_degenerate'] = int(degenerate.sum())
    rejected['subpixel_edge'] = int(edge.sum())
    rejected['subpixel_range'] = int(out_of_range.sum())
    return SubpixelResult(refined, total, peak_value, accepted, rejected, int(negative.sum()))
