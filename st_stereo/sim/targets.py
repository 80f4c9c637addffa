"""
Heated calibration targets in front of the simulated rig (for ``st-stereo calibrate``).

A target is a flat plate with an analytic temperature pattern (warm dots on a cold plate, cold
holes in a warm plate, or a heated chessboard), posed in front of the rig at 0.75-2.2 m with
tilts up to 45 degrees about each axis and spread over the field of view, rendered through the
same rig, optics and Lepton sensor model as the sequences.
"""

import dataclasses

import numpy as np

from st_stereo.sim.render import render_temperature
from st_stereo.sim.rig import rotation_xyz
from st_stereo.sim.scene import FACES, RoomShell, Scene, ThermalMaterial
from st_stereo.sim.sensor import LeptonSensor, SensorModel


@dataclasses.dataclass
class PatternMaterial:
    """Temperature of a target plate at plate coordinates (metres from the first point)."""

    target: object
    hot: float = 32.0
    cold: float = 22.0
    warm_features: bool = True

    def temperature(self, plate_xy):
        """Hot or cold per point (n, 2) of the plate."""
        t = self.target
        x, y = plate_xy[:, 0], plate_xy[:, 1]
        if t.kind == 'chessboard':
            # Inner corners at multiples of the spacing: squares are offset by one spacing.
            parity = (np.floor(x / t.spacing_m) + np.floor(y / t.spacing_m)) % 2 == 0
            return np.where(parity, self.hot, self.cold)
        centres = t.object_points()[:, :2].astype(np.float64)
        radius = (t.spacing_m / 2.0 if t.kind == 'acircles' else t.spacing_m) * 0.3
        distance = np.min(np.hypot(x[:, None] - centres[None, :, 0],
                                   y[:, None] - centres[None, :, 1]), axis=1)
        inside = distance <= radius
        feature, plate = (self.hot, self.cold) if self.warm_features else (self.cold, self.hot)
        return np.where(inside, feature, plate)

    def extent(self):
        """Plate rectangle (x0, y0, x1, y1) in plate coordinates: the grid plus a margin."""
        points = self.target.object_points()
        margin = self.target.spacing_m
        return (points[:, 0].min() - margin, points[:, 1].min() - margin,
                points[:, 0].max() + margin, points[:, 1].max() + margin)


@dataclasses.dataclass
class Plate:
    """A posed target plate: world = origin + rotation @ (x, y, 0)."""

    label: int
    origin: np.ndarray
    rotation: np.ndarray
    pattern: PatternMaterial

    def intersect(self, origin, directions):
        """Distance to the plate (inf outside its rectangle) and its normal."""
        normal = self.rotation[:, 2]
        denominator = directions @ normal
        with np.errstate(divide='ignore', invalid='ignore'):
            t = ((self.origin - origin) @ normal) / denominator
        points = origin + np.where(np.isfinite(t), t, 0.0)[:, None] * directions
        local = (points - self.origin) @ self.rotation
        x0, y0, x1, y1 = self.pattern.extent()
        inside = (local[:, 0] >= x0) & (local[:, 0] <= x1) & (local[:, 1] >= y0) & \
            (local[:, 1] <= y1) & (t > 1e-9)
        normals = np.broadcast_to(normal, directions.shape).copy()
        return np.where(inside, t, np.inf), normals

    def local(self, points):
        """Plate coordinates of world points."""
        return (points - self.origin) @ self.rotation

    @property
    def material(self):
        """Return the plate's temperature as a ThermalMaterial-like object."""
        pattern = self.pattern

        class _Material:
            def temperature(self, points, normals, directions, local_points):
                return pattern.temperature(local_points[:, :2])
        return _Material()


def target_poses(rig, target, count, seed=0, distance=(0.9, 1.8), max_tilt_deg=45.0,
                 both=False):
    """
    ``count`` plate poses (origin, rotation), spread over the image, fully in view.

    Each pose is aimed through a random pixel of one camera (alternating), offset, turned and
    tilted; with ``both`` it must be fully seen by both cameras (a stereo view), otherwise by at
    least the camera it was aimed through (a user sweeping the target over each camera's whole
    field, which a wide baseline at short range requires).
    """
    rng = np.random.default_rng(seed)
    cameras = rig.cameras()
    material = PatternMaterial(target)
    x0, y0, x1, y1 = material.extent()
    centre_local = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    corners_local = np.array([[x0, y0, 0], [x1, y0, 0], [x0, y1, 0], [x1, y1, 0]])

    def seen(camera, corners):
        pixels = camera.project(corners)
        return bool((pixels > 1).all() and (pixels[:, 0] < rig.width - 2).all()
                    and (pixels[:, 1] < rig.height - 2).all()
                    and (camera.to_camera(corners)[:, 2] > 0.3).all())
    poses = []
    attempts = 0
    while len(poses) < count:
        attempts += 1
        if attempts > 500 * count:
            width, height = x1 - x0, y1 - y0
            raise ValueError(
                f'could not place the {width:.2f} x {height:.2f} m target plate fully in view '
                f'{"of both cameras " if both else ""}at {distance[0]:g}-{distance[1]:g} m '
                f'({len(poses)} of {count} poses found): use a smaller target')
        aim = cameras[len(poses) % 2]
        z = rng.uniform(*distance)
        u = rng.uniform(0.05, 0.95) * rig.width
        v = rng.uniform(0.05, 0.95) * rig.height
        ray = aim.pixel_rays(np.array([[u, v]]))[0]
        centre = aim.centre + ray / (ray @ aim.rotation[2]) * z
        # Plate faces the camera (plate z along its axis), then turns and tilts.
        facing = aim.rotation.T @ rotation_xyz(rng.uniform(-15, 15), 0, 0)
        tilt = rotation_xyz(0.0, rng.uniform(-max_tilt_deg, max_tilt_deg),
                            rng.uniform(-max_tilt_deg, max_tilt_deg))
        rotation = facing @ tilt
        origin = centre - rotation @ centre_local
        corners = origin + corners_local @ rotation.T
        if (all(seen(c, corners) for c in cameras) if both else seen(aim, corners)):
            poses.append((origin, rotation))
    return poses


def calibration_scene(target, pose, warm_features=True):
    """Build a plain room (ambient walls) with the plate at ``pose``."""
    flat = ThermalMaterial(base=21.0)
    shell = RoomShell((-6.0, -1.0, -1.0), (6.0, 8.0, 6.0), dict.fromkeys(FACES, flat),
                      dict.fromkeys(FACES, 0))
    plate = Plate(1, pose[0], pose[1], PatternMaterial(target, warm_features=warm_features))
    return Scene(shell, [plate], {0: 'room', 1: 'target'})


def render_calibration_pairs(rig, target, count, seed=0, warm_features=True, supersample=6,
                             noise=True, stereo_share=0.4, stereo_distance=(1.3, 2.2),
                             mono_distance=(0.75, 1.5)):
    """
    Render ``count`` raw pairs (uint16) of the target at random poses; also the poses.

    ``stereo_share`` of the pairs see the target in both cameras (farther away, where the
    fields of view overlap); the others sweep it close over each camera's whole field, as a
    user would to fill the image with the target at strong tilts (what pins down the principal
    point at 80x60). Distances in metres.
    """
    shape = (rig.height, rig.width)
    sensors = [LeptonSensor(SensorModel(seed=seed * 2 + 1, ffc_period_s=0.0), shape),
               LeptonSensor(SensorModel(seed=seed * 2 + 2, gain=1.03, offset_counts=60.0,
                                        ffc_period_s=0.0), shape)]
    pairs = []
    stereo = int(round(count * stereo_share))
    poses = target_poses(rig, target, stereo, seed, distance=stereo_distance, both=True) + \
        target_poses(rig, target, count - stereo, seed + 1000, distance=mono_distance)
    for index, pose in enumerate(poses):
        scene = calibration_scene(target, pose, warm_features)
        frames = [sensor.frame(render_temperature(scene, camera, supersample), index / 8.7,
                               noise)
                  for sensor, camera in zip(sensors, rig.cameras())]
        pairs.append(tuple(frames))
    return pairs, poses


def floor_target_pose(target, floor_xy, yaw_deg=0.0, thickness_m=0.005):
    """
    Pose (origin, rotation) of a target lying flat on the floor.

    Its grid is centred on ``floor_xy`` (world metres) and turned ``yaw_deg`` about the
    vertical; its surface lies ``thickness_m`` above the floor.
    """
    x0, y0, x1, y1 = PatternMaterial(target).extent()
    rotation = rotation_xyz(yaw_deg, 0.0, 0.0)      # about the world's vertical z axis
    centre = np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0])
    origin = np.array([floor_xy[0], floor_xy[1], thickness_m]) - rotation @ centre
    return origin, rotation


def render_floor_target_pairs(rig, target, floor_xy, yaw_deg=0.0, count=20, room='office',
                              thickness_m=0.005, hot=30.0, cold=20.5, seed=0, supersample=4,
                              noise=True):
    """
    Render ``count`` raw pairs (uint16) of a static room with a target lying on its floor.

    For ``st-stereo rig-pose``: warm discs (``hot``) on a mat at about the floor's
    temperature (``cold``), degrees Celsius, in one of the sequences' rooms
    (``st_stereo.sim.sequences.ROOMS``). The scene is static; the pairs differ by the
    sensors' noise (8.7 frames per second, no flat-field correction).
    """
    from st_stereo.sim.sequences import LABELS, load_textures, ROOMS
    shell, furniture = ROOMS[room](load_textures())
    origin, rotation = floor_target_pose(target, floor_xy, yaw_deg, thickness_m)
    label = max(LABELS) + 1
    plate = Plate(label, origin, rotation, PatternMaterial(target, hot=hot, cold=cold))
    scene = Scene(shell, list(furniture) + [plate], {**LABELS, label: 'target'})
    shape = (rig.height, rig.width)
    sensors = [LeptonSensor(SensorModel(seed=seed * 2 + 1, ffc_period_s=0.0), shape),
               LeptonSensor(SensorModel(seed=seed * 2 + 2, gain=1.03, offset_counts=60.0,
                                        ffc_period_s=0.0), shape)]
    temperatures = [render_temperature(scene, camera, supersample) for camera in rig.cameras()]
    return [tuple(sensor.frame(temperature, index / 8.7, noise)
                  for sensor, temperature in zip(sensors, temperatures))
            for index in range(count)]
