"""
Ray casting of a thermal room: surfaces with temperatures, intersected by camera rays.

A scene is a list of surfaces (the room's inside faces, boxes, ellipsoids); each has an integer
label and a thermal material that gives the apparent temperature of every hit point. Rendering
averages supersampled rays per pixel (the pixel's area), so a scene seen by two cameras is
sampled consistently: that is what makes the ground-truth disparity exact.
"""

import dataclasses

import numpy as np
from scipy import ndimage

FACES = ('x-', 'x+', 'y-', 'y+', 'floor', 'ceiling')


@dataclasses.dataclass
class ThermalMaterial:
    """
    Apparent temperature of a surface, degrees Celsius.

    ``T(p) = base + gradient . (p - origin) + texture(p) + noise(p)``, then pulled towards
    ``ambient`` at grazing angles (emissivity falls with the view angle).

    Attributes
    ----------
    texture : ndarray or None
        Zero-mean unit-std image mapped on the plane spanned by ``texture_axes`` (metres per
        texel ``texel_m``), bilinear, wrapped; scaled by ``texture_kelvin``.
    noise_kelvin, noise_wavelength_m : float
        Amplitude and mean wavelength of a smooth 3-D procedural pattern (clothing folds,
        skin blood flow) in the surface's own frame.

    """

    base: float
    gradient: tuple = (0.0, 0.0, 0.0)
    origin: tuple = (0.0, 0.0, 0.0)
    texture: np.ndarray = None
    texture_axes: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    texel_m: float = 0.02
    texture_kelvin: float = 0.0
    noise_kelvin: float = 0.0
    noise_wavelength_m: float = 0.15
    grazing: float = 0.0
    ambient: float = 21.0
    seed: int = 0

    def __post_init__(self):
        """Draw the procedural pattern's waves once (fixed per material)."""
        rng = np.random.default_rng(self.seed)
        directions = rng.normal(size=(8, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        wavelengths = self.noise_wavelength_m * rng.uniform(0.5, 1.5, 8)
        self._waves = directions / wavelengths[:, None]
        self._phases = rng.uniform(0, 2 * np.pi, 8)

    def temperature(self, points, normals, directions, local_points):
        """Apparent temperature of hit points (n, 3) with unit normals and ray directions."""
        values = self.base + (points - np.asarray(self.origin)) @ np.asarray(self.gradient)
        if self.texture is not None and self.texture_kelvin:
            axes = np.asarray(self.texture_axes, dtype=np.float64)
            u = (points - np.asarray(self.origin)) @ axes[0] / self.texel_m
            v = (points - np.asarray(self.origin)) @ axes[1] / self.texel_m
            values = values + self.texture_kelvin * ndimage.map_coordinates(
                self.texture, [v, u], order=1, mode='grid-wrap')
        if self.noise_kelvin:
            waves = np.sin(2 * np.pi * local_points @ self._waves.T + self._phases)
            values = values + self.noise_kelvin * waves.sum(axis=1) / 2.0
        if self.grazing:
            cosine = np.abs(np.einsum('ij,ij->i', normals, directions))
            values = self.ambient + (values - self.ambient) * (1 - self.grazing * (1 - cosine))
        return values


def normalised_texture(image):
    """Zero-mean, unit-std float texture of an image."""
    image = np.asarray(image, dtype=np.float64)
    return (image - image.mean()) / max(float(image.std()), 1e-12)


@dataclasses.dataclass
class RoomShell:
    """
    The inside of an axis-aligned box (floor, ceiling, walls).

    ``materials`` and ``labels`` map the names of ``FACES`` to a material and a label.
    """

    low: tuple
    high: tuple
    materials: dict
    labels: dict

    def intersect(self, origin, directions):
        """Distance to the face each ray leaves the room through, its normal and face index."""
        low, high = np.asarray(self.low), np.asarray(self.high)
        with np.errstate(divide='ignore', invalid='ignore'):
            exits = np.where(directions > 0, (high - origin) / directions,
                             np.where(directions < 0, (low - origin) / directions, np.inf))
        rows = np.arange(len(directions))
        axis = np.argmin(exits, axis=1)
        t = exits[rows, axis]
        positive = directions[rows, axis] > 0
        normals = np.zeros_like(directions)
        normals[rows, axis] = np.where(positive, -1.0, 1.0)
        return t, normals, axis * 2 + positive


@dataclasses.dataclass
class Box:
    """A solid axis-aligned box (furniture, radiator, screen)."""

    name: str
    label: int
    low: tuple
    high: tuple
    material: ThermalMaterial

    def intersect(self, origin, directions):
        """Entry distance (inf on a miss) and the outward normal of the entry face."""
        low, high = np.asarray(self.low), np.asarray(self.high)
        with np.errstate(divide='ignore', invalid='ignore'):
            t1 = (low - origin) / directions
            t2 = (high - origin) / directions
        t_near = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
        t_far = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
        rows = np.arange(len(directions))
        axis = np.argmax(t_near, axis=1)
        entry = t_near[rows, axis]
        leave = t_far.min(axis=1)
        hit = (entry <= leave) & (entry > 1e-9)
        normals = np.zeros_like(directions)
        normals[rows, axis] = -np.sign(directions[rows, axis])
        return np.where(hit, entry, np.inf), normals

    def local(self, points):
        """Points relative to the box's low corner."""
        return points - np.asarray(self.low)


@dataclasses.dataclass
class Ellipsoid:
    """An ellipsoid: centre, semi-axes along the columns of ``rotation`` (a body part)."""

    name: str
    label: int
    centre: np.ndarray
    semi_axes: np.ndarray
    rotation: np.ndarray
    material: ThermalMaterial

    def intersect(self, origin, directions):
        """
        Nearest positive distance (inf on a miss) and the outward unit normals.

        ``directions`` must be unit vectors: rays are first culled by the bounding sphere.
        """
        t_all = np.full(len(directions), np.inf)
        normals_all = np.zeros_like(directions)
        offset = self.centre - origin
        along = directions @ offset
        near = along * along - offset @ offset + max(self.semi_axes) ** 2 >= 0
        if not near.any():
            return t_all, normals_all
        scale = 1.0 / np.asarray(self.semi_axes)
        o = (-offset @ self.rotation) * scale
        d = (directions[near] @ self.rotation) * scale
        a = np.einsum('ij,ij->i', d, d)
        b = d @ o
        c = o @ o - 1.0
        disc = b * b - a * c
        root = np.sqrt(np.maximum(disc, 0.0))
        t = (-b - root) / a
        t = np.where((disc >= 0) & (t > 1e-9), t, np.inf)
        local = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        normals = (local * scale) @ self.rotation.T
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        t_all[near] = t
        normals_all[near] = normals
        return t_all, normals_all

    def local(self, points):
        """Points in the part's own frame (the pattern moves with the body)."""
        return (points - self.centre) @ self.rotation


@dataclasses.dataclass
class Hits:
    """Result of casting rays: distance, label and apparent temperature per ray."""

    distance: np.ndarray
    label: np.ndarray
    temperature: np.ndarray
    points: np.ndarray


class Scene:
    """A room shell plus solid objects; ``cast`` returns the nearest hit of every ray."""

    def __init__(self, shell, objects, label_names):
        self.shell = shell
        self.objects = list(objects)
        self.label_names = dict(label_names)

    def cast(self, origin, directions, with_temperature=True):
        """Cast rays from one origin (3,) along directions (n, 3); unit-length not required."""
        directions = np.asarray(directions, dtype=np.float64)
        directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        origin = np.asarray(origin, dtype=np.float64)
        distance, normals, faces = self.shell.intersect(origin, directions)
        label = np.array([self.shell.labels[f] for f in FACES], dtype=np.int32)[faces]
        owner = np.full(len(directions), -1)
        for index, item in enumerate(self.objects):
            t, n = item.intersect(origin, directions)
            closer = t < distance
            distance = np.where(closer, t, distance)
            normals[closer] = n[closer]
            label[closer] = item.label
            owner[closer] = index
        points = origin + distance[:, None] * directions
        temperature = None
        if with_temperature:
            temperature = np.empty(len(directions))
            for face, material in self.shell.materials.items():
                mask = (owner < 0) & (faces == FACES.index(face))
                if mask.any():
                    temperature[mask] = material.temperature(
                        points[mask], normals[mask], directions[mask], points[mask])
            for index, item in enumerate(self.objects):
                mask = owner == index
                if mask.any():
                    temperature[mask] = item.material.temperature(
                        points[mask], normals[mask], directions[mask], item.local(points[mask]))
        return Hits(distance, label, temperature, points)
