"""
Phase congruency: Kovesi's oriented log-Gabor moments and the monogenic variant.

The feature image of ST is the maximum moment M of phase congruency (paper eqs. 3-8). Both
methods follow Kovesi's reference code (``phasecong3.m``, ``phasecongmono.m``) including its
normalisation of the moments, without which the paper's thresholds gamma = 0.3 / 0.1 / 0.01 mean
nothing (the paper's a, b, c omit it; its M is 3x Kovesi's at six orientations).

All filters of a bank are built once per image size and parameter set and applied with one
batched inverse FFT over every image, orientation and scale.
"""

import functools

import numpy as np
import scipy.fft as sfft

from st_stereo.core.fourier import butterworth_lowpass, frequency_grid, periodic_fft2
from st_stereo.core.kernels import phase_congruency_from_responses, use_compiled

EPSILON = 1e-4  # Kovesi's epsilon, guards divisions by vanishing amplitude sums


@functools.lru_cache(maxsize=32)
def log_gabor_radial_filters(rows, cols, nscale, min_wavelength, mult, sigma_onf):
    """
    Radial log-Gabor filters, one per scale, times a Butterworth low-pass (cut-off 0.45).

    ``G_s(f) = exp(-(ln(f / f_s))^2 / (2 ln(sigma_onf)^2))`` with ``f_s = 1 / (min_wavelength
    mult^s)``; ``G_s(0) = 0``, so every response is blind to the image's mean (paper eq. 4).

    Returns
    -------
    ndarray, shape (nscale, rows, cols), read-only

    """
    radius, _, _ = frequency_grid(rows, cols)
    lowpass = butterworth_lowpass(radius, 0.45, 15)
    wavelengths = min_wavelength * mult ** np.arange(nscale)
    centre = (1.0 / wavelengths)[:, None, None]
    filters = np.exp(-np.log(radius / centre) ** 2 / (2.0 * np.log(sigma_onf) ** 2)) * lowpass
    filters[:, 0, 0] = 0.0
    filters = filters.astype(np.float32)
    filters.setflags(write=False)
    return filters


@functools.lru_cache(maxsize=32)
def oriented_log_gabor_bank(rows, cols, nscale, norient, min_wavelength, mult, sigma_onf):
    """
    Oriented log-Gabor bank of phasecong3: radial filters times angular spreads.

    The angular spread of orientation ``theta_o = o pi / norient`` is
    ``(cos(dtheta) + 1) / 2`` with ``dtheta = min(|angle - theta_o| norient / 2, pi)``: each
    filter covers one half-plane of frequencies, so its response is complex (even + i odd).

    Returns
    -------
    bank : ndarray, shape (norient, nscale, rows, cols), read-only
    angles : ndarray, shape (norient,)

    """
    radius, u1, u2 = frequency_grid(rows, cols)
    sintheta = u2 / radius
    costheta = u1 / radius
    radial = log_gabor_radial_filters(rows, cols, nscale, min_wavelength, mult, sigma_onf)
    angles = np.arange(norient) * np.pi / norient
    ca = np.cos(angles)[:, None, None]
    sa = np.sin(angles)[:, None, None]
    ds = sintheta * ca - costheta * sa
    dc = costheta * ca + sintheta * sa
    dtheta = np.minimum(np.abs(np.arctan2(ds, dc)) * norient / 2.0, np.pi)
    spread = (np.cos(dtheta) + 1.0) / 2.0
    # Stored complex: complex x complex broadcasting is twice as fast as complex x real here.
    bank = (spread[:, None] * radial[None]).astype(np.complex64)
    bank.setflags(write=False)
    angles.setflags(write=False)
    return bank, angles


def _image_spectra(images, periodic):
    # Single precision from here on: the thresholds need ~1e-3, complex64 halves the cost.
    images = np.asarray(images, dtype=np.float64)
    if periodic:
        return periodic_fft2(images).astype(np.complex64)
    return sfft.fft2(images, workers=1).astype(np.complex64)


def _median_last_two_axes(values):
    # A SIMD sort of float32 rows is faster here than np.median's partition (measured).
    flat = np.sort(values.reshape(values.shape[:-2] + (-1,)), axis=-1)
    count = flat.shape[-1]
    return 0.5 * (flat[..., (count - 1) // 2] + flat[..., count // 2])


def noise_threshold(smallest_scale_amplitude, nscale, mult, k):
    """
    Noise energy threshold T of Kovesi's ``noiseMethod = -1``.

    ``tau = median(A_0) / sqrt(ln 4)`` estimates the Rayleigh parameter of the noise amplitude at
    the smallest scale; summed over scales it grows as a geometric series, and
    ``T = totalTau (sqrt(pi/2) + k sqrt((4 - pi)/2))`` is the mean noise energy plus k standard
    deviations (paper eq. 2, term T).

    Parameters
    ----------
    smallest_scale_amplitude : ndarray, shape (..., rows, cols)
        Amplitude of the smallest-scale responses; the median is taken over the last two axes.
    nscale : int
        Number of scales.
    mult : float
        Wavelength ratio between successive scales.
    k : float
        Standard deviations of noise energy above its mean.

    Returns
    -------
    ndarray, shape (...,)

    """
    tau = _median_last_two_axes(smallest_scale_amplitude) / np.sqrt(np.log(4.0))
    total_tau = tau * (1.0 - (1.0 / mult) ** nscale) / (1.0 - 1.0 / mult)
    threshold = total_tau * (np.sqrt(np.pi / 2.0) + k * np.sqrt((4.0 - np.pi) / 2.0))
    return threshold.astype(smallest_scale_amplitude.dtype)


def frequency_spread_weight(sum_amplitude, max_amplitude, nscale, cutoff, gain):
    """Sigmoid weighting W(x) of the frequency spread (paper eq. 2, term W)."""
    width = (sum_amplitude / (max_amplitude + EPSILON) - 1.0) / (nscale - 1)
    return 1.0 / (1.0 + np.exp((cutoff - width) * np.float32(gain)))


def phase_congruency_moments(images, config):
    """
    Maximum and minimum moments of phase congruency, Kovesi phasecong3 (paper eqs. 2, 5-8).

    For each orientation theta, ``PC_theta = W max(E_theta - T_theta, 0) / sum_n A_n`` with the
    phase-deviation energy ``E_theta = sum_n (e_n cos_phi + o_n sin_phi - |e_n sin_phi - o_n
    cos_phi|)``; then with Kovesi's normalisation
    ``a = sum (PC cos theta)^2 / (norient / 2)``, ``c = sum (PC sin theta)^2 / (norient / 2)``,
    ``b = 4 sum (PC cos theta)(PC sin theta) / norient``,
    ``M = (a + c + sqrt(b^2 + (a - c)^2)) / 2`` and ``m = (a + c - sqrt(...)) / 2``.

    Parameters
    ----------
    images : ndarray, shape (rows, cols) or (n, rows, cols)
        Real images (any scale: phase congruency is invariant to gain and offset).
    config : STConfig
        The ``pc_*`` fields.

    Returns
    -------
    maximum_moment, minimum_moment : ndarray, same shape as ``images``

    References
    ----------
    P. Kovesi, "Phase congruency detects corners and edges", DICTA 2003; phasecong3.m.
    Zoetgnande et al. 2020, eqs. 2 and 5-8.

    """
    images = np.asarray(images, dtype=np.float64)
    single = images.ndim == 2
    if single:
        images = images[None]
    _, rows, cols = images.shape
    nscale, norient, mult = config.pc_scales, config.pc_orientations, config.pc_mult
    bank, angles = oriented_log_gabor_bank(rows, cols, nscale, norient,
                                           config.pc_min_wavelength, mult, config.pc_sigma_onf)
    spectra = _image_spectra(images, config.pc_periodic)
    # responses: (n, norient, nscale, rows, cols), complex: even = real, odd = imag
    responses = sfft.ifft2(spectra[:, None, None] * bank[None], workers=1)
    if use_compiled(config.kernels):
        # The same arithmetic as below, one compiled pass (st_stereo.core.kernels).
        threshold = noise_threshold(np.abs(responses[:, :, 0]), nscale, mult, config.noise_k)
        maximum_moment, minimum_moment = phase_congruency_from_responses(
            responses, threshold, angles, EPSILON, config.pc_cutoff, config.pc_gain)
        if single:
            return maximum_moment[0], minimum_moment[0]
        return maximum_moment, minimum_moment
    amplitude = np.abs(responses)
    sum_amplitude = amplitude.sum(axis=2)
    max_amplitude = amplitude.max(axis=2)
    sum_response = responses.sum(axis=2)
    sum_magnitude = np.abs(sum_response)
    inverse_energy = 1.0 / (sum_magnitude + np.float32(EPSILON))
    mean_phase_conj = np.conj(sum_response * inverse_energy)[:, :, None]
    # Phase-deviation energy sum_n (e_n cos + o_n sin - |e_n sin - o_n cos|): the first two
    # terms sum linearly to Re(conj(sum_n EO_n) mean) = |sum EO|^2 / (|sum EO| + eps); only the
    # absolute deviation term needs every scale: |Im(EO_n conj(mean))|.
    deviation = np.abs((responses * mean_phase_conj).imag).sum(axis=2)
    energy = sum_magnitude * sum_magnitude * inverse_energy - deviation
    threshold = noise_threshold(amplitude[:, :, 0], nscale, mult, config.noise_k)
    energy = np.maximum(energy - threshold[:, :, None, None], np.float32(0.0))
    weight = frequency_spread_weight(sum_amplitude, max_amplitude, nscale, config.pc_cutoff,
                                     config.pc_gain)
    # A flat image has no amplitude at all: PC is 0 there, not 0 / 0.
    pc = weight * energy / np.where(sum_amplitude > 0, sum_amplitude, np.float32(1.0))
    cos_a = np.cos(angles).astype(np.float32)[None, :, None, None]
    sin_a = np.sin(angles).astype(np.float32)[None, :, None, None]
    pc_x = pc * cos_a
    pc_y = pc * sin_a
    cov_x2 = (pc_x * pc_x).sum(axis=1) * np.float32(2.0 / norient)
    cov_y2 = (pc_y * pc_y).sum(axis=1) * np.float32(2.0 / norient)
    cov_xy = (pc_x * pc_y).sum(axis=1) * np.float32(4.0 / norient)
    denom = np.sqrt(cov_xy ** 2 + (cov_x2 - cov_y2) ** 2) + EPSILON
    maximum_moment = (cov_x2 + cov_y2 + denom) / 2.0
    minimum_moment = (cov_x2 + cov_y2 - denom) / 2.0
    if single:
        return maximum_moment[0], minimum_moment[0]
    return maximum_moment, minimum_moment


@functools.lru_cache(maxsize=32)
def monogenic_bank(rows, cols, nscale, min_wavelength, mult, sigma_onf):
    """
    Log-Gabor filters times the Riesz kernel ``H = (i u1 - u2) / |u|`` (Felsberg 2001).

    Returns
    -------
    radial, riesz_radial : ndarray, shape (nscale, rows, cols), read-only

    """
    radius, u1, u2 = frequency_grid(rows, cols)
    riesz = (1j * u1 - u2) / radius
    radial = log_gabor_radial_filters(rows, cols, nscale, min_wavelength, mult, sigma_onf)
    riesz_radial = (radial * riesz[None]).astype(np.complex64)
    riesz_radial.setflags(write=False)
    return radial, riesz_radial


def monogenic_phase_congruency(images, config):
    """
    Phase congruency from monogenic filters, Kovesi phasecongmono (Wang 2014's variant).

    ``PC = W max(1 - g_d acos(E / sum_n A_n), 0) max(E - T, 0) / (E + eps)`` with the local
    energy ``E = |(sum f_n, sum h1_n, sum h2_n)|`` of the monogenic signal. One value per
    pixel, no orientation moments: ST uses ``M := PC`` with this method (paper section 2.2).

    Parameters
    ----------
    images : ndarray, shape (rows, cols) or (n, rows, cols)
        Real images.
    config : STConfig
        The ``pc_*`` fields.

    Returns
    -------
    ndarray, same shape as ``images``

    References
    ----------
    P. Kovesi, phasecongmono.m (2013); Wang et al. 2014; Zoetgnande et al. 2020, eq. 2.

    """
    images = np.asarray(images, dtype=np.float64)
    single = images.ndim == 2
    if single:
        images = images[None]
    _, rows, cols = images.shape
    nscale, mult = config.pc_scales, config.pc_mult
    radial, riesz_radial = monogenic_bank(rows, cols, nscale, config.pc_min_wavelength, mult,
                                          config.pc_sigma_onf)
    spectra = _image_spectra(images, config.pc_periodic)[:, None]
    even = sfft.ifft2(spectra * radial[None], workers=1).real
    odd = sfft.ifft2(spectra * riesz_radial[None], workers=1)
    h1, h2 = odd.real, odd.imag
    amplitude = np.sqrt(even ** 2 + h1 ** 2 + h2 ** 2)
    sum_amplitude = amplitude.sum(axis=1)
    max_amplitude = amplitude.max(axis=1)
    threshold = noise_threshold(amplitude[:, 0], nscale, mult, config.noise_k)
    weight = frequency_spread_weight(sum_amplitude, max_amplitude, nscale, config.pc_cutoff,
                                     config.pc_gain)
    energy = np.sqrt(even.sum(axis=1) ** 2 + h1.sum(axis=1) ** 2 + h2.sum(axis=1) ** 2)
    deviation = np.arccos(np.clip(energy / (sum_amplitude + EPSILON), -1.0, 1.0))
    pc = (weight * np.maximum(1.0 - config.pc_deviation_gain * deviation, 0.0)
          * np.maximum(energy - threshold[:, None, None], 0.0) / (energy + EPSILON))
    return pc[0] if single else pc


def feature_strength(images, config):
    """Feature image of ST: M of phasecong3, or PC of the monogenic method (``M := PC``)."""
    if config.pc_method == 'monogenic':
        return monogenic_phase_congruency(images, config)
    return phase_congruency_moments(images, config)[0]
