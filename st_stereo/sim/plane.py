"""
The simulated driver's scene (``source:=sim``): a textured plane facing the rig.

The plane faces the rig at a known depth; the left camera sees a real thermal frame, the right
camera the same frame moved left by the rig's disparity at that depth (Fourier shift), with
independent temporal noise, and a gain / offset difference as two uncooled cameras have.
"""

import numpy as np

from st_stereo.core.fourier import fourier_shift_image_x
from st_stereo.core.image_io import read_thermal_image, resize_area
from st_stereo.lepton.simulator import ArraySource


def plane_scene_sources(model, depth_m, texture_path=None, frames=32, seed=0,
                        low=7800.0, high=8600.0, noise_counts=3.0):
    """
    Left and right frame sources of a textured plane at ``depth_m`` (metres).

    Returns
    -------
    (ArraySource, ArraySource, float)
        The two sources and the true disparity, pixels.

    """
    if texture_path is None:
        from st_stereo.package_data import packaged_texture
        texture_path = packaged_texture()
    texture = resize_area(read_thermal_image(texture_path), 80, 60)
    texture = low + (texture - texture.min()) * (high - low) / max(np.ptp(texture), 1e-9)
    disparity = float(model.disparity_of_depth(depth_m))
    shifted = fourier_shift_image_x(texture, disparity)
    rng = np.random.default_rng(seed)
    left = texture[None] + rng.normal(0.0, noise_counts, (frames, 60, 80))
    right = 1.02 * shifted[None] + 15.0 + rng.normal(0.0, noise_counts, (frames, 60, 80))
    return ArraySource(left), ArraySource(right), disparity


class ImageFileSource(ArraySource):
    """
    Frames from thermal image files, resized to 80x60 (pixel-area) and mapped to 14-bit counts.

    Each file's range is mapped linearly onto ``low..high`` counts (a room-temperature scene
    of a Lepton spans a few hundred counts around 8000); the files repeat cyclically.
    """

    def __init__(self, paths, low=7800.0, high=8600.0):
        frames = []
        for path in paths:
            image = resize_area(read_thermal_image(path), 80, 60)
            span = max(float(np.ptp(image)), 1e-9)
            frames.append(low + (image - image.min()) * (high - low) / span)
        super().__init__(np.stack(frames))
