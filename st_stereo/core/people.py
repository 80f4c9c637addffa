"""
People on the floor from the matcher's 3-D points: detection and tracking (no ROS).

The stages, each a pure function or a small state machine fed one pair at a time:

1. ``rectified_to_world``: the points of ``points2`` (rectified left optical frame) into the
   room (``world_frame``, floor at z = 0, z up) with the rig pose (``core.rig_pose``) and the
   left camera's rectification R1: ``p_world = R_world_rig R_rig_optical R1^T p + t``.
2. ``WarmBackground``: which points are warmer than the static room behind them. A per-pixel
   background of the rectified left image, learned only where nothing warm stands, compared
   after removing the frame's global offset (the median difference to the background), so a
   flat-field correction's jump or the sensor's slow drift does not light the whole image up.
3. ``detect_people``: the points between two heights above the floor, projected onto the
   floor, smoothed into an occupancy map; each local maximum with enough points is a person.
   Its floor position is the median of its upper-body points pushed back by the body's
   half-depth (the camera sees the side facing it), its head height the top of its points
   less the head's half-height, its position covariance the spread of those points over their
   number plus the depth uncertainty of a point along the horizontal viewing direction
   (``sigma_Z = Z sigma_d / d``: from ``Z = f B / d``, ``dZ / dd = -Z / d``).
   A body cut by the image's top edge (far off, the head above the image) looks like a warm
   screen on a desk; ``legs_fraction`` tells them apart by what stands below it: warm legs
   at the body's depth (matched points on them) or a cool desk. Farther still only the legs
   show: a second pass over the lower points finds them where they reach the top edge
   (``far_legs_min_height_m``), and ``warm_run_width_m`` tells legs from a radiator.
   Matches on a warm body lie on its outlines, often more on one side: once the legs are
   tested, ``centred_on_silhouette`` measures each detection's shift across the view to
   the middle of its warm silhouette (``centre_on_silhouette``); a published track's
   ``position`` adds it (the points give the depth).
4. ``PeopleTracker``: constant-velocity Kalman filter per person on the floor, detections
   assigned by ``scipy.optimize.linear_sum_assignment`` on the distance within a gate
   (leaving a track out costs the largest gate, ``gated_assignment``), ids that
   never repeat, a track confirmed after ``min_hits`` detections (or at once when its first
   stands on warm legs with its head high enough, ``confirm_on_legs``), kept without
   detections for ``max_coast_s`` (short occlusions) and then ended; one not confirmed yet
   ends after ``unconfirmed_coast_s`` without detections. Its head height is the median of
   its last ``head_height_pairs`` detections seen whole; a detection cut by the image's edge,
   or whose warm column above its points reaches the top row (``warm_column_reaches_top``:
   the head in the top rows, where no 9-pixel window fits), only raises it (a lower bound).
"""

import dataclasses
import math

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from st_stereo.core.config import parse_bool
from st_stereo.core.rig_pose import rig_to_optical_rotation, rotation_z
from st_stereo.core.silhouette_stereo import EIGHT_CONNECTED, right_to_left_agrees, \
    silhouette_disparity, top_silhouettes


def _field(default, description):
    return dataclasses.field(default=default, metadata={'description': description})


@dataclasses.dataclass(frozen=True)
class PeopleConfig:
    """Parameters of people detection and tracking (see the module docstring)."""

    min_point_height_m: float = _field(
        0.6, 'points lower than this above the floor are not used (floor, chairs, desks), m')
    far_legs_min_height_m: float = _field(
        0.15, 'a body so far off that only its legs show (the image top edge 0.5-1 m above '
        'the floor there: 5.1-6.5 m away for a rig 2.9 m high looking 40 deg down): warm '
        'points from this height up to min_point_height_m, away from every other detection, '
        'make a detection when their warm region reaches the top row; it must stand on its '
        'legs, no wider than far_legs_max_width_m, to start a track (without them it may only '
        'continue a published one: legs_only_not_started); 0: off (needs the image, the '
        'camera matrix and legs_min_fraction > 0), m')
    far_legs_max_width_m: float = _field(
        0.7, 'such a legs-only body is a person only if the warm run across its legs rows is '
        'no wider than this and does not run off the image side (a radiator), m')
    max_point_height_m: float = _field(
        2.3, 'points higher than this above the floor are not used (walls, lamps), m')
    min_head_height_m: float = _field(
        1.0, 'a cluster whose head is lower is not a person (a sitting head is about 1.1 m), m')
    person_radius_m: float = _field(
        0.3, 'radius of one person on the floor: two people closer than it are one, m')
    cell_m: float = _field(
        0.05, 'cell of the floor occupancy map, m')
    min_points: int = _field(
        8, 'fewest points of one person')
    min_confidence: float = _field(
        0.0, 'points with a lower match confidence (points2 field confidence) are not used')
    require_warm: bool = _field(
        True, 'use only points warmer than the learned thermal background (needs left/image_rect)')
    warm_margin_counts: float = _field(
        100.0, 'warmer than the background by at least this, raw counts (the simulator: '
        '35 counts per kelvin)')
    background_time_s: float = _field(
        20.0, 'time constant of the background where nothing warm is, s')
    absorb_time_s: float = _field(
        300.0, 'time constant of the background where something warm is (a static warm '
        'object fades in), s')
    edge_px: float = _field(
        10.0, 'points this near the image top or a side edge mean the body is cut by it, pixels')
    head_offset_m: float = _field(
        0.0, 'the top of the points (95th percentile) minus this is the head centre height, m')
    head_height_pairs: int = _field(
        5, "a track's head height is the median of its last this many detections seen whole "
        "(one whose head found no matches does not pull it down); one cut by the image's "
        "edge raises it to its points' top for this many pairs (1: the last one)")
    body_half_depth_m: float = _field(
        0.0, 'a whole body: its floor position is pushed this far back from the camera, m')
    cut_body_offset_m: float = _field(
        0.1, 'a body cut by the top edge (what is seen is its front): pushed this far back, m')
    centre_on_silhouette: bool = _field(
        True, "a person's published position across the view is the middle of its warm "
        'silhouette (per image row, the warm run holding its points), not the median of its '
        'points, which lie mostly on one outline; tracking uses the points (needs the image '
        'and camera matrix)')
    silhouette_margin_counts: float = _field(
        40.0, 'a body rising out of the image top edge that no detection of points covers '
        '(far off, starved of matches) is placed by its warm silhouette: the pixels warmer than '
        'the background by this, connected to warm ones (warm_margin_counts), make its shape, '
        'and the disparity of the whole shape (correlated with the right image) its depth; '
        'such a detection is cut by the top edge without legs: a new track needs '
        'min_travel_m or steady_walk_m to be published; the pixels of a published one are not '
        "learned into the background; corrected for the cameras' skew with pair_info (needs "
        'right/image_rect and right/camera_info); 0: off, raw counts')
    silhouette_min_correlation: float = _field(
        0.5, "a silhouette's disparity is used only when its correlation (ZNCC, -1..1) with "
        'the right image is at least this, and its shift since the previous left image (for the '
        'skew) only when that one is')
    disparity_sigma_px: float = _field(
        0.15, 'disparity uncertainty of one point, for the position covariance, pixels')
    gate_m: float = _field(
        0.8, "farthest a detection may be from a track's prediction (plus 3 sigma of it), m")
    max_coast_s: float = _field(
        1.5, 'a track without detections (and not held beside a neighbour, '
        'hold_beside_points) ends after this, s')
    publish_coast_s: float = _field(
        0.3, 'a track without detections (and not held beside a neighbour) is published for '
        'this long (kept to max_coast_s), s')
    unconfirmed_coast_s: float = _field(
        0.3, 'a track not yet published ends after this long without detections (its gate '
        'grows while it coasts: it would take a stray detection metres away), s')
    min_hits: int = _field(
        2, 'detections before a track is published')
    confirm_on_legs: bool = _field(
        True, 'a new track is published at its first detection, not after min_hits, when that '
        'one is not cut by the top edge, its head is high enough and it stands on warm legs '
        'at its depth as a body cut by the top edge must (legs_min_fraction, legs_max_gap_m), '
        'and no track is within gate_m of it')
    min_travel_m: float = _field(
        1.0, 'a track never seen as a person by itself (only cut by the top edge, its legs not '
        'seen: like a warm screen) is published only after moving this far, m')
    steady_walk_m: float = _field(
        0.4, 'or once its last 5 detections, of consecutive pairs, walk steadily this far: '
        "every step forward at half the walk's pace or more and none longer than twice it, "
        "the path at most 1.5 times the line (a warm object's detections stay in place and "
        'jump between its pieces); not a track with object_min_hits detections when the walk '
        'began within object_radius_m of its start; renews a published track as legs do '
        '(legs_lapse_s); 0: off, m')
    legs_lapse_s: float = _field(
        5.0, 'a published track on thin evidence (not min_travel_m from its start in min_hits '
        'detections, legs or head seen in under 30 % of its detections) that has shown '
        'neither legs in min_hits of min_hits + 1 detections nor its head (whole) for this '
        'long since its publication is withdrawn (its id ends; the track goes on '
        'unpublished): a warm screen lent legs by passers-by is not a person for good; so is '
        'one standing still (within object_radius_m) on silhouettes alone '
        '(silhouette_margin_counts, no detection of points) for this long (a person missed as '
        'a warm screen showed beside them); 0: never, s')
    legs_min_fraction: float = _field(
        0.5, 'a body cut by the top edge is a person standing on the floor (not a warm object '
        'on a desk) when at least this fraction of the image rows of its legs (0.1-0.5 m above '
        'the floor at its position) hold warm pixels with matches at their depth, in min_hits '
        'of its last min_hits + 1 detections; 0: never (and no legs-only body, '
        'far_legs_min_height_m) (needs the camera matrix)')
    legs_depth_tolerance_m: float = _field(
        0.4, 'a row of those legs shows them only if matched points on its warm pixels lie '
        'within this of the depth of the legs (median; else something in front or behind), m')
    legs_max_gap_m: float = _field(
        0.25, 'and the warm column at it from 0.1 to 0.8 m has no cool stretch longer than '
        'this (a warm computer under a desk with a screen on it: knee space and desk top), m')
    object_min_hits: int = _field(
        5, 'an unpublished track detected this many times, never seen as a person and never '
        'farther than object_radius_m from where it started is a warm object (a screen): a '
        'detection cut by the top edge without legs within person_radius_m of where it has '
        'been, and nearer to that than to the prediction of a published track, is not given to '
        'that track (which coasts instead); 0: off')
    object_radius_m: float = _field(
        0.6, 'how far the detections of one warm object may spread (a screen cut by the top '
        'edge makes one or two detections up to 0.5 m apart), m')
    reacquire_cut_s: float = _field(
        0.35, 'a body cut by the top edge continues a track only if it was seen this recently, s')
    max_range_m: float = _field(
        15.0, 'points farther than this from the camera, horizontally, are not used (a '
        'near-zero disparity puts a point kilometres away), m')
    hold_beside_points: int = _field(
        8, 'a published track whose head has been seen (10 whole detections), at rest '
        '(under 0.3 m/s) at its last detection, without a detection now, is held there while a '
        "published neighbour's detection lies within twice person_radius_m of it and at least "
        'this many warm body points lie within person_radius_m / 2 of it (its points joined the '
        "neighbour's cluster: two people closer than about 0.6 m make one); 0: off")
    acceleration_sigma: float = _field(
        2.0, 'process noise of the constant-velocity filter, m/s^2')

    def __post_init__(self):
        for name, zero in (('legs_lapse_s', 'never'), ('steady_walk_m', 'off'),
                           ('silhouette_margin_counts', 'off')):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not (math.isfinite(value) and value >= 0):
                raise ValueError(f'people.{name}: expected a number >= 0 (0: {zero}), got '
                                 f'{value!r}')
        positive = ('person_radius_m', 'cell_m', 'background_time_s', 'absorb_time_s',
                    'disparity_sigma_px', 'gate_m', 'max_coast_s', 'acceleration_sigma',
                    'max_range_m', 'object_radius_m')
        for name in ('publish_coast_s', 'unconfirmed_coast_s'):
            if not 0.0 <= getattr(self, name) <= self.max_coast_s:
                raise ValueError(f'people.{name}: expected 0 .. max_coast_s '
                                 f'({self.max_coast_s!r}), got {getattr(self, name)!r}')
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'people.{name}: expected a number > 0, got {value!r}')
        if not 0.0 <= self.min_point_height_m < self.max_point_height_m:
            raise ValueError(f'people.min_point_height_m, max_point_height_m: expected 0 <= min '
                             f'< max, got {self.min_point_height_m!r}, '
                             f'{self.max_point_height_m!r}')
        for name in ('min_points', 'min_hits', 'head_height_pairs'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f'people.{name}: expected an integer >= 1, got {value!r}')
        if isinstance(self.object_min_hits, bool) or \
                not isinstance(self.object_min_hits, int) or self.object_min_hits < 0:
            raise ValueError(f'people.object_min_hits: expected an integer >= 0 (0: off), got '
                             f'{self.object_min_hits!r}')
        if isinstance(self.hold_beside_points, bool) or \
                not isinstance(self.hold_beside_points, (int, np.integer)) or \
                self.hold_beside_points < 0:
            raise ValueError(f'people.hold_beside_points: expected an integer >= 0 (0: off), '
                             f'got {self.hold_beside_points!r}')
        if not 0.0 <= self.legs_min_fraction <= 1.0:
            raise ValueError(f'people.legs_min_fraction: expected 0..1, got '
                             f'{self.legs_min_fraction!r}')
        if not (math.isfinite(self.far_legs_min_height_m) and
                (self.far_legs_min_height_m == 0.0 or
                 0.0 < self.far_legs_min_height_m < self.min_point_height_m)):
            raise ValueError(f'people.far_legs_min_height_m: expected 0 (off) or a value below '
                             f'min_point_height_m ({self.min_point_height_m!r}), got '
                             f'{self.far_legs_min_height_m!r}')
        for field in dataclasses.fields(self):
            if field.type in (bool, 'bool') and \
                    not isinstance(getattr(self, field.name), (bool, np.bool_)):
                raise ValueError(f'people.{field.name}: expected true or false, got '
                                 f'{getattr(self, field.name)!r}')
        for name in ('legs_depth_tolerance_m', 'legs_max_gap_m', 'far_legs_max_width_m'):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f'people.{name}: expected a number > 0, got '
                                 f'{getattr(self, name)!r}')
        if not -1.0 <= self.silhouette_min_correlation <= 1.0:
            raise ValueError(f'people.silhouette_min_correlation: expected -1..1, got '
                             f'{self.silhouette_min_correlation!r}')
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f'people.min_confidence: expected 0..1, got {self.min_confidence!r}')
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.type in (float, 'float') and isinstance(value, (int, float)) and \
                    not isinstance(value, bool) and not math.isfinite(value):
                raise ValueError(f'people.{field.name}: expected a finite number, got '
                                 f'{value!r}')
        for name in ('warm_margin_counts', 'edge_px', 'min_head_height_m', 'min_travel_m',
                     'reacquire_cut_s'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
                raise ValueError(f'people.{name}: expected a number >= 0, got {value!r}')

    def to_dict(self):
        """Return the fields as a dict."""
        return dataclasses.asdict(self)


def people_config_from_assignments(assignments):
    """Build a PeopleConfig from ``NAME=VALUE`` strings (``st-stereo eval people --people``)."""
    kinds = {name: kind for name, kind, _, _ in people_fields()}
    values = {}
    for assignment in assignments or ():
        name, sep, text = assignment.partition('=')
        if not sep or name not in kinds:
            raise ValueError(f'--people: expected NAME=VALUE with NAME one of '
                             f'{", ".join(kinds)}; got {assignment!r}')
        kind = kinds[name]
        try:
            values[name] = parse_bool(text) if kind is bool else kind(text)
        except ValueError:
            raise ValueError(f'--people {name}: expected a {kind.__name__}, got {text!r}') \
                from None
    return PeopleConfig(**values)


def people_fields():
    """Yield ``(name, type, default, description)`` of every PeopleConfig field."""
    for field in dataclasses.fields(PeopleConfig):
        yield field.name, type(field.default), field.default, field.metadata['description']


def world_from_rectified(pose, rectification):
    """
    Return ``(R, t)`` with ``p_world = R p + t`` for points in the rectified left frame.

    ``pose``: RigPose; ``rectification``: the left camera's R1 (camera_info ``R``), which turns
    a raw optical direction into the rectified one (``v_rect = R1 v_raw``).
    """
    r1 = np.asarray(rectification, dtype=np.float64).reshape(3, 3)
    world_rig = rotation_z(math.radians(pose.yaw_deg))
    rotation = world_rig @ rig_to_optical_rotation(pose) @ r1.T
    return rotation, np.array([pose.x_m, pose.y_m, pose.height_m])


def rectified_to_world(points, transform):
    """Points (n, 3) of the rectified left frame into the world frame of ``transform``."""
    rotation, translation = transform
    return np.asarray(points, dtype=np.float64).reshape(-1, 3) @ rotation.T + translation


def camera_centre_in_world(transform):
    """Return the left camera's optical centre in the world (the ``t`` of the transform)."""
    return np.asarray(transform[1], dtype=np.float64)


@dataclasses.dataclass(frozen=True)
class Detection:
    """
    One person in one pair: floor position, head height, evidence and uncertainty.

    ``head_visible`` False: the body is cut by the image's edge (the head may be outside it,
    ``head_height`` then only a lower bound). ``cut_top``: cut by the top edge (far off, what
    is seen is the front of the body below the head, as of a warm screen). ``legs_seen``: cut
    by the top edge and standing on the floor, its legs warm in the image (``legs_fraction``),
    so a person by itself, not a warm object on a desk. ``depth_spread_m``:
    the standard deviation of the points' camera depth Z (the paper's measure of a matcher on
    a standing person).
    """

    x: float
    y: float
    head_height: float
    points: int
    confidence: float
    covariance: np.ndarray        # 2x2, floor position, m^2
    head_visible: bool = True
    cut_top: bool = False
    depth_spread_m: float = 0.0
    members: np.ndarray = None    # indices of its points in the points given to detect_people
    legs_seen: bool = False
    legs_under_head: bool = False  # not cut by the top edge, head high enough, on legs
    legs_only: bool = False       # cut by the top edge so far off that only its legs show
    head_above: bool = False      # whole, but warm up to the top row above its points
    across: tuple = (0.0, 0.0)    # floor shift to its silhouette's middle (published only)
    silhouette: bool = False      # placed by its warm silhouette's disparity, not its points
    shape_pixels: np.ndarray = None   # that silhouette's pixels (flat indices of the image)


class WarmBackground:
    """
    Per-pixel background of the rectified left image and the warm foreground against it.

    The background starts as the first image's median everywhere (an empty room at one
    temperature), so a person standing still from the first pair is foreground. Pixels that are
    not warm follow the scene with the time constant ``background_time_s`` (a running mean over
    the first pairs); warm pixels only with ``absorb_time_s`` (a radiator, a screen or a
    long-parked person fades into the background after minutes, a sitting one does not). Before
    comparing, the image's median difference to the background (a flat-field correction's
    offset jump, the sensor's drift) is removed.
    """

    def __init__(self, config=None):
        self.config = config or PeopleConfig()
        self.background = None
        self.valid = None            # the last image's pixels with data
        self.difference = None       # the last image less the background and its offset
        self.stamp_s = None
        self.frames = 0

    def update(self, image, stamp_s, protect=None, hold=None):
        """
        Return the warm mask of ``image`` (bool, the image's shape) and learn from it.

        ``protect``: pixels (bool mask) where a published person stands; warm ones there are
        not learned at all, so a person seated for longer than ``absorb_time_s`` stays
        foreground. ``hold``: pixels not learned at all, warm or not (a published silhouette's:
        most of its pixels are under the warm margin). Pixels that are 0 (no data after
        rectification) or not finite are never warm and never learned.
        """
        image = np.asarray(image, dtype=np.float64)
        valid = np.isfinite(image) & (image > 0)
        self.valid = valid
        if self.background is None or self.background.shape != image.shape:
            level = float(np.median(image[valid])) if valid.any() else 0.0
            self.background = np.full(image.shape, level)
            self.stamp_s, self.frames = stamp_s, 0
        offset = float(np.median((image - self.background)[valid])) if valid.any() else 0.0
        difference = np.where(valid, image - self.background - offset, 0.0)
        warm = valid & (difference > self.config.warm_margin_counts)
        self.difference = difference
        dt = max(0.0, stamp_s - self.stamp_s)
        self.frames += 1
        cool_rate = max(1.0 / self.frames, 1.0 - math.exp(-dt / self.config.background_time_s))
        warm_rate = 1.0 - math.exp(-dt / self.config.absorb_time_s)
        rate = np.where(warm, warm_rate, cool_rate) * valid
        if protect is not None and np.shape(protect) == image.shape:
            rate[warm & protect] = 0.0
        if hold is not None and np.shape(hold) == image.shape:
            rate[hold] = 0.0
        self.background = self.background + offset + rate * difference
        self.stamp_s = stamp_s
        return warm


def pixel_indices(shape, x_left, y):
    """Return rounded (rows, cols) of pixels and whether each is inside ``shape``."""
    x = np.asarray(x_left, dtype=np.float64).reshape(-1)
    v = np.asarray(y, dtype=np.float64).reshape(-1)
    inside = np.isfinite(x) & np.isfinite(v)
    cols = np.rint(np.where(inside, x, -1.0)).astype(int)
    rows = np.rint(np.where(inside, v, -1.0)).astype(int)
    inside &= (cols >= 0) & (cols < shape[1]) & (rows >= 0) & (rows < shape[0])
    return np.where(inside, rows, 0), np.where(inside, cols, 0), inside


def warm_points(mask, x_left, y):
    """
    Whether each point's left pixel (rounded ``x_left``, ``y``) is in the warm ``mask``.

    The mask is dilated by one pixel (a match on a person's outline); a pixel outside the
    image or not finite is not warm.
    """
    rows, cols, inside = pixel_indices(mask.shape, x_left, y)
    dilated = ndimage.binary_dilation(mask, iterations=1)
    return dilated[rows, cols] & inside


def project_to_pixels(points, fx, fy, cx, cy):
    """Left pixel (x, y) of points (n, 3) in the rectified left frame."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z = np.where(points[:, 2] > 0, points[:, 2], np.nan)
    return fx * points[:, 0] / z + cx, fy * points[:, 1] / z + cy


LEGS_HEIGHTS_M = (0.1, 0.5)      # the legs' segment above the floor that legs_fraction looks at
COLUMN_HEIGHTS_M = (0.1, 0.8)    # the column warm_column_gap_m looks at: legs up past a desk


def vertical_segment_rows(floor_xy, heights_m, transform, intrinsics, shape, half_width_m):
    """
    Image rows a vertical segment above the floor crosses, each with its window and depth.

    The points ``heights_m`` above the floor at ``floor_xy`` (world frame) go into the
    rectified left frame (``p = R^T (p_world - t)``, the inverse of ``transform``) and onto
    the image (``u = fx X / Z + cx``, ``v = fy Y / Z + cy``). Returns, in order of height,
    ``(samples, row, low, high, depth)`` per distinct row inside the image of ``shape``: how
    many of the heights fall on it, the columns within ``half_width_m`` of the segment at its
    depth ``Z``. Points behind the camera, and rows whose window lies wholly off the image's
    side (a column leans outwards and leaves it before its foot), are left out.
    """
    rotation, translation = transform
    fx, fy, cx, cy = intrinsics
    heights = np.asarray(heights_m, dtype=np.float64)
    world = np.column_stack([np.full(len(heights), floor_xy[0]),
                             np.full(len(heights), floor_xy[1]), heights])
    camera = (world - translation) @ rotation
    ahead = camera[:, 2] > 0
    heights, camera = heights[ahead], camera[ahead]
    rows = np.rint(fy * camera[:, 1] / camera[:, 2] + cy).astype(int)
    out = []
    for row in dict.fromkeys(rows.tolist()):
        if not 0 <= row < shape[0]:
            continue
        at = camera[rows == row].mean(axis=0)
        u = fx * at[0] / at[2] + cx
        half = half_width_m * fx / at[2]
        low, high = max(0, math.ceil(u - half)), min(shape[1] - 1, math.floor(u + half))
        if low <= high:
            out.append((int(np.count_nonzero(rows == row)), row, low, high, float(at[2])))
    return out


def in_window(rows, cols, row, low, high):
    """Whether each pixel (``rows``, ``cols``) is within one row of ``row``, in ``low..high``."""
    return (np.abs(rows - row) <= 1) & (cols >= low) & (cols <= high)


def legs_fraction(warm, floor_xy, transform, intrinsics, points, pixels, config=None):
    """
    Fraction of the image rows of a standing body's legs that show warm legs at their depth.

    The segment ``LEGS_HEIGHTS_M`` above the floor at ``floor_xy`` goes onto the image
    (``vertical_segment_rows``). A row it crosses shows legs when a pixel of ``warm`` lies
    within ``person_radius_m / 2`` of the segment (horizontally, at the segment's depth: two
    legs, or a position a little off) and the matched ``points`` (rectified left frame,
    n x 3, at left ``pixels`` n x 2) on warm pixels of that window, within one row of it,
    exist and lie within ``legs_depth_tolerance_m`` of the segment's depth (their median).
    Warm pixels without a matched point there are no evidence: a nearer warm body (a person
    seated in front of a screen) covers the rows under a far object as well as legs would.
    A warm object on a desk has the cool desk below it; a person cut by the image's top edge
    stands on warm legs.

    Returns NaN when no row of the segment is in the image (or it is behind the camera).
    """
    config = config or PeopleConfig()
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    point_rows, point_cols, inside = pixel_indices(warm.shape, pixels[:, 0], pixels[:, 1])
    on_warm = inside & warm[point_rows, point_cols]
    segment = vertical_segment_rows(floor_xy, np.linspace(*LEGS_HEIGHTS_M, 17), transform,
                                    intrinsics, warm.shape, config.person_radius_m / 2)
    shown = 0
    for _, row, low, high, depth in segment:
        if not warm[row, low:high + 1].any():
            continue
        here = on_warm & in_window(point_rows, point_cols, row, low, high)
        if here.any() and \
                abs(np.median(points[here, 2]) - depth) <= config.legs_depth_tolerance_m:
            shown += 1
    return shown / len(segment) if segment else float('nan')


def warm_column_gap_m(warm, floor_xy, transform, intrinsics, points, pixels, config=None):
    """
    Longest cool stretch, in metres of height, of the column ``COLUMN_HEIGHTS_M`` at a body.

    A standing person is warm from the feet up (legs, hips); a warm computer on the floor
    under a warm screen is two warm pieces with the knee space and the desk top between
    them, cool for 0.3 m. The column is sampled every 12.5 mm; a sample is warm when
    ``warm`` holds a pixel within ``person_radius_m / 2`` of it on its row
    (``vertical_segment_rows``). A cool row whose window holds a matched point (``points``,
    n x 3 in the rectified left frame, at ``pixels``, within one row) nearer than the column
    by more than ``legs_depth_tolerance_m`` is unknown, neither cool nor warm: something cool
    in front of the body (a chair's back, a cart) hides it there. Closer than that (a box
    carried against the body) it cannot be told from a desk top in front of a knee space,
    and is a gap. The gap is the longest run of cool samples in view times the step. NaN
    without a row in view.
    """
    config = config or PeopleConfig()
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    point_rows, point_cols, inside = pixel_indices(warm.shape, pixels[:, 0], pixels[:, 1])
    heights = np.arange(COLUMN_HEIGHTS_M[0], COLUMN_HEIGHTS_M[1] + 1e-9, 0.0125)
    segment = vertical_segment_rows(floor_xy, heights, transform, intrinsics, warm.shape,
                                    config.person_radius_m / 2)
    if not segment:
        return float('nan')
    run = longest = 0
    for samples, row, low, high, depth in segment:
        if warm[row, low:high + 1].any():
            run = 0
            continue
        here = inside & in_window(point_rows, point_cols, row, low, high)
        if (points[here, 2] < depth - config.legs_depth_tolerance_m).any():
            continue                    # hidden behind something nearer: not evidence
        run += samples
        longest = max(longest, run)
    return longest * 0.0125


def warm_run_width_m(warm, floor_xy, transform, intrinsics, config=None):
    """
    Width of the warm run across a standing body's legs rows, metres (median over the rows).

    On each image row of the legs' segment (``LEGS_HEIGHTS_M`` at ``floor_xy``,
    ``vertical_segment_rows``) the warm pixel of the segment's window nearest its middle
    is followed left and right while ``warm`` holds; its length in pixels times the row's
    depth over ``fx`` is the width there. Two legs blurred together are about 0.3-0.5 m; a
    radiator or a warm cabinet is as wide as it is. NaN when no row of the window holds a
    warm pixel (or the segment is off the image), and when a run reaches the image's side:
    what lies beyond it is not seen, so the width is not known (a wide radiator running off
    the image measures as narrow as legs).
    """
    config = config or PeopleConfig()
    fx = intrinsics[0]
    widths = []
    for _, row, low, high, depth in vertical_segment_rows(
            floor_xy, np.linspace(*LEGS_HEIGHTS_M, 9), transform, intrinsics, warm.shape,
            config.person_radius_m / 2):
        run = central_warm_run(warm[row], low, high, 0.5 * (low + high))
        if run is None:
            continue
        start, end = run
        if start == 0 or end == warm.shape[1] - 1:
            return float('nan')
        widths.append((end - start + 1) * depth / fx)
    return float(np.median(widths)) if widths else float('nan')


SILHOUETTE_MAX_WIDTH_M = 0.6   # wider than shoulders (0.5 m) and a pixel of blur each side
SILHOUETTE_MIN_ROWS = 2         # one usable row (a body at the image's side) moves nothing
SILHOUETTE_MIN_USABLE = 0.5     # of the rows holding its points (else joined to a neighbour)
SILHOUETTE_MAX_SLANT = 1.0      # |du/dv| of a vertical's image: steeper views cross bodies aslant


def vertical_line_columns(floor_xy, rows, transform, intrinsics):
    """
    Column at each image row of the image of the vertical line at ``floor_xy`` (world).

    Two of its points (0 and 2 m high) go into the rectified left frame and onto the image;
    every point of the vertical plane through them and the camera centre lies on the same
    image line, so a position pushed along the horizontal viewing direction keeps its
    column at a given row. Returns the columns and the line's slant ``du/dv``; NaN when
    either point is behind the camera or the line is horizontal in the image.
    """
    rotation, translation = transform
    fx, fy, cx, cy = intrinsics
    rows = np.asarray(rows, dtype=np.float64)
    world = np.array([[floor_xy[0], floor_xy[1], 0.0], [floor_xy[0], floor_xy[1], 2.0]])
    camera = (world - translation) @ rotation
    if not (camera[:, 2] > 0).all():
        return np.full(rows.shape, np.nan), float('nan')
    u = fx * camera[:, 0] / camera[:, 2] + cx
    v = fy * camera[:, 1] / camera[:, 2] + cy
    if abs(v[1] - v[0]) < 1e-9:
        return np.full(rows.shape, np.nan), float('nan')
    slant = float((u[1] - u[0]) / (v[1] - v[0]))
    return u[0] + (rows - v[0]) * slant, slant


def warm_run(line, start, end, bridge=True):
    """
    Return the warm run of the row ``line`` (bool) holding ``start..end``: its first and last.

    From ``start`` left and from ``end`` right while the next pixel is warm, or, with
    ``bridge``, cool with a warm one after it (an arm or a leg one pixel apart from the body
    is the body's).
    """
    width = len(line)
    while start > 0 and (line[start - 1] or (bridge and start > 1 and line[start - 2])):
        start -= 1 if line[start - 1] else 2
    while end < width - 1 and (line[end + 1] or (bridge and end < width - 2 and line[end + 2])):
        end += 1 if line[end + 1] else 2
    return start, end


def central_warm_run(line, low, high, middle):
    """
    Return the warm run (first, last) of ``line`` through its warm pixel nearest ``middle``.

    Only the pixels ``low..high`` are candidates; no gap is bridged; None when none is warm.
    """
    hot = np.flatnonzero(line[low:high + 1]) + low
    if not len(hot):
        return None
    nearest = int(hot[np.argmin(np.abs(hot - middle))])
    return warm_run(line, nearest, nearest, bridge=False)


def _median(values):
    """Return ``np.median`` of a short 1-D array, bit for bit, without its per-call cost."""
    ordered = np.sort(values)
    count = len(ordered)
    return float(0.5 * (ordered[(count - 1) // 2] + ordered[count // 2]))


def silhouette_runs(warm, detection, intrinsics, points, pixels, valid=None):
    """
    Return the warm runs across a detection's body and the rows that hold its points.

    ``({row: (start, end, depth)}, rows)``: ``rows`` counts every row holding the
    detection's points on warm pixels, the runs only those usable.

    On each image row holding the detection's points on warm pixels (``members`` of
    ``points``, rectified left frame n x 3, at left ``pixels`` n x 2) the warm run spanning
    them (``warm_run``); ``depth`` is the median Z of those points. Rows whose run reaches
    the image's side or a pixel without data (``valid`` False: the rectification's invalid
    border; the width beyond it is not seen) or is wider than ``SILHOUETTE_MAX_WIDTH_M`` at
    that depth (two people side by side, a person before a warm object) are left out.
    """
    members = np.asarray(detection.members if detection.members is not None else [], int)
    if not len(members):
        return {}, 0
    rows, cols, inside = pixel_indices(warm.shape, pixels[members, 0], pixels[members, 1])
    on = inside & warm[rows, cols]
    fx, width = intrinsics[0], warm.shape[1]
    held = np.flatnonzero(on)
    held = held[np.argsort(rows[held], kind='stable')]
    groups = np.split(held, np.flatnonzero(np.diff(rows[held])) + 1) if len(held) else []
    runs = {}
    for here in groups:                 # the points on one row, per row in order
        row, columns = int(rows[here[0]]), cols[here].tolist()
        start, end = warm_run(warm[row], min(columns), max(columns))
        if start == 0 or end == width - 1 or \
                (valid is not None and not (valid[row, start - 1] and valid[row, end + 1])):
            continue
        depth = _median(points[members[here], 2])
        if (end - start + 1) * depth / fx <= SILHOUETTE_MAX_WIDTH_M:
            runs[row] = (start, end, depth)
    return runs, len(groups)


def silhouette_shift_xy(runs, detection, transform, intrinsics, rows_with_points=None):
    """
    Floor shift ``(dx, dy)`` of a detection across the view to its warm silhouette's middle.

    Matches on a warm body lie on its outlines, often more on one side than the other, so
    the median of its points can sit up to half a body off its middle; the thermal image
    shows the whole width. The shift is along the floor's direction ``n`` across the view
    (horizontal, perpendicular to the horizontal viewing direction): on each row of ``runs``
    (``silhouette_runs``) the run's middle less the column of the vertical at the
    detection's position (``vertical_line_columns``), over how many columns the vertical
    moves there per metre along ``n`` (from a second vertical 1 cm along it), is the shift
    that puts the vertical through the middle (exact to first order, with roll too). Returns
    the median over the rows times ``n``, or None with fewer than ``SILHOUETTE_MIN_ROWS``
    rows or fewer than ``SILHOUETTE_MIN_USABLE`` of the ``rows_with_points`` (most of its
    rows joined to a neighbour's, through a one-pixel gap or by touching: the few left, the
    narrowest joins, would decide), or when the vertical's image is slanted more than
    ``SILHOUETTE_MAX_SLANT`` (a rig looking steeply down: a row crosses the body aslant).
    """
    if len(runs) < SILHOUETTE_MIN_ROWS or (
            rows_with_points and len(runs) < SILHOUETTE_MIN_USABLE * rows_with_points):
        return None
    rows = np.array(sorted(runs), dtype=np.float64)
    centre = camera_centre_in_world(transform)
    away = np.array([detection.x - centre[0], detection.y - centre[1]])
    if not np.hypot(*away) > 1e-6:
        return None
    across = np.array([-away[1], away[0]]) / np.hypot(*away)
    lines, slant = vertical_line_columns((detection.x, detection.y), rows, transform,
                                         intrinsics)
    moved, _ = vertical_line_columns((detection.x + 0.01 * across[0],
                                      detection.y + 0.01 * across[1]), rows, transform,
                                     intrinsics)
    if not abs(slant) <= SILHOUETTE_MAX_SLANT:
        return None
    per_metre = (moved - lines) / 0.01
    middles = np.array([0.5 * (runs[row][0] + runs[row][1]) for row in sorted(runs)])
    usable = np.isfinite(per_metre) & (np.abs(per_metre) > 1e-6)
    if not usable.any():
        return None
    return float(np.median((middles - lines)[usable] / per_metre[usable])) * across


def shared_runs(runs, other):
    """Fraction of the rows of ``runs`` whose run is ``other``'s on that row (same span)."""
    if not runs:
        return 0.0
    return float(np.mean([row in other and other[row][:2] == span[:2]
                          for row, span in runs.items()]))


def centred_on_silhouette(detections, warm, transform, intrinsics, points, pixels,
                          counts=None, valid=None):
    """
    Return the detections, each with its shift across the view to its silhouette's middle.

    The shift goes into ``Detection.across``, not into the position the tracker follows:
    the gates, the travel a cut body must walk and the legs tests were chosen on the
    points' positions, and a track's published ``position`` adds it.

    ``silhouette_runs`` and ``silhouette_shift_xy`` for each (the arguments are theirs;
    ``valid``: the pixels with data, as ``WarmBackground`` takes them); one without enough
    usable rows is not shifted. Strongest (most points) first: a detection half or more of
    whose runs are a stronger one's (``shared_runs``: the same span on the same row) is not
    shifted either. The silhouette is the stronger one's: it may be a fragment of that body
    (its points matched at another depth: a cut body's often lie 0.4-0.8 m behind it), or
    another person partly behind it, whose own position is the points'. ``counts`` (a dict,
    optional) gains ``silhouette_centred``, ``silhouette_not_found`` and
    ``silhouette_shared``.
    """
    counts = {} if counts is None else counts
    for key in ('silhouette_centred', 'silhouette_not_found', 'silhouette_shared'):
        counts.setdefault(key, 0)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    out, stronger = list(detections), []
    for index in sorted(range(len(detections)), key=lambda i: -detections[i].points):
        detection = detections[index]
        runs, rows_with_points = silhouette_runs(warm, detection, intrinsics, points, pixels,
                                                 valid)
        shared = any(shared_runs(runs, other) >= 0.5 for other in stronger)
        stronger.append(runs)
        if shared:
            counts['silhouette_shared'] += 1
            continue
        shift = silhouette_shift_xy(runs, detection, transform, intrinsics, rows_with_points)
        if shift is None:
            counts['silhouette_not_found'] += 1
            continue
        counts['silhouette_centred'] += 1
        out[index] = dataclasses.replace(detection, across=(float(shift[0]),
                                                            float(shift[1])))
    return out


def warm_column_reaches_top(warm, pixels, band_rows=3, spread_px=2):
    """
    Whether a warm column above a body's topmost points continues up to the image's top row.

    ``pixels`` (n x 2, x and y in the rectified left image) are the body's points. The band
    of columns of those within ``band_rows`` rows of the topmost, widened by one pixel each
    side, is followed up from the row above the topmost: each row must hold a warm run
    touching (8-neighbours) the previous row's, no wider than the band plus ``spread_px``
    each side (the upper body and the head are no wider than the body where its points end;
    a warm screen or wall behind, wider, stops it). The run may drift sideways from row to
    row (verticals slant in the image). When every row up to row 0 holds one, the head may
    lie at or above the image's edge and the points' top is only a lower bound (the matches
    end several rows below a head in the image's top rows, where a 9-pixel window does not
    fit). A cool gap, pixels without data (never warm) or a topmost point off the body make it
    False: the points' top is then taken as the head's, as before.
    """
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if not len(pixels):
        return False
    rows = np.rint(pixels[:, 1]).astype(int)
    cols = np.rint(pixels[:, 0]).astype(int)
    top = int(rows.min())
    if top <= 0:
        return True
    near = rows <= top + band_rows
    width = warm.shape[1]
    low, high = max(int(cols[near].min()) - 1, 0), min(int(cols[near].max()) + 1, width - 1)
    widest = high - low + 1 + 2 * spread_px
    for row in range(top - 1, -1, -1):
        # The run touching the previous one, nearest its middle.
        run = central_warm_run(warm[row], max(low - 1, 0), high + 1, 0.5 * (low + high))
        if run is None or run[1] - run[0] + 1 > widest:
            return False
        low, high = run
    return True


def top_edge_height_m(floor_xy, transform, intrinsics):
    """
    Height above the floor at which the image's top edge crosses a vertical at ``floor_xy``.

    The vertical's points 0-3 m high (1 cm apart) go into the rectified left frame (the
    inverse of ``transform``) and onto the image rows (``v = fy Y / Z + cy``); the highest one
    on or below the top edge (``v >= -0.5``) is returned when the next one is above it. NaN
    when the top edge does not cross the vertical between 0 and 3 m (near the rig it passes
    above 3 m; behind the camera nothing is seen).
    """
    rotation, translation = transform
    _, fy, _, cy = intrinsics
    heights = np.arange(0.0, 3.0 + 1e-9, 0.01)
    world = np.column_stack([np.full(len(heights), floor_xy[0]),
                             np.full(len(heights), floor_xy[1]), heights])
    camera = (world - translation) @ rotation
    ahead = camera[:, 2] > 0
    rows = np.full(len(heights), -np.inf)
    rows[ahead] = fy * camera[ahead, 1] / camera[ahead, 2] + cy
    crossing = np.flatnonzero((rows[:-1] >= -0.5) & (rows[1:] < -0.5) & ahead[1:])
    return float(heights[crossing.max()]) if len(crossing) else float('nan')


def silhouette_reaches_top(warm, pixels):
    """
    Whether the warm region holding a detection's points has a pixel on the image's top row.

    ``pixels`` (n, 2) are the detection's points' left pixels; the 8-connected warm regions
    of ``warm`` (not dilated) holding any of them must reach row 0 within the columns the
    points span: a body rising out of the image does, a low warm thing wholly in view (a pet,
    a heater, a radiator under a higher top edge) has cool rows above it.
    """
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    rows, cols, inside = pixel_indices(warm.shape, pixels[:, 0], pixels[:, 1])
    if not inside.any():
        return False
    labels, _ = ndimage.label(warm, structure=np.ones((3, 3), dtype=bool))
    held = np.unique(labels[rows[inside], cols[inside]])
    held = held[held > 0]
    low, high = int(cols[inside].min()), int(cols[inside].max())
    return bool(np.isin(labels[0, low:high + 1], held).any())


def legs_only_bodies(detections, warm, transform, intrinsics, pixels, counts=None):
    """
    Keep the legs-only detections (``detect_people``) that can be a body rising out of view.

    A legs-only detection is kept when the warm region of its points reaches the image's top
    row (``silhouette_reaches_top``) and the top edge crosses it at least ``LEGS_HEIGHTS_M``
    high (the whole legs' segment in view: farther, a low warm thing reaches the edge as
    legs do; a crossing outside 0-3 m, as for a rig looking steeply down, counts as too
    far); its head height becomes that crossing's height when higher than its points'
    top (a lower bound: the body goes on above the image). ``pixels``: the left pixels of
    the points the detections' ``members`` index. Other detections pass unchanged.
    ``counts`` gains ``legs_only_detections``, ``legs_only_below_top`` and
    ``legs_only_too_far``.
    """
    counts = {} if counts is None else counts
    for key in ('legs_only_detections', 'legs_only_below_top', 'legs_only_too_far'):
        counts.setdefault(key, 0)
    out = []
    for detection in detections:
        if detection.legs_only:
            counts['legs_only_detections'] += 1
            edge = top_edge_height_m((detection.x, detection.y), transform, intrinsics)
            if not edge >= LEGS_HEIGHTS_M[1]:
                counts['legs_only_too_far'] += 1
                continue
            if not silhouette_reaches_top(warm, pixels[detection.members]):
                counts['legs_only_below_top'] += 1
                continue
            detection = dataclasses.replace(detection,
                                            head_height=max(detection.head_height, edge))
        out.append(detection)
    return out


def on_warm_legs(warm, detection, transform, intrinsics, points, pixels, config):
    """
    Whether a detection stands on warm legs at its depth, its warm column without a gap.

    ``legs_fraction`` at least ``legs_min_fraction`` and ``warm_column_gap_m`` not longer
    than ``legs_max_gap_m`` (the arguments are those functions'); False when the legs are
    off the image.
    """
    floor_xy = (detection.x, detection.y)
    fraction = legs_fraction(warm, floor_xy, transform, intrinsics, points, pixels, config)
    return bool(fraction >= config.legs_min_fraction) and warm_column_gap_m(
        warm, floor_xy, transform, intrinsics, points, pixels, config) <= config.legs_max_gap_m


def standing_on_legs(detections, warm, transform, intrinsics, points, pixels, config=None,
                     counts=None, tracked_xy=()):
    """
    Return the detections, those cut by the top edge on warm legs marked ``legs_seen``.

    Each cut detection's ``legs_fraction`` (the other arguments are that function's) against
    ``legs_min_fraction``. Strongest first: a cut body's points often make two peaks up to
    0.6 m apart (depth noise, arms), whose leg windows each hold one leg, so a detection
    within twice ``person_radius_m`` of a stronger one standing on legs is that body's
    fragment, left weak (cut, no legs). The price: of two far people standing closer than
    that, the weaker is published only once it walks ``min_travel_m`` or shows its head (a
    legs-only one, ``detect_people``'s second pass, never: without legs it starts no track).
    A detection on legs whose warm column has a cool stretch longer than ``legs_max_gap_m``
    (``warm_column_gap_m``) is two warm things, not one body, and gets none; nor does a
    legs-only one (``detect_people``) whose warm run across the legs is wider than
    ``far_legs_max_width_m`` (``warm_run_width_m``: a radiator under the image's top edge).
    ``counts`` (a dict, optional) gains ``cut_legs_checked``, ``cut_legs_seen``,
    ``cut_legs_out_of_image`` (the segment off the image), ``cut_legs_fragment``,
    ``cut_legs_gap`` and ``cut_legs_wide``.

    With ``confirm_on_legs``, a detection not cut by the top edge whose head is at least
    ``min_head_height_m`` high gets the same test and ``legs_under_head`` when it passes
    (``head_legs_checked``, ``head_legs_seen``): a track starting on it is published at
    once (``PeopleTracker``). Only one farther than ``gate_m`` from every ``tracked_xy``
    (every track's predicted floor position, published or not) is tested: one nearer
    continues a track, or waits for ``min_hits`` beside an unpublished one.
    """
    config = config or PeopleConfig()
    counts = {} if counts is None else counts
    for key in ('cut_legs_checked', 'cut_legs_seen', 'cut_legs_out_of_image',
                'cut_legs_fragment', 'cut_legs_gap', 'cut_legs_wide', 'head_legs_checked',
                'head_legs_seen'):
        counts.setdefault(key, 0)
    standing, out = [], []
    for detection in detections:
        if not detection.cut_top:
            if config.confirm_on_legs and \
                    detection.head_height >= config.min_head_height_m and \
                    all(math.hypot(detection.x - x, detection.y - y) > config.gate_m
                        for x, y in tracked_xy):
                counts['head_legs_checked'] += 1
                if on_warm_legs(warm, detection, transform, intrinsics, points, pixels,
                                config):
                    counts['head_legs_seen'] += 1
                    detection = dataclasses.replace(detection, legs_under_head=True)
            out.append(detection)
            continue
        if any(math.hypot(detection.x - x, detection.y - y) < 2 * config.person_radius_m
               for x, y in standing):
            counts['cut_legs_fragment'] += 1
        else:
            fraction = legs_fraction(warm, (detection.x, detection.y), transform, intrinsics,
                                     points, pixels, config)
            counts['cut_legs_checked'] += 1
            if math.isnan(fraction):
                counts['cut_legs_out_of_image'] += 1
            elif fraction >= config.legs_min_fraction and detection.legs_only and not \
                    warm_run_width_m(warm, (detection.x, detection.y), transform, intrinsics,
                                     config) <= config.far_legs_max_width_m:
                # (NaN: no warm row, or a run off the image's side: the width is unknown)
                counts['cut_legs_wide'] += 1
            elif fraction >= config.legs_min_fraction and not warm_column_gap_m(
                    warm, (detection.x, detection.y), transform, intrinsics, points, pixels,
                    config) <= config.legs_max_gap_m:
                counts['cut_legs_gap'] += 1     # (NaN, no row in view: no legs either)
            elif fraction >= config.legs_min_fraction:
                counts['cut_legs_seen'] += 1
                standing.append((detection.x, detection.y))
                detection = dataclasses.replace(detection, legs_seen=True)
        out.append(detection)
    return out


TOP_SILHOUETTE_MIN_ROWS = 3       # rows from the top edge down (a head's tip is not a body)
TOP_SILHOUETTE_SPLIT = 0.5        # a column running under half the tallest: another thing
TOP_SILHOUETTE_MAX_WIDTH_M = 0.7  # shoulders (0.5 m), a pixel of blur each side, arms
SHOULDERS_M = 0.5                 # a body's width across the shoulders
SILHOUETTE_NEAREST_M = 1.0        # the disparity searched: from max_range_m to this depth


SHAPE_MAX_STEP_PX = 8     # a shape's shift between consecutive left images searched (70 px/s)
SHAPE_MAX_DT_S = 0.3      # consecutive pairs (0.115 s at 8.7 Hz, one dropped)


def _skew_shift_px(left, mask, motion, exclude, min_correlation):
    """
    Return how far a moving shape moved on in the image during the pair's skew, px (or NaN).

    ``motion`` is ``(previous_left, dt_s, skew_s)`` (``silhouette_detections``): the shape's
    shift since the previous left image over ``dt_s``, times ``skew_s``; NaN when that shift's
    correlation is under ``min_correlation`` (the previous image does not show the shape).
    """
    if motion is None:
        return float('nan')
    previous, dt_s, skew_s = motion
    if previous is None or skew_s is None or not 0.0 < dt_s <= SHAPE_MAX_DT_S or \
            np.shape(previous) != np.shape(left):
        return float('nan')
    valid_previous = np.isfinite(previous) & (np.asarray(previous) > 0)
    step, correlation = silhouette_disparity(left, previous, mask, -SHAPE_MAX_STEP_PX,
                                             SHAPE_MAX_STEP_PX, valid_right=valid_previous,
                                             exclude=exclude)
    # silhouette_disparity finds s with previous[c - s] ~ left[c]: the shape moved by +s. A
    # shape the previous image does not show (an old or blank one) is not corrected.
    if not (math.isfinite(step) and correlation >= min_correlation):
        return float('nan')
    return step / dt_s * skew_s


def _one_depth(left, right, mask, cols, bounds, stereo, depth, tolerance_m, valid_right,
               exclude):
    """
    Whether a silhouette's left and right halves lie at its depth, within ``tolerance_m``.

    Each half (its columns up to, and from, the middle one), with its ring, gets its own
    ``silhouette_disparity``; a half without one (too narrow, flat) is no evidence. A
    silhouette holding two bodies at two depths (a far one's sliver beside a nearer one's
    top, joined in the warm mask) is not one body.
    """
    fx_baseline, disparity_offset = stereo
    middle = 0.5 * (cols.min() + cols.max())
    for half in (np.arange(mask.shape[1]) > middle, np.arange(mask.shape[1]) < middle):
        part = mask & ~half[None, :]
        disparity, _ = silhouette_disparity(left, right, part, *bounds,
                                            valid_right=valid_right, exclude=exclude)
        if disparity > disparity_offset and \
                abs(fx_baseline / (disparity - disparity_offset) - depth) > tolerance_m:
            return False
    return True


def reaches_the_unseen(mask, valid=None):
    """
    Whether a silhouette reaches the image's side or bottom, or a pixel without data.

    ``mask`` (bool) and its 8-neighbours against the image's border and ``valid`` (bool, the
    pixels with data; all when None). The top edge does not count: every silhouette rises
    out of it.
    """
    mask = np.asarray(mask, dtype=bool)
    seen = np.ones(mask.shape, dtype=bool) if valid is None else np.asarray(valid, bool)
    seen = np.pad(seen, 1, constant_values=False)
    seen[0, :] = True                                   # above the top edge
    grown = ndimage.binary_dilation(np.pad(mask, 1), structure=EIGHT_CONNECTED)
    return bool((grown & ~seen).any())


def silhouette_detections(detections, weak, warm, left, right, transform, intrinsics, stereo,
                          pixels, config=None, counts=None, valid_right=None, valid_left=None,
                          motion=None):
    """
    Return detections of bodies rising out of the top edge that no detection covers.

    ``top_silhouettes`` of ``weak`` (the pixels warmer than the background by
    ``silhouette_margin_counts``) seeded by ``warm``; each one whose pixels (dilated by one)
    hold a point of a detection of ``detections`` (members of ``pixels``, the left pixels of
    the points given to ``detect_people``) is that detection's. The others get the
    disparity of their whole shape (``silhouette_disparity`` between the rectified ``left``
    and ``right`` images, searched between the depths ``max_range_m`` and
    ``SILHOUETTE_NEAREST_M``; ``valid_right``, ``valid_left``: the images' pixels with data,
    the left one's others out of the ring as ``weak``'s are), used when
    its correlation is at least ``silhouette_min_correlation``; ``stereo`` is
    ``(fx B, cx_left - cx_right)`` (the right camera_info's ``P``), so
    ``Z = fx B / (d - (cx_left - cx_right))``. The silhouette's middle column and mean row
    at that depth is a point of the body (``u, v`` onto the rectified left ray, into the
    world by ``transform``); a shape wider than ``TOP_SILHOUETTE_MAX_WIDTH_M`` there, or
    whose point lies below ``far_legs_min_height_m`` (``min_point_height_m`` when that is
    off) or above ``max_point_height_m``, is not a body. Its floor position is pushed back by
    ``cut_body_offset_m`` (the front of a cut body is seen) and must lie more than
    ``2 person_radius_m`` from every detection. The detection is cut by the top edge
    (``cut_top``, head not visible: its head height is the top edge's height there, a lower
    bound, ``top_edge_height_m``), without legs, ``silhouette`` True; its points are those
    on its pixels, its confidence the correlation, its covariance the depth's
    (``sigma_Z = Z sigma_d / d``, ``disparity_sigma_px``, and ``cut_body_offset_m``, the
    guess of how far the body's middle lies behind its silhouette, in quadrature) along the
    viewing direction; across it, a quarter of its width, or, for a shape narrower than
    shoulders (``SHOULDERS_M``: a fragment of a body, its middle up to the difference's half
    off), half of what it lacks of them.

    A shape that reaches the image's side or a pixel without data (``reaches_the_unseen``,
    ``valid_left``) is not searched (``silhouette_at_side``): the left image does not show
    what lies beyond, and a nearer body standing there can hide the shape in the right
    image, whose edge the search then finds and the search back may confirm
    (docs/people.md, step 4).

    ``motion``: ``(previous_left, dt_s, skew_s)``, the previous pair's rectified left image,
    the time since it and this pair's skew (right acquisition less left, s). The right
    camera saw a moving shape ``skew_s`` later, where it had moved on by its image velocity
    ``v`` (px/s) times the skew: the disparity measured is ``d - v skew``. ``v`` is the
    shape's shift since the previous left image (``silhouette_disparity`` of this left image
    against it, within ``SHAPE_MAX_STEP_PX``) over ``dt_s``; the depth is that of
    ``d + v skew`` (``silhouette_skew_corrected``; without motion, or no shift found, or
    ``dt_s`` over ``SHAPE_MAX_DT_S``: ``silhouette_skew_not_corrected``). The checks above
    compare the images as they are and use the measured disparity.

    ``counts`` (a dict) gains ``silhouettes``, ``silhouette_covered``,
    ``silhouette_no_disparity``, ``silhouette_not_back``, ``silhouette_two_depths``,
    ``silhouette_at_side``, ``silhouette_not_body``, ``silhouette_detections``,
    ``silhouette_skew_corrected`` and ``silhouette_skew_not_corrected``.
    """
    config = config or PeopleConfig()
    counts = {} if counts is None else counts
    for key in ('silhouettes', 'silhouette_covered', 'silhouette_no_disparity',
                'silhouette_not_back', 'silhouette_two_depths', 'silhouette_not_body',
                'silhouette_at_side', 'silhouette_detections', 'silhouette_skew_corrected',
                'silhouette_skew_not_corrected'):
        counts.setdefault(key, 0)
    fx, fy, cx, cy = intrinsics
    fx_baseline, disparity_offset = stereo
    rotation, translation = transform
    centre = camera_centre_in_world(transform)
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    point_rows, point_cols, inside = pixel_indices(np.shape(warm), pixels[:, 0], pixels[:, 1])
    low = disparity_offset + fx_baseline / config.max_range_m
    high = disparity_offset + fx_baseline / SILHOUETTE_NEAREST_M
    lowest = config.far_legs_min_height_m or config.min_point_height_m
    exclude = weak if valid_left is None else weak | ~valid_left
    out = []
    for mask in top_silhouettes(weak, warm, TOP_SILHOUETTE_MIN_ROWS, TOP_SILHOUETTE_SPLIT):
        counts['silhouettes'] += 1
        region = ndimage.binary_dilation(mask, structure=EIGHT_CONNECTED)
        held = inside & region[point_rows, point_cols]
        if any(d.members is not None and held[np.asarray(d.members, dtype=int)].any()
               for d in detections):
            counts['silhouette_covered'] += 1
            continue
        if reaches_the_unseen(mask, valid_left):
            counts['silhouette_at_side'] += 1
            continue
        disparity, correlation = silhouette_disparity(left, right, mask, low, high,
                                                      valid_right=valid_right, exclude=exclude)
        if not correlation >= config.silhouette_min_correlation or \
                not disparity > disparity_offset:
            counts['silhouette_no_disparity'] += 1
            continue
        if not right_to_left_agrees(left, right, mask, disparity, low, high,
                                    valid_left=valid_left, exclude=exclude):
            counts['silhouette_not_back'] += 1
            continue
        rows, cols = np.nonzero(mask)
        if not _one_depth(left, right, mask, cols, (low, high), stereo,
                          fx_baseline / (disparity - disparity_offset),
                          2 * config.person_radius_m, valid_right, exclude):
            counts['silhouette_two_depths'] += 1
            continue
        moved = _skew_shift_px(left, mask, motion, exclude, config.silhouette_min_correlation)
        counts['silhouette_skew_corrected' if math.isfinite(moved) else
               'silhouette_skew_not_corrected'] += 1
        if math.isfinite(moved):
            disparity += moved
            if not disparity > disparity_offset:
                counts['silhouette_no_disparity'] += 1
                continue
        depth = fx_baseline / (disparity - disparity_offset)
        u, v = 0.5 * (cols.min() + cols.max()), rows.mean()
        body = rotation @ np.array([(u - cx) * depth / fx, (v - cy) * depth / fy, depth]) + \
            translation
        if (cols.max() - cols.min() + 1) * depth / fx > TOP_SILHOUETTE_MAX_WIDTH_M or \
                not lowest <= body[2] <= config.max_point_height_m:
            counts['silhouette_not_body'] += 1
            continue
        away = body[:2] - centre[:2]
        away /= max(float(np.hypot(*away)), 1e-9)
        xy = body[:2] + config.cut_body_offset_m * away
        if any(math.hypot(d.x - xy[0], d.y - xy[1]) <= 2 * config.person_radius_m
               for d in detections + out):
            counts['silhouette_covered'] += 1
            continue
        ray = body - centre
        sigma = depth * config.disparity_sigma_px / (disparity - disparity_offset) * \
            math.hypot(ray[0], ray[1]) / float(np.linalg.norm(ray))
        half_width = 0.5 * (cols.max() - cols.min() + 1) * depth / fx
        sigma_across = max(0.5 * half_width, SHOULDERS_M / 2 - half_width)
        sigma_along = math.hypot(sigma, config.cut_body_offset_m)
        across = np.array([-away[1], away[0]])
        covariance = sigma_along ** 2 * np.outer(away, away) + \
            sigma_across ** 2 * np.outer(across, across)
        head = top_edge_height_m(xy, transform, intrinsics)
        members = np.flatnonzero(held)
        out.append(Detection(float(xy[0]), float(xy[1]),
                             float(body[2]) if not math.isfinite(head) else head,
                             int(len(members)), float(correlation), covariance,
                             head_visible=False, cut_top=True, depth_spread_m=float('nan'),
                             members=members, silhouette=True,
                             shape_pixels=np.flatnonzero(mask)))
        counts['silhouette_detections'] += 1
    return out


def occupancy_peaks(xy, config):
    """
    Floor positions of the local maxima of the points' smoothed occupancy.

    A histogram of ``cell_m`` cells smoothed by a Gaussian of sigma ``person_radius_m / 2``;
    a peak is the largest value within ``person_radius_m`` and holds at least ``min_points``
    points' worth of mass (a person's points spread over about that radius).
    """
    if len(xy) == 0:
        return np.zeros((0, 2))
    margin = 2 * config.person_radius_m
    low = xy.min(axis=0) - margin
    shape = tuple(int(v) + 1 for v in np.ceil((xy.max(axis=0) + margin - low) / config.cell_m))
    cells = np.floor((xy - low) / config.cell_m).astype(int)
    grid = np.zeros(shape)
    np.add.at(grid, (cells[:, 0], cells[:, 1]), 1.0)
    sigma = 0.5 * config.person_radius_m / config.cell_m
    smooth = ndimage.gaussian_filter(grid, sigma, mode='constant')
    size = 2 * int(round(config.person_radius_m / config.cell_m)) + 1
    peaks = (smooth == ndimage.maximum_filter(smooth, size=size, mode='constant'))
    # Mass within one sigma of a peak: the Gaussian puts 1 / (2 pi sigma^2) of a point there.
    threshold = 0.5 * config.min_points / (2 * math.pi * sigma * sigma)
    peaks &= smooth > threshold
    index = np.argwhere(peaks)
    order = np.argsort(-smooth[peaks])
    return low + (index[order] + 0.5) * config.cell_m


def detect_people(points_world, camera_centre, disparity=None, depth=None, confidence=None,
                  config=None, pixels=None, image_shape=None):
    """
    Detect the people in one pair's points (see the module docstring).

    Parameters
    ----------
    points_world : ndarray, shape (n, 3)
        Points in the world frame (floor z = 0), already restricted to the warm ones if the
        caller uses the warm foreground.
    camera_centre : ndarray, shape (3,)
        The left camera's centre in the world (the viewing direction of each point).
    disparity, depth : ndarray, shape (n,), optional
        Each point's disparity (px) and Z (m) in the camera: its depth uncertainty
        ``Z sigma_d / d``; without them the covariance is the points' spread alone.
    confidence : ndarray, shape (n,), optional
        Each point's match confidence (0..1); ``min_confidence`` drops the lower ones.
    config : PeopleConfig, optional
        The parameters (defaults when None).
    pixels : ndarray, shape (n, 2), optional
        Each point's left pixel (x, y).
    image_shape : tuple, optional
        (rows, cols) of the left image. With ``pixels``: a person whose
        points come within ``edge_px`` of the image's top or side edge is cut by it (far
        away, the head above the image; walking in or out at a side), kept without the
        ``min_head_height_m`` test, with ``head_visible`` False and its position pushed back
        by ``cut_body_offset_m`` (what the camera sees of a cut body is its front).
        Farther still only the legs show, below ``min_point_height_m``: the points from
        ``far_legs_min_height_m`` up to it, away from every detection above, make one more
        pass, in which only a cluster cut by the top edge is kept (``legs_only``: it must
        then rise out of the image, ``legs_only_bodies``, and stand on its legs,
        ``standing_on_legs``).

    Returns
    -------
    list of Detection
        Strongest first (the legs-only ones after the others).

    """
    config = config or PeopleConfig()
    points = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    centre = np.asarray(camera_centre, dtype=np.float64)
    usable = np.isfinite(points).all(axis=1) & \
        (np.hypot(points[:, 0] - centre[0], points[:, 1] - centre[1]) <= config.max_range_m)
    if confidence is not None:
        # NaN: the matcher gave none (points2's confidence field) -- kept, weight 1.
        usable &= ~(np.asarray(confidence, dtype=np.float64) < config.min_confidence)
    sigma_depth = None
    if disparity is not None and depth is not None:
        d, z = np.asarray(disparity, dtype=np.float64), np.asarray(depth, dtype=np.float64)
        usable &= d > 0
        sigma_depth = np.where(d > 0, z * config.disparity_sigma_px / np.maximum(d, 1e-9), 0)
    weights = np.ones(len(points)) if confidence is None else \
        np.nan_to_num(np.asarray(confidence, dtype=np.float64), nan=1.0)
    at_top = at_side = np.zeros(len(points), dtype=bool)
    if pixels is not None and image_shape is not None:
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        at_top = px[:, 1] <= config.edge_px
        # The left edge of what both cameras see is the right image's: x - d.
        left_x = px[:, 0] - (0.0 if disparity is None else np.asarray(disparity))
        # The bottom edge too: a body cut there (a person under a rig looking straight down)
        # is not whole, though not a screen's shape either.
        at_side = (left_x <= config.edge_px) | \
            (px[:, 0] >= image_shape[1] - 1 - config.edge_px) | \
            (px[:, 1] >= image_shape[0] - 1 - config.edge_px)
    evidence = _PointEvidence(points, weights, sigma_depth,
                              None if depth is None else np.asarray(depth, dtype=np.float64),
                              at_top, at_side, centre)
    body = usable & (points[:, 2] >= config.min_point_height_m) & \
        (points[:, 2] <= config.max_point_height_m)
    detections = _cluster_detections(evidence, np.flatnonzero(body), config, legs_only=False)
    if config.far_legs_min_height_m > 0:
        low = usable & (points[:, 2] >= config.far_legs_min_height_m) & \
            (points[:, 2] < config.min_point_height_m)
        for detection in detections:
            low &= np.hypot(points[:, 0] - detection.x, points[:, 1] - detection.y) > \
                2 * config.person_radius_m
        if (low & at_top).any():        # (a cluster without a point at the top is not kept)
            detections += _cluster_detections(evidence, np.flatnonzero(low), config,
                                              legs_only=True)
    return detections


@dataclasses.dataclass
class _PointEvidence:
    """Per-point arrays ``detect_people`` clusters (all of the caller's points)."""

    points: np.ndarray
    weights: np.ndarray
    sigma_depth: np.ndarray       # None without disparity and depth
    depth: np.ndarray             # None without depth
    at_top: np.ndarray
    at_side: np.ndarray
    centre: np.ndarray


def _cluster_detections(evidence, indices, config, legs_only):
    """
    Return the detections of the points ``indices`` (``detect_people``), one per peak.

    ``legs_only``: only clusters cut by the top edge are kept, marked ``legs_only`` (their
    height is that of the legs' tops, no head).
    """
    points = evidence.points[indices]
    at_top, at_side = evidence.at_top[indices], evidence.at_side[indices]
    weights = evidence.weights[indices]
    sigma_depth = None if evidence.sigma_depth is None else evidence.sigma_depth[indices]
    centre = evidence.centre
    detections, taken = [], np.zeros(len(points), dtype=bool)
    for peak in occupancy_peaks(points[:, :2], config):
        near = (~taken) & (np.hypot(*(points[:, :2] - peak).T) <= config.person_radius_m)
        if near.sum() < config.min_points:
            continue
        member = points[near]
        top = float(np.percentile(member[:, 2], 95))
        head = top - config.head_offset_m
        upper = near & (points[:, 2] >= top - 0.4)
        if upper.sum() < 3:
            upper = near
        # Cut by the image's edge: a fifth of the upper body at it (one arm is not enough).
        cut_top = bool(np.mean(at_top[upper]) >= 0.2)
        if legs_only and not cut_top:
            continue
        head_visible = not cut_top and bool(np.mean(at_side[upper]) < 0.2)
        if head_visible and head < config.min_head_height_m:
            continue
        taken |= near
        upper = points[upper]
        xy = np.median(upper[:, :2], axis=0)
        away = xy - centre[:2]
        away /= max(float(np.hypot(*away)), 1e-9)
        xy = xy + (0.0 if legs_only else config.cut_body_offset_m if cut_top else
                   config.body_half_depth_m) * away
        spread = np.cov(upper[:, :2].T) if len(upper) > 2 else np.eye(2) * 0.01
        covariance = spread / len(upper)
        if sigma_depth is not None:
            ray = member - centre
            horizontal = np.hypot(ray[:, 0], ray[:, 1]) / np.linalg.norm(ray, axis=1)
            sigma = float(np.median(sigma_depth[near] * horizontal))
            covariance = covariance + (sigma ** 2 / len(upper)) * np.outer(away, away)
        strength = float(np.mean(weights[near])) * min(1.0, near.sum() / (3 * config.min_points))
        spread_z = float(np.std(evidence.depth[indices][near])) \
            if evidence.depth is not None else float('nan')
        detections.append(Detection(float(xy[0]), float(xy[1]), head, int(near.sum()),
                                    strength, covariance, head_visible, cut_top, spread_z,
                                    indices[near], legs_only=legs_only))
    return detections


PLACES_KEPT = 8      # a track's last detections' positions kept (where a warm object is)
# A published track whose legs or head (whole) showed in fewer than this share of its
# detections is one lent them (a screen: 2 of dozens or hundreds), not a person standing on
# its legs (the tuning sequences' far person: 61 of 63), when they lapse (``legs_lapse_s``).
LENT_LEGS_FRACTION = 0.3
# The places a warm object's track left by a jump to another piece (a screen's other half:
# its spots, one per SPOT_SPACING_M, the last SPOTS_KEPT), and those of an ended one, hold
# the object's detections when they come back there within their jitter (0.03-0.05 m on the
# simulated screens): a person standing 0.2 m in front of it is not it.
REMEMBERED_RADIUS_M = 0.1
HOLD_MAX_SPEED = 0.3      # m/s: a track this slow at its last detection is a person at rest
HOLD_MIN_WHOLE_HITS = 10  # whole detections (over a second) before a track can be held
SPOT_SPACING_M = 0.05
SPOTS_KEPT = 32


STEADY_WALK_DETECTIONS = 5     # detections of consecutive pairs a steady walk spans
STEADY_WALK_GAP_RATIO = 1.5    # consecutive: no step over more than this times the shortest
STEADY_WALK_PATH_RATIO = 1.5   # its path at most this times its line
STEADY_WALK_JITTER_M = 0.02    # the detections' jitter allowed below a step's pace
STEADY_WALK_JUMP_M = 0.1       # and above it


def walks_steadily(places, times, distance_m, count=STEADY_WALK_DETECTIONS):
    """
    Whether the last ``count`` floor positions ``places`` walk steadily ``distance_m`` or more.

    ``times``: the stamps of ``places`` (seconds, increasing). The ``count`` detections come
    from consecutive pairs (no step's time over ``STEADY_WALK_GAP_RATIO`` times the shortest
    one's: a track that coasted unseen may jump far at the walk's pace). Steadily, at the
    walk's mean pace ``v`` (its line over its time): each step goes forward along the line
    from the first position to the last by at least half of ``v`` times the step's time (less
    ``STEADY_WALK_JITTER_M``), none is longer than twice it (plus ``STEADY_WALK_JUMP_M``), and
    the path is at most ``STEADY_WALK_PATH_RATIO`` times the line. A warm object cut by the
    image's top edge (a screen) makes detections that stay in place within a few
    centimetres and jump between its pieces, up to 0.5 m apart; a person walking away or
    across advances at every step. At 8.7 pairs/s, 5 detections span 0.46 s: 0.4 m takes a
    walk of 0.87 m/s or more. False for ``distance_m`` 0 (off) and with fewer than ``count``
    positions.
    """
    if distance_m <= 0 or len(places) < count or len(times) < count:
        return False
    path = np.asarray(places[-count:], dtype=np.float64)
    stamps = np.asarray(times[-count:], dtype=np.float64)
    line = path[-1] - path[0]
    length = float(np.hypot(*line))
    intervals = np.diff(stamps)
    if length < distance_m or not intervals.min() > 0 or \
            intervals.max() > STEADY_WALK_GAP_RATIO * intervals.min():
        return False
    steps = np.diff(path, axis=0)
    forward = steps @ (line / length)
    lengths = np.hypot(steps[:, 0], steps[:, 1])
    pace = length / float(stamps[-1] - stamps[0]) * intervals
    return bool((forward >= 0.5 * pace - STEADY_WALK_JITTER_M).all() and
                (lengths <= 2.0 * pace + STEADY_WALK_JUMP_M).all() and
                lengths.sum() <= STEADY_WALK_PATH_RATIO * length)


def new_spots(spots, x, y):
    """Return ``spots`` with ``(x, y)`` added when farther than SPOT_SPACING_M from each."""
    if all(math.hypot(x - sx, y - sy) > SPOT_SPACING_M for sx, sy in spots):
        spots = (spots + ((x, y),))[-SPOTS_KEPT:]
    return spots


def updated_head_height(whole_heights, bounds, detection, pairs):
    """
    Return a track's head height, whole heights, bounds and ``whole`` after ``detection``.

    ``whole_heights``: the heights of its last ``pairs`` detections seen whole (head in the
    image), whose median is the height after a whole one: one detection whose head found no
    matches (its points' top on the shoulders, 0.25 m low in the recording) does not pull it
    down, and a person sitting down is followed within about ``pairs / 2`` pairs. A detection
    cut by the image's edge (``head_visible`` False), or whose warm column continues from its
    points up to the image's top row (``head_above``), shows only part of the body: its
    points' top is a lower bound. ``bounds``: the last ``pairs`` detections' bounds (-inf for
    whole ones), so a bound holds for ``pairs`` pairs and then lapses (one cut detection
    that merged two bodies does not stay). After a bound, the height is the whole heights'
    median raised to the highest bound still held; on a track never seen whole, that bound.
    ``whole``: the height is the whole heights' median, not raised (published as
    ``head_visible``).
    """
    pairs = max(int(pairs), 1)
    height = detection.head_height
    if detection.head_visible and not detection.head_above:
        whole_heights = (whole_heights + (height,))[-pairs:]
        bounds = (bounds + (-math.inf,))[-pairs:]
        return _median(whole_heights), whole_heights, bounds, True
    bounds = (bounds + (height,))[-pairs:]
    bound = max(bounds)
    if whole_heights:
        median = _median(whole_heights)
        return max(median, bound), whole_heights, bounds, bound <= median
    return bound, whole_heights, bounds, False


@dataclasses.dataclass
class Track:
    """One person followed over pairs: constant-velocity state ``x, y, vx, vy``."""

    track_id: int
    state: np.ndarray            # x, y, vx, vy
    covariance: np.ndarray       # 4x4
    head_height: float
    confidence: float
    points: int
    hits: int
    last_seen_s: float
    head_visible: bool = True     # head_height is its whole detections' median, not a bound
    updated: bool = True
    seen_as_person: bool = False  # head seen once, or legs in min_hits of min_hits + 1
    whole_hits: int = 0           # detections not cut by the top edge, head high enough
    legs_hits: int = 0            # detections standing on legs (legs_seen)
    legs_seen_s: float = -math.inf    # last stamp with legs in min_hits of min_hits + 1, a
    #                                   whole detection, or its publication
    legs_recent: tuple = ()       # legs_seen of its last min_hits + 1 detections
    confirmed: bool = False       # published (min_hits, and seen as a person or min_travel_m)
    cut_top: bool = False         # the last detection was cut by the image's top edge
    depth_spread_m: float = float('nan')   # the last detection's depth spread
    detection: Detection = None   # the last detection it took
    start: np.ndarray = None      # first floor position
    farthest_m: float = 0.0       # farthest any detection it took lay from ``start``
    far_hits: int = 0             # detections it took min_travel_m or more from ``start``
    places: tuple = ()            # floor positions of its last PLACES_KEPT detections
    place_times: tuple = ()       # and their stamps
    spots: tuple = ()             # places it left by a jump (a warm object's other piece)
    whole_heights: tuple = ()     # head heights of its last head_height_pairs whole detections
    bounds: tuple = ()            # its last head_height_pairs detections' lower bounds (-inf)
    corrected: tuple = None       # (state, covariance) after its last detection
    held_s: float = -math.inf     # last stamp it was held beside a neighbour (_hold_beside)
    points_seen_s: float = -math.inf  # last stamp of a detection of points (not a silhouette)
    still_at: tuple = None        # where it has stood since still_since_s (within
    still_since_s: float = -math.inf  # object_radius_m of it)

    def __post_init__(self):
        if self.start is None:
            self.start = self.state[:2].copy()

    @property
    def travel_m(self):
        """Return the distance of the last detection from the first, metres (not predicted)."""
        if self.detection is None:
            return 0.0
        return float(math.hypot(self.detection.x - self.start[0],
                                self.detection.y - self.start[1]))

    @property
    def position(self):
        """
        Return the published floor position: x and y, metres.

        The filtered state (the detections as found, on which the gates, the travel and the
        legs tests work) moved across the view by the last detection's ``across``: the
        middle of its warm silhouette (``centred_on_silhouette``).
        """
        shift = (0.0, 0.0) if self.detection is None else self.detection.across
        return np.array([self.state[0] + shift[0], self.state[1] + shift[1]])

    @property
    def position_covariance(self):
        """Return the 2x2 floor position covariance, m^2."""
        return self.covariance[:2, :2]


def gated_assignment(distance, gate, miss_cost):
    """
    Pair tracks (rows) with detections (columns) at the least cost, each within its gate.

    Global nearest neighbour with a cost for leaving a track without a detection: the cost
    matrix gets one more column per track, its own "no detection" at ``miss_cost`` (the same
    for every track, at least the largest gate), so ``linear_sum_assignment`` takes a set of
    pairs only when it is cheaper than leaving tracks out: it minimises the pairs' distances
    plus ``miss_cost`` per track left out. Any one pair within its gate is taken; of two
    tracks wanting one detection the nearer gets it. Without those columns (infeasible pairs
    at a large finite cost) the solver maximises the number of pairs first: a track coasting
    with a grown gate, allowed only the detection another track sits on (0.01 m from it),
    takes it 1.3 m away and pushes that track onto a detection 0.7 m off, its neighbour's
    (found on ``open_office``: two people standing 0.7 m apart swapped ids while a walker
    passed in front of them). A cost per track, its own gate, would let a track with the
    larger gate take a detection from a nearer one. A trade-off (docs/people.md, step 5):
    two tracks coasting past people who stopped while hidden can now leave the right pairing
    for a cheaper single one.

    Parameters
    ----------
    distance : ndarray, shape (tracks, detections)
        Distances, m (``inf``: not allowed).
    gate : ndarray, shape (tracks,)
        Each track's gate, m.
    miss_cost : float
        Cost of a track left without a detection, m (not below the largest gate).

    Returns
    -------
    list of (row, col)
        The pairs, each with ``distance <= gate`` of its row.

    """
    distance = np.asarray(distance, dtype=np.float64)
    gate = np.asarray(gate, dtype=np.float64).reshape(-1)
    tracks, count = distance.shape
    if not tracks or not count:
        return []
    if miss_cost < gate.max():
        raise ValueError(f'gated_assignment: miss_cost must be at least the largest gate '
                         f'({gate.max()} m), got {miss_cost} m')
    infeasible = 1e6 * (1.0 + float(miss_cost))
    cost = np.full((tracks, count + tracks), infeasible)
    cost[:, :count] = np.where(distance <= gate[:, None], distance, infeasible)
    cost[np.arange(tracks), count + np.arange(tracks)] = miss_cost
    return [(int(row), int(col)) for row, col in zip(*linear_sum_assignment(cost))
            if col < count and distance[row, col] <= gate[row]]


class PeopleTracker:
    """
    Ids across pairs: predict, assign within the gate, update, start and end tracks.

    ``update(detections, stamp_s)`` returns the confirmed tracks seen or coasting; ``ended``
    after each update lists the ids that ended in it (their markers are deleted).
    """

    def __init__(self, config=None):
        self.config = config or PeopleConfig()
        self.tracks = []
        self.next_id = 1
        self.stamp_s = None
        self.ended = []
        self.object_memory = []      # (last seen s, spots) of warm objects' ended tracks
        self.counts = {'started': 0, 'ended': 0, 'unconfirmed_ended': 0, 'assigned': 0,
                       'unassigned_detections': 0, 'time_backwards': 0,
                       'object_detections': 0, 'legs_lapsed': 0, 'shape_lapsed': 0,
                       'held_beside': 0, 'legs_only_not_started': 0}

    def _predict(self, dt):
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        q = self.config.acceleration_sigma ** 2
        g = np.array([[dt * dt / 2, 0], [0, dt * dt / 2], [dt, 0], [0, dt]])
        for track in self.tracks:
            track.state = f @ track.state
            track.covariance = f @ track.covariance @ f.T + q * (g @ g.T)
            track.updated = False

    def _correct(self, track, detection, stamp_s):
        h = np.zeros((2, 4))
        h[0, 0] = h[1, 1] = 1.0
        r = detection.covariance + np.eye(2) * 1e-4
        s = h @ track.covariance @ h.T + r
        gain = track.covariance @ h.T @ np.linalg.inv(s)
        innovation = np.array([detection.x, detection.y]) - track.state[:2]
        track.state = track.state + gain @ innovation
        track.covariance = (np.eye(4) - gain @ h) @ track.covariance
        track.head_height, track.whole_heights, track.bounds, track.head_visible = \
            updated_head_height(track.whole_heights, track.bounds, detection,
                                self.config.head_height_pairs)
        track.legs_recent = (track.legs_recent + (detection.legs_seen,))[
            -(self.config.min_hits + 1):]
        track.seen_as_person = track.seen_as_person or self._is_person(track, detection)
        track.whole_hits += int(self._seen_whole(detection))
        track.legs_hits += int(detection.legs_seen)
        track.cut_top = detection.cut_top
        track.detection = detection
        track.farthest_m = max(track.farthest_m, track.travel_m)
        track.far_hits += int(track.travel_m >= self.config.min_travel_m)
        if self.is_warm_object(track) and track.places and min(
                math.hypot(detection.x - x, detection.y - y) for x, y in track.places) > \
                self.config.person_radius_m:
            for x, y in track.places:      # jumped to the object's other piece
                track.spots = new_spots(track.spots, x, y)
        track.places = (track.places + ((detection.x, detection.y),))[-PLACES_KEPT:]
        track.place_times = (track.place_times + (stamp_s,))[-PLACES_KEPT:]
        if not detection.silhouette:
            track.points_seen_s = stamp_s
        if track.still_at is None or math.hypot(detection.x - track.still_at[0],
                                                detection.y - track.still_at[1]) > \
                self.config.object_radius_m:
            track.still_at, track.still_since_s = (detection.x, detection.y), stamp_s
        track.depth_spread_m = detection.depth_spread_m
        track.confidence = detection.confidence
        track.points = detection.points
        track.hits += 1
        track.corrected = (track.state.copy(), track.covariance.copy())
        track.updated = True

    def _is_person(self, track, detection):
        """
        Whether a track, with this detection, has shown a person, not possibly a warm object.

        A detection not cut by the top edge with its head high enough does by itself; a body
        cut by the top edge (a warm screen looks the same) does when ``min_hits`` of the
        track's last ``min_hits + 1`` detections stood on warm legs (``legs_seen``): a
        passer-by's legs in front of a screen lent it legs for one pair on the bundled
        recording, which does not make it a person, nor do lends far apart in time.
        """
        if detection.cut_top:
            return sum(track.legs_recent) >= self.config.min_hits
        return self._seen_whole(detection)

    def _seen_whole(self, detection):
        """Whether a detection shows a person by itself: not cut by the top edge, head high."""
        return not detection.cut_top and detection.head_height >= self.config.min_head_height_m

    def _legs_lapsed(self, track, stamp_s):
        """
        Whether a published track's only evidence of a person, lent legs, has lapsed.

        Not ``min_travel_m`` from where it started in ``min_hits`` detections (a screen's
        track that took one passer-by's detection has not walked); legs or a whole body
        (``_seen_whole``) in fewer than ``LENT_LEGS_FRACTION`` of its detections; detected
        now; and for more than ``legs_lapse_s`` neither legs in ``min_hits`` of
        ``min_hits + 1`` detections (what published it), nor a whole detection, nor its
        publication. A warm screen cut by the top edge that a passer-by's legs, in front of
        it in two of three pairs, made a person (its pixels then kept from the background)
        shows none afterwards, and single lends now and then do not renew it, nor does a
        person standing up in front of it for a moment keep it for longer than the lapse; a
        far person standing on the floor shows legs pair after pair (the tuning sequences:
        61 of 63), one nearer its head.
        """
        return self.config.legs_lapse_s > 0 and track.confirmed and track.updated and \
            track.far_hits < self.config.min_hits and \
            track.legs_hits + track.whole_hits < LENT_LEGS_FRACTION * track.hits and \
            stamp_s - track.legs_seen_s > self.config.legs_lapse_s

    def _shape_lapsed(self, track, stamp_s):
        """
        Whether a published track has stood still on silhouettes alone for the lapse.

        Detected now, on a silhouette; for more than ``legs_lapse_s`` no detection of points
        (its start counts as one) and every detection within ``object_radius_m`` of where it
        stood at the lapse's start (``still_at``: a walker leaves it). A published person
        missed in the pair a warm screen's silhouette shows beside them (a screen with no
        texture: no points of its own) takes it and stays there; withdrawn, it must walk
        ``min_travel_m`` anew (from where it is) or show its legs or head to be published
        again. A far person standing still without a point for that long is withdrawn too
        (published again when it walks off).
        """
        return self.config.legs_lapse_s > 0 and track.confirmed and track.updated and \
            track.detection is not None and track.detection.silhouette and \
            stamp_s - max(track.points_seen_s, track.still_since_s) > self.config.legs_lapse_s

    def predicted_xy(self, stamp_s):
        """Return each track's floor position predicted to ``stamp_s`` (no state change)."""
        if self.stamp_s is not None and stamp_s < self.stamp_s:
            return []       # time went back: ``update`` starts over without these tracks
        dt = 0.0 if self.stamp_s is None else stamp_s - self.stamp_s
        return [(t.state[0] + dt * t.state[2], t.state[1] + dt * t.state[3])
                for t in self.tracks]

    def _walks_steadily(self, track):
        """
        Whether a track's last detections walk steadily (``walks_steadily``, ``steady_walk_m``).

        Not for a track that may have been a warm object when that walk began: one with
        ``object_min_hits`` detections up to the walk's first, which lies within
        ``object_radius_m`` of where the track started (``is_warm_object`` asks for the
        farthest detection, which a jittering screen of two pieces may carry past it). A
        warm screen's track, whose detections a passer-by sliding in front of it or its other
        piece after a short hiding can move in steps, is that; a walker's track is young, or
        has left its start.
        """
        if not walks_steadily(track.places, track.place_times, self.config.steady_walk_m):
            return False
        first = track.places[-STEADY_WALK_DETECTIONS]
        at_walk_start = track.hits - (STEADY_WALK_DETECTIONS - 1)
        return not (self.config.object_min_hits and
                    at_walk_start >= self.config.object_min_hits and
                    math.hypot(first[0] - track.start[0], first[1] - track.start[1]) <=
                    self.config.object_radius_m)

    def is_warm_object(self, track):
        """
        Whether an unpublished track has shown a static warm object, not a person.

        Detected at least ``object_min_hits`` times, never seen as a person (``_is_person``)
        and never farther than ``object_radius_m`` from where it started: a warm screen on a
        desk, cut by the image's top edge, detected pair after pair in the same place (in
        one piece or two, which the track takes in turn).
        """
        return bool(self.config.object_min_hits) and not track.confirmed and \
            track.hits >= self.config.object_min_hits and not track.seen_as_person and \
            track.farthest_m <= self.config.object_radius_m

    def object_distances(self, detections):
        """
        Return each detection's distance to where a warm object has been (inf: none near).

        For a detection cut by the top edge without its legs seen, the distance to the
        nearest of the last ``PLACES_KEPT`` detections of a warm object's track
        (``is_warm_object``), or, when within ``REMEMBERED_RADIUS_M``, to a place such a
        track left by a jump (a screen's other half, which its track took in turn) or one
        an object's track that ended within ``max_coast_s`` held (a passer-by hid the
        screen for a few pairs: its track ends after ``unconfirmed_coast_s``, and a new one
        is an object only after ``object_min_hits``); inf for the others and when there is
        no such track.
        """
        objects = [t for t in self.tracks if self.is_warm_object(t)]
        live = [xy for t in objects for xy in t.places]
        remembered = [xy for t in objects for xy in t.spots] + \
            [xy for _, kept in self.object_memory for xy in kept]
        out = np.full(len(detections), np.inf)
        for places, radius in ((live, np.inf), (remembered, REMEMBERED_RADIUS_M)):
            if not places:
                continue
            places = np.asarray(places)
            for index, d in enumerate(detections):
                if d.cut_top and not d.legs_seen:
                    near = float(np.hypot(places[:, 0] - d.x, places[:, 1] - d.y).min())
                    if near <= radius:
                        out[index] = min(out[index], near)
        return out

    def gate(self, track):
        """
        Return how far a detection may be from the track's prediction.

        ``gate_m`` plus 3 sigma of the predicted position, at most twice ``gate_m`` (a track
        coasting for long must not take a newcomer metres away).
        """
        return min(self.largest_gate(), self.config.gate_m + 3.0 * math.sqrt(max(
            0.0, float(np.linalg.eigvalsh(track.position_covariance)[-1]))))

    def largest_gate(self):
        """Return the cap of every track's gate, twice ``gate_m`` (``gate``), m."""
        return 2.0 * self.config.gate_m

    def _hold_beside(self, taken, stamp_s, support):
        """
        Keep published a still person whose points joined a neighbour's cluster (``held_beside``).

        A confirmed track that has shown its head (``HOLD_MIN_WHOLE_HITS`` whole detections),
        without a detection now, at rest at its last one (speed under ``HOLD_MAX_SPEED``),
        with a detection another confirmed track took now (``taken``) within twice
        ``person_radius_m`` of it, and at least ``hold_beside_points`` warm body points within
        ``person_radius_m / 2`` of it nearer to it than to those detections
        (``support(x, y, others)``: someone is still there), is held at
        its last detection, velocity zero: published and kept alive as if seen now
        (``held_s``), but not seen for ``reacquire_cut_s`` or the lent legs' lapse. Two people
        closer than about 0.6 m make one occupancy peak, the one with more points': the
        recording's person who sits down while a walker stops 0.28 m beside them had no
        detection and their track ended. Once the points at its place are gone (the person
        left) or the neighbour moved away, it coasts like any track.
        """
        if not self.config.hold_beside_points or support is None:
            return
        reach = 2.0 * self.config.person_radius_m
        for track in self.tracks:
            if not track.confirmed or track.updated or track.corrected is None or \
                    track.whole_hits < HOLD_MIN_WHOLE_HITS:
                continue
            state, covariance = track.corrected
            near = [(d.x, d.y) for d in taken
                    if math.hypot(d.x - state[0], d.y - state[1]) <= reach]
            if math.hypot(state[2], state[3]) > HOLD_MAX_SPEED or not near or \
                    support(state[0], state[1], near) < self.config.hold_beside_points:
                continue
            track.state = np.array([state[0], state[1], 0.0, 0.0])
            track.covariance = covariance.copy()
            track.held_s = stamp_s
            self.counts['held_beside'] += 1

    def update(self, detections, stamp_s, support=None):
        """
        Feed one pair's detections; return the published tracks.

        Published: confirmed (``min_hits``) and seen (or held, ``_hold_beside``) within
        ``publish_coast_s``; the others are kept for their id until ``max_coast_s``.
        ``support(x, y, others)``: the number of warm body points at a floor position this
        pair, not nearer to any of ``others`` (``PeopleEstimator`` gives it when it has the
        image), for ``_hold_beside``; None: nothing is held.
        """
        self.ended = []
        if self.stamp_s is not None and stamp_s < self.stamp_s:
            # A replay restarted or time jumped back: start over rather than predict backwards.
            self.counts['time_backwards'] += 1
            self.ended = [t.track_id for t in self.tracks if t.confirmed]
            self.tracks = []
            self.object_memory = []
        dt = 0.0 if self.stamp_s is None or stamp_s < self.stamp_s else stamp_s - self.stamp_s
        self.stamp_s = stamp_s
        self._predict(dt)
        assigned, beside = set(), []
        to_object = self.object_distances(detections)
        withheld = set()
        # Confirmed tracks first (a person walking up to a warm screen keeps the id; the
        # screen's unconfirmed track gets what is left).
        # A track held beside a neighbour (``_hold_beside``) since it was last seen comes after
        # the other confirmed ones: it must not take their detections.
        held = [t.held_s > t.last_seen_s for t in self.tracks]
        for group in ([t for t, h in zip(self.tracks, held) if t.confirmed and not h],
                      [t for t, h in zip(self.tracks, held) if t.confirmed and h],
                      [t for t in self.tracks if not t.confirmed]):
            free = [i for i in range(len(detections)) if i not in assigned]
            if not group or not free:
                continue
            distance = np.array([[math.hypot(t.state[0] - detections[i].x,
                                             t.state[1] - detections[i].y) for i in free]
                                 for t in group])
            gate = np.array([self.gate(t) for t in group])[:, None]
            # A body cut off by the image's edge (a warm screen looks the same) without its
            # legs seen is weak evidence: it continues a track only within ``gate_m`` of the
            # prediction and when the track was seen within ``reacquire_cut_s``.
            lost = np.array([stamp_s - t.last_seen_s > self.config.reacquire_cut_s
                             for t in group])[:, None]
            cut = np.array([detections[i].cut_top and not detections[i].legs_seen
                            for i in free])[None, :]
            distance = np.where(cut & (lost | (distance > self.config.gate_m)), np.inf,
                                distance)
            if not group[0].confirmed:
                # Low warm points rising out of view are a far body only on its legs: without
                # them they may continue a published track (its legs missed in a pair), never
                # build one (far_walker: a radiator's top beside the walker travelled 1.16 m).
                unseen = np.array([detections[i].legs_only and not detections[i].legs_seen
                                   for i in free])[None, :]
                distance = np.where(unseen, np.inf, distance)
            if group[0].confirmed:
                # Where a warm object has been, nearer than the track's prediction: the
                # object's, not a passing published track's (it coasts instead).
                near = to_object[free][None, :]
                objects = (near <= self.config.person_radius_m) & (near < distance)
                takable = objects & (distance <= gate)
                withheld.update(free[col] for col in np.flatnonzero(takable.any(axis=0)))
                distance = np.where(objects, np.inf, distance)
            # Leaving a track out costs the largest gate (the farthest any track may reach).
            for row, col in gated_assignment(distance, gate[:, 0], self.largest_gate()):
                self._correct(group[row], detections[free[col]], stamp_s)
                group[row].last_seen_s = stamp_s
                if sum(group[row].legs_recent) >= self.config.min_hits or \
                        self._seen_whole(detections[free[col]]) or \
                        self._walks_steadily(group[row]):
                    # Seen as a person now (a far person pacing without legs seen keeps it).
                    group[row].legs_seen_s = stamp_s
                assigned.add(free[col])
                if group[row].confirmed:
                    beside.append(detections[free[col]])
                self.counts['assigned'] += 1
        self.counts['object_detections'] += len(withheld)
        self._hold_beside(beside, stamp_s, support)
        for index, detection in enumerate(detections):
            if index in assigned:
                continue
            self.counts['unassigned_detections'] += 1
            if detection.legs_only and not detection.legs_seen:
                self.counts['legs_only_not_started'] += 1      # (above: no track of them)
                continue
            covariance = np.zeros((4, 4))
            covariance[:2, :2] = detection.covariance + np.eye(2) * 1e-4
            covariance[2:, 2:] = np.eye(2) * 1.0     # walking speed unknown: 1 m/s sigma
            height, whole_heights, bounds, whole = updated_head_height(
                (), (), detection, self.config.head_height_pairs)
            self.tracks.append(Track(0, np.array([detection.x, detection.y, 0, 0]),
                                     covariance, height, detection.confidence,
                                     detection.points, 1, stamp_s, whole,
                                     cut_top=detection.cut_top,
                                     depth_spread_m=detection.depth_spread_m,
                                     detection=detection,
                                     legs_recent=(detection.legs_seen,),
                                     points_seen_s=stamp_s,
                                     still_at=(detection.x, detection.y),
                                     still_since_s=stamp_s,
                                     places=((detection.x, detection.y),),
                                     place_times=(stamp_s,),
                                     whole_heights=whole_heights, bounds=bounds))
            self.tracks[-1].seen_as_person = self._is_person(self.tracks[-1], detection)
            self.tracks[-1].whole_hits = int(self._seen_whole(detection))
            self.tracks[-1].legs_hits = int(detection.legs_seen)
        alive = []
        for track in self.tracks:
            coast = self.config.max_coast_s if track.confirmed else \
                self.config.unconfirmed_coast_s
            if stamp_s - max(track.last_seen_s, track.held_s) > coast:
                if track.confirmed:
                    self.ended.append(track.track_id)
                    self.counts['ended'] += 1
                else:
                    self.counts['unconfirmed_ended'] += 1
                    if self.is_warm_object(track):
                        self.object_memory.append((track.last_seen_s,
                                                   track.spots + track.places))
            else:
                alive.append(track)
        self.tracks = alive
        self.object_memory = [(seen, kept) for seen, kept in self.object_memory
                              if stamp_s - seen <= self.config.max_coast_s]
        for track in self.tracks:
            if self._legs_lapsed(track, stamp_s):
                # Withdrawn: its id ends (markers deleted); unpublished and never seen as a
                # person (a warm object to the tracker again when it stayed within
                # object_radius_m), it needs legs in min_hits of min_hits + 1 detections anew
                # to be published again, under a new id.
                self.ended.append(track.track_id)
                self.counts['legs_lapsed'] += 1
                track.confirmed, track.seen_as_person, track.track_id = False, False, 0
            elif self._shape_lapsed(track, stamp_s):
                # Withdrawn as above; its walk so far no longer counts (it would publish it
                # again at once).
                self.ended.append(track.track_id)
                self.counts['shape_lapsed'] += 1
                track.confirmed, track.seen_as_person, track.track_id = False, False, 0
                track.start, track.farthest_m, track.far_hits = track.state[:2].copy(), 0.0, 0
        for track in self.tracks:
            on_legs = self.config.confirm_on_legs and track.hits == 1 and \
                track.detection is not None and track.detection.legs_under_head and \
                not any(other.confirmed and math.hypot(*(other.state[:2] - track.state[:2]))
                        <= self.config.gate_m for other in self.tracks)
            if not track.confirmed and track.updated and \
                    (track.hits >= self.config.min_hits or on_legs) and \
                    (track.seen_as_person or track.travel_m >= self.config.min_travel_m or
                     self._walks_steadily(track)):
                # Cut off by the image's top edge and never moving: a warm object, not a person.
                # Ids are given here, so noise that never becomes a track uses none.
                track.confirmed = True
                # The legs' lapse counts from here at the earliest (published by a head).
                track.legs_seen_s = max(track.legs_seen_s, stamp_s)
                track.track_id = self.next_id
                self.next_id += 1
                self.counts['started'] += 1
        confirmed = [t for t in self.tracks if t.confirmed]
        return [t for t in confirmed
                if stamp_s - max(t.last_seen_s, t.held_s) <= self.config.publish_coast_s]


@dataclasses.dataclass
class PeopleFrame:
    """One pair's result: the published tracks, the detections, the points used."""

    tracks: list
    detections: list
    ended: list
    points_used: int


class PeopleEstimator:
    """
    Detection and tracking of one rig, fed pair by pair.

    The people node and the evaluation run this one code path.

    ``transform``: ``world_from_rectified(pose, R1)``. Each pair: the left rectified image
    (optional; without it no warm filter is applied, counted as ``no_image``) and the points
    in the rectified left frame with their left pixels, disparities and confidences. Where a
    published person's points are, the background does not learn the warm pixels (a person
    seated for long stays foreground).
    """

    def __init__(self, transform, config=None):
        self.config = config or PeopleConfig()
        self.transform = transform
        self.background = WarmBackground(self.config)
        self.tracker = PeopleTracker(self.config)
        self.protect = None
        self.hold = None
        self.counts = {'pairs': 0, 'no_image': 0, 'no_points': 0, 'points_in': 0,
                       'points_not_warm': 0, 'points_out_of_range': 0,
                       'points_below_min_confidence': 0, 'points_without_disparity': 0,
                       'detections': 0,
                       'cut_legs_checked': 0, 'cut_legs_seen': 0, 'cut_legs_out_of_image': 0,
                       'cut_legs_fragment': 0, 'cut_legs_gap': 0, 'cut_legs_not_checked': 0,
                       'cut_legs_wide': 0, 'head_legs_checked': 0, 'head_legs_seen': 0,
                       'legs_only_detections': 0, 'legs_only_below_top': 0,
                       'legs_only_too_far': 0, 'legs_only_not_checked': 0,
                       'silhouette_centred': 0, 'silhouette_not_found': 0,
                       'silhouette_shared': 0, 'silhouette_not_checked': 0,
                       'head_above_detections': 0, 'silhouettes': 0, 'silhouette_covered': 0,
                       'silhouette_no_disparity': 0, 'silhouette_not_back': 0,
                       'silhouette_two_depths': 0,
                       'silhouette_not_body': 0,
                       'silhouette_detections': 0, 'silhouette_pairs_not_checked': 0,
                       'silhouette_at_side': 0,
                       'silhouette_skew_corrected': 0, 'silhouette_skew_not_corrected': 0}
        self.previous_left = None       # (stamp, the last pair's left image) for the skew

    def process(self, stamp_s, points, x_left, y, disparity=None, confidence=None,
                left_image=None, image_shape=None, intrinsics=None, right_image=None,
                stereo=None, skew_s=None):
        """
        Return the PeopleFrame of one pair (see the class docstring).

        ``intrinsics``: ``(fx, fy, cx, cy)`` of the rectified left image (camera_info ``P``);
        with it and ``left_image``, a body cut by the image's top edge standing on warm legs
        (``standing_on_legs``) in ``min_hits`` of its track's last ``min_hits + 1`` pairs
        counts as a person (``cut_legs_seen``); without, such a body must move
        ``min_travel_m`` first (``cut_legs_not_checked``). With the rectified ``right_image``
        and ``stereo`` (``(fx B, cx_left - cx_right)`` of the right camera_info's ``P``) too,
        bodies rising out of the top edge that no detection covers are found by their
        silhouettes (``silhouette_detections``, ``silhouette_margin_counts``); with the left
        image but without those, the pairs are counted (``silhouette_pairs_not_checked``).
        ``skew_s``: the pair's right acquisition less its left one (``pair_info``), for the
        silhouettes' motion during it (their disparities; None: not corrected).
        """
        self.counts['pairs'] += 1
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        x_left = np.asarray(x_left, dtype=np.float64).reshape(-1)
        y = np.asarray(y, dtype=np.float64).reshape(-1)
        self.counts['points_in'] += len(points)
        if not len(points):
            self.counts['no_points'] += 1
        if image_shape is None and left_image is not None:
            image_shape = np.shape(left_image)
        keep = np.ones(len(points), dtype=bool)
        warm = None
        if left_image is not None:
            warm = self.background.update(left_image, stamp_s, self.protect, self.hold)
            if self.config.require_warm:
                keep = warm_points(warm, x_left, y)
                self.counts['points_not_warm'] += int((~keep).sum())
        else:
            self.counts['no_image'] += 1
        world = rectified_to_world(points, self.transform)
        centre = camera_centre_in_world(self.transform)
        in_range = np.hypot(world[:, 0] - centre[0], world[:, 1] - centre[1]) <= \
            self.config.max_range_m
        self.counts['points_out_of_range'] += int((keep & ~in_range).sum())
        keep &= in_range
        # What detect_people leaves out of the detections (counted here, where the points of
        # the pair are known; they still count as matched points for the legs' tests).
        if confidence is not None:
            self.counts['points_below_min_confidence'] += int(
                (keep & (np.asarray(confidence, dtype=np.float64) <
                         self.config.min_confidence)).sum())
        if disparity is not None:
            self.counts['points_without_disparity'] += int(
                (keep & ~(np.asarray(disparity, dtype=np.float64) > 0)).sum())
        used = np.flatnonzero(keep)
        pixels = np.column_stack([x_left, y])[keep]
        detections = detect_people(
            world[keep], centre, None if disparity is None else np.asarray(disparity)[keep],
            points[keep, 2], None if confidence is None else np.asarray(confidence)[keep],
            self.config, pixels, image_shape)
        self.counts['detections'] += len(detections)
        legs_checked = warm is not None and intrinsics is not None and \
            self.config.legs_min_fraction > 0
        if legs_checked:
            detections = legs_only_bodies(detections, warm, self.transform, intrinsics,
                                          pixels, self.counts)
        else:       # nothing tells a far body's legs from a low warm thing (or the legs
            #         test is off, legs_min_fraction 0: a legs-only body never starts a track)
            self.counts['legs_only_not_checked'] += sum(d.legs_only for d in detections)
            detections = [d for d in detections if not d.legs_only]
        if legs_checked:
            detections = standing_on_legs(detections, warm, self.transform, intrinsics,
                                          points[keep], pixels, self.config, self.counts,
                                          self.tracker.predicted_xy(stamp_s))
        else:       # no image or no camera matrix (or the check off): cut bodies must walk
            self.counts['cut_legs_not_checked'] += sum(d.cut_top for d in detections)
        if self.config.centre_on_silhouette and warm is not None and intrinsics is not None:
            # After the legs tests: their windows were chosen around the points' median.
            detections = centred_on_silhouette(detections, warm, self.transform, intrinsics,
                                               points[keep], pixels, self.counts,
                                               self.background.valid)
        elif self.config.centre_on_silhouette:     # no image or camera matrix: the points'
            self.counts['silhouette_not_checked'] += len(detections)
        if warm is not None:
            detections = [self._head_above(d, warm, pixels) for d in detections]
        if self.config.silhouette_margin_counts > 0 and warm is not None:
            if intrinsics is not None and right_image is not None and stereo is not None:
                detections = detections + self._silhouettes(
                    detections, warm, left_image, right_image, intrinsics, stereo, pixels,
                    self._motion(stamp_s, skew_s))
            else:       # the left image alone: no silhouette's depth
                self.counts['silhouette_pairs_not_checked'] += 1
        tracks = self.tracker.update(detections, stamp_s,
                                     None if warm is None else self._warm_support(world[keep]))
        self.protect = self._people_pixels(tracks, used, x_left, y, image_shape)
        self.hold = self._shape_pixels(tracks, image_shape)
        if left_image is not None and self.config.silhouette_margin_counts > 0:
            self.previous_left = (stamp_s, np.asarray(left_image, dtype=np.float64))
        return PeopleFrame(tracks, detections, list(self.tracker.ended), int(keep.sum()))

    def _motion(self, stamp_s, skew_s):
        """``(previous left image, time since it, skew)`` for ``silhouette_detections``."""
        if self.previous_left is None or skew_s is None:
            return None
        return self.previous_left[1], stamp_s - self.previous_left[0], skew_s

    def _silhouettes(self, detections, warm, left_image, right_image, intrinsics, stereo,
                     pixels, motion=None):
        """``silhouette_detections`` of this pair (the background's last difference)."""
        background = self.background
        weak = background.valid & (background.difference > self.config.silhouette_margin_counts)
        right = np.asarray(right_image, dtype=np.float64)
        if right.shape != warm.shape:
            raise ValueError(f'people: right image shape {right.shape} differs from the left '
                             f'image shape {warm.shape}')
        return silhouette_detections(detections, weak, warm, left_image, right, self.transform,
                                     intrinsics, stereo, pixels, self.config, self.counts,
                                     valid_right=np.isfinite(right) & (right > 0),
                                     valid_left=background.valid, motion=motion)

    def _warm_support(self, points):
        """
        Return ``support(x, y, others)``: the warm body points of a place, not its neighbours'.

        The points (0.6-2.3 m above the floor, ``min_point_height_m``, ``max_point_height_m``)
        within ``person_radius_m / 2`` of ``(x, y)`` that lie nearer to it than to every floor
        position in ``others`` (the neighbours' detections): a neighbour's own points that
        spill towards the place do not count.
        """
        config = self.config
        body = points[(points[:, 2] >= config.min_point_height_m) &
                      (points[:, 2] <= config.max_point_height_m), :2]
        radius = 0.5 * config.person_radius_m

        def support(x, y, others=()):
            distance = np.hypot(body[:, 0] - x, body[:, 1] - y)
            own = distance <= radius
            for ox, oy in others:
                own &= distance < np.hypot(body[:, 0] - ox, body[:, 1] - oy)
            return int(np.count_nonzero(own))
        return support

    def _head_above(self, detection, warm, pixels):
        """Mark a whole detection whose silhouette reaches the top row (``head_above``)."""
        if not detection.head_visible or detection.members is None:
            return detection
        if not warm_column_reaches_top(warm, pixels[detection.members]):
            return detection
        self.counts['head_above_detections'] += 1
        return dataclasses.replace(detection, head_above=True)

    @staticmethod
    def _shape_pixels(tracks, image_shape):
        """
        Pixels of the published tracks' silhouettes now (``WarmBackground.update``'s hold).

        Most of a far body's silhouette is under the warm margin: learned with the cool time
        constant, a far person standing still would fade within a minute.
        """
        if image_shape is None:
            return None
        mask = np.zeros(image_shape, dtype=bool)
        for track in tracks:
            if track.updated and track.detection is not None and \
                    track.detection.shape_pixels is not None and \
                    mask.size > track.detection.shape_pixels.max(initial=-1):
                mask.flat[track.detection.shape_pixels] = True
        return mask

    @staticmethod
    def _people_pixels(tracks, used, x_left, y, image_shape):
        """Pixels (dilated by 2) of the points of the published tracks' detections now."""
        if image_shape is None:
            return None
        mask = np.zeros(image_shape, dtype=bool)
        for track in tracks:
            # A legs-only body's pixels stay learnable: a narrow warm thing standing far off
            # (a panel radiator) then fades into the background in minutes, as a far person
            # standing still that long does too.
            if track.updated and track.detection is not None and \
                    track.detection.members is not None and not track.detection.legs_only:
                members = used[track.detection.members]
                rows, cols, inside = pixel_indices(image_shape, x_left[members], y[members])
                mask[rows[inside], cols[inside]] = True

        return ndimage.binary_dilation(mask, iterations=2) if mask.any() else mask
