"""Sub-pixel POC: the sign both ways, the estimator on its own model, rejections."""

import dataclasses

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from st_stereo.core.config import STConfig
from st_stereo.core.fourier import fourier_shift_image_x
from st_stereo.core.subpixel import (extract_windows, half_sample_hann, nagashima_peak_offset,
                                     phase_only_correlation, refine_subpixel_poc)


def test_half_sample_hann_is_symmetric_and_nonzero_at_the_ends():
    window = half_sample_hann(9)
    assert np.allclose(window, window[::-1, ::-1])
    assert window.min() > 0
    assert window[4, 4] == pytest.approx(1.0)


def test_poc_of_identical_windows_peaks_at_zero_lag(rng):
    windows = rng.random((3, 9, 9))
    surface = phase_only_correlation(windows, windows)
    assert np.all(surface.reshape(3, -1).argmax(axis=1) == 4 * 9 + 4)


@pytest.mark.parametrize('residual', [0.3, -0.3])
def test_subpixel_sign_both_ways(people_80x60, residual):
    # right = left moved left by (10 + residual): the disparity is 10 + residual
    shift = 10.0 + residual
    right = fourier_shift_image_x(people_80x60, shift)
    y = np.array([20, 30, 35])
    x = np.array([40, 50, 45])
    d_int = np.full(3, 10)
    for estimator in ('nagashima', 'recentred'):
        config = STConfig(poc_source='intensity', poc_estimator=estimator)
        result = refine_subpixel_poc(people_80x60, right, y, x, d_int, config)
        assert result.accepted.all()
        assert np.all(np.abs(result.disparity - shift) < 0.15), (estimator, result.disparity)


@settings(max_examples=60, deadline=None)
@given(delta=st.floats(-0.9, 0.9), peak_offset=st.integers(-1, 1),
       band=st.sampled_from([9, 5]))
def test_nagashima_recovers_delta_exactly_on_its_model(delta, peak_offset, band):
    size = 15
    lag = np.arange(size) - size // 2
    t = lag + delta
    with np.errstate(invalid='ignore', divide='ignore'):
        profile = np.where(np.abs(t) < 1e-12, band / size,
                           np.sin(np.pi * band * t / size) / (np.pi * t))
    peak = int(np.argmax(profile))
    estimate, denominator = nagashima_peak_offset(profile[None], np.array([peak]), band / size)
    assert denominator[0] > 0
    assert estimate[0] == pytest.approx(delta, abs=1e-9)


@settings(max_examples=25, deadline=None)
@given(shift=st.floats(2.0, 20.0))
def test_recentred_estimator_recovers_random_shifts(people_80x60, shift):
    right = fourier_shift_image_x(people_80x60, shift)
    y = np.array([15, 25, 30, 40, 45])
    x = np.array([40, 50, 60, 45, 55])
    d_int = np.full(5, int(round(shift)))
    result = refine_subpixel_poc(people_80x60, right, y, x, d_int, STConfig())
    assert result.accepted.all()
    assert np.median(np.abs(result.disparity - shift)) < 0.05


def test_flat_windows_are_rejected_and_counted():
    flat = np.full((40, 60), 100.0)
    y = np.array([20, 20])
    x = np.array([30, 40])
    result = refine_subpixel_poc(flat, flat, y, x, np.array([5, 5]), STConfig())
    assert not result.accepted.any()
    assert sum(result.rejected.values()) == 2


def test_corrections_beyond_the_limit_are_rejected(people_80x60):
    right = fourier_shift_image_x(people_80x60, 10.0)
    y, x = np.array([30]), np.array([50])
    strict = dataclasses.replace(STConfig(), poc_max_shift=0.2)
    result = refine_subpixel_poc(people_80x60, right, y, x, np.array([9]), strict)
    assert not result.accepted[0] and result.rejected['subpixel_range'] == 1


def test_takita_band_limit_runs_and_stays_close(people_80x60):
    right = fourier_shift_image_x(people_80x60, 8.4)
    y = np.array([20, 30, 40])
    x = np.array([40, 50, 45])
    config = dataclasses.replace(STConfig(), poc_band='takita')
    result = refine_subpixel_poc(people_80x60, right, y, x, np.full(3, 8), config)
    assert np.all(np.abs(result.disparity[result.accepted] - 8.4) < 0.3)


@pytest.mark.parametrize('y, x', [(3, 40), (56, 40), (30, 3), (30, 76)])
def test_a_window_leaving_the_image_is_refused(y, x):
    image = np.zeros((60, 80))
    with pytest.raises(ValueError, match='window leaves the 80x60 image'):
        extract_windows(image, np.array([30, y]), np.array([40, x]), 9)
    # Touching the border is inside.
    assert extract_windows(image, np.array([4, 55]), np.array([4, 75]), 9).shape == (2, 9, 9)
