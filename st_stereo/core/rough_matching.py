"""
Rough (integer) matching of phase-congruency features along rectified rows (paper 2.3).

A left feature at (y, x) is compared with every candidate right pixel (y, x - d), d in the
disparity range, by the Lades similarity of the 5x5 windows of M around them (paper eq. 9).
The similarity of all pixels at all disparities is one dense volume computed with box
filters, so there is no loop over features. The constraints (similarity, uniqueness,
left-right consistency, ordering, continuity) then prune the best candidates; each can be
switched off and each counts what it rejects.
"""

import dataclasses

import cv2
import numpy as np

import st_stereo.core.kernels as kernels

TINY = 1e-12

REJECTION_KEYS = ('no_candidate', 'similarity', 'ambiguous', 'left_right', 'ordering',
                  'continuity')


def lades_similarity(window_a, window_b):
    """
    Lades similarity of two windows: a cosine without mean removal (paper eq. 9).

    ``S = sum_j a_j b_j / sqrt(sum_j a_j^2 sum_j b_j^2)``; 1 for identical (non-zero)
    windows, 0 when either window is zero.

    Parameters
    ----------
    window_a, window_b : ndarray, shape (..., k, k)
        Windows of M (batched over leading axes).

    Returns
    -------
    ndarray, shape (...)

    References
    ----------
    M. Lades et al., "Distortion invariant object recognition in the dynamic link
    architecture", IEEE Trans. Computers 42(3), 1993.

    """
    a = np.asarray(window_a, dtype=np.float64)
    b = np.asarray(window_b, dtype=np.float64)
    numerator = (a * b).sum(axis=(-2, -1))
    denominator = np.sqrt((a * a).sum(axis=(-2, -1)) * (b * b).sum(axis=(-2, -1)))
    return np.where(denominator > TINY, numerator / np.maximum(denominator, TINY), 0.0)


def _box_mean(values, size):
    """
    Box mean over ``size x size`` windows, zero outside the image.

    Takes (rows, cols) or (D, rows, cols) float32 stacks. A stack goes through one OpenCV call:
    the slices are stacked into one tall image with zero separator rows, so no window sees two
    slices.
    """
    values = np.asarray(values, dtype=np.float32)
    if values.ndim == 2:
        return cv2.boxFilter(values, -1, (size, size), borderType=cv2.BORDER_CONSTANT)
    count, rows, cols = values.shape
    gap = size // 2
    tall = np.zeros((count, rows + gap, cols), dtype=np.float32)
    tall[:, :rows] = values
    filtered = cv2.boxFilter(tall.reshape(count * (rows + gap), cols), -1, (size, size),
                             borderType=cv2.BORDER_CONSTANT)
    return filtered.reshape(count, rows + gap, cols)[:, :rows]


def shifted_stack(image, disparities):
    """
    Stack ``out[i, y, x] = image[y, x - disparities[i]]``, zero where ``x - d < 0``.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Image to shift.
    disparities : ndarray of int, shape (D,)
        Non-negative shifts.

    Returns
    -------
    ndarray, shape (D, rows, cols)

    """
    rows, cols = image.shape
    d_max = int(disparities.max())
    padded = np.zeros((rows, cols + d_max), dtype=image.dtype)
    padded[:, d_max:] = image
    # Column c of the padded image is image column c - d_max; start d_max - d gives shift d.
    views = np.lib.stride_tricks.sliding_window_view(padded, cols, axis=1)
    return views[:, d_max - disparities].transpose(1, 0, 2)


def lades_similarity_volume(left_moments, right_moments, disparities, window):
    """
    Lades similarity of every left pixel with the right pixel ``d`` to its left, for all d.

    ``S[i, y, x] = S(window of left at (y, x), window of right at (y, x - d_i))`` (paper eq.
    9), with M taken as zero outside the images.

    Returns
    -------
    ndarray, shape (D, rows, cols), float32

    """
    left = np.asarray(left_moments, dtype=np.float32)
    right = np.asarray(right_moments, dtype=np.float32)
    right_shifted = shifted_stack(right, disparities)
    numerator = _box_mean(left[None] * right_shifted, window)
    left_energy = _box_mean(left * left, window)
    right_energy = shifted_stack(_box_mean(right * right, window), disparities)
    # Box means of squares can round to tiny negatives in float32: clamp before the root.
    denominator = np.sqrt(np.maximum(left_energy[None] * right_energy, np.float32(0.0)))
    return numerator / np.maximum(denominator, np.float32(TINY))


@dataclasses.dataclass
class RoughMatches:
    """
    Integer matches of left features: row, left column, integer disparity, similarity.

    ``distinctiveness``: similarity minus the best similarity more than 1 px away on the row
    (``runner_up_similarity``; +inf for a match without rival, -inf without room for one).
    """

    y: np.ndarray
    x_left: np.ndarray
    disparity: np.ndarray
    similarity: np.ndarray
    rejected: dict
    distinctiveness: np.ndarray = None

    @property
    def x_right(self):
        """Column of the matched right pixel."""
        return self.x_left - self.disparity

    def subset(self, keep):
        """Return the matches where ``keep`` is true (rejection counts are shared)."""
        distinctiveness = None if self.distinctiveness is None else self.distinctiveness[keep]
        return RoughMatches(self.y[keep], self.x_left[keep], self.disparity[keep],
                            self.similarity[keep], self.rejected, distinctiveness)

    def __len__(self):
        """Return the number of matches."""
        return len(self.y)


def disparity_search_range(config, prior, shape):
    """
    Candidate disparities and a per-pixel admissibility mask from the range and the prior.

    Parameters
    ----------
    config : STConfig
        ``disparity_min``, ``disparity_max``, ``prior_radius``.
    prior : None, float or ndarray (rows, cols)
        Expected disparity; NaN where unknown. With a prior, only ``|d - prior| <=
        prior_radius`` is searched (paper 2.3: a range from prior knowledge or the previous
        frame).
    shape : tuple
        (rows, cols) of the images.

    Returns
    -------
    disparities : ndarray of int, shape (D,)
    admissible : ndarray of bool, shape (D, rows, cols) or (D, 1, 1)

    """
    rows, cols = shape
    d_high = min(config.disparity_max, cols - 1)
    disparities = np.arange(config.disparity_min, d_high + 1)
    if prior is None:
        return disparities, np.ones((len(disparities), 1, 1), dtype=bool)
    prior = np.asarray(prior, dtype=np.float64)
    if prior.ndim == 0:
        prior = np.full((1, 1), float(prior))
    elif prior.shape != (rows, cols):
        raise ValueError(f'disparity prior: expected a scalar or shape {(rows, cols)}, got '
                         f'{prior.shape}')
    distance = np.abs(disparities[:, None, None] - prior[None])
    admissible = (distance <= config.prior_radius) | np.isnan(prior)[None]
    return disparities, admissible


def _best_candidates(volume, valid):
    masked = np.where(valid, volume, -np.inf)
    best = masked.argmax(axis=0)
    best_value = np.take_along_axis(masked, best[None], axis=0)[0]
    return best, best_value


def runner_up_similarity(volume, valid, searchable, best, y, x, exclusion=1):
    """
    Best similarity of each left pixel at a disparity more than ``exclusion`` px from its best.

    The distinctiveness of a rough match (paper 2.3 takes the most similar candidate; one
    barely more similar than a candidate two pixels away is poorly located, and one as similar
    as a candidate elsewhere on the row is a guess): weak texture gives a flat similarity
    curve, an edge parallel to the rows or periodic structure a second peak as high as the
    first. ``searchable`` (D, rows, cols) marks the disparities the image borders leave for
    each pixel: where none is left beyond ``exclusion`` the result is +inf (nothing shows
    that the match is located: it is rejected, e.g. a row edge at the image border); where
    some are left but none holds a candidate, -inf (the match is the only one: distinct).
    (Measured: the runner-up among the other local maxima only, which ignores flat curves,
    separated outliers far worse.)
    """
    scores = np.where(valid[:, y, x], volume[:, y, x], -np.inf)
    index = np.arange(volume.shape[0])[:, None]
    scores = np.where(np.abs(index - best[y, x][None]) <= exclusion, -np.inf, scores)
    if not len(scores):
        return np.full(len(y), np.inf)
    rivals = searchable[:, y, x] & (np.abs(index - best[y, x][None]) > exclusion)
    return np.where(rivals.any(axis=0), scores.max(axis=0), np.inf)


def drop_less_similar_of_conflicts(y, position, similarity, conflict):
    """
    Resolve conflicts between row neighbours by dropping the less similar match, repeatedly.

    Matches are sorted by (row, ``position``); ``conflict(first, second)`` says, for index
    arrays of consecutive kept matches of one row, which pairs conflict. The less similar of
    each conflicting pair is dropped and the neighbours are looked at again, until no pair
    conflicts (the constraints of paper section 2.3). Returns the bool mask of kept matches.
    """
    keep = np.ones(len(y), dtype=bool)
    order = np.lexsort((position, y))
    while True:
        idx = order[keep[order]]
        if len(idx) < 2:
            return keep
        first, second = idx[:-1], idx[1:]
        clash = (y[second] == y[first]) & conflict(first, second)
        if not clash.any():
            return keep
        first, second = first[clash], second[clash]
        keep[np.where(similarity[first] < similarity[second], first, second)] = False


def enforce_uniqueness(y, x_left, x_right, similarity, tolerance):
    """
    One-to-one matching: a right point serves at most one left feature (paper 2.3).

    Two matches of one row collide when their right positions are closer than ``tolerance``
    (sub-pixel positions, so neighbouring left pixels whose integer matches round onto the
    same right pixel do not collide once refined). Of colliding matches the most similar
    is kept.

    Returns
    -------
    ndarray of bool, the matches kept

    """
    return drop_less_similar_of_conflicts(
        y, x_right, similarity,
        lambda first, second: np.abs(x_right[second] - x_right[first]) < tolerance)


def left_right_consistent(volume, valid_left, disparities, y, x_right, disparity, tolerance,
                          compiled=False):
    """
    Left-right check: the best left pixel for the matched right pixel is the original one.

    For the right pixel (y, x_r), the left candidates are (y, x_r + d'); their similarity is
    ``volume[d', y, x_r + d']``. The match survives when the best d' is within ``tolerance``
    of its own disparity. ``compiled``: the same search by a numba kernel.
    """
    if compiled:
        best = kernels.left_right_best(volume, valid_left, disparities, y, x_right)
        return np.abs(best - disparity) <= tolerance
    rows, cols = valid_left.shape
    x_candidates = x_right[:, None] + disparities[None, :]
    inside = x_candidates < cols
    x_clipped = np.minimum(x_candidates, cols - 1)
    d_index = np.broadcast_to(np.arange(len(disparities))[None, :], x_candidates.shape)
    scores = volume[d_index, y[:, None], x_clipped]
    ok = inside & valid_left[y[:, None], x_clipped]
    scores = np.where(ok, scores, -np.inf)
    best = disparities[scores.argmax(axis=1)]
    return np.abs(best - disparity) <= tolerance


def ordering_consistent(y, x_left, x_right, similarity):
    """
    Ordering constraint: along a row, right positions keep the order of the left ones.

    Matches are sorted by (row, x_left); wherever two neighbours in a row invert their right
    positions, the less similar of the two is dropped, repeatedly until no inversion is left.
    Equal right positions are left to the uniqueness constraint.

    Returns
    -------
    ndarray of bool, the matches kept

    """
    return drop_less_similar_of_conflicts(
        y, x_left, similarity, lambda first, second: x_right[second] < x_right[first])


def continuity_consistent(shape, y, x_left, disparity, radius, max_jump, min_neighbours,
                          compiled=False):
    """
    Continuity: a disparity must be close to the median of its neighbours' (paper 2.3).

    The neighbourhood is the (2 radius + 1)^2 square around the left feature, the match
    itself excluded; matches with fewer than ``min_neighbours`` neighbours are kept.
    ``compiled``: the medians by a numba kernel.

    Returns
    -------
    ndarray of bool, the matches kept

    """
    rows, cols = shape
    grid = np.full((rows + 2 * radius, cols + 2 * radius), np.nan)
    grid[y + radius, x_left + radius] = disparity
    if compiled:
        count, median = kernels.continuity_medians(grid, y, x_left, radius)
        return (count < min_neighbours) | (np.abs(disparity - median) <= max_jump)
    side = 2 * radius + 1
    dy, dx = np.mgrid[0:side, 0:side]
    neighbours = grid[y[:, None] + dy.ravel()[None], x_left[:, None] + dx.ravel()[None]]
    neighbours[:, (side * side) // 2] = np.nan
    count = np.sum(~np.isnan(neighbours), axis=1)
    keep = np.ones(len(y), dtype=bool)
    enough = count >= min_neighbours
    if enough.any():
        # Median of the finite values: a sort puts NaN last (7x faster than np.nanmedian).
        ordered = np.sort(neighbours[enough], axis=1)
        k = count[enough]
        rows_index = np.arange(len(k))
        median = 0.5 * (ordered[rows_index, (k - 1) // 2] + ordered[rows_index, k // 2])
        keep[enough] = np.abs(disparity[enough] - median) <= max_jump
    return keep


def rough_match(left_moments, right_moments, left_features, config, prior=None,
                right_margin=0, right_valid=None):
    """
    Integer matching of left features along rows under the paper's constraints.

    Parameters
    ----------
    left_moments, right_moments : ndarray, shape (rows, cols)
        Feature images M of the rectified pair.
    left_features : ndarray of bool, shape (rows, cols)
        Left pixels to match.
    config : STConfig
        Matching parameters and constraint switches.
    prior : None, float or ndarray
        Disparity prior (see ``disparity_search_range``).
    right_margin : int
        Right candidates must lie at least this far from the left and right image borders
        (the sub-pixel window must fit).
    right_valid : ndarray of bool, optional
        Right pixels allowed as candidates (their window inside the image data).

    Returns
    -------
    RoughMatches
        With ``rejected`` counting, per constraint, the left features it removed. Uniqueness
        is enforced after sub-pixel refinement (``enforce_uniqueness``).

    """
    rows, cols = left_moments.shape
    rejected = dict.fromkeys(REJECTION_KEYS, 0)
    disparities, admissible = disparity_search_range(config, prior, (rows, cols))
    if not left_features.any() or len(disparities) == 0:
        rejected['no_candidate'] = int(left_features.sum())
        empty = np.zeros(0, dtype=np.int64)
        return RoughMatches(empty, empty, empty, np.zeros(0), rejected, np.zeros(0))
    compiled = kernels.use_compiled(config.kernels)
    if compiled:
        volume = kernels.lades_similarity_volume(left_moments, right_moments, disparities,
                                                 config.similarity_window, TINY)
    else:
        volume = lades_similarity_volume(left_moments, right_moments, disparities,
                                         config.similarity_window)
    candidate_level = config.candidate_ratio * config.gamma
    # Right columns whose sub-pixel window fits: where candidates (and rivals) may lie.
    inside = np.ones((rows, cols), dtype=bool)
    if right_margin:
        inside[:, :right_margin] = False
        inside[:, cols - right_margin:] = False
    candidates = (right_moments > candidate_level) & inside
    if right_valid is not None:
        candidates &= right_valid
    y, x_left = np.nonzero(left_features)
    if compiled:
        # The same candidates and rivals, for the features only (st_stereo.core.kernels).
        best, similarity, runner_up = kernels.feature_candidates(
            volume, candidates, inside, admissible, disparities, y, x_left, 1)
        with np.errstate(invalid='ignore'):      # -inf - -inf: features without candidate
            distinctiveness = similarity - runner_up
    else:
        valid = shifted_stack(candidates, disparities) & admissible
        best_of_pixel, best_value = _best_candidates(volume, valid)
        best = best_of_pixel[y, x_left]
        similarity = best_value[y, x_left].astype(np.float64)
        distinctiveness = None
    disparity = disparities[best]
    has_candidate = np.isfinite(similarity)
    rejected['no_candidate'] = int((~has_candidate).sum())
    matches = RoughMatches(y, x_left, disparity, similarity, rejected,
                           distinctiveness).subset(has_candidate)

    def apply(name, keep):
        rejected[name] = int((~keep).sum())
        return matches.subset(keep)

    matches = apply('similarity', matches.similarity >= config.min_similarity)
    if not compiled:
        searchable = shifted_stack(inside, disparities) & admissible
        runner_up = runner_up_similarity(volume, valid, searchable, best_of_pixel, matches.y,
                                         matches.x_left)
        matches.distinctiveness = matches.similarity - runner_up
    if config.min_distinctiveness > 0:
        matches = apply('ambiguous', matches.distinctiveness >= config.min_distinctiveness)
    if config.left_right_check:
        valid_left = left_moments > candidate_level
        matches = apply('left_right', left_right_consistent(
            volume, valid_left, disparities, matches.y, matches.x_right, matches.disparity,
            config.left_right_tolerance, compiled))
    if config.ordering:
        matches = apply('ordering', ordering_consistent(matches.y, matches.x_left,
                                                        matches.x_right, matches.similarity))
    if config.continuity:
        matches = apply('continuity', continuity_consistent(
            (rows, cols), matches.y, matches.x_left, matches.disparity.astype(np.float64),
            config.continuity_radius, config.continuity_max_jump,
            config.continuity_min_neighbours, compiled))
    return matches
