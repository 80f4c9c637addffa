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


def test_a_second_process_loads_every_kernel_from_the_disk_cache(tmp_path):
    # Would catch a kernel whose cache key changes per process (a closure over another
    # kernel did): recompiled at every node start, seconds on a small board.
    import os
    import subprocess
    import sys
    names = sorted(('orientation_energy', 'moments', 'lades_volume', 'cross_power',
                    'shift_phases', 'poc_peak_fits', 'feature_candidates', 'left_right_best',
                    'continuity_medians', 'deramped_strips', 'reramped_columns',
                    'window_ncc'))
    script = (
        f'KERNELS = {names!r}\n'
        'from st_stereo.core import kernels\n'
        'kernels.warm_up()\n'
        'module = kernels._compiled()\n'
        'print(sorted(name for name in KERNELS '
        'if sum(getattr(module, name).stats.cache_hits.values()) > 0))\n')
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    runs = []
    for _ in range(2):
        runs.append(subprocess.run([sys.executable, '-c', script], env=env, check=True,
                                   capture_output=True, text=True).stdout.strip())
    assert runs[1] == repr(names), runs


def test_the_lades_volume_matches_the_numpy_reference(any_frame_80x60):
    from scipy import ndimage
    from st_stereo.core.phase_congruency import feature_strength
    from st_stereo.core.rough_matching import lades_similarity_volume, shifted_stack, TINY
    left, right = make_shifted_pair(any_frame_80x60, 6.4, np.random.default_rng(2),
                                    realistic=True)
    moments = feature_strength(np.stack([left, right]), NUMPY).astype(np.float64)
    for disparities, window in ((np.arange(0, 41), 11), (np.arange(3, 9), 5)):
        expected = lades_similarity_volume(moments[0], moments[1], disparities, window)
        got = kernels.lades_similarity_volume(moments[0], moments[1], disparities, window,
                                              TINY)
        assert got.dtype == np.float32 and got.shape == expected.shape

        def energy(image):
            return ndimage.uniform_filter(image ** 2, window, mode='constant')

        # Where both windows hold some M: windows of M ~ 0 give 0 / 0 ratios in which
        # OpenCV's float32 running-sum residues (~1e-9) decide the reference's value.
        held = np.sqrt(energy(moments[0])[None] *
                       shifted_stack(energy(moments[1]), disparities)) > 1e-3
        assert held.mean() > 0.3
        np.testing.assert_allclose(got[held], expected[held], rtol=0, atol=1e-5)


def _rough_matches(frame, shift, seed):
    from st_stereo.core.matcher import feature_mask
    left, right = make_shifted_pair(frame, shift, np.random.default_rng(seed), realistic=True)
    moments = StereoMatcher(NUMPY).feature_images(left, right)
    features, _ = feature_mask(moments[0], NUMPY.gamma, NUMPY.poc_window // 2)
    return left, right, moments, features


@pytest.mark.parametrize('prior', ['none', 'per-pixel'])
def test_rough_matching_is_the_numpy_reference_bit_for_bit(any_frame_80x60, prior):
    # Same moments in, so every candidate, rival and constraint must come out identical.
    from st_stereo.core.rough_matching import rough_match
    _, _, moments, features = _rough_matches(any_frame_80x60, 7.6, 3)
    expected_prior = None
    if prior == 'per-pixel':
        known = np.random.default_rng(1).random(features.shape) < 0.5
        expected_prior = np.where(known, 7.0, np.nan)
    expected = rough_match(moments[0], moments[1], features, NUMPY, expected_prior,
                           right_margin=4)
    got = rough_match(moments[0], moments[1], features, COMPILED, expected_prior,
                      right_margin=4)
    assert len(expected) > 50
    for name in ('y', 'x_left', 'disparity', 'similarity', 'distinctiveness'):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name), name)
    assert got.rejected == expected.rejected


@pytest.mark.parametrize('settings', [{}, {'poc_iterations': 1}, {'poc_band': 'takita'},
                                      {'poc_hann': False}])
def test_the_subpixel_stage_matches_the_numpy_reference(any_frame_80x60, settings):
    from st_stereo.core.rough_matching import rough_match
    from st_stereo.core.subpixel import refine_subpixel_poc
    left, right, moments, features = _rough_matches(any_frame_80x60, 3.25, 4)
    rough = rough_match(moments[0], moments[1], features, NUMPY, right_margin=4)
    results = [refine_subpixel_poc(left, right, rough.y, rough.x_left, rough.disparity,
                                   dataclasses.replace(config, **settings))
               for config in (NUMPY, COMPILED)]
    expected, got = results
    assert expected.accepted.sum() > 50
    np.testing.assert_array_equal(got.accepted, expected.accepted)
    assert got.rejected == expected.rejected and got.clamped_to_zero == expected.clamped_to_zero
    # The phase ramps and the spectra's products are numpy's own; the cross-power spectrum
    # uses sqrt and one reciprocal for hypot and a complex division (a few ulp).
    np.testing.assert_allclose(got.disparity, expected.disparity, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.peak_value, expected.peak_value, rtol=0, atol=1e-12)


def _moving_block(frame, rng, shift_px=1.7):
    # The frame with a block of columns moved along the rows between two frames of a
    # camera (a walker), the rest static; the sensor's noise in both frames.
    from st_stereo.core.fourier import fourier_shift_image_x
    moved = fourier_shift_image_x(frame, shift_px)
    block = np.zeros(frame.shape, dtype=bool)
    block[:, 25:55] = True
    noise = 0.01 * np.ptp(frame)
    previous = np.where(block, moved, frame) + rng.normal(0, noise, frame.shape)
    return previous, frame + rng.normal(0, noise, frame.shape)


def test_the_skew_tracks_match_the_numpy_reference(any_frame_80x60):
    # The NCC search of the camera-skew correction: OpenCV's float32 matchTemplate per
    # feature against the compiled float64 kernel, same decisions, velocities within
    # 1e-3 px/s (a 1e-4 px shift over the 0.1 s period; ~1e-5 px of disparity at 57 ms).
    from st_stereo.core.skew import feature_motion
    previous, current = _moving_block(any_frame_80x60, np.random.default_rng(6))
    result = StereoMatcher(COMPILED).match(current, current)
    motions = [feature_motion(previous, current, result.x_left, result.y, 0.1,
                              kernels=config.kernels) for config in (NUMPY, COMPILED)]
    expected, got = motions
    assert expected.moving.sum() > 20 and (~expected.changed).sum() > 20
    for name in ('moving', 'changed', 'tracked'):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name), name)
    np.testing.assert_allclose(got.velocity_x, expected.velocity_x, rtol=0, atol=1e-3)
    np.testing.assert_allclose(got.ncc, expected.ncc, rtol=0, atol=2e-5)


@pytest.mark.parametrize('features', ['scattered', 'dense'])
def test_the_ncc_kernel_is_opencvs_matchtemplate(lepton_frame, features):
    # Both ways the kernel sums (per window for a few scattered features, shared running
    # sums for many), and OpenCV's flat windows: a flat template correlates 1 at every
    # offset, a flat window 0.
    from st_stereo.core.skew import window_ncc
    frame = lepton_frame.astype(np.float64)
    previous, current = _moving_block(frame, np.random.default_rng(7))
    current[40:52, 8:20] = 700.0          # a flat template around (46, 14)
    previous[5:20, 60:79] = 300.0         # flat windows around (12, 69)
    previous, current = (np.pad(image - image.mean(), 12, mode='edge')
                         for image in (previous, current))
    if features == 'scattered':
        # padded pixels: the flat template's, the flat windows', two textured ones
        y, x = np.array([58, 24, 40, 70]), np.array([26, 81, 40, 90])
    else:
        y, x = (axis.ravel() + 12 for axis in np.mgrid[2:58:2, 2:78:3])
    offsets_y, offsets_x = np.arange(-3, 4), np.arange(-9, 10)
    opencv = window_ncc(current, previous, y, x, 4, offsets_y, offsets_x, 'numpy')
    got = window_ncc(current, previous, y, x, 4, offsets_y, offsets_x, 'compiled')
    assert got.shape == opencv.shape == (len(y), 7, 19)
    # In float64 by definition, where neither window is flat:
    windows = np.lib.stride_tricks.sliding_window_view
    template = windows(current, (9, 9))[y - 4, x - 4]
    template = template - template.mean(axis=(1, 2), keepdims=True)
    region = windows(previous, (9, 9))[(y - 4)[:, None, None] + offsets_y[:, None],
                                       (x - 4)[:, None, None] + offsets_x]
    region = region - region.mean(axis=(3, 4), keepdims=True)
    numerator = np.einsum('kij,kabij->kab', template, region)
    template_norm = np.sqrt(np.einsum('kij,kij->k', template, template))[:, None, None]
    region_norm = np.sqrt(np.einsum('kabij,kabij->kab', region, region))
    norm = template_norm * region_norm
    textured = norm > 1e-9 * norm.max()
    assert textured.mean() > 0.5 and not textured.all()
    np.testing.assert_allclose(got[textured], (numerator / norm)[textured], rtol=0, atol=1e-9)
    # OpenCV correlates in float32 (its error grows where a window's spread is small beside
    # the frame's values: up to 4e-3 here); where both hold 1 % of the largest spread:
    held = (template_norm > 0.01 * template_norm.max()) & \
        (region_norm > 0.01 * region_norm.max())
    assert held.any()
    np.testing.assert_allclose(got[held], opencv[held], rtol=0, atol=2e-4)
    # Flat windows as OpenCV has them: a flat template 1 at every offset, a flat window 0.
    assert (opencv[~textured] == got[~textured]).all()
    assert (got == 1.0).all(axis=(1, 2)).any() and (got == 0.0).any()


def test_the_ncc_kernel_refuses_a_window_outside_the_frames():
    # The kernel reads without bounds checks: its wrapper checks, as OpenCV does.
    frame = np.random.default_rng(8).normal(size=(30, 40))
    offsets_y, offsets_x = np.arange(-3, 4), np.arange(-9, 10)
    kernels.window_ncc(frame, frame, np.array([7]), np.array([13]), 4, offsets_y, offsets_x)
    for y, x in ((6, 13), (7, 12), (23, 20), (10, 27)):
        with pytest.raises(ValueError, match='leave the 40x30 frames'):
            kernels.window_ncc(frame, frame, np.array([y]), np.array([x]), 4, offsets_y,
                               offsets_x)
