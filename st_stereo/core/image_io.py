"""Reading thermal frames from image files with clear errors."""

import os

import cv2
import numpy as np


def read_thermal_image(path):
    """
    Read a single-channel image (16-bit raw counts or 8-bit) without any rescaling.

    Parameters
    ----------
    path : str or os.PathLike
        Image file (PNG, TIFF, ... as OpenCV reads them).

    Returns
    -------
    ndarray, shape (rows, cols), dtype uint8 / uint16 / float32 as stored

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        The file is not a readable image, or it has colour channels.

    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f'{path}: no such image file')
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f'{path}: not a readable image (OpenCV could not decode it)')
    if image.ndim == 3:
        if image.shape[2] == 1:
            image = image[:, :, 0]
        else:
            raise ValueError(f'{path}: expected a single-channel thermal image, got '
                             f'{image.shape[2]} channels')
    return image


def resize_area(image, width, height):
    """Resize with pixel-area averaging (the sensor-like downsampling), float64 out."""
    return cv2.resize(np.asarray(image, dtype=np.float64), (int(width), int(height)),
                      interpolation=cv2.INTER_AREA)


def contrast_stretch_u8(image, low_percentile=1.0, high_percentile=99.0):
    """
    Map an image to 8 bits between two percentiles, for overlays and viewers only.

    The percentiles are taken over the non-zero pixels when there are any (0 marks a rectified
    pixel without data), so a border without data does not wash the image out.
    """
    image = np.asarray(image, dtype=np.float64)
    data = image[image != 0]
    low, high = np.percentile(data if data.size else image, [low_percentile, high_percentile])
    scale = 255.0 / max(high - low, 1e-9)
    return np.clip((image - low) * scale, 0, 255).astype(np.uint8)
