"""
Geometry of the simulated ceiling rig: two pinhole cameras with optional distortion.

World frame: x to the right along the rig's baseline, y into the room, z up, metres; the floor
is ``z = 0``. Camera frames follow REP 103 (x right, y down, z forward). The true calibration
of a rig is written in camera_calibration form, so the rectifier and the matcher work from the
same files a real rig would have.
"""

import dataclasses
import math

import cv2
import numpy as np

from st_stereo.core.calibration.files import CameraCalibration
from st_stereo.core.triangulation import DEFAULT_FX_BASELINE_PX_M


def rotation_xyz(roll_deg, pitch_deg, yaw_deg):
    """Rotation about the camera's z (roll), x (pitch) and y (yaw) axes, applied in that order."""
    roll, pitch, yaw = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    rz = np.array([[math.cos(roll), -math.sin(roll), 0], [math.sin(roll), math.cos(roll), 0],
                   [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, math.cos(pitch), -math.sin(pitch)],
                   [0, math.sin(pitch), math.cos(pitch)]])
    ry = np.array([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0],
                   [-math.sin(yaw), 0, math.cos(yaw)]])
    return ry @ rx @ rz


def distort_normalised(points, distortion):
    """plumb_bob distortion (k1, k2, p1, p2, k3) of normalised image points (n, 2)."""
    k1, k2, p1, p2, k3 = np.asarray(distortion, dtype=np.float64)[:5]
    x, y = points[:, 0], points[:, 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return np.column_stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y])


def undistort_normalised(distorted, distortion, iterations=100, tolerance=1e-13):
    """
    Invert ``distort_normalised`` by fixed-point iteration; raises if it does not converge.

    Converges for the mild distortion of a 51 deg lens; the residual is checked, never assumed.
    """
    distorted = np.asarray(distorted, dtype=np.float64)
    if not np.any(distortion):
        return distorted.copy()
    points = distorted.copy()
    with np.errstate(over='ignore', invalid='ignore'):
        for _ in range(iterations):
            error = distort_normalised(points, distortion) - distorted
            points -= error
            if not np.isfinite(error).all():
                break
            if np.abs(error).max() < tolerance:
                return points
    raise ValueError(f'undistortion did not converge (residual {np.abs(error).max():.2e}); '
                     f'distortion {list(distortion)} is too strong for this solver')


def focal_length_of_hfov(width, hfov_deg):
    """Return the pinhole focal length (px) of a field of view: ``(w / 2) / tan(hfov / 2)``."""
    return (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)


@dataclasses.dataclass(frozen=True)
class PinholeCamera:
    """
    One simulated camera: intrinsics, distortion and pose.

    Attributes
    ----------
    camera_matrix : ndarray, 3x3
        K of the raw image.
    distortion : ndarray, (5,)
        plumb_bob k1, k2, p1, p2, k3 of the raw image.
    rotation : ndarray, 3x3
        World-to-camera rotation (rows are the camera axes in world coordinates).
    centre : ndarray, (3,)
        Optical centre in the world frame, metres.

    """

    width: int
    height: int
    camera_matrix: np.ndarray
    distortion: np.ndarray
    rotation: np.ndarray
    centre: np.ndarray

    def to_camera(self, points_world):
        """World points (n, 3) in this camera's optical frame."""
        return (np.asarray(points_world) - self.centre) @ self.rotation.T

    def project(self, points_world):
        """Raw pixel coordinates (n, 2) of world points, through the distortion model."""
        points = self.to_camera(points_world).reshape(-1, 1, 3)
        pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), self.camera_matrix,
                                      self.distortion)
        return pixels.reshape(-1, 2)

    def pixel_rays(self, pixels):
        """
        Return world ray directions (n, 3) through raw pixel coordinates (n, 2), undistorted.

        The inverse of the distortion model is solved iteratively (``undistort_normalised``).
        """
        pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        k = self.camera_matrix
        distorted = np.column_stack([(pixels[:, 0] - k[0, 2]) / k[0, 0],
                                     (pixels[:, 1] - k[1, 2]) / k[1, 1]])
        normalised = undistort_normalised(distorted, self.distortion)
        directions = np.column_stack([normalised, np.ones(len(normalised))])
        return directions @ self.rotation


@dataclasses.dataclass(frozen=True)
class RigGeometry:
    """
    The simulated stereo rig on the ceiling, looking down into the room at an angle.

    Defaults: Lepton 2 (80x60, HFOV 51 deg, fx = 83.9 px) and the baseline that gives the
    paper's fx B = 46,300 px mm (../shared/notes/algorithm.md section 6), mounted 2.9 m above the
    floor, tilted 40 deg below the horizontal (``roll_deg`` turns both cameras about the left
    optical axis). ``distortion`` (k1, k2) and the right camera's
    ``misalignment_deg`` (roll, pitch, yaw) make the rectifier do real work; all zero gives an
    ideal, already rectified rig.
    """

    width: int = 80
    height: int = 60
    hfov_deg: float = 51.0
    baseline_m: float = DEFAULT_FX_BASELINE_PX_M / focal_length_of_hfov(80, 51.0)
    mount_height_m: float = 2.9
    tilt_deg: float = 40.0
    roll_deg: float = 0.0
    distortion: tuple = (0.0, 0.0)
    misalignment_deg: tuple = (0.0, 0.0, 0.0)
    right_focal_scale: float = 1.0

    @property
    def focal_length(self):
        """Return fx = fy of the left camera, pixels."""
        return focal_length_of_hfov(self.width, self.hfov_deg)

    def nominal_camera_matrix(self, focal_scale=1.0):
        """K with the principal point at the image centre."""
        f = self.focal_length * focal_scale
        return np.array([[f, 0.0, (self.width - 1) / 2.0], [0.0, f, (self.height - 1) / 2.0],
                         [0.0, 0.0, 1.0]])

    def base_rotation(self):
        """
        World-to-camera rotation: tilted ``tilt_deg`` below the horizontal, rolled ``roll_deg``.

        The roll turns the image about the optical axis (the camera's x axis towards its y).
        """
        t, r = math.radians(self.tilt_deg), math.radians(self.roll_deg)
        x_axis = np.array([1.0, 0.0, 0.0])
        z_axis = np.array([0.0, math.cos(t), -math.sin(t)])
        y_axis = np.cross(z_axis, x_axis)
        return np.vstack([math.cos(r) * x_axis + math.sin(r) * y_axis,
                          -math.sin(r) * x_axis + math.cos(r) * y_axis, z_axis])

    def cameras(self):
        """Return the left and right PinholeCamera."""
        rotation = self.base_rotation()
        distortion = np.array([self.distortion[0], self.distortion[1], 0.0, 0.0, 0.0])
        half = self.baseline_m / 2.0
        left = PinholeCamera(self.width, self.height, self.nominal_camera_matrix(), distortion,
                             rotation, np.array([-half, 0.0, self.mount_height_m]))
        # The baseline runs along the left camera's x axis: a rolled rig rolls its bar too.
        right = PinholeCamera(self.width, self.height,
                              self.nominal_camera_matrix(self.right_focal_scale),
                              distortion.copy(), rotation_xyz(*self.misalignment_deg) @ rotation,
                              left.centre + self.baseline_m * rotation[0])
        return left, right

    def stereo_extrinsics(self):
        """Return OpenCV's R, T: a left-camera point p is ``R p + T`` in the right camera."""
        left, right = self.cameras()
        r = right.rotation @ left.rotation.T
        t = right.rotation @ (left.centre - right.centre)
        return r, t

    def rectification(self):
        """
        Rectifying rotations and projections of the true geometry.

        R1, R2 come from ``cv2.stereoRectify``; both rectified cameras use the nominal K (so an
        ideal rig rectifies to itself) and ``P_right[0, 3] = -fx B``.
        """
        left, right = self.cameras()
        r, t = self.stereo_extrinsics()
        r1, r2, _, _, _, _, _ = cv2.stereoRectify(
            left.camera_matrix, left.distortion, right.camera_matrix, right.distortion,
            (self.width, self.height), r, t.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=-1)
        k = self.nominal_camera_matrix()
        p1 = np.hstack([k, np.zeros((3, 1))])
        p2 = p1.copy()
        p2[0, 3] = -k[0, 0] * float(np.linalg.norm(t))
        return r1, r2, p1, p2

    def calibrations(self):
        """Return the true left and right CameraCalibration (camera_calibration YAML content)."""
        left, right = self.cameras()
        r1, r2, p1, p2 = self.rectification()
        return tuple(CameraCalibration(
            width=self.width, height=self.height, camera_name=f'sim_{side}',
            camera_matrix=camera.camera_matrix, distortion_model='plumb_bob',
            distortion=camera.distortion, rectification=r, projection=p)
            for side, camera, r, p in (('left', left, r1, p1), ('right', right, r2, p2)))

    def rectified_rays(self, pixels, side='left'):
        """World origin and ray directions through rectified pixel coordinates (n, 2)."""
        camera = self.cameras()[0 if side == 'left' else 1]
        r1, r2, p1, _ = self.rectification()
        rect = r1 if side == 'left' else r2
        pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        normalised = np.column_stack([(pixels[:, 0] - p1[0, 2]) / p1[0, 0],
                                      (pixels[:, 1] - p1[1, 2]) / p1[1, 1],
                                      np.ones(len(pixels))])
        return camera.centre, normalised @ rect @ camera.rotation

    def to_rectified_left(self, points_world):
        """World points in the rectified left optical frame (the frame of ``points2``)."""
        left, _ = self.cameras()
        r1 = self.rectification()[0]
        return left.to_camera(points_world) @ r1.T

    def rig_pose(self, world_frame='map', rig_frame='stereo_rig'):
        """
        Return the true RigPose of the left camera (``st_stereo.core.rig_pose`` conventions).

        Tilt and roll come from the world's up axis in the left camera's frame
        (``st_stereo.core.floor_pose.tilt_roll_of_up``), the yaw from the horizontal direction
        of its optical axis. The world here has x to the right, y away from the rig
        horizontally and z up: the rig's x axis (the tilt direction) is the world's y (yaw 90
        degrees) and the tilt from straight down is ``90 - tilt_deg``.
        """
        from st_stereo.core.floor_pose import tilt_roll_of_up
        from st_stereo.core.rig_pose import RigPose
        left, _ = self.cameras()
        tilt, roll = tilt_roll_of_up(left.rotation @ np.array([0.0, 0.0, 1.0]))
        axis = left.rotation[2]
        return RigPose(world_frame=world_frame, rig_frame=rig_frame, x_m=float(left.centre[0]),
                       y_m=float(left.centre[1]), height_m=float(left.centre[2]),
                       yaw_deg=math.degrees(math.atan2(axis[1], axis[0])), tilt_deg=tilt,
                       roll_deg=roll)

    @property
    def fx_baseline(self):
        """Return fx B of the rectified pair, pixel metres: ``d = fx B / Z``."""
        return self.focal_length * self.baseline_m


def realistic_rig():
    """Return the recordings' rig: barrel distortion, a slightly misaligned right camera."""
    return RigGeometry(distortion=(-0.12, 0.03), misalignment_deg=(0.4, -0.3, 0.6),
                       right_focal_scale=1.006)
