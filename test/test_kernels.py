"""The compiled kernels against the numpy reference (st_stereo.core.kernels)."""

import dataclasses

import numpy as np
import pytest
from st_stereo.core import kernels
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.phase_congruency import phase_congruency_moments
from st_stereo.tools.eval_subpixel import make_shifted_pair

NUMPY = STConfig(kernels='numpy')
COMPILED = STConfig(kernels='compiled')


def test_numba_is_installed_where_the_tests_run():
    # The pinned environment has numba: the comparisons below must not silently compare
    # numpy with itself.
    assert kernels.numba_available()
    assert kernels.use_compiled('auto') and kernels.use_compiled('compiled')
    assert not kernels.use_compiled('numpy')


def test_phase_congruency_moments_match_the_numpy_reference(any_frame_80x60, rng):
    images = np.stack([any_frame_80x60, any_frame_80x60 + rng.normal(0, 2, (60, 80))])
    expected = phase_congruency_moments(images, NUMPY)
    got = phase_congruency_moments(images, COMPILED)
    for e, g in zip(expected, got):
        assert g.dtype == e.dtype and g.shape == e.shape
        # float32 arithmetic in the same order; magnitudes by sqrt instead of hypot.
        np.testing.assert_allclose(g, e, rtol=0, atol=2e-6)
    single = phase_congruency_moments(any_frame_80x60, COMPILED)[0]
    np.testing.assert_allclose(single, expected[0][0], rtol=0, atol=2e-6)


@pytest.mark.parametrize('shift', [3.25, 7.6])
def test_the_matcher_gives_the_same_matches_with_either_implementation(any_frame_80x60,
                                                                       shift):
    left, right = make_shifted_pair(any_frame_80x60, shift, np.random.default_rng(5),
                                    realistic=True)
    reference = StereoMatcher(NUMPY).match(left, right)
    compiled = StereoMatcher(COMPILED).match(left, right)
    assert len(reference) > 20
    np.testing.assert_array_equal(compiled.x_left, reference.x_left)
    np.testing.assert_array_equal(compiled.y, reference.y)
    np.testing.assert_allclose(compiled.disparity, reference.disparity, rtol=0, atol=1e-6)
    assert compiled.counts == reference.counts


def test_compiled_without_numba_is_a_clear_error_and_auto_falls_back(monkeypatch):
    monkeypatch.setattr(kernels, 'numba_available', lambda: '')
    with pytest.raises(ValueError, match='kernels: compiled needs numba'):
        kernels.use_compiled('compiled')
    assert not kernels.use_compiled('auto')
    with pytest.raises(ValueError, match='kernels: expected one of auto, compiled, numpy, '
                                         'got .fast.'):
        kernels.use_compiled('fast')


def test_the_configuration_rejects_an_unknown_kernel_choice():
    with pytest.raises(ValueError, match='kernels'):
        dataclasses.replace(STConfig(), kernels='gpu')


def test_warm_up_compiles_and_reports_its_time():
    assert kernels.warm_up() >= 0.0
    assert kernels._compiled.cache_info().currsize == 1
