"""
Consistency with the previous pair: a static feature must have been matched there alike.

A feature whose 9x9 window did not change between the left camera's previous frame and its
current one beyond the sensor noise (``changed_windows``, the skew compensation's test) sees
the same scene in both pairs, so its disparity cannot have changed. Its match in the current
pair is kept only when the previous pair matched the same pixel with a disparity within
``tolerance_px``. A static match the previous pair did not make (its feature below the
threshold there, or rejected) or made differently is one the matcher cannot reproduce from
the same scene with other noise: an ambiguous match (a periodic radiator, weak floor texture,
a window that a neighbouring edge decides). Measured on 18 pairs each of sit_down and
two_people (synchronized, every fourth pair against the one before it): static features
unmatched in the previous pair were 8.5 / 6.2 % of the static ones and held half / 42 % of
their 3-D outliers; with a tolerance of 0.3 px, the inconsistent ones 2.6 / 0.5 %, holding
31 / 6 % (docs/results.md section 5).

Off by default (``temporal_tolerance_px`` 0): the people stage loses a person seen by a
handful of points when it thins them (docs/results.md section 5).

Moving features (their window changed) are not checked; nor is a pair with a camera in a
flat-field correction, or the pair after it (a frozen frame looks static everywhere), nor a
pair without a usable previous one (the first, one after a gap longer than ``max_age_s``,
another image size or another calibration), counted as such. The previous pair's matches are
remembered before this check, so a feature dropped once is judged again against the next
pair.
"""

import numpy as np

from st_stereo.core.skew import changed_windows

TEMPORAL_COUNT_KEYS = ('pairs_checked', 'pairs_without_previous', 'pairs_in_ffc',
                       'features_static', 'rejected_temporal_unmatched',
                       'rejected_temporal_inconsistent')


def previous_disparity_map(shape, x_left, y, disparity):
    """Disparity of each matched left pixel (NaN where the pair has no match), shape ``shape``."""
    image = np.full(shape, np.nan)
    image[np.asarray(y, dtype=np.int64), np.asarray(x_left, dtype=np.int64)] = disparity
    return image


def temporal_rejects(static, disparity, previous_disparity, tolerance_px):
    """
    Return ``(unmatched, inconsistent)`` masks of the static matches to drop.

    Unmatched: no previous match at their pixel; inconsistent: a previous disparity more than
    ``tolerance_px`` away.
    """
    static = np.asarray(static, dtype=bool)
    known = np.isfinite(previous_disparity)
    unmatched = static & ~known
    with np.errstate(invalid='ignore'):
        inconsistent = static & known & \
            (np.abs(np.asarray(disparity) - previous_disparity) > tolerance_px)
    return unmatched, inconsistent


class TemporalCheck:
    """
    Drop static matches the previous pair did not make alike (see the module docstring).

    ``check`` once per pair, in order; ``counts`` holds ``TEMPORAL_COUNT_KEYS``.
    """

    def __init__(self, tolerance_px=0.3, max_age_s=0.25):
        if not tolerance_px > 0:
            raise ValueError(f'tolerance_px: expected > 0, got {tolerance_px!r}')
        self.tolerance_px = float(tolerance_px)
        self.max_age_s = float(max_age_s)
        self.previous = None          # (left image, time, model, disparity map)
        self.previous_ffc = False
        self.counts = dict.fromkeys(TEMPORAL_COUNT_KEYS, 0)

    def remember(self, result, left, time_s, model=None, ffc=False):
        """Keep a pair's left image and matches for the next pair (no check)."""
        left = np.asarray(left, dtype=np.float64)
        self.previous = (left, time_s, model,
                         previous_disparity_map(left.shape, result.x_left, result.y,
                                                result.disparity))
        self.previous_ffc = bool(ffc)

    def _usable(self, left, time_s, model):
        if self.previous is None:
            return False
        image, previous_time, previous_model, _ = self.previous
        age = None if previous_time is None or time_s is None else time_s - previous_time
        return image.shape == np.shape(left) and previous_model == model and \
            age is not None and 0.0 < age <= self.max_age_s

    def check(self, result, left, time_s, model=None, ffc=False):
        """
        Return ``result`` without the static matches the previous pair did not make alike.

        ``ffc``: a camera of this pair was in a flat-field correction (``pair_info``): its
        frozen frame makes every window look static, so neither this pair nor the next is
        checked (counted as ``pairs_in_ffc``).
        """
        usable = self._usable(left, time_s, model)
        previous, frozen = self.previous, bool(ffc) or self.previous_ffc
        self.remember(result, left, time_s, model, ffc)
        if not usable:
            self.counts['pairs_without_previous'] += 1
            return result
        if frozen:
            self.counts['pairs_in_ffc'] += 1
            return result
        self.counts['pairs_checked'] += 1
        image, _, _, disparity_map = previous
        static = ~changed_windows(image, left, result.x_left, result.y)
        self.counts['features_static'] += int(static.sum())
        unmatched, inconsistent = temporal_rejects(
            static, result.disparity, disparity_map[result.y, result.x_left], self.tolerance_px)
        self.counts['rejected_temporal_unmatched'] += int(unmatched.sum())
        self.counts['rejected_temporal_inconsistent'] += int(inconsistent.sum())
        return result.select(~(unmatched | inconsistent))
