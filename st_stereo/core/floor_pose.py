"""
The rig's height, tilt and roll from a heated target lying flat on the floor.

Why a target and not the room's own floor: the floor fit to the static background's stereo
points was measured on the simulated rooms (docs/people.md, "rig pose"): at 3.4-8 m a floor's
few-centimetre texture is averaged away below the sensors' fixed pattern noise, and neither
ST nor StereoSGBM finds the floor well enough for centimetres and tenths of a degree. A
planar target of known geometry on the floor gives both: its points are found to a few
hundredths of a pixel (``st_stereo.core.calibration.targets``) and their pose follows from
the calibrated cameras (perspective-n-point, refined over both cameras at once).

Geometry (conventions of ``st_stereo.core.rig_pose``): with ``n`` the floor's upward unit
normal in the left camera's raw optical frame and ``p`` any point of the target's surface,

- the camera's height above the floor is ``h = -n . p + thickness`` (the target's surface
  lies ``thickness`` above the floor);
- ``R_rig_optical = R_y(-tilt) M R_z(roll)`` gives ``n = (-sin(tilt) sin(roll),
  -sin(tilt) cos(roll), -cos(tilt))``, so ``tilt = acos(-n_z)`` and
  ``roll = atan2(-n_x, -n_y)``. Looking straight down (tilt 0) roll and yaw are the same
  rotation about the vertical and the floor fixes neither; near it the roll is still what
  the floor's normal says (the tilt's direction), only measured less precisely.

The yaw and the position in the room are not the floor's to give: the user sets them.
"""

import dataclasses
import math

import cv2
import numpy as np
from scipy.optimize import least_squares

from st_stereo.core.calibration.targets import grid_numberings
from st_stereo.core.rig_pose import stereo_extrinsics

# Below this tilt (degrees from straight down) the roll is poorly determined by the floor.
MIN_TILT_FOR_ROLL_DEG = 2.0
# Distortion models ``cv2.projectPoints`` / ``solvePnP`` apply (5 or 8 coefficients).
SUPPORTED_DISTORTION = ('plumb_bob', 'rational_polynomial')


class FloorPoseError(ValueError):
    """Input from which the floor cannot be found (names the problem)."""


def tilt_roll_of_up(up):
    """
    Return ``(tilt_deg, roll_deg)`` of the floor's upward normal in the left optical frame.

    Inverse of ``st_stereo.core.rig_pose.rig_to_optical_rotation`` applied to the world's z
    axis (module docstring). ``up`` need not be unit length.
    """
    up = np.asarray(up, dtype=np.float64)
    norm = float(np.linalg.norm(up))
    if not norm > 0 or not np.isfinite(norm):
        raise FloorPoseError(f'floor normal: expected a non-zero vector, got {up.tolist()}')
    up = up / norm
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, -up[2]))))
    roll = math.degrees(math.atan2(-up[0], -up[1]))
    return tilt, roll


def floor_of_target(rotation, translation, thickness_m=0.0):
    """
    Return ``(up, height_m)``: the floor under a target lying flat on it, in the camera frame.

    ``rotation``, ``translation``: the target's pose in the camera's optical frame (target
    points ``X`` are ``rotation @ X + translation``; the target's plane is its z = 0).
    ``up`` is the target's normal turned towards the camera (a camera above the floor).
    """
    normal = np.asarray(rotation, dtype=np.float64)[:, 2]
    origin = np.asarray(translation, dtype=np.float64).reshape(3)
    up = normal if normal @ origin < 0 else -normal
    return up, float(-up @ origin + thickness_m)


def check_distortion_model(calibration, source='calibration'):
    """Refuse a distortion model the perspective-n-point fit would apply wrongly."""
    if calibration.distortion_model not in SUPPORTED_DISTORTION:
        raise FloorPoseError(f'{source}: distortion_model {calibration.distortion_model!r} is '
                             f'not supported here (expected one of '
                             f'{", ".join(SUPPORTED_DISTORTION)})')


def _project(object_points, rotation_vector, translation, calibration):
    """Pixels (n, 2) of target points seen by one calibrated raw camera."""
    pixels, _ = cv2.projectPoints(object_points, rotation_vector, translation,
                                  np.asarray(calibration.camera_matrix, dtype=np.float64),
                                  np.asarray(calibration.distortion, dtype=np.float64))
    return pixels.reshape(-1, 2)


def _right_pose(rotation_vector, translation, extrinsics):
    """Return the target's pose in the right raw optical frame from its pose in the left one."""
    stereo_rotation, stereo_translation = extrinsics      # p_left = R p_right + t
    rotation = stereo_rotation.T @ cv2.Rodrigues(rotation_vector)[0]
    return cv2.Rodrigues(rotation)[0].ravel(), \
        stereo_rotation.T @ (np.asarray(translation).ravel() - stereo_translation)


def reprojection_rms(object_points, image_points, rotation_vector, translation, calibration):
    """Root mean square of the reprojection error, pixels (per point distance)."""
    error = _project(object_points, rotation_vector, translation, calibration) - image_points
    return float(np.sqrt(np.mean(np.sum(error ** 2, axis=1))))


def target_pose(object_points, left_points, right_points, left, right):
    """
    Pose of the target in the left raw optical frame: ``(rotation, translation, rms)``.

    ``left_points`` / ``right_points``: its points found in the raw images (either may be
    None, not both); ``left``, ``right``: CameraCalibration. A start from OpenCV's
    ``solvePnP`` in one camera, then the pose that minimises the reprojection error in every
    camera that saw the target (Levenberg-Marquardt on the six pose parameters; the right
    camera through the calibration's extrinsics). ``rms``: per camera, None where unseen.
    """
    objects = np.asarray(object_points, dtype=np.float64)
    if left_points is None and right_points is None:
        raise FloorPoseError('target pose: the target was seen by neither camera')
    extrinsics = stereo_extrinsics(left, right)
    first, calibration = (left_points, left) if left_points is not None else \
        (right_points, right)
    ok, rotation_vector, translation = cv2.solvePnP(
        objects, np.asarray(first, dtype=np.float64),
        np.asarray(calibration.camera_matrix, dtype=np.float64),
        np.asarray(calibration.distortion, dtype=np.float64), flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise FloorPoseError('target pose: solvePnP found no pose')
    rotation_vector, translation = rotation_vector.ravel(), translation.ravel()
    if left_points is None:         # the pose above is in the right frame: into the left
        stereo_rotation, stereo_translation = extrinsics
        rotation_vector = cv2.Rodrigues(stereo_rotation @ cv2.Rodrigues(rotation_vector)[0])[
            0].ravel()
        translation = stereo_rotation @ translation + stereo_translation

    def residuals(params):
        parts = []
        if left_points is not None:
            parts.append((_project(objects, params[:3], params[3:], left) - left_points).ravel())
        if right_points is not None:
            r, t = _right_pose(params[:3], params[3:], extrinsics)
            parts.append((_project(objects, r, t, right) - right_points).ravel())
        return np.concatenate(parts)
    fit = least_squares(residuals, np.concatenate([rotation_vector, translation]), method='lm')
    rotation_vector, translation = fit.x[:3], fit.x[3:]
    rms = [None if points is None else
           reprojection_rms(objects, points, *pose, calibration)
           for points, pose, calibration in (
               (left_points, (rotation_vector, translation), left),
               (right_points, _right_pose(rotation_vector, translation, extrinsics), right))]
    return cv2.Rodrigues(rotation_vector)[0], translation, tuple(rms)


def stereo_scale(object_points, left_points, right_points, left, right, rotation,
                 translation):
    """
    Return the target's size as the two cameras measure it, relative to its description.

    The pose and a scale factor of the target's points are fitted to both cameras at once,
    starting from ``rotation``, ``translation``: with two cameras the baseline gives the
    scale, so a target described with a wrong spacing (or a calibration of another rig)
    shows as a factor away from 1.
    """
    objects = np.asarray(object_points, dtype=np.float64)
    extrinsics = stereo_extrinsics(left, right)

    def residuals(params):
        scaled = objects * math.exp(params[6])
        r, t = _right_pose(params[:3], params[3:6], extrinsics)
        return np.concatenate([
            (_project(scaled, params[:3], params[3:6], left) - left_points).ravel(),
            (_project(scaled, r, t, right) - right_points).ravel()])
    start = np.concatenate([cv2.Rodrigues(np.asarray(rotation))[0].ravel(),
                            np.asarray(translation).ravel(), [0.0]])
    return float(math.exp(least_squares(residuals, start, method='lm').x[6]))


@dataclasses.dataclass(frozen=True)
class FloorView:
    """The floor as one pair's view of the target gives it."""

    name: str
    height_m: float
    tilt_deg: float
    roll_deg: float
    rms_left_px: object         # float, or None when the left camera did not see the target
    rms_right_px: object
    up: tuple = (0.0, 0.0, -1.0)    # the floor's upward unit normal, left raw optical frame
    scale: object = None        # the target's size by the baseline / as described (stereo)

    @property
    def stereo(self):
        """Whether both cameras saw the target."""
        return self.rms_left_px is not None and self.rms_right_px is not None


def floor_view(name, target, left_points, right_points, left, right, thickness_m=0.0):
    """
    Height, tilt and roll of the rig from one pair's detections of a floor target.

    ``target``: the CalibrationTarget. With both cameras, the right camera's points are taken
    in each numbering the grid's symmetry allows (``grid_numberings``: the two cameras may
    number a grid turned on the floor from different corners) and the one that agrees with
    the left camera's (the lowest reprojection error) is kept; the target's size as the baseline
    measures it is fitted too (``stereo_scale``).
    """
    objects = target.object_points()
    orders = [right_points] if left_points is None or right_points is None else \
        grid_numberings(target, right_points)
    fits = [(order, target_pose(objects, left_points, order, left, right)) for order in orders]
    right_points, (rotation, translation, (rms_left, rms_right)) = min(
        fits, key=lambda fit: max(r for r in fit[1][2] if r is not None))
    up, height = floor_of_target(rotation, translation, thickness_m)
    tilt, roll = tilt_roll_of_up(up)
    scale = None
    if rms_left is not None and rms_right is not None:
        scale = stereo_scale(objects, left_points, right_points, left, right, rotation,
                             translation)
    return FloorView(name, height, tilt, roll, rms_left, rms_right,
                     tuple(float(v) for v in up), scale)


@dataclasses.dataclass(frozen=True)
class FloorPose:
    """The rig's height, tilt and roll over many views, and their spread."""

    height_m: float
    tilt_deg: float
    roll_deg: float
    views: int
    spread: dict                # field -> (5th, 95th percentile) over the views
    roll_determined: bool       # False near straight down (roll and yaw nearly coincide)


def wrapped_deg(angle):
    """Return an angle in degrees wrapped into [-180, 180)."""
    return (np.asarray(angle, dtype=np.float64) + 180.0) % 360.0 - 180.0


def combine_views(views):
    """
    Combine the views of a static rig and target: median height, median floor normal.

    The target does not move, so the views differ by sensor noise alone; medians also keep a
    few views with a wrongly ordered grid from moving the result. The normal's components are
    combined (then normalised), not the angles: a roll near +-180 degrees (a camera mounted
    upside down) would otherwise average to 0. The 5th-95th percentile range of each field
    is reported as its spread (the roll's as the combined roll plus its views' wrapped
    differences from it).
    """
    views = list(views)
    if not views:
        raise FloorPoseError('no view of the target: the floor cannot be found')
    heights = np.array([v.height_m for v in views])
    up = np.median(np.array([v.up for v in views]), axis=0)
    tilt, roll = tilt_roll_of_up(up)
    tilts = np.array([v.tilt_deg for v in views])
    rolls = roll + wrapped_deg(np.array([v.roll_deg for v in views]) - roll)

    def span(values):
        return tuple(float(x) for x in np.percentile(values, [5, 95]))
    return FloorPose(float(np.median(heights)), tilt, roll, len(views),
                     {'height_m': span(heights), 'tilt_deg': span(tilts),
                      'roll_deg': span(rolls)}, tilt >= MIN_TILT_FOR_ROLL_DEG)
