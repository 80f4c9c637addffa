"""
Triangulation of sub-pixel disparities in a rectified stereo rig (REP 103 optical frame).

For a rectified pair, ``Z = fx B / (d - (cx_left - cx_right))``,
``X = (u - cx) Z / fx``, ``Y = (v - cy) Z / fy``, in metres, x right, y down, z forward from
the left camera's optical centre. ``dZ = Z^2 / (fx B) dd`` is why sub-pixel precision matters
(paper eqs. 1-2).
"""

import dataclasses
import math

import numpy as np

# Default rig (../shared/notes/algorithm.md section 6): Lepton 2, 80x60, HFOV 51 deg,
# fx = 40 / tan(25.5 deg) = 83.9 px; the paper's depth figures imply fx B = 46,300 px mm.
LEPTON2_FX = 40.0 / math.tan(math.radians(25.5))
DEFAULT_FX_BASELINE_PX_M = 46.3


@dataclasses.dataclass(frozen=True)
class StereoModel:
    """
    Rectified stereo geometry: left intrinsics, baseline, right principal point.

    Attributes
    ----------
    fx, fy, cx, cy : float
        Rectified left projection (pixels).
    baseline : float
        Distance between the optical centres, metres (> 0).
    cx_right : float
        Rectified right principal point x; equals ``cx`` unless the rectification offsets it.

    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    cx_right: float = None

    def __post_init__(self):
        """Validate the geometry and default ``cx_right`` to ``cx``."""
        for name in ('fx', 'fy', 'baseline'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'stereo model: {name} must be a positive finite number, got '
                                 f'{value!r}')
        for name in ('cx', 'cy'):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f'stereo model: {name} must be finite, got '
                                 f'{getattr(self, name)!r}')
        if self.cx_right is None:
            object.__setattr__(self, 'cx_right', float(self.cx))

    @classmethod
    def default_lepton_rig(cls, width=80, height=60):
        """Model of the default ceiling rig: 80x60 Lepton 2 pair, fx B = 46.3 px m."""
        scale = width / 80.0
        fx = LEPTON2_FX * scale
        return cls(fx=fx, fy=fx, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
                   baseline=DEFAULT_FX_BASELINE_PX_M / LEPTON2_FX)

    @classmethod
    def from_projection_matrices(cls, left_projection, right_projection):
        """
        Build the model from rectified 3x4 projection matrices (camera_info P).

        ``P_right[0, 3] = -fx B`` encodes the baseline (``B = -P_right[0, 3] / P_right[0, 0]``).
        """
        left = np.asarray(left_projection, dtype=np.float64).reshape(3, 4)
        right = np.asarray(right_projection, dtype=np.float64).reshape(3, 4)
        fx = left[0, 0]
        if right[0, 0] <= 0:
            raise ValueError(f'right projection: P[0,0] must be positive, got {right[0, 0]}')
        baseline = -right[0, 3] / right[0, 0]
        if not baseline > 0:
            raise ValueError(f'right projection: P[0,3] = {right[0, 3]} gives baseline '
                             f'{baseline} m; expected P[0,3] = -fx * B < 0 (left camera first)')
        # One rectified pair shares fx, fy and cy (rows aligned): two P that do not are not
        # (e.g. the raw camera_info given to the matcher instead of the rectifier's).
        checks = (('fx', 0, 0, 1e-3 * abs(fx)), ('fy', 1, 1, 1e-3 * abs(left[1, 1])),
                  ('cy', 1, 2, 0.01))
        for name, row, column, tolerance in checks:
            if not abs(right[row, column] - left[row, column]) <= tolerance:
                raise ValueError(
                    f'right projection: {name} {right[row, column]:g}, left '
                    f'{left[row, column]:g}: not the P of one rectified pair (rows must align: '
                    f'the camera_info of the rectifier)')
        return cls(fx=float(fx), fy=float(left[1, 1]), cx=float(left[0, 2]),
                   cy=float(left[1, 2]), baseline=float(baseline), cx_right=float(right[0, 2]))

    @property
    def disparity_offset(self):
        """``cx_left - cx_right``: disparity of a point at infinity."""
        return self.cx - self.cx_right

    def reprojection_matrix(self):
        """OpenCV-style 4x4 Q with ``[X Y Z W]^T = Q [u v d 1]^T`` (same geometry)."""
        return np.array([
            [1.0, 0.0, 0.0, -self.cx],
            [0.0, self.fx / self.fy, 0.0, -self.cy * self.fx / self.fy],
            [0.0, 0.0, 0.0, self.fx],
            [0.0, 0.0, 1.0 / self.baseline, -self.disparity_offset / self.baseline],
        ])

    def depth(self, disparity):
        """``Z = fx B / (d - (cx - cx_right))``; inf where the disparity is at infinity."""
        disparity = np.asarray(disparity, dtype=np.float64) - self.disparity_offset
        with np.errstate(divide='ignore'):
            return np.where(disparity > 0, self.fx * self.baseline / disparity, np.inf)

    def disparity_of_depth(self, depth):
        """Inverse of ``depth``: the disparity a point at depth Z (metres) has."""
        return self.fx * self.baseline / np.asarray(depth, dtype=np.float64) + \
            self.disparity_offset


def triangulate(model, x_left, y, disparity):
    """
    3-D points of matches in the left optical frame, metres (REP 103: x right, y down, z fwd).

    Parameters
    ----------
    model : StereoModel
        Rectified geometry.
    x_left, y, disparity : ndarray, shape (n,)
        Left pixel coordinates and sub-pixel disparity ``x_left - x_right``.

    Returns
    -------
    ndarray, shape (n, 3)
        X, Y, Z; rows with a disparity at or beyond infinity are NaN.

    """
    z = model.depth(disparity)
    z = np.where(np.isfinite(z), z, np.nan)
    x = (np.asarray(x_left, dtype=np.float64) - model.cx) * z / model.fx
    y_out = (np.asarray(y, dtype=np.float64) - model.cy) * z / model.fy
    return np.stack((x, y_out, z), axis=-1)


def at_their_features(points, u, v, projection):
    """
    Return points moved onto the rays of the pixels their matches were measured at, and how many.

    ``points2`` places a point at its window's structure (``point_location: structure``),
    up to a few pixels from its feature; the people stage was chosen on points at their
    features, and the paper's protocol scores them there. Each point keeps its depth ``z`` and gets
    ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy`` (the triangulation's, with the rectified
    left ``projection`` P). ``u``, ``v`` None (an older cloud without the fields) or NaN:
    the point stays where it is.
    """
    points = np.array(points, dtype=np.float64).reshape(-1, 3)
    if u is None or v is None:
        return points, 0
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    fx, fy, cx, cy = projection[0, 0], projection[1, 1], projection[0, 2], projection[1, 2]
    known = np.isfinite(u) & np.isfinite(v) & np.isfinite(points[:, 2])
    z = points[known, 2]
    points[known, 0] = (u[known] - cx) * z / fx
    points[known, 1] = (v[known] - cy) * z / fy
    return points, int(known.sum())


def project(model, points):
    """Project 3-D points into the rectified pair: left (u, v) and disparity (inverse of above)."""
    points = np.asarray(points, dtype=np.float64)
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    u = model.fx * x / z + model.cx
    v = model.fy * y / z + model.cy
    disparity = model.fx * model.baseline / z + model.disparity_offset
    return u, v, disparity
