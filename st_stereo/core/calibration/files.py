"""
camera_calibration YAML: the calibration files the driver, rectifier and matcher load.

The format is the one ROS ``camera_calibration`` writes and ``camera_info_manager`` reads:
image_width, image_height, camera_name, camera_matrix, distortion_model,
distortion_coefficients, rectification_matrix, projection_matrix, each matrix as
``{rows, cols, data}`` in row-major order. Errors name the file and the field.

Read as ROS's own reader (camera_calibration_parsers, yaml-cpp) reads them: a file without
``distortion_model`` (what that parser wrote before the field existed) is plumb_bob, said in
``CameraCalibration.notes``; a number PyYAML's YAML 1.1 rules leave a string, such as
``1e-05`` (no decimal point, as yaml-cpp of the Melodic era wrote a small coefficient) or a
quoted one, is read as the number it spells.
"""

import dataclasses
import os

import numpy as np
import yaml

DISTORTION_MODELS = {'plumb_bob': (5,), 'rational_polynomial': (8,), 'equidistant': (4,)}
MATRIX_FIELDS = {'camera_matrix': (3, 3), 'rectification_matrix': (3, 3),
                 'projection_matrix': (3, 4)}


class CalibrationError(ValueError):
    """A calibration file is missing, malformed, or inconsistent; the message says where."""


@dataclasses.dataclass(frozen=True)
class CameraCalibration:
    """One camera of a stereo calibration (sensor_msgs/CameraInfo content)."""

    width: int
    height: int
    camera_name: str
    camera_matrix: np.ndarray          # K, 3x3
    distortion_model: str
    distortion: np.ndarray             # D, (n,)
    rectification: np.ndarray          # R, 3x3
    projection: np.ndarray             # P, 3x4
    # What the reader assumed (a missing distortion_model), for the loader's user to log.
    notes: tuple = dataclasses.field(default=(), compare=False)

    @property
    def is_calibrated(self):
        """K[0, 0] != 0 (an all-zero K means uncalibrated in ROS)."""
        return bool(self.camera_matrix[0, 0] != 0)


def _number(value):
    """
    Return a YAML scalar as a float, as yaml-cpp's ``as<double>`` reads it.

    PyYAML's YAML 1.1 float needs a decimal point: ``1e-05`` (yaml-cpp of the Melodic era
    wrote small coefficients so) and quoted numbers arrive as strings. Booleans and anything
    else raise TypeError / ValueError.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise TypeError(f'not a number: {value!r}')
    return float(value)


def _matrix(document, field, shape, source):
    if field not in document:
        raise CalibrationError(f'{source}: missing field {field!r}')
    entry = document[field]
    if not isinstance(entry, dict) or not {'rows', 'cols', 'data'} <= set(entry):
        raise CalibrationError(f'{source}: field {field!r} must be a mapping with rows, cols, '
                               f'data; got {entry!r}')
    rows, cols, data = entry['rows'], entry['cols'], entry['data']
    for name, value in (('rows', rows), ('cols', cols)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= 64:
            raise CalibrationError(f'{source}: {field}.{name} must be an integer from 1 to '
                                   f'64, got {value!r}')
    if shape is not None and (rows, cols) != shape:
        raise CalibrationError(f'{source}: {field} must be {shape[0]}x{shape[1]}, got '
                               f'{rows}x{cols}')
    if not isinstance(data, list) or len(data) != rows * cols:
        length = len(data) if isinstance(data, list) else type(data).__name__
        raise CalibrationError(f'{source}: {field}.data must hold rows*cols = {rows * cols} '
                               f'numbers, got {length}')
    try:
        values = np.array([_number(value) for value in data], dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise CalibrationError(f'{source}: {field}.data must be numbers, got {data!r}') from None
    if not np.isfinite(values).all():
        raise CalibrationError(f'{source}: {field}.data holds non-finite values')
    return values.reshape(rows, cols)


def parse_calibration(document, source='<calibration>'):
    """Validate a parsed camera_calibration YAML document and return a CameraCalibration."""
    if not isinstance(document, dict):
        raise CalibrationError(f'{source}: expected a YAML mapping at top level, got '
                               f'{type(document).__name__}')
    for field in ('image_width', 'image_height'):
        value = document.get(field)
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise CalibrationError(f'{source}: {field} must be a positive integer, got '
                                   f'{value!r}')
    notes = ()
    model = document.get('distortion_model')
    if 'distortion_model' not in document:
        # camera_calibration_parsers: "did not specify distortion model, assuming plumb bob".
        model = 'plumb_bob'
        notes = (f'{source}: no distortion_model, plumb_bob assumed (as '
                 f'camera_calibration_parsers reads such a file)',)
    if not isinstance(model, str) or model not in DISTORTION_MODELS:
        raise CalibrationError(f'{source}: distortion_model must be one of '
                               f'{", ".join(DISTORTION_MODELS)}, got {model!r}')
    matrices = {field: _matrix(document, field, shape, source)
                for field, shape in MATRIX_FIELDS.items()}
    distortion = _matrix(document, 'distortion_coefficients', None, source).ravel()
    expected = DISTORTION_MODELS[model][0]
    if model != 'rational_polynomial' and len(distortion) != expected:
        raise CalibrationError(f'{source}: distortion_coefficients for {model} must hold '
                               f'{expected} values, got {len(distortion)}')
    if model == 'rational_polynomial' and len(distortion) not in (8, 12, 14):
        raise CalibrationError(f'{source}: distortion_coefficients for rational_polynomial '
                               f'must hold 8, 12 or 14 values, got {len(distortion)}')
    return CameraCalibration(width=document['image_width'], height=document['image_height'],
                             camera_name=str(document.get('camera_name', '')),
                             camera_matrix=matrices['camera_matrix'], distortion_model=model,
                             distortion=distortion,
                             rectification=matrices['rectification_matrix'],
                             projection=matrices['projection_matrix'], notes=notes)


def calibration_from_camera_info(msg, camera_name='', source=None):
    """
    Return the CameraCalibration of a sensor_msgs/CameraInfo, validated as a file is.

    Any object with CameraInfo's fields (rclpy's message, a rosbags-deserialized one). The
    checks of ``parse_calibration`` apply (a known distortion model with its number of
    coefficients, finite matrices, a positive size: OpenCV raises on a wrong distortion length,
    and non-finite values rectify to nothing), and R must be a rotation; an empty D is no
    distortion. CalibrationError names ``source`` (default ``<camera_name> camera_info``).
    """
    source = source or f'{camera_name} camera_info'.strip()
    model = msg.distortion_model or 'plumb_bob'
    distortion = [float(value) for value in msg.d]
    if not distortion and model in DISTORTION_MODELS:
        distortion = [0.0] * DISTORTION_MODELS[model][0]

    def matrix(values, rows, cols):
        return {'rows': rows, 'cols': cols, 'data': [float(value) for value in values]}

    document = {'image_width': int(msg.width), 'image_height': int(msg.height),
                'camera_name': camera_name, 'distortion_model': model,
                'camera_matrix': matrix(msg.k, 3, 3),
                'distortion_coefficients': matrix(distortion, 1, max(len(distortion), 1)),
                'rectification_matrix': matrix(msg.r, 3, 3),
                'projection_matrix': matrix(msg.p, 3, 4)}
    calibration = parse_calibration(document, source)
    rotation = calibration.rectification
    if not (np.abs(rotation @ rotation.T - np.eye(3)).max() < 1e-3 and
            np.linalg.det(rotation) > 0):
        raise CalibrationError(f'{source}: rectification_matrix R is not a rotation, got '
                               f'{", ".join(f"{value:g}" for value in rotation.ravel())}')
    return calibration


def load_calibration(path):
    """Read and validate a camera_calibration YAML file."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise CalibrationError(f'{path}: calibration file not found')
    with open(path, 'rb') as stream:
        return calibration_from_bytes(stream.read(), path)


def calibration_from_bytes(raw, source='<calibration>'):
    """Parse and validate camera_calibration YAML bytes; CalibrationError names ``source``."""
    try:
        text = raw.decode('utf-8')
    except UnicodeDecodeError as error:
        raise CalibrationError(f'{source}: not UTF-8 text (byte {error.start}: '
                               f'0x{raw[error.start]:02x})') from None
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise CalibrationError(f'{source}: not valid YAML: {error}') from None
    except RecursionError:
        raise CalibrationError(f'{source}: not valid YAML: nested too deeply') from None
    except ValueError as error:      # e.g. an integer of more than 4300 digits
        raise CalibrationError(f'{source}: not valid YAML: {error}') from None
    return parse_calibration(document, source)


def calibration_document(calibration):
    """Return the camera_calibration YAML mapping of a CameraCalibration."""
    def matrix(values):
        values = np.atleast_2d(np.asarray(values, dtype=np.float64))
        return {'rows': int(values.shape[0]), 'cols': int(values.shape[1]),
                'data': [float(v) for v in values.ravel()]}
    return {'image_width': int(calibration.width), 'image_height': int(calibration.height),
            'camera_name': calibration.camera_name,
            'camera_matrix': matrix(calibration.camera_matrix),
            'distortion_model': calibration.distortion_model,
            'distortion_coefficients': matrix(np.asarray(calibration.distortion)[None, :]),
            'rectification_matrix': matrix(calibration.rectification),
            'projection_matrix': matrix(calibration.projection)}


def calibration_yaml(calibration):
    """Return camera_calibration YAML text, matrices as flow lists as camera_calibration writes."""
    document = calibration_document(calibration)
    lines = []
    for key, value in document.items():
        if isinstance(value, dict):
            data = ', '.join(repr(v) for v in value['data'])
            lines += [f'{key}:', f'  rows: {value["rows"]}', f'  cols: {value["cols"]}',
                      f'  data: [{data}]']
        else:
            # A scalar dumps as 'value\n...\n': its first line is the YAML scalar.
            lines.append(f'{key}: {yaml.safe_dump(value).splitlines()[0]}')
    return '\n'.join(lines) + '\n'


def save_calibration(calibration, path):
    """Write a CameraCalibration as camera_calibration YAML."""
    with open(os.fspath(path), 'w', encoding='utf-8') as stream:
        stream.write(calibration_yaml(calibration))


def check_stereo_pair(left, right, left_source='left', right_source='right'):
    """Check that two calibrations form a rectified stereo pair (same size, P layout)."""
    if (left.width, left.height) != (right.width, right.height):
        raise CalibrationError(f'{left_source} is {left.width}x{left.height} but '
                               f'{right_source} is {right.width}x{right.height}')
    for calibration, source in ((left, left_source), (right, right_source)):
        if not calibration.is_calibrated:
            raise CalibrationError(f'{source}: camera_matrix K[0,0] is 0: uncalibrated camera')
    if left.projection[0, 3] != 0:
        raise CalibrationError(f'{left_source}: projection_matrix P[0,3] must be 0 for the '
                               f'left camera, got {left.projection[0, 3]}')
    if not right.projection[0, 3] < 0:
        raise CalibrationError(f'{right_source}: projection_matrix P[0,3] must be -fx*B < 0 '
                               f'for the right camera, got {right.projection[0, 3]}')
