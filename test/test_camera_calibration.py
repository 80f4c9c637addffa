"""camera_calibration YAML reader / writer and rectification."""

import numpy as np
import pytest
from st_stereo.core.calibration.files import (CalibrationError, CameraCalibration,
                                              load_calibration, save_calibration)
from st_stereo.core.rectification import StereoRectifier
import yaml


def rig_calibration(name, tx):
    k = np.array([[83.9, 0, 39.5], [0, 83.9, 29.5], [0, 0, 1]])
    p = np.array([[83.9, 0, 39.5, tx], [0, 83.9, 29.5, 0], [0, 0, 1, 0]])
    return CameraCalibration(width=80, height=60, camera_name=name, camera_matrix=k,
                             distortion_model='plumb_bob', distortion=np.zeros(5),
                             rectification=np.eye(3), projection=p)


def test_round_trip(tmp_path):
    calibration = rig_calibration('left', 0.0)
    path = tmp_path / 'left.yaml'
    save_calibration(calibration, path)
    document = yaml.safe_load(path.read_text())
    assert document['camera_matrix'] == {'rows': 3, 'cols': 3,
                                         'data': [83.9, 0, 39.5, 0, 83.9, 29.5, 0, 0, 1]}
    assert document['distortion_coefficients']['rows'] == 1
    loaded = load_calibration(path)
    assert np.allclose(loaded.projection, calibration.projection)
    assert loaded.distortion_model == 'plumb_bob' and loaded.camera_name == 'left'


def _write(tmp_path, document):
    path = tmp_path / 'cal.yaml'
    path.write_text(yaml.safe_dump(document))
    return path


@pytest.mark.parametrize('mutate, message', [
    (lambda d: d.pop('projection_matrix'), "missing field 'projection_matrix'"),
    (lambda d: d.update(image_width=0), 'image_width must be a positive integer'),
    (lambda d: d.update(distortion_model='fisheye9'), 'distortion_model must be one of'),
    # Found by .ci/fuzz.py (was TypeError: unhashable type: 'dict'):
    (lambda d: d.update(distortion_model={'rows': 3}), 'distortion_model must be one of'),
    (lambda d: d['camera_matrix'].update(rows=2), 'camera_matrix must be 3x3'),
    (lambda d: d['projection_matrix'].update(data=[1, 2]), 'must hold rows\\*cols = 12'),
    (lambda d: d['distortion_coefficients'].update(cols=4, data=[0, 0, 0, 0]),
     'plumb_bob must hold 5 values'),
])
def test_bad_files_name_file_and_field(tmp_path, mutate, message):
    from st_stereo.core.calibration.files import calibration_document
    document = calibration_document(rig_calibration('left', 0.0))
    mutate(document)
    path = _write(tmp_path, document)
    with pytest.raises(CalibrationError, match=message) as error:
        load_calibration(path)
    assert str(path) in str(error.value)


def test_missing_and_invalid_yaml(tmp_path):
    with pytest.raises(CalibrationError, match='not found'):
        load_calibration(tmp_path / 'none.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('camera_matrix: [unclosed')
    with pytest.raises(CalibrationError, match='not valid YAML'):
        load_calibration(bad)


def test_identity_rectification_keeps_the_image(people_80x60):
    rectifier = StereoRectifier(rig_calibration('left', 0.0),
                                rig_calibration('right', -83.9 * 0.55))
    left, right = rectifier.rectify(people_80x60, people_80x60)
    assert np.allclose(left, people_80x60, atol=0.05 * people_80x60.std())
    assert rectifier.model.baseline == pytest.approx(0.55)


def test_rectifier_rejects_wrong_sizes_and_swapped_cameras(people_80x60):
    rectifier = StereoRectifier(rig_calibration('left', 0.0),
                                rig_calibration('right', -46.0))
    with pytest.raises(ValueError, match='left image is 40x30'):
        rectifier.rectify(people_80x60[:30, :40], people_80x60)
    with pytest.raises(CalibrationError, match='P\\[0,3\\] must be -fx\\*B'):
        StereoRectifier(rig_calibration('left', 0.0), rig_calibration('right', 46.0))


CAMERA_CALIBRATION_OUTPUT = """image_width: 80
image_height: 60
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [83.52, 0.0, 39.71, 0.0, 83.61, 29.33, 0.0, 0.0, 1.0]
distortion_model: {model}
distortion_coefficients:
  rows: 1
  cols: {count}
  data: [{coefficients}]
rectification_matrix:
  rows: 3
  cols: 3
  data: [0.9999, 0.0093, -0.0089, -0.0093, 0.9999, -0.0005, 0.0089, 0.0006, 0.9999]
projection_matrix:
  rows: 3
  cols: 4
  data: [83.53, 0.0, 40.45, 0.0, 0.0, 83.53, 29.21, 0.0, 0.0, 0.0, 1.0, 0.0]
"""


@pytest.mark.parametrize('model, count', [('plumb_bob', 5), ('rational_polynomial', 8),
                                          ('equidistant', 4)])
def test_reads_what_camera_calibration_writes(tmp_path, model, count):
    coefficients = [-0.12, 0.03, 0.001, -0.002, 0.0, 0.0, 0.0, 0.0][:count]
    path = tmp_path / 'left.yaml'
    path.write_text(CAMERA_CALIBRATION_OUTPUT.format(
        model=model, count=count, coefficients=', '.join(map(str, coefficients))))
    loaded = load_calibration(path)
    assert (loaded.width, loaded.height, loaded.camera_name) == (80, 60, 'narrow_stereo/left')
    assert loaded.distortion_model == model
    np.testing.assert_allclose(loaded.distortion, coefficients)
    # Row-major: K[0, 2] is cx, P[1, 2] is the rectified cy.
    assert loaded.camera_matrix[0, 2] == 39.71 and loaded.camera_matrix[1, 1] == 83.61
    assert loaded.projection.shape == (3, 4) and loaded.projection[1, 2] == 29.21
    assert loaded.rectification[0, 1] == 0.0093
    # Written back: the same keys in the same order, the same numbers.
    save_calibration(loaded, tmp_path / 'again.yaml')
    text = (tmp_path / 'again.yaml').read_text()
    keys = [line.split(':')[0] for line in text.splitlines() if not line.startswith(' ')]
    assert keys == ['image_width', 'image_height', 'camera_name', 'camera_matrix',
                    'distortion_model', 'distortion_coefficients', 'rectification_matrix',
                    'projection_matrix']
    again = load_calibration(tmp_path / 'again.yaml')
    for field in ('camera_matrix', 'distortion', 'rectification', 'projection'):
        np.testing.assert_array_equal(getattr(again, field), getattr(loaded, field))


def test_mutated_calibration_files_fail_only_with_calibration_errors(tmp_path):
    # Fuzzing: a few bytes of the shipped file changed (bit flips, insertions, deletions,
    # truncation); every outcome is a valid calibration or a CalibrationError naming the file.
    import pathlib

    from hypothesis import given, HealthCheck, settings
    from hypothesis import strategies as st
    original = (pathlib.Path(__file__).parents[1] / 'config' / 'calibration' /
                'left.yaml').read_bytes()
    target = tmp_path / 'mutated.yaml'
    edit = st.tuples(st.sampled_from(['flip', 'insert', 'delete', 'truncate']),
                     st.integers(0, len(original) - 1), st.integers(0, 255))

    @settings(max_examples=400, deadline=None, database=None,
              suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(st.lists(edit, min_size=1, max_size=4))
    def check(edits):
        data = bytearray(original)
        for kind, position, value in edits:
            position = min(position, max(len(data) - 1, 0))
            if kind == 'flip' and data:
                data[position] ^= value or 1
            elif kind == 'insert':
                data.insert(position, value)
            elif kind == 'delete' and data:
                del data[position]
            else:
                del data[position:]
        target.write_bytes(bytes(data))
        try:
            load_calibration(target)
        except CalibrationError as error:
            assert str(error).startswith(str(target))
    check()


# What ROS's C++ reader (camera_calibration_parsers, yaml-cpp) reads and PyYAML alone did not:
# a file from before distortion_model existed, yaml-cpp's flow style with integer zeros, and
# a coefficient without a decimal point (yaml-cpp 0.5's six significant digits: 1e-05), which
# YAML 1.1 leaves a string. The layout is the one that parser wrote (its emitter's key order).
YAML_CPP_OUTPUT = """image_width: 80
image_height: 60
camera_name: lepton_left
camera_matrix:
  rows: 3
  cols: 3
  data: [83.61, 0, 39.71, 0, 83.58, 29.65, 0, 0, 1]
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.1234, 0.0312, 1e-05, -2e-05, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [83.61, 0, 39.71, 0, 0, 83.58, 29.65, 0, 0, 0, 1, 0]
"""


def test_reads_what_camera_calibration_parsers_wrote_before_distortion_model(tmp_path):
    path = tmp_path / 'left.yaml'
    path.write_text(YAML_CPP_OUTPUT)
    assert isinstance(yaml.safe_load(YAML_CPP_OUTPUT)['distortion_coefficients']['data'][2],
                      str)                          # what PyYAML alone makes of 1e-05
    loaded = load_calibration(path)
    assert loaded.distortion_model == 'plumb_bob'
    np.testing.assert_array_equal(loaded.distortion, [-0.1234, 0.0312, 1e-05, -2e-05, 0.0])
    assert loaded.notes == (f'{path}: no distortion_model, plumb_bob assumed (as '
                            f'camera_calibration_parsers reads such a file)',)
    assert loaded.camera_matrix[1, 2] == 29.65
    # Written back, the model is explicit and nothing is assumed any more.
    save_calibration(loaded, tmp_path / 'again.yaml')
    again = load_calibration(tmp_path / 'again.yaml')
    assert again.notes == () and again.distortion_model == 'plumb_bob'


@pytest.mark.parametrize('value, message', [
    ("'abc'", 'data must be numbers'), ('true', 'data must be numbers'),
    ("'nan'", 'non-finite'), ('[1]', 'data must be numbers')])
def test_a_string_that_is_not_a_number_is_still_refused(tmp_path, value, message):
    path = tmp_path / 'left.yaml'
    path.write_text(YAML_CPP_OUTPUT.replace('data: [-0.1234,', f'data: [{value},'))
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)
