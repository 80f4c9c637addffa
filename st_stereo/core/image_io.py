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


# sensor_msgs/Image encodings read here: dtype (little-endian) and bytes per pixel.
IMAGE_ENCODINGS = {'mono16': (np.dtype('<u2'), 2), '16UC1': (np.dtype('<u2'), 2),
                   'mono8': (np.dtype('u1'), 1), '32FC1': (np.dtype('<f4'), 4)}
# Raw counts: one unsigned 16-bit channel. mono16 is what this suite (and image_proc, which
# keeps its input's encoding) publishes; 16UC1 is the same bytes under the name libuvc_camera
# gives a PureThermal board's Y16 stream (its camera_driver.cpp). Either is read as counts.
COUNT_ENCODINGS = ('mono16', '16UC1')


def image_from_buffer(data, encoding, width, height, step, is_bigendian=False,
                      expected_encoding=None):
    """
    Decode the pixels of a sensor_msgs/Image (its fields given one by one, no ROS needed).

    ``expected_encoding='mono16'`` asks for raw counts and also takes 16UC1
    (``COUNT_ENCODINGS``). Rows padded beyond ``width`` pixels (``step`` larger than the row,
    which sensor_msgs/Image allows) are cut to ``width``; ``is_bigendian`` is honoured.
    Returns a read-only 2-D array; ValueError naming the bad field, expected versus got.
    """
    if encoding not in IMAGE_ENCODINGS:
        raise ValueError(f'image encoding: expected one of {", ".join(IMAGE_ENCODINGS)}, got '
                         f'{encoding!r}')
    accepted = COUNT_ENCODINGS if expected_encoding == 'mono16' else (expected_encoding,)
    if expected_encoding is not None and encoding not in accepted:
        raise ValueError(f'image encoding: expected {" or ".join(accepted)}, got {encoding}')
    dtype, size = IMAGE_ENCODINGS[encoding]
    if is_bigendian:
        dtype = dtype.newbyteorder('>')
    row = size * width
    if step < row:
        raise ValueError(f'image step: expected at least {row} for width {width}, got {step}')
    data = np.frombuffer(bytes(data), dtype=np.uint8)
    if data.size != step * height:
        raise ValueError(f'image data: expected {step * height} bytes, got {data.size}')
    if step != row:
        data = np.ascontiguousarray(data.reshape(height, step)[:, :row])
        data.flags.writeable = False
    return data.view(dtype).reshape(height, width)


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
