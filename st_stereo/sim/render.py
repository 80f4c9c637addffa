"""
Rendering a scene through the rig: pixel-area temperature images and exact ground truth.

Each raw pixel integrates ``supersample x supersample`` rays over its area (mean in-band
radiance); ground truth is cast through the rectified left camera: depth ``Z`` along its optical
axis, disparity ``d = fx B / Z`` at the pixel centre and its range over the pixel's area (a
pixel on a depth edge legitimately holds any disparity in that range), the label of what the
centre ray hits, and whether that point is visible from the right camera.
"""

import dataclasses

import numpy as np

from st_stereo.sim.sensor import band_radiance, temperature_of_radiance


def pixel_samples(width, height, supersample):
    """Sample positions (n, 2) in pixel coordinates: ``supersample^2`` per pixel, row-major."""
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    v, u, dv, du = np.meshgrid(np.arange(height), np.arange(width), offsets, offsets,
                               indexing='ij')
    return np.column_stack([(u + du).ravel(), (v + dv).ravel()])


def pixel_centres(width, height):
    """Pixel centres (n, 2), row-major."""
    v, u = np.mgrid[0:height, 0:width]
    return np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)


def render_temperature(scene, camera, supersample=4, offset_px=(0.0, 0.0)):
    """
    Apparent temperature image (rows, cols), deg C, of what a raw camera sees.

    ``offset_px`` moves the sampling grid (the ground-truth tests render one camera at the
    positions the other camera's pixels must correspond to).
    """
    samples = pixel_samples(camera.width, camera.height, supersample) + np.asarray(offset_px)
    hits = scene.cast(camera.centre, camera.pixel_rays(samples))
    radiance = band_radiance(hits.temperature).reshape(camera.height, camera.width, -1)
    return temperature_of_radiance(radiance.mean(axis=2))


@dataclasses.dataclass
class GroundTruth:
    """Ground truth of one frame in the rectified left camera (the frame of ``points2``)."""

    depth: np.ndarray             # Z along the rectified left optical axis, metres
    disparity: np.ndarray         # fx B / Z at the pixel centre
    disparity_min: np.ndarray     # range of fx B / Z over the pixel's area
    disparity_max: np.ndarray
    labels: np.ndarray            # label of the surface the centre ray hits
    visible_right: np.ndarray     # the centre point is seen by the right camera
    raw_depth_left: np.ndarray    # Z in the raw left / right camera frames, pixel centres
    raw_depth_right: np.ndarray


def ground_truth(scene, rig, supersample=4):
    """Ground truth of a scene seen by a rig (see the module docstring)."""
    width, height = rig.width, rig.height
    fxb = rig.fx_baseline
    left, right = rig.cameras()

    def rectified_depth(pixels):
        origin, directions = rig.rectified_rays(pixels)
        hits = scene.cast(origin, directions, with_temperature=False)
        return rig.to_rectified_left(hits.points)[:, 2], hits

    depth, hits = rectified_depth(pixel_centres(width, height))
    sub_depth, _ = rectified_depth(pixel_samples(width, height, supersample))
    sub_disparity = (fxb / sub_depth).reshape(height, width, -1)
    # Visibility from the right camera: nothing nearer on the segment right centre -> point.
    to_point = hits.points - right.centre
    distance = np.linalg.norm(to_point, axis=1)
    seen = scene.cast(right.centre, to_point, with_temperature=False)
    visible = seen.distance >= distance - 0.01
    raw = []
    for camera in (left, right):
        cast = scene.cast(camera.centre, camera.pixel_rays(pixel_centres(width, height)),
                          with_temperature=False)
        raw.append(camera.to_camera(cast.points)[:, 2].reshape(height, width))
    shape = (height, width)
    return GroundTruth(
        depth=depth.reshape(shape), disparity=(fxb / depth).reshape(shape),
        disparity_min=np.minimum(sub_disparity.min(axis=2), (fxb / depth).reshape(shape)),
        disparity_max=np.maximum(sub_disparity.max(axis=2), (fxb / depth).reshape(shape)),
        labels=hits.label.reshape(shape), visible_right=visible.reshape(shape),
        raw_depth_left=raw[0], raw_depth_right=raw[1])


def disparity_error(truth, x_left, y, disparity, neighbourhood=0):
    """
    Distance of matched disparities to the ground truth's per-pixel range, pixels.

    Zero when the estimate lies within the range the pixel's area holds (depth edges), the
    distance to that range otherwise; NaN where the point is hidden from the right camera.
    ``neighbourhood`` = r widens the range to the pixels within r (a feature located up to r
    pixels off a depth edge may carry the other side's disparity).
    """
    rows = np.clip(np.rint(y).astype(int), 0, truth.disparity.shape[0] - 1)
    cols = np.clip(np.rint(x_left).astype(int), 0, truth.disparity.shape[1] - 1)
    low_map, high_map = truth.disparity_min, truth.disparity_max
    if neighbourhood:
        from scipy import ndimage
        size = 2 * neighbourhood + 1
        low_map = ndimage.minimum_filter(low_map, size, mode='nearest')
        high_map = ndimage.maximum_filter(high_map, size, mode='nearest')
    low = low_map[rows, cols]
    high = high_map[rows, cols]
    error = np.maximum(np.maximum(low - disparity, disparity - high), 0.0)
    return np.where(truth.visible_right[rows, cols], error, np.nan)
