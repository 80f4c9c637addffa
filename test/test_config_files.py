"""The files in config/ agree with the code: parameters and the default rig calibration."""

import pathlib

import pytest
from st_stereo.cli import parameters_yaml
from st_stereo.core.calibration.files import load_calibration
from st_stereo.core.config import STConfig
from st_stereo.core.rectification import StereoRectifier
import yaml

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'


def test_parameter_file_is_generated_from_the_config():
    text = (CONFIG / 'st_stereo.yaml').read_text()
    assert text == parameters_yaml(), 'regenerate with `st-stereo params --yaml`'
    document = yaml.safe_load(text)
    from st_stereo.nodes.node_parameters import MATCHER_PARAMETERS
    values = dict(document['/**/matcher']['ros__parameters'])
    for parameter in MATCHER_PARAMETERS:            # the node's own, not ST's
        assert values.pop(parameter.name) == parameter.default
    assert STConfig.from_mapping(values) == STConfig()
    assert document['/**/lepton_driver']['ros__parameters']['source'] == 'sim'


def test_default_rig_calibration_is_a_rectified_pair():
    left = load_calibration(CONFIG / 'calibration' / 'left.yaml')
    right = load_calibration(CONFIG / 'calibration' / 'right.yaml')
    rectifier = StereoRectifier(left, right)
    assert (left.width, left.height) == (80, 60)
    assert left.camera_matrix[0, 0] == pytest.approx(83.9, abs=0.05)
    assert rectifier.model.fx * rectifier.model.baseline == pytest.approx(46.3, abs=0.01)
