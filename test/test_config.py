"""STConfig: validated, documented, frozen."""

import dataclasses

import pytest

from st_stereo.core.config import describe_fields, STConfig


def test_defaults_are_valid_and_frozen():
    config = STConfig()
    assert config.poc_window == 9 and config.gamma == 0.1
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.gamma = 0.3


@pytest.mark.parametrize('changes, message', [
    ({'poc_window': 8}, 'poc_window: expected an odd number, got 8'),
    ({'gamma': 1.5}, 'gamma: expected a value in'),
    ({'pc_method': 'sobel'}, 'pc_method: expected one of'),
    ({'uniqueness': 1}, 'uniqueness: expected a bool'),
    ({'pc_scales': 4.0}, 'pc_scales: expected an integer'),
    ({'gamma': float('nan')}, 'gamma: expected a finite number'),
    ({'disparity_min': 30, 'disparity_max': 10}, 'disparity_min'),
])
def test_invalid_values_name_the_field(changes, message):
    with pytest.raises(ValueError, match=message.replace('[', '\\[')):
        STConfig(**changes)


def test_replace_validates_too():
    with pytest.raises(ValueError, match='similarity_window'):
        dataclasses.replace(STConfig(), similarity_window=4)


def test_from_mapping_rejects_unknown_keys():
    with pytest.raises(ValueError, match='unknown ST parameter.*poc_windw'):
        STConfig.from_mapping({'poc_windw': 9})
    assert STConfig.from_mapping({'gamma': 0.3}).gamma == 0.3


def test_every_field_is_documented():
    for name, _, _, meta in describe_fields():
        assert len(meta['description']) > 10, name


def test_noise_k_defaults_per_method():
    assert STConfig().noise_k == 2.0
    assert STConfig(pc_method='monogenic').noise_k == 3.0
    assert STConfig(pc_noise_k=5.0).noise_k == 5.0
