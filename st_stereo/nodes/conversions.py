"""
Conversions between ROS messages and the arrays / objects of the core and the Lepton layer.

No cv_bridge here (not installable from the package index): images are built with
``ndarray.tobytes()`` and read with ``np.frombuffer`` (``../shared/notes/ros.md``: 10 us
instead of 1.3 ms for ``list(...)``). Every reader checks encoding, size and step and raises
``ValueError`` naming the field, expected versus got.
"""

import numpy as np
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from st_stereo.core import image_io
from stereo_msgs.msg import DisparityImage

ENCODINGS = image_io.IMAGE_ENCODINGS
COUNT_ENCODINGS = image_io.COUNT_ENCODINGS     # mono16 or 16UC1: raw counts


def image_to_msg(array, header, encoding='mono16'):
    """Build a sensor_msgs/Image from a 2-D array (mono16: raw counts, never rescaled)."""
    dtype, size = ENCODINGS[encoding]
    array = np.ascontiguousarray(array, dtype=dtype)
    msg = Image()
    msg.header = header
    msg.height, msg.width = array.shape
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = size * msg.width
    msg.data = array.tobytes()
    return msg


def msg_to_image(msg, expected_encoding=None):
    """
    Read a sensor_msgs/Image into a 2-D array; ValueError naming the bad field.

    ``expected_encoding='mono16'`` asks for raw counts and also takes 16UC1; padded rows and
    ``is_bigendian`` are read (``image_io.image_from_buffer``).
    """
    return image_io.image_from_buffer(msg.data, msg.encoding, msg.width, msg.height, msg.step,
                                      msg.is_bigendian, expected_encoding)


def camera_info_from_calibration(calibration, header):
    """sensor_msgs/CameraInfo of a camera_calibration file."""
    msg = CameraInfo()
    msg.header = header
    msg.width, msg.height = calibration.width, calibration.height
    msg.distortion_model = calibration.distortion_model
    msg.d = [float(v) for v in calibration.distortion]
    msg.k = [float(v) for v in calibration.camera_matrix.ravel()]
    msg.r = [float(v) for v in calibration.rectification.ravel()]
    msg.p = [float(v) for v in calibration.projection.ravel()]
    return msg


def rectified_camera_info(msg, header):
    """Return the camera_info of a rectified stream: K = P[:3, :3], no distortion, R = I."""
    out = CameraInfo()
    out.header = header
    out.width, out.height = msg.width, msg.height
    out.distortion_model = 'plumb_bob'
    out.d = [0.0] * 5
    projection = np.array(msg.p, dtype=float).reshape(3, 4)
    out.k = [float(v) for v in projection[:, :3].ravel()]
    out.r = [float(v) for v in np.eye(3).ravel()]
    out.p = list(msg.p)
    return out


POINT_FIELDS = ('x', 'y', 'z', 'disparity', 'similarity', 'intensity', 'confidence', 'u',
                'v')


def point_cloud(header, points, disparity, similarity, intensity, confidence=None,
                pixels=None):
    """
    Build a sparse sensor_msgs/PointCloud2 of the matches.

    Fields float32 x, y, z (offsets 0, 4, 8), disparity, similarity, intensity, confidence
    (0..1, ``MatchResult.confidence``; NaN when not given), u, v (``pixels``: the rectified
    left pixel where the match was measured, ``MatchResult.x_left`` and ``y``; with
    ``point_location: structure`` x, y, z lie up to a few pixels from it; NaN when not given);
    height 1, width N, is_dense when no NaN in x, y, z.
    """
    count = len(disparity)
    data = np.empty((count, len(POINT_FIELDS)), dtype='<f4')
    if count:
        data[:, :3] = points
        data[:, 3] = disparity
        data[:, 4] = similarity
        data[:, 5] = intensity
        data[:, 6] = np.nan if confidence is None else confidence
        data[:, 7:9] = np.nan if pixels is None else np.column_stack(pixels)
    msg = PointCloud2()
    msg.header = header
    msg.height = 1
    msg.width = count
    msg.fields = [PointField(name=name, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, name in enumerate(POINT_FIELDS)]
    msg.is_bigendian = False
    msg.point_step = 4 * len(POINT_FIELDS)
    msg.row_step = msg.point_step * count
    msg.is_dense = bool(np.isfinite(data[:, :3]).all())
    msg.data = data.tobytes()
    return msg


def point_cloud_array(msg):
    """Read our PointCloud2 back as an (n, len(POINT_FIELDS)) float32 array (tests, tools)."""
    return np.frombuffer(bytes(msg.data), dtype='<f4').reshape(msg.width, -1)


def disparity_image(header, shape, x_left, y, disparity, focal, baseline, min_disparity,
                    max_disparity, valid_window=None, disparity_offset=0.0):
    """
    Sparse stereo_msgs/DisparityImage: 32FC1, invalid pixels below ``min_disparity``.

    Each match is written at its feature's pixel (``MatchResult.x_left``, ``y``: one match per
    pixel, every match kept). With ``point_location: structure`` the ``points2`` point of a
    match lies at its window's structure instead, up to a few pixels away, with the same
    disparity.

    Values are ``d - (cx_left - cx_right)`` (``disparity_offset``), as stereo_image_proc's
    disparity node publishes them (``Z = f T / value``, as its point_cloud node computes);
    ``min_disparity`` and ``max_disparity`` stay the matcher's unshifted search bounds, as
    there. Pixels without a match hold ``min_disparity - 1 - max(offset, 0)``, below any value.

    ``delta_d`` is the smallest disparity step the matcher resolves (continuous: 1/64 px is
    reported, finer than any realistic sub-pixel error).
    """
    rows, cols = shape
    image = np.full((rows, cols), float(min_disparity) - 1.0 - max(disparity_offset, 0.0),
                    dtype=np.float32)
    image[y, x_left] = np.asarray(disparity, dtype=np.float64) - disparity_offset
    msg = DisparityImage()
    msg.header = header
    msg.image = image_to_msg(image, header, '32FC1')
    msg.f = float(focal)
    msg.t = float(baseline)
    msg.min_disparity = float(min_disparity)
    msg.max_disparity = float(max_disparity)
    msg.delta_d = 1.0 / 64.0
    if valid_window is not None:
        msg.valid_window.x_offset, msg.valid_window.y_offset = valid_window[:2]
        msg.valid_window.width, msg.valid_window.height = valid_window[2:]
    return msg


POINT_FIELD_DTYPES = {PointField.INT8: 'i1', PointField.UINT8: 'u1', PointField.INT16: 'i2',
                      PointField.UINT16: 'u2', PointField.INT32: 'i4', PointField.UINT32: 'u4',
                      PointField.FLOAT32: 'f4', PointField.FLOAT64: 'f8'}


def point_cloud_fields(msg, required, optional=()):
    """
    Read named fields of any sensor_msgs/PointCloud2 as float64 arrays (n,).

    Any layout (field order, padding, endianness, organised or not); a ``required`` field that
    is missing, a field type that is not a number, or data of the wrong size is a ValueError
    naming it. ``optional`` fields that are missing are None.
    """
    fields = {field.name: field for field in msg.fields}
    missing = [name for name in required if name not in fields]
    if missing:
        raise ValueError(f'point cloud: no field(s) {missing} (fields: '
                         f'{", ".join(fields) or "none"})')
    count = msg.width * msg.height
    if msg.point_step <= 0 and count:
        raise ValueError(f'point cloud point_step: expected > 0, got {msg.point_step}')
    if count and msg.row_step < msg.width * msg.point_step:
        raise ValueError(f'point cloud row_step: expected >= width x point_step = '
                         f'{msg.width * msg.point_step}, got {msg.row_step}')
    if len(msg.data) < count * msg.point_step or msg.row_step * msg.height > len(msg.data):
        raise ValueError(f'point cloud data: expected {msg.row_step * msg.height} bytes '
                         f'({msg.height} rows of {msg.row_step}), got {len(msg.data)}')
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if count:
        rows = raw[:msg.row_step * msg.height].reshape(msg.height, msg.row_step)
        raw = rows[:, :msg.width * msg.point_step].reshape(count, msg.point_step)
    out = {}
    for name in tuple(required) + tuple(optional):
        field = fields.get(name)
        if field is None:
            out[name] = None
            continue
        if field.count > 1:
            raise ValueError(f'point cloud field {name}: count {field.count}, expected 1 '
                             f'(one number per point)')
        if field.datatype not in POINT_FIELD_DTYPES:
            raise ValueError(f'point cloud field {name}: datatype {field.datatype} is not a '
                             f'number type')
        dtype = np.dtype(POINT_FIELD_DTYPES[field.datatype]).newbyteorder(
            '>' if msg.is_bigendian else '<')
        if field.offset + dtype.itemsize > msg.point_step:
            raise ValueError(f'point cloud field {name}: offset {field.offset} + '
                             f'{dtype.itemsize} bytes beyond point_step {msg.point_step}')
        if not count:
            out[name] = np.zeros(0)
            continue
        column = np.ascontiguousarray(raw[:, field.offset:field.offset + dtype.itemsize])
        out[name] = column.view(dtype).reshape(count).astype(np.float64)
    return out
