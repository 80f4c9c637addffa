"""
The rig's place in the room and its cameras' frames: the static transforms of a fixed rig.

Frames (REP 103, REP 105):

- ``world_frame`` (default ``map``): the room, at floor level, z up.
- ``rig_frame`` (``stereo_rig``): at the left camera's optical centre, z up, x the horizontal
  direction the cameras tilt towards, y to the left of it. ``world -> rig`` is the rig's
  position (``x_m``, ``y_m``, ``height_m`` above the floor) and its heading (``yaw_deg`` about
  the world's z).
- the left optical frame (the driver's ``left.frame_id``): z along the optical axis, x to the
  image's right, y down. Looking straight down (``tilt_deg`` 0) the image's top is towards
  the rig's +x and its right towards the rig's -y; ``tilt_deg`` turns the optical axis from
  straight down towards +x (a rotation about the rig's y axis), ``roll_deg`` turns the image
  about the optical axis: ``R_rig_optical = R_y(-tilt) M R_z(roll)`` with ``M`` the
  straight-down axes.
- the right optical frame: from the stereo calibration. The rectified frames are the raw
  ones rotated by the rectification matrices (``v_rect = R_i v_raw``) and the right rectified
  centre lies at ``c = (-P2[0, 3] / P2[0, 0], -P2[1, 3] / P2[1, 1], 0)`` in the rectified left
  frame (P2[0, 3] = -fx' B), so ``left -> right`` is ``R = R1^T R2``, ``t = R1^T c``.

``points2`` and the rectified images carry the left optical frame id, as stereo_image_proc's
do; their coordinates are in the *rectified* left frame, which differs from the raw left
optical frame by R1 (for the bundled recording's calibration, 0.4 degrees).
"""

import dataclasses
import math

import numpy as np

POSE_FIELDS = ('world_frame', 'rig_frame', 'x_m', 'y_m', 'height_m', 'yaw_deg', 'tilt_deg',
               'roll_deg')


class RigPoseError(ValueError):
    """A rig pose file or value that cannot be used (names the source, field and problem)."""


@dataclasses.dataclass(frozen=True)
class RigPose:
    """Where the rig is in the room (see the module docstring for the frames)."""

    world_frame: str = 'map'
    rig_frame: str = 'stereo_rig'
    x_m: float = 0.0
    y_m: float = 0.0
    height_m: float = 2.7
    yaw_deg: float = 0.0
    tilt_deg: float = 0.0
    roll_deg: float = 0.0

    def __post_init__(self):
        for name in ('world_frame', 'rig_frame'):
            value = getattr(self, name)
            if not isinstance(value, str) or not value or value.startswith('/') or ' ' in value:
                raise RigPoseError(f'{name}: expected a frame id (no leading /, no spaces), '
                                   f'got {value!r}')
        for name in POSE_FIELDS[2:]:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value):
                raise RigPoseError(f'{name}: expected a finite number, got {value!r}')
        if not self.height_m > 0:
            raise RigPoseError(f'height_m: expected the height above the floor (> 0 m), got '
                               f'{self.height_m!r}')
        if not -90.0 < self.tilt_deg < 90.0:
            raise RigPoseError(f'tilt_deg: expected -90 < tilt < 90 degrees from straight down, '
                               f'got {self.tilt_deg!r}')


def rig_pose_from_mapping(values, source='rig pose'):
    """Build a RigPose from a dict (e.g. a YAML file's); unknown keys are an error."""
    if not isinstance(values, dict):
        raise RigPoseError(f'{source}: expected a mapping of {", ".join(POSE_FIELDS)}, got '
                           f'{type(values).__name__}')
    unknown = sorted(set(values) - set(POSE_FIELDS))
    if unknown:
        raise RigPoseError(f'{source}: unknown field(s) {unknown} (expected some of '
                           f'{", ".join(POSE_FIELDS)})')
    try:
        return RigPose(**values)
    except RigPoseError as error:
        raise RigPoseError(f'{source}: {error}') from None


def load_rig_pose(path, required=()):
    """
    Read a rig pose YAML file (the fields of RigPose, optional but ``required``).

    A field of ``required`` missing from the file is an error naming it (the launch files
    require ``height_m``: a rig placed 2.7 m high by default puts every person at the wrong
    distance without a word).
    """
    import yaml
    try:
        with open(path, encoding='utf-8') as stream:
            values = yaml.safe_load(stream)
    except OSError as error:
        raise RigPoseError(f'{path}: cannot be read: {error.strerror}') from None
    except yaml.YAMLError as error:
        raise RigPoseError(f'{path}: not YAML: {str(error).splitlines()[0]}') from None
    values = {} if values is None else values
    missing = [field for field in required if isinstance(values, dict) and field not in values]
    if missing:
        raise RigPoseError(f'{path}: {", ".join(missing)} missing (st-stereo rig-pose '
                           f'measures height_m, tilt_deg and roll_deg; the user sets x_m, y_m '
                           f'and yaw_deg)')
    return rig_pose_from_mapping(values, str(path))


def rig_pose_yaml(pose, header=(), notes=None):
    """
    Return a rig pose as YAML text that ``load_rig_pose`` reads back exactly.

    ``header``: comment lines (with their ``#``) put first; ``notes``: field -> a comment
    written after that field's value.
    """
    notes = notes or {}
    lines = list(header)
    for field in POSE_FIELDS:
        value = getattr(pose, field)
        text = f'{field}: {value if isinstance(value, str) else repr(float(value))}'
        lines.append(f'{text}    # {notes[field]}' if field in notes else text)
    return '\n'.join(lines) + '\n'


def rotation_y(angle):
    """Rotation matrix about y by ``angle`` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(angle):
    """Rotation matrix about z by ``angle`` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# Columns: the optical x (image right), y (image down), z (optical axis) in the rig frame of a
# camera looking straight down with the image's top towards the rig's +x.
LOOKING_DOWN = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def rig_to_optical_rotation(pose):
    """Return ``R_rig_optical`` of a pose (columns: the optical axes in the rig frame)."""
    return rotation_y(-math.radians(pose.tilt_deg)) @ LOOKING_DOWN @ \
        rotation_z(math.radians(pose.roll_deg))


def nearest_rotation(matrix, tolerance=1e-3):
    """
    Return the rotation nearest ``matrix`` (SVD), which must be one to within ``tolerance``.

    Calibration files store R1 and R2 rounded (often to 4-6 decimals), so R1^T R2 is a
    rotation only to about that precision; anything farther is not a rotation at all.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (3, 3) or not np.isfinite(m).all():
        raise ValueError(f'not a 3x3 rotation matrix: {m.tolist()}')
    u, _, vt = np.linalg.svd(m)
    nearest = u @ vt
    if np.linalg.det(nearest) < 0 or np.abs(nearest - m).max() > tolerance:
        raise ValueError(f'not a rotation matrix (more than {tolerance} from the nearest '
                         f'one): {m.tolist()}')
    return nearest


def quaternion_of_rotation(rotation):
    """Return the unit quaternion ``(x, y, z, w)``, ``w >= 0``, of a rotation (Shepperd)."""
    m = nearest_rotation(rotation)
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    q = np.array(q)
    q /= np.linalg.norm(q)
    return tuple(float(v) for v in (q if q[3] >= 0 else -q))


@dataclasses.dataclass(frozen=True)
class StaticTransform:
    """One static transform: ``child``'s origin and axes in ``parent``'s frame."""

    parent: str
    child: str
    translation: tuple       # metres
    rotation: tuple          # quaternion x, y, z, w


def stereo_extrinsics(left, right):
    """
    Return ``(R, t)``: the right raw optical frame in the left one, from a stereo calibration.

    ``left``, ``right``: CameraCalibration (rectification R1, R2 and projection P2).
    """
    r1 = np.asarray(left.rectification, dtype=np.float64)
    r2 = np.asarray(right.rectification, dtype=np.float64)
    p2 = np.asarray(right.projection, dtype=np.float64)
    centre = np.array([-p2[0, 3] / p2[0, 0], -p2[1, 3] / p2[1, 1], 0.0])
    return r1.T @ r2, r1.T @ centre


def rig_static_transforms(pose, left, right, left_frame, right_frame):
    """Return the three static transforms world -> rig -> left optical -> right optical."""
    def transform(parent, child, rotation, translation):
        return StaticTransform(parent, child, tuple(float(v) for v in translation),
                               quaternion_of_rotation(rotation))
    stereo_rotation, stereo_translation = stereo_extrinsics(left, right)
    return [
        transform(pose.world_frame, pose.rig_frame, rotation_z(math.radians(pose.yaw_deg)),
                  (pose.x_m, pose.y_m, pose.height_m)),
        transform(pose.rig_frame, left_frame, rig_to_optical_rotation(pose), (0.0, 0.0, 0.0)),
        transform(left_frame, right_frame, stereo_rotation, stereo_translation),
    ]


def static_transform_arguments(transform):
    """Command-line arguments of tf2_ros' ``static_transform_publisher`` for one transform."""
    names = ('--x', '--y', '--z', '--qx', '--qy', '--qz', '--qw')
    values = transform.translation + transform.rotation
    arguments = []
    for name, value in zip(names, values):
        arguments += [name, repr(float(value))]
    return arguments + ['--frame-id', transform.parent, '--child-frame-id', transform.child]
