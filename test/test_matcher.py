"""StereoMatcher end to end: accuracy on real frames, accounting, bad input."""

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from st_stereo.core import STConfig, StereoMatcher, StereoModel
from st_stereo.core.fourier import fourier_shift_image_x
from st_stereo.core.matcher import PUBLISH_REJECTION_KEYS
from st_stereo.core.rough_matching import REJECTION_KEYS
from st_stereo.core.subpixel import SUBPIXEL_REJECTION_KEYS


@settings(max_examples=12, deadline=None)
@given(shift=st.floats(0.5, 28.0))
def test_random_subpixel_shifts_are_recovered(people_80x60, shift):
    right = fourier_shift_image_x(people_80x60, shift)
    result = StereoMatcher().match(people_80x60, right)
    inside = result.x_left - shift >= 4
    errors = np.abs(result.disparity[inside] - shift)
    assert inside.sum() > 100
    assert np.mean(errors <= 0.1) > 0.97
    assert np.median(errors) < 0.02


def test_every_shared_frame_matches(any_frame_80x60):
    right = fourier_shift_image_x(any_frame_80x60, 9.37)
    result = StereoMatcher().match(any_frame_80x60, right)
    inside = result.x_left - 9.37 >= 4
    assert inside.sum() > 50
    assert np.mean(np.abs(result.disparity[inside] - 9.37) <= 0.25) > 0.9


def test_every_feature_is_accounted_for(people_80x60):
    right = fourier_shift_image_x(people_80x60, 13.8) * 1.05 + 40.0
    result = StereoMatcher().match(people_80x60, right)
    counts = result.counts
    rough_rejected = sum(counts[f'rejected_{key}'] for key in REJECTION_KEYS)
    assert counts['features'] == counts['rough_matches'] + rough_rejected
    late = sum(counts[f'rejected_{key}'] for key in SUBPIXEL_REJECTION_KEYS +
               PUBLISH_REJECTION_KEYS)
    assert counts['rough_matches'] == counts['matches'] + late
    assert counts['matches'] == len(result)
    assert set(result.timings_ms) == {'features', 'rough_matching', 'subpixel', 'depth_edges',
                                      'triangulation', 'total'}


def test_points_follow_the_stereo_model(people_80x60):
    model = StereoModel.default_lepton_rig()
    depth = 3.5
    right = fourier_shift_image_x(people_80x60, float(model.disparity_of_depth(depth)))
    result = StereoMatcher(model=model).match(people_80x60, right)
    inside = result.x_left - model.disparity_of_depth(depth) >= 4
    assert np.median(np.abs(result.points[inside, 2] - depth)) < 0.01


@pytest.mark.parametrize('dtype', [np.uint8, np.uint16, np.float32])
def test_integer_and_float_inputs(people_80x60, dtype):
    scale = 255.0 if dtype is np.uint8 else 16383.0
    low, high = people_80x60.min(), people_80x60.max()
    left = (people_80x60 - low) / (high - low) * scale
    right = fourier_shift_image_x(left, 7.25)
    result = StereoMatcher().match(np.round(left).astype(dtype),
                                   np.clip(np.round(right), 0, scale).astype(dtype))
    inside = result.x_left - 7.25 >= 4
    assert np.mean(np.abs(result.disparity[inside] - 7.25) <= 0.25) > 0.9


def test_constant_images_give_an_empty_result():
    flat = np.full((60, 80), 7000, dtype=np.uint16)
    result = StereoMatcher(model=StereoModel.default_lepton_rig()).match(flat, flat)
    assert len(result) == 0 and result.counts['features'] == 0
    assert result.points.shape == (0, 3)
    assert result.to_csv().count('\n') == 1


@pytest.mark.parametrize('left, right, message', [
    (np.zeros((60, 80, 3)), np.zeros((60, 80, 3)), 'left image: expected a 2-D array'),
    (np.zeros((60, 80)), np.zeros((60, 81)), 'image sizes differ'),
    (np.zeros((8, 80)), np.zeros((8, 80)), 'at least 16x16'),
    (np.array([['a'] * 20] * 20), np.zeros((20, 20)), 'integer or float pixels'),
])
def test_bad_input_is_named(left, right, message):
    with pytest.raises(ValueError, match=message):
        StereoMatcher().match(left, right)


def test_non_finite_pixels_are_rejected():
    right = np.ones((60, 80))
    right[3, 4] = np.nan
    with pytest.raises(ValueError, match='right image: 1 non-finite'):
        StereoMatcher().match(np.ones((60, 80)), right)


def test_config_type_is_checked():
    with pytest.raises(TypeError, match='STConfig'):
        StereoMatcher({'gamma': 0.1})


def test_prior_from_the_previous_frame(people_80x60):
    right = fourier_shift_image_x(people_80x60, 11.3)
    matcher = StereoMatcher(STConfig(prior_radius=2))
    first = matcher.match(people_80x60, right)
    prior = np.full(people_80x60.shape, np.nan)
    prior[first.y, first.x_left] = first.disparity
    second = matcher.match(people_80x60, right, disparity_prior=np.nanmedian(prior))
    assert len(second) >= 0.95 * len(first)
    inside = second.x_left - 11.3 >= 4
    assert np.median(np.abs(second.disparity[inside] - 11.3)) < 0.02


def test_monogenic_and_paper_configurations_run(people_80x60):
    right = fourier_shift_image_x(people_80x60, 10.5)
    for config in (STConfig(pc_method='monogenic', gamma=0.2),
                   STConfig(similarity_window=5, poc_source='moments',
                            poc_estimator='nagashima', poc_max_shift=1.0)):
        result = StereoMatcher(config).match(people_80x60, right)
        inside = result.x_left - 10.5 >= 4
        assert np.mean(np.abs(result.disparity[inside] - 10.5) <= 0.5) > 0.9
