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
    except ImportError:
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
    """Build (or load from the cache) the numba kernels; returns a namespace of them."""
    import numba

    jit = functools.partial(numba.njit, cache=True, nogil=True)

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
        # Separable running sums over (2 half + 1)^2 windows, zero outside the image.
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

    class Kernels:
        pass

    kernels = Kernels()
    kernels.orientation_energy = orientation_energy
    kernels.moments = moments
    kernels.lades_volume = lades_volume
    return kernels


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


def warm_up():
    """Compile (or load) every kernel now; returns the seconds it took."""
    start = time.perf_counter()
    if numba_available():
        phase_congruency_from_responses(np.ones((1, 2, 2, 4, 4), np.complex64),
                                        np.zeros((1, 2), np.float32), np.zeros(2), 1e-4, 0.5,
                                        10.0)
        lades_similarity_volume(np.ones((4, 4)), np.ones((4, 4)), np.arange(2), 3, 1e-12)
    return time.perf_counter() - start
