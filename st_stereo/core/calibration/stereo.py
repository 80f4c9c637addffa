"""
Mono and stereo calibration of the thermal rig from target detections, and rectification.

Distortion model: plumb_bob with k1 and k2 only (p1 = p2 = k3 = 0 fixed). A 51 deg lens has a
mild, radially symmetric barrel distortion that two radial terms describe; tangential terms and
k3 are poorly constrained by blurred targets a few dozen pixels wide and would fit noise (at
80x60 they trade against the principal point). The result is written as plumb_bob with five
coefficients, as camera_calibration does.
"""

import dataclasses

import cv2
import numpy as np

from st_stereo.core.calibration.files import CameraCalibration
from st_stereo.core.calibration.targets import CalibrationInputError

MONO_FLAGS = cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
COVERAGE_GRID = (4, 3)          # columns x rows of image cells for the coverage report
OUTLIER_VIEW_FACTOR = 3.0       # a view reprojecting 3x worse than the median view is dropped
OUTLIER_VIEW_FLOOR_PX = 0.1     # ... unless it is within 0.1 px RMS anyway


@dataclasses.dataclass
class MonoResult:
    """One camera's intrinsics and its per-view poses."""

    camera_matrix: np.ndarray
    distortion: np.ndarray
    rms: float
    rotations: list
    translations: list
    per_view_rms: np.ndarray


@dataclasses.dataclass
class StereoResult:
    """The rig: both cameras, extrinsics, rectification and the quality figures."""

    left: MonoResult
    right: MonoResult
    rotation: np.ndarray          # R: left camera frame -> right camera frame
    translation: np.ndarray       # T, metres
    stereo_rms: float
    rectification: tuple          # R1, R2, P1, P2
    vertical_disparity: np.ndarray
    views: int
    dropped_views: dict = dataclasses.field(default_factory=dict)   # side -> count

    @property
    def baseline_m(self):
        """Distance between the optical centres, metres."""
        return float(np.linalg.norm(self.translation))

    def calibrations(self, size, names=('left', 'right')):
        """Return the left and right CameraCalibration (camera_calibration YAML content)."""
        r1, r2, p1, p2 = self.rectification
        return tuple(CameraCalibration(
            width=size[0], height=size[1], camera_name=name,
            camera_matrix=mono.camera_matrix, distortion_model='plumb_bob',
            distortion=np.asarray(mono.distortion, dtype=np.float64).ravel()[:5],
            rectification=r, projection=p)
            for name, mono, r, p in zip(names, (self.left, self.right), (r1, r2), (p1, p2)))


def coverage(points_per_view, size, grid=COVERAGE_GRID):
    """Count of detected points per image cell (rows x cols of ``grid``)."""
    counts = np.zeros((grid[1], grid[0]), dtype=int)
    for points in points_per_view:
        cols = np.clip((points[:, 0] / size[0] * grid[0]).astype(int), 0, grid[0] - 1)
        rows = np.clip((points[:, 1] / size[1] * grid[1]).astype(int), 0, grid[1] - 1)
        np.add.at(counts, (rows, cols), 1)
    return counts


def calibrate_mono(object_points, image_points, size):
    """Intrinsics of one camera from per-view target points (OpenCV calibrateCamera)."""
    if len(image_points) < 3:
        raise CalibrationInputError(f'need the target in at least 3 views per camera, got '
                                    f'{len(image_points)}')
    objects = [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points]
    images = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in image_points]
    guess = np.array([[size[0] / 2 / np.tan(np.radians(25.5)), 0, (size[0] - 1) / 2],
                      [0, size[0] / 2 / np.tan(np.radians(25.5)), (size[1] - 1) / 2],
                      [0, 0, 1]])
    rms, k, d, rvecs, tvecs, _, _, per_view = cv2.calibrateCameraExtended(
        objects, images, size, guess, np.zeros(5),
        flags=MONO_FLAGS | cv2.CALIB_USE_INTRINSIC_GUESS)
    return MonoResult(camera_matrix=k, distortion=d.ravel(), rms=float(rms),
                      rotations=list(rvecs), translations=list(tvecs),
                      per_view_rms=per_view.ravel())


def rectified_vertical_disparity(left_points, right_points, left, right, rectification):
    """|y_left - y_right| of matched target points after rectification, pixels (all views)."""
    r1, r2, p1, p2 = rectification
    values = []
    for lp, rp in zip(left_points, right_points):
        lr = cv2.undistortPoints(np.asarray(lp, np.float64).reshape(-1, 1, 2),
                                 left.camera_matrix, left.distortion, R=r1, P=p1)
        rr = cv2.undistortPoints(np.asarray(rp, np.float64).reshape(-1, 1, 2),
                                 right.camera_matrix, right.distortion, R=r2, P=p2)
        values.append(np.abs(lr[:, 0, 1] - rr[:, 0, 1]))
    return np.concatenate(values) if values else np.zeros(0)


def outlier_views(per_view_rms, factor=OUTLIER_VIEW_FACTOR, floor_px=OUTLIER_VIEW_FLOOR_PX):
    """Flag the views whose reprojection RMS exceeds ``factor`` x the median and ``floor_px``."""
    per_view_rms = np.asarray(per_view_rms, dtype=np.float64)
    limit = max(factor * float(np.median(per_view_rms)), floor_px)
    return per_view_rms > limit


def calibrate_stereo(target, left_points, right_points, size, left_only=(), right_only=()):
    """
    Calibrate both cameras, then the rig, then rectify.

    ``left_points`` / ``right_points`` are the detections of the pairs where both cameras saw the
    target (same order); ``left_only`` / ``right_only`` add views one camera saw alone to that
    camera's intrinsics. Views that reproject much worse than the others after a first
    calibration (``outlier_views``: a mis-located point) are dropped, counted in
    ``dropped_views``, and the cameras calibrated again.
    """
    if len(left_points) < 3:
        raise CalibrationInputError(f'need at least 3 pairs with the target in both images, '
                                    f'got {len(left_points)}')
    model = target.object_points()
    left_points, right_points = list(left_points), list(right_points)
    left_only, right_only = list(left_only), list(right_only)
    dropped = {'left': 0, 'right': 0}
    for attempt in range(2):
        left = calibrate_mono([model] * (len(left_points) + len(left_only)),
                              left_points + left_only, size)
        right = calibrate_mono([model] * (len(right_points) + len(right_only)),
                               right_points + right_only, size)
        flags = [outlier_views(mono.per_view_rms) for mono in (left, right)]
        if attempt or not (flags[0].any() or flags[1].any()):
            break
        pairs = len(left_points)
        bad_pair = flags[0][:pairs] | flags[1][:pairs]
        if (~bad_pair).sum() < 3:
            break
        dropped['left'] += int(flags[0].sum())
        dropped['right'] += int(flags[1].sum())
        left_only = [p for p, bad in zip(left_only, flags[0][pairs:]) if not bad]
        right_only = [p for p, bad in zip(right_only, flags[1][pairs:]) if not bad]
        left_points = [p for p, bad in zip(left_points, bad_pair) if not bad]
        right_points = [p for p, bad in zip(right_points, bad_pair) if not bad]
    objects = [model.reshape(-1, 1, 3)] * len(left_points)
    lp = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in left_points]
    rp = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in right_points]
    rms, _, _, _, _, rotation, translation, _, _ = cv2.stereoCalibrate(
        objects, lp, rp, left.camera_matrix, left.distortion, right.camera_matrix,
        right.distortion, size, flags=cv2.CALIB_FIX_INTRINSIC)
    translation = np.asarray(translation, dtype=np.float64).reshape(3, 1)
    r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(
        left.camera_matrix, left.distortion, right.camera_matrix, right.distortion, size,
        rotation, translation, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    rectification = (r1, r2, p1, p2)
    vertical = rectified_vertical_disparity(left_points, right_points, left, right,
                                            rectification)
    return StereoResult(left=left, right=right, rotation=rotation,
                        translation=translation.ravel(), stereo_rms=float(rms),
                        rectification=rectification, vertical_disparity=vertical,
                        views=len(left_points), dropped_views=dropped)
