"""
The numba kernels themselves (imported only by ``st_stereo.core.kernels``, when numba is).

Module-level functions, so that numba's on-disk cache finds them again in the next process
(a kernel defined inside a function, calling another, gets a new cache key in every process
and is compiled again at every start). Where no cache directory is writable (a read-only
install without ``NUMBA_CACHE_DIR`` or a writable home) they are compiled without a cache.
"""

import math

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
    Phase congruency of each orientation (phasecong3, paper eq. 2).

    ``responses`` (n, norient, nscale, rows, cols) complex64; ``thresholds`` (n, norient)
    float32; writes ``out_pc`` (n, norient, rows, cols) float32. The float32 arithmetic
    follows ``phase_congruency_moments`` operation by operation (the sums over scales in
    scale order), except that magnitudes are ``sqrt(re^2 + im^2)`` rather than numpy's
    ``hypot`` (a few times faster; equal to within an ulp at these magnitudes). Each pass runs
    over all the pixels of one orientation, so that the compiler vectorises it (1.1 -> 0.67 ms
    at 80x60 against one pass per pixel, the same results bit for bit).
    """
    n, norient, nscale, rows, cols = responses.shape
    one = np.float32(1.0)
    zero = np.float32(0.0)
    spread_scale = np.float32(nscale - 1)
    size = rows * cols
    flat = responses.reshape(n, norient, nscale, size)
    out = out_pc.reshape(n, norient, size)
    sum_amplitude = np.empty(size, np.float32)
    max_amplitude = np.empty(size, np.float32)
    sum_re = np.empty(size, np.float32)
    sum_im = np.empty(size, np.float32)
    deviation = np.empty(size, np.float32)
    mean_re = np.empty(size, np.float32)
    mean_im = np.empty(size, np.float32)
    magnitude = np.empty(size, np.float32)
    inverse_energy = np.empty(size, np.float32)
    for i in range(n):
        for o in range(norient):
            threshold = thresholds[i, o]
            for p in range(size):
                value = flat[i, o, 0, p]
                amplitude = np.sqrt(value.real * value.real + value.imag * value.imag)
                sum_amplitude[p] = zero + amplitude
                max_amplitude[p] = amplitude
                sum_re[p] = zero + value.real
                sum_im[p] = zero + value.imag
            for s in range(1, nscale):
                for p in range(size):
                    value = flat[i, o, s, p]
                    amplitude = np.sqrt(value.real * value.real + value.imag * value.imag)
                    sum_amplitude[p] += amplitude
                    if amplitude > max_amplitude[p]:
                        max_amplitude[p] = amplitude
                    sum_re[p] += value.real
                    sum_im[p] += value.imag
            for p in range(size):
                total = np.sqrt(sum_re[p] * sum_re[p] + sum_im[p] * sum_im[p])
                magnitude[p] = total
                inverse = one / (total + epsilon)
                inverse_energy[p] = inverse
                mean_re[p] = sum_re[p] * inverse
                mean_im[p] = -(sum_im[p] * inverse)          # the conjugate
                deviation[p] = zero
            for s in range(nscale):
                for p in range(size):
                    value = flat[i, o, s, p]
                    deviation[p] += abs(value.real * mean_im[p] + value.imag * mean_re[p])
            for p in range(size):
                energy = magnitude[p] * magnitude[p] * inverse_energy[p] - deviation[p]
                energy = max(energy - threshold, zero)
                width = (sum_amplitude[p] / (max_amplitude[p] + epsilon) - one) / spread_scale
                weight = one / (one + np.exp((cutoff - width) * gain))
                divisor = sum_amplitude[p] if sum_amplitude[p] > zero else one
                out[i, o, p] = weight * energy / divisor


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


@jit
def cross_power(left_spectra, right_spectra, mask, out):
    """
    Band-limited normalised cross-power spectra ``R = F_R conj(F_L) / |.|`` (paper eq. 10).

    ``left_spectra``, ``right_spectra``, ``out`` (n, W, W // 2 + 1) complex128 (rfft2 half
    spectra); ``mask`` (W, W // 2 + 1): 1 inside the pass band, 0 outside. What
    ``subpixel.poc_from_spectra`` computes (magnitudes floored at float32's 1e-20), with
    ``sqrt(re^2 + im^2)`` for numpy's ``hypot`` and one reciprocal for its complex division
    (a few times faster; equal to within a few ulp).
    """
    n, rows, cols = out.shape
    tiny = np.float64(np.float32(1e-20))
    for i in range(n):
        for r in range(rows):
            for c in range(cols):
                a = right_spectra[i, r, c]
                b = left_spectra[i, r, c]
                re = a.real * b.real + a.imag * b.imag
                im = a.imag * b.real - a.real * b.imag
                scale = mask[r, c] / max(np.sqrt(re * re + im * im), tiny)
                out[i, r, c] = complex(re * scale, im * scale)


@jit
def shift_phases(omega, shifts, out):
    """
    Phase ramps ``exp(i omega shift)`` of ``fourier.RowShifter.shift``, complex64.

    ``omega`` (F,) float32, ``2 pi f`` rounded to float32 as the reference does; ``shifts``
    (n,) float32; writes ``out`` (n, F). float32 arithmetic, libm's ``cosf`` / ``sinf`` as
    numpy's complex64 ``exp`` (the spectrum is multiplied by numpy: its SIMD complex64
    product rounds differently from a scalar one).
    """
    n, count = out.shape
    for i in range(n):
        for k in range(count):
            angle = omega[k] * shifts[i]
            out[i, k] = np.complex64(complex(np.cos(angle), np.sin(angle)))


@jit
def poc_peak_fits(surfaces, band_ratio, delta, denominator, inside, peak_value, lag):
    """
    Peak of each POC surface and Nagashima's fit along its row (paper eqs. 11, 14-17).

    ``surfaces`` (n, W, W) float64, unshifted (lag ``k`` at index ``k mod W``). Per surface:
    the highest sample (the first in row order on ties, as ``argmax``), the row through it
    re-ordered so that lag 0 sits at ``W // 2``, and, where the peak is at least 3 samples
    from both ends (``inside``), the least-squares offset over ``p in {p - 1, p, p + 1}``,
    ``d in {1, 2}`` in the order of ``subpixel.nagashima_peak_offset`` (elsewhere the fit is
    taken about the centre, as there). Writes ``delta``, ``denominator`` (``sum(u^2)``),
    ``inside``, ``peak_value`` and ``lag`` (the peak's integer lag).
    """
    n, size, _ = surfaces.shape
    half = size // 2
    cos_1 = np.cos(np.pi * band_ratio * 1)
    cos_2 = np.cos(np.pi * band_ratio * 2)
    profile = np.empty(size, dtype=np.float64)
    for i in range(n):
        best = surfaces[i, 0, 0]
        best_row = 0
        best_col = 0
        for r in range(size):
            for c in range(size):
                if surfaces[i, r, c] > best:
                    best = surfaces[i, r, c]
                    best_row = r
                    best_col = c
        for j in range(size):
            profile[j] = surfaces[i, best_row, (j - half) % size]
        peak = (best_col + half) % size
        peak_value[i] = profile[peak]
        inside[i] = 3 <= peak <= size - 4
        centre = peak if inside[i] else half
        # numpy's sum over the six terms: the first, plus the sum of the other five.
        numerator = 0.0
        total = 0.0
        first_uv = 0.0
        first_uu = 0.0
        for k in range(6):
            p = centre + k // 2 - 1
            d = 1 + k % 2
            cos_d = cos_1 if d == 1 else cos_2
            r_p = profile[p]
            r_minus = profile[p - d]
            r_plus = profile[p + d]
            at = np.float64(p - half)
            u = r_minus + r_plus - 2.0 * cos_d * r_p
            v = 2.0 * at * cos_d * r_p - (at - d) * r_minus - (at + d) * r_plus
            if k == 0:
                first_uu = u * u
                first_uv = u * v
            else:
                total += u * u
                numerator += u * v
        total = first_uu + total
        numerator = first_uv + numerator
        denominator[i] = total
        delta[i] = numerator / (total if total > 0 else 1.0)
        lag[i] = peak - half


@jit
def feature_candidates(volume, candidates, inside, admissible, disparities, ys, xs, exclusion,
                       best_index, best_value, runner_up):
    """
    Best candidate of each left feature and the best one beyond ``exclusion`` px (eq. 9).

    What ``rough_matching._best_candidates`` and ``runner_up_similarity`` compute, for the
    features ``(ys, xs)`` only: candidate ``k`` of a feature at (y, x) is valid where the right
    pixel ``x - d_k`` exists, is a candidate (``candidates``) and ``admissible`` allows ``k``
    (shape (D, rows, cols), or (D, 1, 1) for every pixel); the best is the first highest
    similarity (-inf, index 0, without any); the runner-up is the highest valid similarity
    more than ``exclusion`` from the best, -inf where the borders leave room for a rival
    (``inside``) but none is valid, +inf where they leave none.
    """
    count = len(disparities)
    per_pixel = admissible.shape[1] > 1
    for i in range(len(ys)):
        y = ys[i]
        x = xs[i]
        best = -np.inf
        index = 0
        for k in range(count):
            c = x - disparities[k]
            allowed = admissible[k, y, x] if per_pixel else admissible[k, 0, 0]
            if c >= 0 and allowed and candidates[y, c] and volume[k, y, x] > best:
                best = volume[k, y, x]
                index = k
        best_index[i] = index
        best_value[i] = best
        rival = -np.inf
        room = False
        for k in range(count):
            if abs(k - index) <= exclusion:
                continue
            c = x - disparities[k]
            allowed = admissible[k, y, x] if per_pixel else admissible[k, 0, 0]
            if c >= 0 and allowed:
                if inside[y, c]:
                    room = True
                if candidates[y, c] and volume[k, y, x] > rival:
                    rival = volume[k, y, x]
        runner_up[i] = rival if room else np.inf


@jit
def left_right_best(volume, valid_left, disparities, ys, x_rights, out):
    """
    Best left disparity of each matched right pixel (``left_right_consistent``).

    For the right pixel (y, x_r) candidate ``k`` is the left pixel ``x_r + d_k``, valid where it
    exists and ``valid_left`` holds; the first highest ``volume[k, y, x_r + d_k]`` (index 0
    without any) gives ``out = d_k``.
    """
    cols = valid_left.shape[1]
    for i in range(len(ys)):
        y = ys[i]
        best = -np.inf
        index = 0
        for k in range(len(disparities)):
            x = x_rights[i] + disparities[k]
            if x < cols and valid_left[y, x] and volume[k, y, x] > best:
                best = volume[k, y, x]
                index = k
        out[i] = disparities[index]


@jit
def continuity_medians(grid, ys, xs, radius, out_count, out_median):
    """
    Median of the finite disparities in each match's (2 radius + 1)^2 square, itself excluded.

    ``grid``: the matches' disparities, NaN elsewhere, padded by ``radius``; writes the number
    of neighbours and their median (the mean of the two middle values for an even number), as
    ``continuity_consistent``'s sort does.
    """
    side = 2 * radius + 1
    values = np.empty(side * side, dtype=np.float64)
    for i in range(len(ys)):
        count = 0
        for dy in range(side):
            for dx in range(side):
                if dy == radius and dx == radius:
                    continue
                value = grid[ys[i] + dy, xs[i] + dx]
                if not np.isnan(value):
                    # Insertion sort: at most (2 radius + 1)^2 - 1 values.
                    j = count
                    while j > 0 and values[j - 1] > value:
                        values[j] = values[j - 1]
                        j -= 1
                    values[j] = value
                    count += 1
        out_count[i] = count
        out_median[i] = 0.5 * (values[(count - 1) // 2] + values[count // 2]) if count else 0.0


@jit
def deramped_strips(image, ys, xs, size, margin, out_strips, out_periodic, out_first,
                    out_slope):
    """
    Gather the strips of ``subpixel.extract_strips`` in float32, and their de-ramped copies.

    ``size`` rows by ``size + 2 margin`` columns centred at (y, x), columns outside the image
    reflected symmetrically (numpy's ``pad(mode='symmetric')``); then, as
    ``fourier.RowShifter`` computes them in float32: ``first`` (the first column),
    ``slope = (last - first) / (width - 1)`` and ``periodic = strip - (first + slope x)``.
    """
    cols = image.shape[1]
    half = size // 2
    width = size + 2 * margin
    steps = np.float32(width - 1)
    for i in range(len(ys)):
        for r in range(size):
            row = ys[i] - half + r
            for k in range(width):
                c = xs[i] - half - margin + k
                if c < 0:
                    c = -c - 1
                elif c >= cols:
                    c = 2 * cols - c - 1
                out_strips[i, r, k] = np.float32(image[row, c])
            first = out_strips[i, r, 0]
            slope = (out_strips[i, r, width - 1] - first) / steps
            out_first[i, r] = first
            out_slope[i, r] = slope
            for k in range(width):
                out_periodic[i, r, k] = out_strips[i, r, k] - (first + slope * np.float32(k))


@jit
def reramped_columns(shifted, first, slope, shifts, start, out):
    """
    ``shifted[..., start:start + W] + first + slope (x + shift)`` (``RowShifter.shift``).

    float32, in numpy's order: ``(shifted + first) + slope * (x + shift)``; ``out`` (n, rows,
    W).
    """
    n, rows, count = out.shape
    for i in range(n):
        for r in range(rows):
            for k in range(count):
                x = np.float32(start + k)
                out[i, r, k] = (shifted[i, r, start + k] + first[i, r]) + \
                    slope[i, r] * (x + shifts[i])


@jit
def _ndtr(a):
    """Return the standard normal CDF as scipy's (cephes') ``ndtr`` computes it."""
    x = a * 0.7071067811865476
    z = abs(x)
    if z < 0.7071067811865476:
        return 0.5 + 0.5 * math.erf(x)
    y = 0.5 * math.erfc(z)
    return 1.0 - y if x > 0.0 else y


@jit
def blurred_ellipses(params, xs, ys, dx, dy, out):
    """
    ``target_refinement.blurred_ellipse`` in one pass: ``out`` (n, m) pixel values.

    The same formulas (``ellipse_matrix``'s ``Q``, the first-order distance to the ellipse,
    the normal CDF of it over the edge width, the mean over the subsamples ``dx, dy``); the
    sums run in another order, so values agree to about 1e-15 relative.
    """
    n, m = xs.shape
    count = dx.shape[0]
    for i in range(n):
        cx, cy = params[i, 0], params[i, 1]
        e1, e2 = params[i, 3], params[i, 4]
        k = math.hypot(e1, e2)
        sinhc = math.sinh(k) / max(k, 1e-8) if k > 1e-8 else 1.0
        scale = math.exp(-2.0 * params[i, 2])
        q11 = scale * (math.cosh(k) + sinhc * e1)
        q22 = scale * (math.cosh(k) - sinhc * e1)
        q12 = scale * sinhc * e2
        width = math.exp(params[i, 5])
        for j in range(m):
            total = 0.0
            for t in range(count):
                x = xs[i, j] + dx[t] - cx
                y = ys[i, j] + dy[t] - cy
                gx = q11 * x + q12 * y
                gy = q12 * x + q22 * y
                s = math.sqrt(max(x * gx + y * gy, 1e-12))
                gradient = math.sqrt(gx * gx + gy * gy) / s
                total += _ndtr((1.0 - s) / max(gradient, 1e-6) / width)
            out[i, j] = params[i, 7] + params[i, 6] * (total / count)


@jit
def _opencv_ccoeff_normed(numerator, template_norm, window_deviation):
    # OpenCV's TM_CCOEFF_NORMED finish (templmatch.cpp): a flat template correlates 1
    # everywhere, |num| within 12.5 % beyond the norm rounds to +-1, beyond that to 0.
    if template_norm == 0.0:
        return 1.0
    norm = window_deviation * template_norm
    if abs(numerator) < norm:
        return numerator / norm
    if abs(numerator) < norm * 1.125:
        return 1.0 if numerator > 0.0 else -1.0
    return 0.0


@jit
def window_ncc(current, previous, ys, xs, half, offsets_y, offsets_x, out):
    """
    Zero-mean NCC of each feature's window against another frame at every offset.

    ``out[k, a, b]`` is OpenCV's ``TM_CCOEFF_NORMED`` of ``current``'s window of side
    ``2 half + 1`` centred on ``(ys[k], xs[k])`` against ``previous``'s window centred on
    ``(ys[k] + offsets_y[a], xs[k] + offsets_x[b])``, in float64 (OpenCV's is float32, a few
    1e-6 apart), with OpenCV's handling of flat windows. Every window must lie inside both
    frames. The cross sums are the one cost (the windows' own sums are running box sums): per
    offset either directly over each window, or, when the features are dense enough for it
    to be cheaper, as running box sums of the frames' product over the features' bounding box
    (features 1 px apart share 72 of their 81 products).
    """
    rows, cols = current.shape
    n = ys.shape[0]
    side = 2 * half + 1
    area = float(side * side)
    if n == 0:
        return
    template_sum = np.empty(n)
    template_norm = np.empty(n)
    for k in range(n):
        total = 0.0
        for r in range(ys[k] - half, ys[k] + half + 1):
            for c in range(xs[k] - half, xs[k] + half + 1):
                total += current[r, c]
        mean = total / area
        spread = 0.0
        for r in range(ys[k] - half, ys[k] + half + 1):
            for c in range(xs[k] - half, xs[k] + half + 1):
                spread += (current[r, c] - mean) * (current[r, c] - mean)
        template_sum[k] = total
        # OpenCV: the variance per pixel is compared with DBL_EPSILON, then the norm is
        # sqrt(variance * area).
        variance = spread / area
        template_norm[k] = math.sqrt(variance * area) if variance >= 2.220446049250313e-16 \
            else 0.0
    # Box sums of the other frame and of its square at every window centre.
    box = np.zeros((rows, cols))
    box_square = np.zeros((rows, cols))
    column = np.zeros(cols)
    column_square = np.zeros(cols)
    for r in range(min(side, rows)):
        for c in range(cols):
            value = previous[r, c]
            column[c] += value
            column_square[c] += value * value
    for r in range(half, rows - half):
        if r > half:
            for c in range(cols):
                value_in = previous[r + half, c]
                value_out = previous[r - half - 1, c]
                column[c] += value_in - value_out
                column_square[c] += value_in * value_in - value_out * value_out
        total = 0.0
        total_square = 0.0
        for c in range(min(side, cols)):
            total += column[c]
            total_square += column_square[c]
        if cols > 2 * half:
            box[r, half] = total
            box_square[r, half] = total_square
        for c in range(half + 1, cols - half):
            total += column[c + half] - column[c - half - 1]
            total_square += column_square[c + half] - column_square[c - half - 1]
            box[r, c] = total
            box_square[r, c] = total_square
    # sqrt(sum of squares - sum^2 / area): OpenCV's window norm, once per pixel; a variance
    # within the running sums' residue (1e-10 of the sum of squares) is a flat window's.
    deviation = np.zeros((rows, cols))
    for r in range(rows):
        for c in range(cols):
            variance = box_square[r, c] - box[r, c] * box[r, c] / area
            if variance > 1e-10 * box_square[r, c]:
                deviation[r, c] = math.sqrt(variance)
    y_low, y_high, x_low, x_high = rows, -1, cols, -1
    for k in range(n):
        y_low, y_high = min(y_low, ys[k]), max(y_high, ys[k])
        x_low, x_high = min(x_low, xs[k]), max(x_high, xs[k])
    first_row, first_col = y_low - half, x_low - half
    height, width = y_high - y_low + side, x_high - x_low + side
    n_y, n_x = offsets_y.shape[0], offsets_x.shape[0]
    if 3 * height * width >= n * side * side:
        # Few or scattered windows: each window's cross sums directly, the offsets innermost
        # (a template pixel times a row of the other frame: contiguous, vectorised).
        cross = np.empty((n_y, n_x))
        for k in range(n):
            cross[:, :] = 0.0
            for r in range(ys[k] - half, ys[k] + half + 1):
                for c in range(xs[k] - half, xs[k] + half + 1):
                    value = current[r, c]
                    for a in range(n_y):
                        row = r + offsets_y[a]
                        for b in range(n_x):
                            cross[a, b] += value * previous[row, c + offsets_x[b]]
            for a in range(n_y):
                for b in range(n_x):
                    y, x = ys[k] + offsets_y[a], xs[k] + offsets_x[b]
                    numerator = cross[a, b] - template_sum[k] * box[y, x] / area
                    out[k, a, b] = _opencv_ccoeff_normed(numerator, template_norm[k],
                                                         deviation[y, x])
        return
    product = np.empty((height, width))
    vertical = np.empty((y_high - y_low + 1, width))
    for a in range(n_y):
        dy = offsets_y[a]
        for b in range(n_x):
            dx = offsets_x[b]
            for i in range(height):
                for j in range(width):
                    product[i, j] = current[first_row + i, first_col + j] * \
                        previous[first_row + i + dy, first_col + j + dx]
            for j in range(width):
                vertical[0, j] = 0.0
            for i in range(side):
                for j in range(width):
                    vertical[0, j] += product[i, j]
            for i in range(1, y_high - y_low + 1):
                for j in range(width):
                    vertical[i, j] = vertical[i - 1, j] + product[i + side - 1, j] - \
                        product[i - 1, j]
            for k in range(n):
                i, j0 = ys[k] - y_low, xs[k] - half - first_col
                cross_sum = 0.0
                for j in range(j0, j0 + side):
                    cross_sum += vertical[i, j]
                y, x = ys[k] + dy, xs[k] + dx
                numerator = cross_sum - template_sum[k] * box[y, x] / area
                out[k, a, b] = _opencv_ccoeff_normed(numerator, template_norm[k],
                                                     deviation[y, x])
