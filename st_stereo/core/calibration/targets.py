"""
Calibration targets and their detection in 80x60 thermal images.

A heated target at 80x60 is a handful of blurred pixels per circle or square, where OpenCV's
detectors (tuned for sharp, large images) fail. Detection therefore runs on a 4x upsampled,
contrast-stretched copy (bicubic), which gives the grid and rough positions; every circle centre
and chessboard corner is then fitted on the original pixels with a model of a blurred,
pixel-integrated blob or corner (``st_stereo.core.calibration.target_refinement``). Polarity
(warm dots on a cold plate or cold holes in a warm plate) is found by trying both. A detection
is accepted only if the points fit the target's plane through a homography to within
``max_homography_rms`` pixels (lens distortion at 51 deg stays well below that over a target),
which rejects partial or mis-ordered grids.
"""

import dataclasses

import cv2
import numpy as np

from st_stereo.core.calibration.target_refinement import refine_chessboard_corners, \
    refine_circle_centres
from st_stereo.core.image_io import contrast_stretch_u8

TARGET_KINDS = ('chessboard', 'circles', 'acircles')
UPSAMPLE = 4


class CalibrationInputError(ValueError):
    """Calibration input that cannot be used; the message says what and where."""


@dataclasses.dataclass(frozen=True)
class CalibrationTarget:
    """
    A planar target: kind, grid size and spacing.

    ``rows`` x ``cols`` are inner corners for a chessboard and circles for circle grids; for an
    asymmetric grid (``acircles``) ``cols`` is the number of circles per row and the rows are
    offset by half a spacing (OpenCV's convention). ``spacing_m`` is the square side or the
    distance between neighbouring circle centres in a row (metres).
    """

    kind: str
    rows: int
    cols: int
    spacing_m: float

    def __post_init__(self):
        """Validate the description."""
        if self.kind not in TARGET_KINDS:
            raise CalibrationInputError(f'target: kind must be one of {", ".join(TARGET_KINDS)}, '
                                        f'got {self.kind!r}')
        if self.rows < 2 or self.cols < 2:
            raise CalibrationInputError(f'target: need at least 2 x 2 points, got '
                                        f'{self.rows} x {self.cols}')
        if self.kind != 'acircles' and self.rows == self.cols:
            raise CalibrationInputError(
                f'target: a square {self.kind} grid ({self.rows} x {self.cols}) has no defined '
                'orientation; use different row and column counts')
        if not self.spacing_m > 0:
            raise CalibrationInputError(f'target: spacing must be positive, got '
                                        f'{self.spacing_m}')

    @property
    def pattern_size(self):
        """Return the pattern size as OpenCV wants it: (points per row, rows)."""
        return (self.cols, self.rows)

    @property
    def count(self):
        """Return the number of points."""
        return self.rows * self.cols

    def object_points(self):
        """Target points (n, 3) in metres on z = 0, in OpenCV's detection order."""
        rows, cols = np.mgrid[0:self.rows, 0:self.cols]
        if self.kind == 'acircles':
            x = (2 * cols + rows % 2) * self.spacing_m / 2.0
            y = rows * self.spacing_m / 2.0
        else:
            x, y = cols * self.spacing_m, rows * self.spacing_m
        return np.column_stack([x.ravel(), y.ravel(), np.zeros(self.count)]).astype(np.float32)


def to_u8(image):
    """Contrast-stretch to 8 bits (0.5th-99.5th percentile)."""
    return contrast_stretch_u8(image, 0.5, 99.5)


def upsample(image_u8, factor=UPSAMPLE):
    """Bicubic upsampling; pixel centres map as ``x_up = (x + 0.5) f - 0.5``."""
    return cv2.resize(image_u8, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC)


def from_upsampled(points, factor=UPSAMPLE):
    """Map upsampled pixel coordinates back to the original image."""
    return (np.asarray(points, dtype=np.float64) + 0.5) / factor - 0.5


def _blob_detector(target, dark_blobs):
    params = cv2.SimpleBlobDetector_Params()
    params.filterByColor = True
    params.blobColor = 0 if dark_blobs else 255
    params.minThreshold, params.maxThreshold, params.thresholdStep = 20, 235, 10
    params.filterByArea = True
    params.minArea, params.maxArea = 6.0, 4000.0
    params.filterByCircularity = True
    params.minCircularity = 0.5
    params.filterByConvexity = False
    params.filterByInertia = True
    params.minInertiaRatio = 0.2
    params.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(params)


def homography_rms(target, points):
    """RMS distance (pixels) of detected points to the best homography of the target plane."""
    model = target.object_points()[:, :2].astype(np.float64)
    homography, _ = cv2.findHomography(model, points.astype(np.float64), 0)
    if homography is None:
        return float('inf')
    mapped = cv2.perspectiveTransform(model.reshape(-1, 1, 2), homography).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum((mapped - points) ** 2, axis=1))))


def canonical_order(target, points, max_rms):
    """
    Reverse a detection that starts at the far end, so left and right views agree on point 0.

    OpenCV may return a grid in either direction; point 0 is made the one nearer the image's
    top-left (smaller x + y than the last point), provided the reversed order still fits the
    target (for an asymmetric grid it may not).
    """
    if points[0].sum() > points[-1].sum():
        reverse = points[::-1].copy()
        if homography_rms(target, reverse) <= max_rms:
            return reverse
    return points


@dataclasses.dataclass
class Detection:
    """Target points found in one image (n, 2), with how they were found."""

    points: np.ndarray
    warm_features: bool
    homography_rms: float


# Below these distances between neighbouring points (pixels) circles merge and corners'
# windows overlap the next corners: located points err by up to 0.3-0.5 px (measured).
MIN_SPACING_PX = {'circles': 3.5, 'acircles': 3.5, 'chessboard': 3.0}
REJECTIONS = ('not found', 'too small', 'fit failed', 'not planar')


def _refine(image, rough, target, warm):
    """Fit every point of a grid around its rough position (``target_refinement``)."""
    if target.kind == 'chessboard':
        return refine_chessboard_corners(image, rough, target.pattern_size)
    return refine_circle_centres(image, rough, warm)


def grid_reseeded(target, refined):
    """
    Start positions for a second fit: the valid fitted points, the others from the grid.

    A point whose rough position was more than a fit's reach off (OpenCV's detector can
    misplace a blob by over a pixel when the grid is small and foreshortened) is placed where
    the homography of the valid points puts it.
    """
    model = target.object_points()[:, :2].astype(np.float64)
    valid = refined.valid
    homography, _ = cv2.findHomography(model[valid], refined.points[valid], 0)
    if homography is None:
        return refined.points
    predicted = cv2.perspectiveTransform(model.reshape(-1, 1, 2), homography).reshape(-1, 2)
    return np.where(valid[:, None], refined.points, predicted)


def find_target(image, target, max_homography_rms=0.5, reseed=False):
    """
    Find the target in one raw image: (Detection, None) or (None, the reason it was rejected).

    Both polarities are tried. OpenCV's detectors on the upsampled image give rough positions
    and the grid order; each point is then fitted on the original pixels
    (``st_stereo.core.calibration.target_refinement``). Reasons, in ``REJECTIONS``:
    ``not found`` (no full grid), ``too small`` (points nearer to each other than
    ``MIN_SPACING_PX``), ``fit failed`` (a point did not fit its model), ``not planar``
    (points off the target's homography by more than ``max_homography_rms``: a partial or
    mis-ordered grid). With ``reseed``, points that did not fit from OpenCV's positions are
    fitted again from the grid's homography through the others (at least half of them
    valid): ``grid_reseeded``.
    """
    base = to_u8(image)
    found, reasons = [], []
    for warm in (True, False):
        rough = rough_points(upsample(base if warm else 255 - base), target)
        if rough is None:
            continue
        if nearest_spacing(rough) < MIN_SPACING_PX[target.kind]:
            reasons.append('too small')
            continue
        refined = _refine(image, rough, target, warm)
        if reseed and not refined.valid.all() and \
                refined.valid.sum() >= max(4, target.count // 2):
            refined = _refine(image, grid_reseeded(target, refined), target, warm)
        if not refined.valid.all():
            reasons.append('fit failed')
            continue
        points = canonical_order(target, refined.points, max_homography_rms)
        rms = homography_rms(target, points)
        if rms > max_homography_rms:
            reasons.append('not planar')
            continue
        found.append(Detection(points=points, warm_features=warm, homography_rms=rms))
    if not found:
        return None, (reasons[0] if reasons else 'not found')
    return min(found, key=lambda d: d.homography_rms), None


def rough_points(upsampled_u8, target):
    """Grid points (n, 2) in original pixels from OpenCV's detector, or None (not found)."""
    if target.kind == 'chessboard':
        ok, points = cv2.findChessboardCornersSB(
            upsampled_u8, target.pattern_size,
            flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    else:
        flags = (cv2.CALIB_CB_ASYMMETRIC_GRID if target.kind == 'acircles'
                 else cv2.CALIB_CB_SYMMETRIC_GRID)
        # In the (possibly inverted) image the target's features are bright: blobColor 255.
        ok, points = cv2.findCirclesGrid(upsampled_u8, target.pattern_size, flags=flags,
                                         blobDetector=_blob_detector(target, False))
    return from_upsampled(points.reshape(-1, 2)) if ok else None


def grid_numberings(target, points):
    """
    Return the numberings of a found grid that fit the target as well as the found one.

    The found order, rows reversed, columns reversed and both, kept when the reordered points
    still fit the target's plane through a homography (all four for symmetric grids and
    chessboards; an asymmetric grid may allow fewer).
    """
    grid = np.asarray(points, dtype=np.float64).reshape(target.rows, target.cols, 2)
    limit = 2.0 * homography_rms(target, grid.reshape(-1, 2)) + 1e-6
    orders = [grid, grid[::-1], grid[:, ::-1], grid[::-1, ::-1]]
    return [order.reshape(-1, 2) for order in orders
            if homography_rms(target, order.reshape(-1, 2)) <= limit]


def stereo_numbering(target, left_points, right_points):
    """
    Return the right camera's points numbered as the left camera numbered them.

    Each image's detector decides apart which corner comes first and which way the rows run:
    a target turned far in its plane can come out numbered from another corner, or with its
    rows reversed, in one image (seen with a chessboard turned 105 degrees and a circle grid
    turned 45 degrees). The two cameras look at it from nearly the same place, so the right
    numbering is the one whose points the left ones map to with an affine map nearest the
    identity (a shift, a slight stretch), not a reflection or a half turn. This assumes the
    two raw images are not turned far against each other (a camera mounted upside down
    would be read as a half turn).
    """
    left = np.asarray(left_points, dtype=np.float64)
    design = np.column_stack([left, np.ones(len(left))])

    def distance_from_a_shift(order):
        affine = np.linalg.lstsq(design, order, rcond=None)[0][:2].T
        return float(np.linalg.norm(affine - np.eye(2)))
    return min(grid_numberings(target, right_points), key=distance_from_a_shift)


def detect_target(image, target, max_homography_rms=0.5):
    """Return the target's Detection in one raw image, or None (``find_target`` says why)."""
    return find_target(image, target, max_homography_rms)[0]


def nearest_spacing(points):
    """Median distance from each point to its nearest neighbour, pixels."""
    points = np.asarray(points, dtype=np.float64)
    distance = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.fill_diagonal(distance, np.inf)
    return float(np.median(distance.min(axis=1)))
