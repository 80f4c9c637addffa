"""Running the driver (or the whole pipeline) against the wall-clock rig emulator."""

import collections

from st_stereo.tools.rig_bench import UNIQUE_PERIOD_S


def pairs_of(got):
    """Stamp -> {side: (digest, frame_id)} of every received image."""
    pairs = collections.defaultdict(dict)
    for side, images in got.images.items():
        for stamp, digest, frame_id in images:
            pairs[stamp].setdefault(side, []).append((digest, frame_id))
    return pairs


def check_stream(got, sent, min_pairs_per_s, window):
    """
    Assert what the issue asks of a published stream against what the cameras sent.

    Every image equals a frame its camera sent, no frame twice, one left and one right image
    per stamp, the two of a pair within one unique frame of each other, and at least
    ``min_pairs_per_s`` pairs per second over ``window`` (monotonic start, end).
    """
    by_digest = {}
    for side, frames in sent.items():
        # An FFC repeats a frame's pixels: the first frame sent with them is the original.
        by_digest[side] = {}
        for frame in frames:
            by_digest[side].setdefault(frame.digest, frame)
    for side, images in got.images.items():
        digests = [digest for _, digest, _ in images]
        unknown = [d for d in digests if d not in by_digest[side]]
        where = [digests.index(d) for d in unknown]
        assert not unknown, f'{side}: images {where} of {len(digests)} were never sent'
        assert len(set(digests)) == len(digests), f'{side}: a frame was published twice'
    pairs = pairs_of(got)
    for stamp, sides in pairs.items():
        assert set(sides) == {'left', 'right'}, f'stamp {stamp}: only {set(sides)}'
        assert len(sides['left']) == len(sides['right']) == 1, f'stamp {stamp} used twice'
        left = by_digest['left'][sides['left'][0][0]]
        right = by_digest['right'][sides['right'][0][0]]
        assert abs(left.stamp - right.stamp) <= UNIQUE_PERIOD_S, \
            f'stamp {stamp}: left frame {left.unique} at {left.stamp:.3f} s, right frame ' \
            f'{right.unique} at {right.stamp:.3f} s: more than one unique frame apart'
    start, end = window
    arrivals = [t for t, side in got.arrivals if side == 'left' and start <= t <= end]
    rate = len(arrivals) / (end - start)
    assert rate >= min_pairs_per_s, f'{rate:.2f} pairs/s between {start:.1f} and {end:.1f}'
    return rate
