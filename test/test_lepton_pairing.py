"""Stereo pairing of two free-running cameras."""

import dataclasses

import numpy as np
import pytest
from st_stereo.lepton.packets import UNIQUE_FRAME_PERIOD_S
from st_stereo.lepton.pairing import PairFfcFlags, PairSynchronizer


@dataclasses.dataclass
class Stamped:
    stamp: float
    name: str = ''


def feed(sync, left, right):
    events = sorted([(t, 'left') for t in left] + [(t, 'right') for t in right])
    pairs = []
    for stamp, side in events:
        pairs += sync.push(side, Stamped(stamp, side))
    return pairs


def test_nearest_one_to_one_pairs_and_counted_drops():
    sync = PairSynchronizer(max_delta=0.05)
    left = [0.000, 0.113, 0.226, 0.339, 0.452, 0.565]
    right = [0.030, 0.150, 0.400, 0.460, 0.700]   # 0.226, 0.339 have no partner in 50 ms
    pairs = feed(sync, left, right)
    sync.flush()
    expected = [(0.0, 0.03), (0.113, 0.15), (0.452, 0.46)]
    assert [(p.left.stamp, p.right.stamp) for p in pairs] == expected
    counters = sync.counters
    assert counters.pairs == 3
    assert counters.dropped_left == 3 and counters.dropped_right == 2
    assert pairs[0].stamp == pytest.approx(0.015) and pairs[0].skew == pytest.approx(0.03)


def test_the_last_pair_waits_until_no_nearer_frame_can_come():
    sync = PairSynchronizer(max_delta=0.05)
    assert feed(sync, [0.452], [0.46]) == []          # a left frame at 0.465 would be nearer
    assert len(sync.push('left', Stamped(0.565))) == 1


def test_a_closer_later_frame_wins():
    sync = PairSynchronizer(max_delta=0.05)
    pairs = feed(sync, [0.100], [0.060, 0.095, 0.300])
    assert len(pairs) == 1 and pairs[0].right.stamp == 0.095
    assert sync.counters.dropped_right == 1


def test_two_drifting_cameras_pair_within_the_window():
    rng = np.random.default_rng(3)
    period = UNIQUE_FRAME_PERIOD_S
    left = np.arange(2000) * period * (1 + 40e-6) + 0.01
    right = np.arange(2000) * period * (1 - 25e-6) + 0.07
    keep_left = rng.random(2000) > 0.02       # a few frames lost on each side
    keep_right = rng.random(2000) > 0.02
    sync = PairSynchronizer(max_delta=0.05)
    pairs = feed(sync, list(left[keep_left]), list(right[keep_right]))
    pairs += sync.flush()           # the last pair waited for a nearer frame: none will come
    # Frame i of one camera belongs with frame i of the other (the skew drifts from 60 ms to
    # 45 ms, the other frames are 114 ms away): exactly those within max_delta, both kept,
    # make the pairs, each once; none is lost and none is paired with a neighbour's frame.
    skew = right - left
    expected = {(left[i], right[i]) for i in range(2000)
                if keep_left[i] and keep_right[i] and abs(skew[i]) <= 0.05}
    got = [(p.left.stamp, p.right.stamp) for p in pairs]
    assert len(got) == len(set(got)) and set(got) == expected
    assert 200 < len(expected) < 1900
    counters = sync.counters
    assert counters.pairs + counters.dropped_left == keep_left.sum()
    assert counters.pairs + counters.dropped_right == keep_right.sum()


def test_bad_input():
    with pytest.raises(ValueError, match='max_delta'):
        PairSynchronizer(max_delta=0)
    with pytest.raises(ValueError, match='max_queue'):
        PairSynchronizer(max_queue=1)
    sync = PairSynchronizer()
    with pytest.raises(ValueError, match='side'):
        sync.push('middle', Stamped(2.0))


def test_a_backward_stamp_is_dropped_and_counted_and_pairing_goes_on():
    sync = PairSynchronizer(max_delta=0.05, min_period=0.1)
    sync.push('left', Stamped(1.0))
    assert sync.push('left', Stamped(0.5)) == []
    assert sync.counters.backward_left == 1 and sync.counters.dropped_left == 1
    pairs = sync.push('right', Stamped(1.01))
    assert [(p.left.stamp, p.right.stamp) for p in pairs] == [(1.0, 1.01)]


def test_a_silent_camera_never_grows_the_other_queue():
    sync = PairSynchronizer(max_delta=0.05, min_period=0.1, max_queue=4)
    for i in range(1000):
        sync.push('left', Stamped(0.1136 * i))
    assert len(sync.queues['left']) == 4
    assert sync.counters.overflow_left == 996 and sync.counters.dropped_left == 996
    # The right camera comes back: pairs resume with the newest left frames.
    pairs = sync.push('right', Stamped(0.1136 * 999 + 0.01))
    assert len(pairs) == 1 and pairs[0].left.stamp == 0.1136 * 999


def test_min_period_decides_pairs_without_waiting():
    sync = PairSynchronizer(max_delta=0.05, min_period=0.1)
    assert len(feed(sync, [0.452], [0.46])) == 1      # no frame can come within 0.1 s
    assert sync.counters.pairs == 1


@dataclasses.dataclass
class Frame:
    stamp: float
    ffc_in_progress: bool = False


def test_ffc_frames_without_a_partner_flag_that_camera_in_the_next_pair():
    # Right frames 0.15 and 0.26 announce an FFC; the left camera lost those instants (a
    # resync), so neither is paired: the right camera's next pair says it was in FFC, the
    # left camera's does not, and the pair after that is clean again.
    sync, flags = PairSynchronizer(max_delta=0.05, min_period=0.1), PairFfcFlags()
    left = [Frame(0.00), Frame(0.45), Frame(0.56), Frame(0.68)]
    right = [Frame(0.01), Frame(0.15, True), Frame(0.26, True), Frame(0.46), Frame(0.57),
             Frame(0.69)]
    events = sorted([(f.stamp, 'left', f) for f in left] + [(f.stamp, 'right', f)
                                                            for f in right])
    got = []
    for _, side, frame in events:
        flags.seen(side, frame)
        got += [(pair.right.stamp, flags.of_pair(pair)) for pair in sync.push(side, frame)]
    assert got == [(0.01, (False, False)), (0.46, (False, True)), (0.57, (False, False)),
                   (0.69, (False, False))]
    assert sync.counters.dropped_right == 2


def test_a_paired_ffc_frame_is_flagged_and_flags_nothing_after_it():
    sync, flags = PairSynchronizer(max_delta=0.05, min_period=0.1), PairFfcFlags()
    events = [('left', Frame(0.00, True)), ('right', Frame(0.01)), ('left', Frame(0.11)),
              ('right', Frame(0.12)), ('left', Frame(0.22)), ('right', Frame(0.23))]
    got = []
    for side, frame in events:
        flags.seen(side, frame)
        got += [flags.of_pair(pair) for pair in sync.push(side, frame)]
    assert got == [(True, False), (False, False), (False, False)]
