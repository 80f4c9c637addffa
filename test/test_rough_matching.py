"""Rough matching: Lades similarity and each constraint on crafted cases."""

import dataclasses

import numpy as np
import pytest

from st_stereo.core.config import STConfig
from st_stereo.core.rough_matching import (continuity_consistent, disparity_search_range,
                                           enforce_uniqueness, lades_similarity,
                                           lades_similarity_volume, left_right_consistent,
                                           ordering_consistent, rough_match, shifted_stack)


def test_lades_similarity_of_identical_windows_is_one(rng):
    window = rng.random((5, 5))
    assert lades_similarity(window, window) == pytest.approx(1.0)


def test_lades_similarity_is_blind_to_gain_but_not_to_offset(rng):
    window = rng.random((5, 5))
    assert lades_similarity(window, 3.0 * window) == pytest.approx(1.0)
    assert lades_similarity(window, window + 1.0) < 1.0


def test_lades_similarity_of_disjoint_and_zero_windows():
    a = np.zeros((5, 5))
    b = np.zeros((5, 5))
    a[:, :2] = 1.0
    b[:, 3:] = 1.0
    assert lades_similarity(a, b) == 0.0
    assert lades_similarity(a, np.zeros((5, 5))) == 0.0


def test_shifted_stack_moves_right_by_d():
    image = np.arange(12, dtype=float).reshape(2, 6)
    stack = shifted_stack(image, np.array([0, 2]))
    assert np.array_equal(stack[0], image)
    assert np.array_equal(stack[1][:, 2:], image[:, :4])
    assert np.all(stack[1][:, :2] == 0)


def test_similarity_volume_matches_the_direct_formula(rng):
    left = rng.random((20, 30))
    right = rng.random((20, 30))
    disparities = np.arange(0, 6)
    volume = lades_similarity_volume(left, right, disparities, 5)
    for d_index, y, x in [(0, 10, 10), (3, 5, 12), (5, 14, 20), (2, 2, 4)]:
        d = disparities[d_index]
        pad_l = np.pad(left, 2)
        pad_r = np.pad(right, 2)
        wl = pad_l[y:y + 5, x:x + 5]
        wr = pad_r[y:y + 5, x - d:x - d + 5]
        assert volume[d_index, y, x] == pytest.approx(lades_similarity(wl, wr), abs=1e-5)


def test_uniqueness_keeps_the_most_similar_claim():
    y = np.array([3, 3, 3])
    x_left = np.array([10, 14, 20])
    x_right = np.array([5.0, 5.2, 9.0])       # the first two collide (0.2 px apart)
    similarity = np.array([0.8, 0.95, 0.9])
    keep = enforce_uniqueness(y, x_left, x_right, similarity, tolerance=0.5)
    assert keep.tolist() == [False, True, True]


def test_uniqueness_ignores_other_rows():
    keep = enforce_uniqueness(np.array([1, 2]), np.array([5, 5]), np.array([3.0, 3.0]),
                              np.array([0.9, 0.8]), tolerance=0.5)
    assert keep.all()


def test_ordering_drops_the_less_similar_of_a_crossing():
    y = np.array([0, 0, 0, 1])
    x_left = np.array([10, 12, 20, 5])
    x_right = np.array([8, 4, 15, 1])          # match 1 lands left of match 0
    similarity = np.array([0.9, 0.7, 0.95, 0.9])
    assert ordering_consistent(y, x_left, x_right, similarity).tolist() == \
        [True, False, True, True]


def test_continuity_rejects_an_outlier_among_smooth_neighbours():
    ys, xs = np.mgrid[10:15, 10:15]
    y, x = ys.ravel(), xs.ravel()
    disparity = np.full(len(y), 12.0)
    disparity[12] = 20.0                        # the centre is an outlier
    keep = continuity_consistent((30, 30), y, x, disparity, radius=2, max_jump=2.0,
                                 min_neighbours=4)
    assert keep.sum() == len(y) - 1 and not keep[12]


def test_continuity_keeps_isolated_matches():
    keep = continuity_consistent((30, 30), np.array([5, 20]), np.array([5, 20]),
                                 np.array([3.0, 25.0]), radius=3, max_jump=1.0,
                                 min_neighbours=2)
    assert keep.all()


def test_left_right_check_rejects_a_one_sided_match():
    # Right pixel (0, 5) is best matched from left x=8 (d=3), but right-to-left its best
    # partner is left x=10 (d=5): inconsistent beyond tolerance 1.
    disparities = np.arange(0, 7)
    volume = np.zeros((7, 1, 20), dtype=np.float32)
    volume[3, 0, 8] = 0.8
    volume[5, 0, 10] = 0.95
    valid_left = np.ones((1, 20), dtype=bool)
    ok = left_right_consistent(volume, valid_left, disparities, np.array([0]), np.array([5]),
                               np.array([3]), tolerance=1)
    assert not ok[0]
    ok = left_right_consistent(volume, valid_left, disparities, np.array([0]), np.array([5]),
                               np.array([3]), tolerance=2)
    assert ok[0]


def _textured_pair(rng, shift):
    base = rng.random((40, 80))
    left = np.repeat(base, 1, axis=0)
    right = np.zeros_like(left)
    right[:, :80 - shift] = left[:, shift:]
    return left, right


def test_rough_match_finds_an_integer_shift(rng):
    left, right = _textured_pair(rng, 7)
    config = STConfig(gamma=0.0, candidate_ratio=0.0, continuity=False)
    features = np.zeros(left.shape, dtype=bool)
    features[5:35, 20:70] = True
    matches = rough_match(left, right, features, config)
    assert len(matches) > 0.95 * features.sum()
    assert np.mean(matches.disparity == 7) > 0.99


def test_prior_restricts_the_search(rng):
    left, right = _textured_pair(rng, 7)
    config = STConfig(gamma=0.0, candidate_ratio=0.0, prior_radius=1)
    features = np.zeros(left.shape, dtype=bool)
    features[10:30, 30:60] = True
    matches = rough_match(left, right, features, config, prior=20.0)
    assert np.all(np.abs(matches.disparity - 20) <= 1)


def test_prior_with_the_wrong_shape_is_rejected():
    with pytest.raises(ValueError, match='disparity prior'):
        disparity_search_range(STConfig(), np.zeros((3, 3)), (60, 80))


def test_each_constraint_can_be_switched_off_and_reports_its_rejections(people_80x60):
    from st_stereo.core.fourier import fourier_shift_image_x
    from st_stereo.core.matcher import feature_mask
    from st_stereo.core.phase_congruency import feature_strength
    config = STConfig()
    right = fourier_shift_image_x(people_80x60, 12.5)
    moments = feature_strength(np.stack((people_80x60, right)), config)
    features, _ = feature_mask(moments[0], config.gamma, 4)
    everything = rough_match(moments[0], moments[1], features, config)
    off = dataclasses.replace(config, left_right_check=False, ordering=False,
                              continuity=False, min_similarity=0.0)
    nothing = rough_match(moments[0], moments[1], features, off)
    assert len(nothing) >= len(everything)
    for key in ('left_right', 'ordering', 'continuity', 'similarity'):
        assert nothing.rejected[key] == 0
    rejected = sum(everything.rejected.values())
    assert rejected + len(everything) == int(features.sum())
