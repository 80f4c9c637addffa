"""
The numba kernels themselves (imported only by ``st_stereo.core.kernels``, when numba is).

Module-level functions, so that numba's on-disk cache finds them again in the next process
(a kernel defined inside a function, calling another, gets a new cache key in every process
and is compiled again at every start). Where no cache directory is writable (a read-only
install without ``NUMBA_CACHE_DIR`` or a writable home) they are compiled without a cache.
"""

import numba
import numpy as np


def jit(function):
    """Compile with numba (no GIL), cached on disk, or uncached where no cache can be written."""
    try:
        return numba.njit(cache=True, nogil=True)(function)
    except RuntimeError:      # numba: "no locator available" for the cache
        return numba.njit(nogil=True)(function)


@jit
def orientation_energy(responses, thresholds, epsilon, cutoff, gain, out_pc):
    """
    Phase congruency of each orientation (phasecong3, paper eq. 2), one pass per pixel.

    ``responses`` (n, norient, nscale, rows, cols) complex64; ``thresholds`` (n, norient)
    float32; writes ``out_pc`` (n, norient, rows, cols) float32. The float32 arithmetic
    follows ``phase_congruency_moments`` operation by operation, except that magnitudes
    are ``sqrt(re^2 + im^2)`` rather than numpy's ``hypot`` (a few times faster; equal to
    within an ulp at these magnitudes).
    """
    n, norient, nscale, rows, cols = responses.shape
    one = np.float32(1.0)
    zero = np.float32(0.0)
    spread_scale = np.float32(nscale - 1)
    for i in range(n):
        for o in range(norient):
            threshold = thresholds[i, o]
            for r in range(rows):
                for c in range(cols):
                    sum_amplitude = zero
                    max_amplitude = zero
                    sum_response = responses[i, o, 0, r, c] * np.float32(0.0)
                    for s in range(nscale):
                        value = responses[i, o, s, r, c]
                        amplitude = np.sqrt(value.real * value.real +
                                            value.imag * value.imag)
                        sum_amplitude += amplitude
                        if s == 0 or amplitude > max_amplitude:
                            max_amplitude = amplitude
                        sum_response += value
                    sum_magnitude = np.sqrt(sum_response.real * sum_response.real +
                                            sum_response.imag * sum_response.imag)
                    inverse_energy = one / (sum_magnitude + epsilon)
                    mean_phase = sum_response * inverse_energy
                    mean_re = mean_phase.real
                    mean_im = -mean_phase.imag        # the conjugate
                    deviation = zero
                    for s in range(nscale):
                        value = responses[i, o, s, r, c]
                        deviation += abs(value.real * mean_im + value.imag * mean_re)
                    energy = sum_magnitude * sum_magnitude * inverse_energy - deviation
                    energy = max(energy - threshold, zero)
                    width = (sum_amplitude / (max_amplitude + epsilon) - one) / spread_scale
                    weight = one / (one + np.exp((cutoff - width) * gain))
                    divisor = sum_amplitude if sum_amplitude > zero else one
                    out_pc[i, o, r, c] = weight * energy / divisor


@jit
def moments(pc, cos_a, sin_a, epsilon, out_max, out_min):
    """Maximum and minimum moments of the orientations' PC (paper eqs. 5-8, Kovesi)."""
    n, norient, rows, cols = pc.shape
    zero = np.float32(0.0)
    two = np.float32(2.0)
    scale_2 = np.float32(2.0 / norient)
    scale_4 = np.float32(4.0 / norient)
    for i in range(n):
        for r in range(rows):
            for c in range(cols):
                x2 = zero
                y2 = zero
                xy = zero
                for o in range(norient):
                    pc_x = pc[i, o, r, c] * cos_a[o]
                    pc_y = pc[i, o, r, c] * sin_a[o]
                    x2 += pc_x * pc_x
                    y2 += pc_y * pc_y
                    xy += pc_x * pc_y
                x2 *= scale_2
                y2 *= scale_2
                xy *= scale_4
                denom = np.sqrt(xy * xy + (x2 - y2) * (x2 - y2)) + epsilon
                out_max[i, r, c] = (x2 + y2 + denom) / two
                out_min[i, r, c] = (x2 + y2 - denom) / two


@jit
def _box_mean(values, half, area):
    # Separable running sums over (2 half + 1)^2 windows, zero outside the image. The two
    # passes are written out: one helper for both (a strided column, a copy) measured 1.34 ->
    # 1.86 ms for the Lades volume.
    rows, cols = values.shape
    across = np.zeros((rows, cols), dtype=np.float64)
    for r in range(rows):
        total = 0.0
        for c in range(min(half, cols)):
            total += values[r, c]
        for c in range(cols):
            if c + half < cols:
                total += values[r, c + half]
            if c - half - 1 >= 0:
                total -= values[r, c - half - 1]
            across[r, c] = total
    out = np.empty((rows, cols), dtype=np.float32)
    for c in range(cols):
        total = 0.0
        for r in range(min(half, rows)):
            total += across[r, c]
        for r in range(rows):
            if r + half < rows:
                total += across[r + half, c]
            if r - half - 1 >= 0:
                total -= across[r - half - 1, c]
            out[r, c] = np.float32(total / area)
    return out


@jit
def lades_volume(left, right, disparities, window, tiny, out):
    """
    Lades similarity for every left pixel and disparity (paper eq. 9), M zero outside.

    The box means of ``lades_similarity_volume`` as running sums (float64 accumulators,
    divided by W^2 as OpenCV's normalised box filter with a zero border does); writes
    ``out`` (D, rows, cols) float32.
    """
    rows, cols = left.shape
    half = window // 2
    area = np.float64(window * window)
    left_energy = _box_mean(left * left, half, area)
    right_energy = _box_mean(right * right, half, area)
    product = np.zeros((rows, cols), dtype=np.float32)
    zero = np.float32(0.0)
    for k in range(len(disparities)):
        d = disparities[k]
        for r in range(rows):
            for c in range(cols):
                product[r, c] = left[r, c] * right[r, c - d] if c >= d else zero
        numerator = _box_mean(product, half, area)
        for r in range(rows):
            for c in range(cols):
                energy = right_energy[r, c - d] if c >= d else zero
                denominator = np.sqrt(max(left_energy[r, c] * energy, zero))
                out[k, r, c] = numerator[r, c] / max(denominator, tiny)
