"""
ST: the sub-pixel thermal stereo matcher, one entry point for a rectified pair.

``StereoMatcher(config, model).match(left, right)`` runs the three stages of the paper
(Fig. 2): phase-congruency features, rough matching on rows, POC sub-pixel refinement, then
triangulates when a stereo model is given. Every feature the pipeline drops is counted by
the stage and the reason it was dropped.
"""

import csv
import dataclasses
import functools
import io
import json
import time

import numpy as np

from st_stereo.core.config import STConfig
from st_stereo.core.depth_edges import (cool_side_features, edge_position, side_agrees,
                                        side_window_centres)
from st_stereo.core.phase_congruency import feature_strength
from st_stereo.core.point_location import structure_offsets
from st_stereo.core.rough_matching import (enforce_uniqueness, REJECTION_KEYS, rough_match,
                                           RoughMatches)
from st_stereo.core.subpixel import refine_subpixel_poc, SUBPIXEL_REJECTION_KEYS
from st_stereo.core.triangulation import triangulate

MIN_IMAGE_SIDE = 16
# Refined matches dropped after the sub-pixel stage, in this order (counts 'rejected_<key>').
PUBLISH_REJECTION_KEYS = ('range', 'confidence', 'depth_edge', 'uniqueness')


def validate_image(image, name):
    """
    Check one image of a pair and return it as float64.

    Raises
    ------
    ValueError
        Naming the image and the problem: not 2-D, too small, not numeric, or non-finite.

    """
    array = np.asarray(image)
    if array.ndim != 2:
        raise ValueError(f'{name} image: expected a 2-D array (rows, cols), got shape '
                         f'{array.shape}')
    if min(array.shape) < MIN_IMAGE_SIDE:
        raise ValueError(f'{name} image: expected at least {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE} '
                         f'pixels, got {array.shape[1]}x{array.shape[0]}')
    if array.dtype == bool or not (np.issubdtype(array.dtype, np.integer)
                                   or np.issubdtype(array.dtype, np.floating)):
        raise ValueError(f'{name} image: expected integer or float pixels, got {array.dtype}')
    array = array.astype(np.float64, copy=False)
    if not np.isfinite(array).all():
        bad = int((~np.isfinite(array)).sum())
        raise ValueError(f'{name} image: {bad} non-finite pixel(s) (NaN or inf)')
    return array


def feature_mask(moments, gamma, margin):
    """
    Features: pixels with ``M > gamma`` (paper 2.2) whose window of half-side ``margin`` fits.

    Returns
    -------
    features : ndarray of bool
    border : int
        Pixels above the threshold dropped because their window would leave the image.

    """
    above = moments > gamma
    inside = np.zeros_like(above)
    inside[margin:moments.shape[0] - margin, margin:moments.shape[1] - margin] = True
    features = above & inside
    return features, int(above.sum() - features.sum())


@dataclasses.dataclass
class MatchResult:
    """
    Matches of one rectified pair, one row per accepted match.

    Attributes
    ----------
    x_left, y : ndarray, shape (n,)
        Left pixel of each match (integer coordinates): the feature, its windows' centre.
    x_point, y_point : ndarray, shape (n,)
        Sub-pixel left pixel the match's point is triangulated from (``point_location``:
        where its window's horizontal structure lies, ``st_stereo.core.point_location``;
        the feature's pixel with ``point_location: feature``).
    disparity : ndarray, shape (n,)
        Sub-pixel disparity ``x_left - x_right`` (>= 0), pixels.
    similarity : ndarray, shape (n,)
        Lades similarity of the rough match.
    poc_peak : ndarray, shape (n,)
        Height of the POC peak (0..1).
    confidence : ndarray, shape (n,)
        Confidence of each match, 0..1 (``match_confidence``: POC peak height times the rough
        match's distinctiveness); ``min_confidence`` drops the matches below it.
    points : ndarray, shape (n, 3) or None
        X, Y, Z in metres in the left optical frame, when a stereo model was given.
    counts : dict
        Features, rough matches, matches, and every rejection by stage and reason.
    timings_ms : dict
        Wall time of each stage and the total, milliseconds.
    feature_images : ndarray, shape (2, rows, cols)
        M of the left and right image (diagnostics, overlays, evaluation).
    rough : RoughMatches
        The integer matches before sub-pixel refinement (evaluation of other refiners).

    """

    x_left: np.ndarray
    y: np.ndarray
    disparity: np.ndarray
    similarity: np.ndarray
    poc_peak: np.ndarray
    points: np.ndarray
    counts: dict
    timings_ms: dict
    image_shape: tuple
    feature_images: np.ndarray = None
    rough: RoughMatches = None
    confidence: np.ndarray = None
    x_point: np.ndarray = None
    y_point: np.ndarray = None

    def __post_init__(self):
        """Set the points' pixels to the features' own when not given; check the lengths."""
        if self.x_point is None:
            self.x_point = np.asarray(self.x_left, dtype=np.float64)
        if self.y_point is None:
            self.y_point = np.asarray(self.y, dtype=np.float64)
        lengths = {name: len(getattr(self, name)) for name in
                   ('x_left', 'y', 'x_point', 'y_point', 'disparity')}
        if len(set(lengths.values())) != 1:
            raise ValueError(f'MatchResult: per-match arrays differ in length: {lengths}')

    def __len__(self):
        """Return the number of matches."""
        return len(self.x_left)

    def select(self, keep, disparity=None, points=None):
        """
        Return the matches where ``keep`` (bool, one per match) holds; counts unchanged.

        ``disparity`` and ``points`` (all matches' new values, e.g. skew-corrected) replace the
        result's before the selection when given.
        """
        keep = np.asarray(keep, dtype=bool)
        disparity = self.disparity if disparity is None else disparity
        points = self.points if points is None else points
        fields = {name: getattr(self, name)[keep] for name in
                  ('x_left', 'y', 'x_point', 'y_point', 'similarity', 'poc_peak', 'confidence')
                  if getattr(self, name) is not None}
        return dataclasses.replace(self, disparity=disparity[keep],
                                   points=None if points is None else points[keep], **fields)

    @property
    def x_right(self):
        """Sub-pixel column of the match in the right image."""
        return self.x_left - self.disparity

    def records(self):
        """Return the matches as a list of dicts (one per match, JSON-ready)."""
        rows = []
        for i in range(len(self)):
            row = {'x_left': int(self.x_left[i]), 'y': int(self.y[i]),
                   'disparity': float(self.disparity[i]),
                   'x_right': float(self.x_right[i]),
                   'similarity': float(self.similarity[i]),
                   'poc_peak': float(self.poc_peak[i]),
                   'confidence': float(self.confidence[i]),
                   'x_point': float(self.x_point[i]), 'y_point': float(self.y_point[i])}
            if self.points is not None:
                row.update(zip(('X', 'Y', 'Z'), map(float, self.points[i])))
            rows.append(row)
        return rows

    def to_json(self):
        """Return matches, counts and timings as a JSON document."""
        return json.dumps({'image_shape': list(self.image_shape), 'counts': self.counts,
                           'timings_ms': self.timings_ms, 'matches': self.records()},
                          indent=1)

    def to_csv(self):
        """Return the matches as CSV text with a header row."""
        fields = ['x_left', 'y', 'disparity', 'x_right', 'similarity', 'poc_peak',
                  'confidence', 'x_point', 'y_point']
        if self.points is not None:
            fields += ['X', 'Y', 'Z']
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator='\n')
        writer.writeheader()
        writer.writerows(self.records())
        return buffer.getvalue()


class StereoMatcher:
    """
    The ST pipeline for rectified pairs: features, rough matching, POC, triangulation.

    Parameters
    ----------
    config : STConfig, optional
        Validated parameters (defaults: the paper's W = 9, gamma = 0.1, chi = 6).
    model : StereoModel, optional
        Rectified geometry; when given, results carry 3-D points.

    Examples
    --------
    >>> result = StereoMatcher().match(left, right)            # doctest: +SKIP
    >>> result.disparity, result.counts['matches']             # doctest: +SKIP

    """

    def __init__(self, config=None, model=None):
        self.config = STConfig() if config is None else config
        if not isinstance(self.config, STConfig):
            raise TypeError(f'config: expected STConfig, got {type(self.config).__name__}')
        self.model = model

    def feature_images(self, left, right):
        """Feature images M of a validated pair, computed in one batch, shape (2, rows, cols)."""
        return feature_strength(np.stack((left, right)), self.config)

    def disparity_bounds(self):
        """
        Admissible sub-pixel disparities ``(low, high)`` of the plausible depth range.

        With a stereo model, ``max_range_m`` and ``min_range_m`` become disparities (eq. 1,
        ``d = fx B / Z + (cx - cx_right)``); without one, only the searched range applies.
        """
        config = self.config
        if self.model is None:
            return float(config.disparity_min), float(config.disparity_max)
        low = float(self.model.disparity_of_depth(config.max_range_m))
        high = float(self.model.disparity_of_depth(config.min_range_m))
        return low, high

    def match(self, left, right, disparity_prior=None, left_valid=None, right_valid=None):
        """
        Match a rectified pair.

        Parameters
        ----------
        left, right : array_like, shape (rows, cols)
            Rectified images: raw counts (uint16, uint8) or float, same shape.
        disparity_prior : None, float or ndarray (rows, cols), optional
            Expected disparity (NaN = unknown), e.g. from the previous frame; restricts the
            search to ``prior +- prior_radius``.
        left_valid, right_valid : ndarray of bool (rows, cols), optional
            Pixels that hold image data (rectification leaves a border without any): no
            feature or candidate whose window reaches outside them, and the rest is filled
            from the nearest valid pixel before the features are computed (no invented edge).

        Returns
        -------
        MatchResult

        """
        started = time.perf_counter()
        left = validate_image(left, 'left')
        right = validate_image(right, 'right')
        if left.shape != right.shape:
            raise ValueError(f'image sizes differ: left {left.shape[1]}x{left.shape[0]}, '
                             f'right {right.shape[1]}x{right.shape[0]}')
        config = self.config
        timings = {}
        counts = {}
        margin = config.poc_window // 2
        left_inside = valid_interior(left_valid, left.shape, margin, 'left')
        right_inside = valid_interior(right_valid, left.shape, margin, 'right')
        left = fill_invalid(left, left_valid)
        right = fill_invalid(right, right_valid)

        tick = time.perf_counter()
        moments = self.feature_images(left, right)
        features, border = feature_mask(moments[0], config.gamma, margin)
        if left_inside is not None:
            counts['features_invalid_region'] = int((features & ~left_inside).sum())
            features &= left_inside
        else:
            counts['features_invalid_region'] = 0
        counts['features'] = int(features.sum())
        counts['features_border'] = border
        timings['features'] = _elapsed_ms(tick)

        tick = time.perf_counter()
        rough = rough_match(moments[0], moments[1], features, config, disparity_prior,
                            right_margin=margin, right_valid=right_inside)
        counts['rough_matches'] = len(rough)
        counts.update({f'rejected_{key}': rough.rejected[key] for key in REJECTION_KEYS})
        timings['rough_matching'] = _elapsed_ms(tick)

        tick = time.perf_counter()
        if config.poc_source == 'moments':
            poc_left, poc_right = moments[0], moments[1]
        else:
            poc_left, poc_right = left, right
        refined = refine_subpixel_poc(poc_left, poc_right, rough.y, rough.x_left,
                                      rough.disparity, config)
        counts.update({f'rejected_{key}': refined.rejected[key]
                       for key in SUBPIXEL_REJECTION_KEYS})
        counts['clamped_to_zero'] = refined.clamped_to_zero
        keep = refined.accepted.copy()
        low, high = self.disparity_bounds()
        outside = keep & ((refined.disparity < low) | (refined.disparity > high))
        counts['rejected_range'] = int(outside.sum())
        keep &= ~outside
        confidence = match_confidence(refined.peak_value, rough.distinctiveness)
        unconfident = keep & (confidence < config.min_confidence)
        counts['rejected_confidence'] = int(unconfident.sum())
        keep &= ~unconfident
        edge_tick = time.perf_counter()
        if config.depth_edge_check:
            beside_edge, unchecked = depth_edge_rejects(left, right, rough.y, rough.x_left,
                                                        refined.disparity, keep, config,
                                                        left_inside, right_inside)
            counts['rejected_depth_edge'] = int(beside_edge.sum())
            counts['depth_edge_unchecked'] = unchecked
            keep &= ~beside_edge
        else:
            counts['rejected_depth_edge'] = counts['depth_edge_unchecked'] = 0
        depth_edges_ms = _elapsed_ms(edge_tick)
        if config.uniqueness:
            unique = enforce_uniqueness(rough.y[keep], rough.x_left[keep],
                                        rough.x_left[keep] - refined.disparity[keep],
                                        rough.similarity[keep], config.uniqueness_tolerance)
            counts['rejected_uniqueness'] = int((~unique).sum())
            keep[np.flatnonzero(keep)[~unique]] = False
        else:
            counts['rejected_uniqueness'] = 0
        counts['matches'] = int(keep.sum())
        timings['subpixel'] = _elapsed_ms(tick) - depth_edges_ms
        timings['depth_edges'] = depth_edges_ms

        tick = time.perf_counter()
        x_left, y = rough.x_left[keep], rough.y[keep]
        disparity = refined.disparity[keep]
        x_point, y_point = x_left.astype(np.float64), y.astype(np.float64)
        if config.point_location == 'structure':
            dx, dy = structure_offsets(poc_left, y, x_left, config.poc_window)
            x_point, y_point = x_point + dx, y_point + dy
        points = None
        if self.model is not None:
            points = triangulate(self.model, x_point, y_point, disparity)
        timings['triangulation'] = _elapsed_ms(tick)
        timings['total'] = _elapsed_ms(started)
        return MatchResult(x_left=x_left, y=y, disparity=disparity,
                           similarity=rough.similarity[keep], poc_peak=refined.peak_value[keep],
                           points=points, counts=counts, timings_ms=timings,
                           image_shape=left.shape, feature_images=moments, rough=rough,
                           confidence=confidence[keep], x_point=x_point, y_point=y_point)


def depth_edge_rejects(left, right, y, x_left, disparity, candidates, config,
                       left_inside=None, right_inside=None):
    """
    Find the matches beside a depth edge whose own side does not carry their disparity.

    Of the ``candidates``, those on the cool side of a strong edge of the intensity image
    ``left`` (``edge_position``, ``cool_side_features``) are re-measured by POC (eqs. 10-17) on
    the intensity images with a window moved into their own side (``side_window_centres``)
    and started at their integer disparity; a match is rejected when that window fails or
    disagrees by more than ``depth_edge_tolerance`` (``st_stereo.core.depth_edges``). A side
    that cannot be measured (the right window not wholly in the image, a window reaching
    pixels without data per ``left_inside`` / ``right_inside``, a centre the image border
    pushed back) keeps its match and is counted. Returns the bool mask of rejects over all
    matches and the number unchecked.
    """
    rejects = np.zeros(len(y), dtype=bool)
    index = np.flatnonzero(candidates)
    if not len(index):
        return rejects, 0
    position, contrast, normal = edge_position(left, y[index], x_left[index])
    cool = cool_side_features(position, contrast)
    index, normal = index[cool], normal[cool]
    if not len(index):
        return rejects, 0
    half = config.poc_window // 2
    side_y, side_x, measurable = side_window_centres(y[index], x_left[index], normal,
                                                     left.shape, half)
    start = np.rint(disparity[index]).astype(int)
    side_x_right = side_x - start
    measurable &= side_x_right >= half
    if left_inside is not None:
        measurable &= left_inside[side_y, side_x]
    if right_inside is not None:
        measurable &= right_inside[side_y, np.clip(side_x_right, 0, left.shape[1] - 1)]
    index = index[measurable]
    side = refine_subpixel_poc(left, right, side_y[measurable], side_x[measurable],
                               start[measurable], config)
    rejects[index[~side_agrees(side, disparity[index], config.depth_edge_tolerance)]] = True
    return rejects, int((~measurable).sum())


DISTINCTIVENESS_SCALE = 0.1


def match_confidence(poc_peak, distinctiveness, scale=DISTINCTIVENESS_SCALE):
    """
    Confidence of matches, 0..1: POC peak height times the rough match's distinctiveness.

    ``clip(peak, 0, 1) * clip(distinctiveness / scale, 0, 1)``: the sub-pixel peak (eq. 11's
    maximum, how well one shift explains the windows) and how much the Lades similarity
    (eq. 9) of the rough match beats the best candidate more than 1 px away. Measured on the
    recording (docs/results.md): keeping the 90 % most confident matches cuts the 3-D outliers
    from 5.4 to 2.3 %, better than either factor alone (3.7 % by the peak, 2.5 % by the
    distinctiveness); the Lades similarity itself and a support-weighted POC re-check did not
    separate the outliers.
    """
    peak = np.clip(np.asarray(poc_peak, dtype=np.float64), 0.0, 1.0)
    distinct = np.clip(np.asarray(distinctiveness, dtype=np.float64) / scale, 0.0, 1.0)
    return peak * distinct


def valid_interior(valid, shape, margin, name):
    """Pixels whose ``2 margin + 1`` window lies inside the valid region (None: all)."""
    if valid is None:
        return None
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != shape:
        raise ValueError(f'{name} valid mask: expected shape {shape}, got {valid.shape}')
    if valid.all():
        # Every window inside: the same as no mask, without the erosion (0.28 ms per image
        # at 80x60, which a node paid twice per pair for a rig's all-valid rectification).
        return None
    from scipy import ndimage
    return ndimage.binary_erosion(valid, np.ones((2 * margin + 1,) * 2, dtype=bool),
                                  border_value=1)


def fill_invalid(image, valid):
    """
    Copy of ``image`` with invalid pixels set to their nearest valid pixel's value.

    The nearest pixels of a mask are computed once and kept (``_nearest_valid``): a rig's
    mask is the same for every pair of a calibration, and each pair fills up to four images.
    """
    if valid is None:
        return image
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != np.shape(image):
        raise ValueError(f'valid mask: expected the shape of the image, {np.shape(image)}, got '
                         f'{valid.shape}')
    if valid.all() or not valid.any():
        return image
    rows, cols = _nearest_valid(np.packbits(valid).tobytes(), valid.shape)
    return np.asarray(image)[rows, cols]


@functools.lru_cache(maxsize=8)
def _nearest_valid(packed_mask, shape):
    from scipy import ndimage
    valid = np.unpackbits(np.frombuffer(packed_mask, dtype=np.uint8),
                          count=shape[0] * shape[1]).reshape(shape).astype(bool)
    _, (rows, cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
    rows.setflags(write=False)
    cols.setflags(write=False)
    return rows, cols


def _elapsed_ms(start):
    return (time.perf_counter() - start) * 1e3
