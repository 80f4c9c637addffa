"""A static match must have been made alike by the previous pair (st_stereo.core.temporal)."""

import numpy as np
import pytest
from st_stereo.core.config import STConfig
from st_stereo.core.fourier import fourier_shift_image_x
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.temporal import TemporalCheck
from st_stereo.core.triangulation import StereoModel

PERIOD_S = 1.0 / 8.7
MODEL = StereoModel.default_lepton_rig()


def thermal(texture):
    return 7800.0 + (texture - texture.min()) * 800.0 / np.ptp(texture)


def noisy(image, seed):
    return image + np.random.default_rng(seed).normal(0.0, 2.0, image.shape)


def pair(texture, disparity, seed, motion=0.0):
    """Return a plane at ``disparity`` px (moved ``motion`` px along the rows), fresh noise."""
    left = fourier_shift_image_x(texture, -motion)
    return noisy(left, seed), noisy(fourier_shift_image_x(left, disparity), seed + 100)


def match(left, right):
    return StereoMatcher(STConfig(), model=MODEL).match(left, right)


@pytest.fixture(scope='module')
def texture(people_80x60):
    return thermal(people_80x60)


def test_a_static_scene_matched_alike_keeps_every_match(texture):
    check = TemporalCheck(0.3)
    first = match(*pair(texture, 12.0, 1))
    assert check.check(first, pair(texture, 12.0, 1)[0], 0.0, MODEL) is first
    left, right = pair(texture, 12.0, 2)
    second = match(left, right)
    kept = check.check(second, left, PERIOD_S, MODEL)
    assert check.counts['pairs_without_previous'] == 1 and check.counts['pairs_checked'] == 1
    assert check.counts['features_static'] > 0.9 * len(second)
    # Fresh noise moves a few features across the threshold or a disparity by > 0.3 px.
    dropped = check.counts['rejected_temporal_unmatched'] + \
        check.counts['rejected_temporal_inconsistent']
    assert len(kept) == len(second) - dropped and dropped < 0.1 * len(second)
    np.testing.assert_array_equal(kept.points, second.points[np.isin(
        second.y * 1000 + second.x_left, kept.y * 1000 + kept.x_left)])


def test_static_matches_made_otherwise_or_not_at_all_are_dropped(texture):
    # The same left scene, but the previous pair's disparities 0.6 px apart (as an ambiguous
    # match flips), or a third of its matches missing: those static matches go, counted.
    left, right = pair(texture, 12.0, 1)
    first = match(left, right)
    check = TemporalCheck(0.3)
    check.check(first, left, 0.0, MODEL)
    later_left, later_right = pair(texture, 12.6, 2)
    later = match(later_left, later_right)
    kept = check.check(later, later_left, PERIOD_S, MODEL)
    assert check.counts['rejected_temporal_inconsistent'] > 0.8 * len(later)
    assert len(kept) < 0.2 * len(later)
    check = TemporalCheck(0.3)
    missing = np.arange(len(first)) % 3 == 0
    check.check(first.select(~missing), left, 0.0, MODEL)
    same = match(*pair(texture, 12.0, 2))
    kept = check.check(same, pair(texture, 12.0, 2)[0], PERIOD_S, MODEL)
    previous = set(zip(first.y[missing], first.x_left[missing]))
    gone = set(zip(same.y, same.x_left)) - set(zip(kept.y, kept.x_left))
    assert check.counts['rejected_temporal_unmatched'] >= 0.8 * len(previous & set(
        zip(same.y, same.x_left)))
    assert len(gone & previous) >= 0.8 * len(previous & set(zip(same.y, same.x_left)))


def test_a_dropped_match_is_judged_again_against_the_next_pair(texture):
    # The check remembers each pair's matches before it drops any: a match dropped once
    # (its previous pair had none) comes back when the next pair makes it alike.
    check = TemporalCheck(0.3)
    left, right = pair(texture, 12.0, 1)
    first = match(left, right)
    check.check(first.select(np.zeros(len(first), dtype=bool)), left, 0.0, MODEL)
    second_left, second_right = pair(texture, 12.0, 2)
    second = match(second_left, second_right)
    assert len(check.check(second, second_left, PERIOD_S, MODEL)) < 0.1 * len(second)
    third_left, third_right = pair(texture, 12.0, 3)
    third = match(third_left, third_right)
    assert len(check.check(third, third_left, 2 * PERIOD_S, MODEL)) > 0.9 * len(third)


def test_a_border_without_data_does_not_make_every_window_changed(texture):
    # A rectified image's border without data is 0 in both frames: it must not set the noise
    # level (before, a border of 5 % or more made it zero and no window static).
    from st_stereo.core.skew import changed_windows
    previous, current = noisy(texture, 1), noisy(texture, 2)
    previous[:, :10] = current[:, :10] = 0.0                 # 12.5 % of the image
    x, y = np.meshgrid(np.arange(20, 70, 5), np.arange(10, 50, 5))
    assert changed_windows(previous, current, x.ravel(), y.ravel()).mean() < 0.1
    moved = noisy(fourier_shift_image_x(texture, 2.0), 3)
    moved[:, :10] = 0.0
    assert changed_windows(previous, moved, x.ravel(), y.ravel()).mean() > 0.9


def test_moving_features_are_not_checked(texture):
    # The scene moves 3 px between the pairs: the windows change, nothing is judged static.
    check = TemporalCheck(0.3)
    left, right = pair(texture, 12.0, 1)
    check.check(match(left, right), left, 0.0, MODEL)
    moved_left, moved_right = pair(texture, 12.0, 2, motion=3.0)
    moved = match(moved_left, moved_right)
    kept = check.check(moved, moved_left, PERIOD_S, MODEL)
    inner = (moved.x_left > 10) & (moved.x_left < 70)
    assert check.counts['features_static'] < 0.1 * inner.sum()
    assert len(kept) >= len(moved) - check.counts['features_static']


@pytest.mark.parametrize('change', ['gap', 'backwards', 'model', 'size'])
def test_a_pair_without_a_usable_previous_one_is_not_checked(texture, change):
    check = TemporalCheck(0.3)
    left, right = pair(texture, 12.0, 1)
    check.check(match(left, right), left, 0.0, MODEL)
    time_s = {'gap': 0.3, 'backwards': -PERIOD_S}.get(change, PERIOD_S)
    model = StereoModel(fx=80.0, fy=80.0, cx=39.5, cy=29.5, baseline=0.5) \
        if change == 'model' else MODEL
    later_left, later_right = pair(texture, 12.6, 2)
    if change == 'size':
        later_left, later_right = later_left[:50], later_right[:50]
    later = StereoMatcher(STConfig(), model=model).match(later_left, later_right)
    assert check.check(later, later_left, time_s, model) is later
    assert check.counts['pairs_without_previous'] == 2 and check.counts['pairs_checked'] == 0


def test_a_pair_in_a_flat_field_correction_and_the_next_are_not_checked(texture):
    # A frozen left frame equals the previous one: every window looks static, so a pair with
    # a camera in FFC (pair_info) and the pair after it are passed through, counted.
    check = TemporalCheck(0.3)
    left, right = pair(texture, 12.0, 1)
    check.check(match(left, right), left, 0.0, MODEL)
    frozen = match(left, fourier_shift_image_x(left, 12.6))        # the right view moved
    assert check.check(frozen, left, PERIOD_S, MODEL, ffc=True) is frozen
    after_left, after_right = pair(texture, 12.6, 2)
    after = match(after_left, after_right)
    assert check.check(after, after_left, 2 * PERIOD_S, MODEL) is after
    assert check.counts['pairs_in_ffc'] == 2 and check.counts['pairs_checked'] == 0
    again_left, again_right = pair(texture, 12.6, 3)
    again = match(again_left, again_right)
    assert len(check.check(again, again_left, 3 * PERIOD_S, MODEL)) > 0.9 * len(again)
    assert check.counts['pairs_checked'] == 1


def test_the_tolerance_is_validated():
    with pytest.raises(ValueError, match='tolerance_px: expected > 0, got 0'):
        TemporalCheck(0)
    with pytest.raises(ValueError, match='temporal_tolerance_px'):
        STConfig(temporal_tolerance_px=-1.0)
