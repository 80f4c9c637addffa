"""
Try to remove a negative skew's error from motion in depth (issue 14; docs/skew.md).

With the right camera exposing first (skew ``s < 0``), the compensation tracks the left camera
(its frames bracket the right one's instant) and corrects ``d + v_L s``: the disparity at the
right camera's instant, not at the left one's, off by ``d_dot s`` for a body walking towards
or away from the rig (docs/skew.md, Known limits). The rate ``d_dot = v_L - v_R`` can be
estimated from the right camera's own track of the same features, but that track's period is
``|s|`` earlier than the left one's, so an accelerating body (a turn, a swinging leg) shows a
``d_dot`` it does not have. Tried here: ``d_dot`` as the median of ``v_L - v_R`` over the
moving features of the same depth layer (disparity within 1.5 px, at least 5 of them),
clamped to what a walk of 1.5 m/s can give (``d^2 1.5 / (f B)``), against the correction of
today and against the person's true ``d_dot`` (the head's, from the renderer).

Every 4th pair of walk_across, two_people, sit_down (the skew's tuning sequences) and
far_standing, far_walker (made for the people stage; walking away from and towards the rig),
each rendered at skews of -55, -40, -25 and -10 ms; matches on people moving faster than
10 px/s, each compared with the synchronized matching of the same left feature: median of the
difference, median and p90 of its absolute value (px). Nothing is dropped.
Also: the same rate with the left camera's acceleration, measured on a third frame (the
feature tracked from ``t - 2T`` to ``t - T``), removed from ``v_L - v_R`` (the two tracks'
periods are ``|s|`` apart). ``--start 2`` scores every 4th pair from the third instead of
the second (the same sequences, other pairs; with the default, the first scored pair's third
frame lies before the sequence, where the renderer holds each person's first pose).
Run: ``.venv/bin/python docs/experiments/skew_depth_motion.py [--start 2]`` (about ten
minutes).
"""

import argparse

import numpy as np
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.rectification import StereoRectifier
from st_stereo.core.skew import camera_motion, CameraFrames, feature_motion, \
    SkewCompensator
from st_stereo.sim.scoring import match_pixels, people_disparity_errors, PERSON_LABEL_BASE
from st_stereo.sim.sequences import SequenceRenderer, standard_sequences

SEQUENCES = ('walk_across', 'two_people', 'sit_down', 'far_standing', 'far_walker')
SKEWS_MS = (-55.0, -40.0, -25.0, -10.0)
STRIDE = 4
LAYER_PX = 1.5
LAYER_MIN = 5
WALK_M_S = 1.5
MIN_SPEED_PX_S = 10.0


NAMES = ('today', 'layer d_dot', 'layer d_dot, clamped', 'clamped, acceleration removed',
         'true d_dot')


def layer_depth_rates(disparity, moving, difference):
    """Median of ``v_L - v_R`` over the moving features within ``LAYER_PX`` of each one."""
    rates = np.zeros(len(disparity))
    known = np.flatnonzero(moving & np.isfinite(difference))
    for i in np.flatnonzero(moving):
        near = known[np.abs(disparity[known] - disparity[i]) <= LAYER_PX]
        if len(near) >= LAYER_MIN:
            rates[i] = np.median(difference[near])
    return rates


def head_depth_rates(renderer, model, t, dt=0.01):
    """Return the true ``d_dot`` (px/s) of each person's head in the rectified pair."""
    def depth(instant):
        return renderer.spec.rig.to_rectified_left(renderer.scene(instant)[1])[:, 2]
    return model.fx * model.baseline * (1 / depth(t + dt) - 1 / depth(t - dt)) / (2 * dt)


def sequence_rows(name, start):
    """Yield ``(skew_ms, variant errors minus synchronized errors)`` per pair of a sequence."""
    spec = standard_sequences()[name]
    renderer = SequenceRenderer(spec)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    model = rectifier.model
    matcher = StereoMatcher(STConfig(), model=model)
    period = 1.0 / spec.fps
    for t in spec.frame_times[start::STRIDE]:
        speeds = np.abs(renderer.head_image_velocity(t, model.fx))
        true_rates = head_depth_rates(renderer, model, t)
        previous_raw = renderer.camera_frame('left', t - period)
        previous = rectifier.rectify(previous_raw, previous_raw)[0]
        earlier_raw = renderer.camera_frame('left', t - 2 * period)
        earlier = rectifier.rectify(earlier_raw, earlier_raw)[0]
        frame = renderer.frame(t, with_truth=True)
        left0, right0 = rectifier.rectify(frame['left'], frame['right'])
        synchronized = matcher.match(left0, right0, **rectifier.valid_keywords())
        sync_of = dict(zip(_keys(synchronized), synchronized.disparity.tolist()))
        for skew_ms in SKEWS_MS:
            skew = skew_ms * 1e-3
            right_raw = renderer.camera_frame('right', t + skew)
            left, right = rectifier.rectify(frame['left'], right_raw)
            result = matcher.match(left, right, **rectifier.valid_keywords())
            previous_right_raw = renderer.camera_frame('right', t + skew - period)
            previous_right = rectifier.rectify(previous_right_raw, previous_right_raw)[1]
            compensator = SkewCompensator()
            compensator.remember(previous, t - period, previous_right, skew, model)
            today = compensator.correct(result, left, t, skew, right=right,
                                        drop_untracked=False, agreement_px=0.0)
            on_left = camera_motion(CameraFrames(previous, left, period), 'left',
                                    result.x_left, result.y, result.disparity)
            on_right = camera_motion(CameraFrames(previous_right, right, period), 'right',
                                     result.x_left, result.y, result.disparity)
            moving = on_left.moving
            v_left = np.where(moving, on_left.velocity_x, 0.0)
            difference = np.where(moving & on_right.tracked, v_left - on_right.velocity_x,
                                  np.nan)
            rates = layer_depth_rates(result.disparity, moving, difference)
            bound = (result.disparity - model.disparity_offset) ** 2 * WALK_M_S / (
                model.fx * model.baseline)
            clamped = np.clip(rates, -bound, bound)
            x_before = np.clip(np.rint(result.x_left - v_left * period), 0,
                               left.shape[1] - 1).astype(np.int64)
            before = feature_motion(earlier, previous, x_before, result.y, period)
            acceleration = np.where(moving & before.tracked,
                                    (v_left - before.velocity_x) / period, 0.0)
            steady = np.clip(layer_depth_rates(result.disparity, moving,
                                               difference - acceleration * abs(skew)),
                             -bound, bound)
            u, v = match_pixels(frame['truth'], result.x_left, result.y)
            person = frame['truth'].labels[v, u] - PERSON_LABEL_BASE
            on_person = (person >= 0) & (person < len(true_rates))
            true_rate = np.where(on_person,
                                 true_rates[np.clip(person, 0, len(true_rates) - 1)], 0.0)
            same = np.array([sync_of.get(key, np.nan) for key in _keys(result)])
            variants = {
                'today': today.disparity,
                'layer d_dot': result.disparity + (v_left - np.where(moving, rates, 0)) * skew,
                'layer d_dot, clamped': result.disparity + (
                    v_left - np.where(moving, clamped, 0)) * skew,
                'clamped, acceleration removed': result.disparity + (
                    v_left - np.where(moving, steady, 0)) * skew,
                'true d_dot': result.disparity + (
                    v_left - np.where(moving, true_rate, 0)) * skew}
            _, speed, index = people_disparity_errors(model, frame['truth'], result.x_left,
                                                      result.y, result.disparity, speeds,
                                                      with_index=True)
            fast = (speed >= MIN_SPEED_PX_S) & np.isfinite(same[index])
            yield skew_ms, {key: (value - same)[index][fast] for key, value in
                            variants.items()}


def _keys(result):
    return (np.rint(result.y).astype(np.int64) * 10000 +
            np.rint(result.x_left).astype(np.int64)).tolist()


def _cell(values):
    values = np.concatenate(values)
    return (f'{np.median(values):+.3f} / {np.median(np.abs(values)):.3f} / '
            f'{np.percentile(np.abs(values), 90):.3f}')


def main():
    """Print one row per sequence and skew, and the five sequences together."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--start', type=int, default=1,
                        help='first scored pair of each sequence (every 4th from it)')
    start = max(parser.parse_args().start, 1)
    names = NAMES
    print('| sequence | skew (ms) | matches | ' + ' | '.join(names) + ' |')
    print('|---|---:|---:|' + '---|' * len(names))
    together = {skew: {name: [] for name in names} for skew in SKEWS_MS}
    for sequence in SEQUENCES:
        rows = {skew: {name: [] for name in names} for skew in SKEWS_MS}
        for skew_ms, values in sequence_rows(sequence, start):
            for name in names:
                rows[skew_ms][name].append(values[name])
                together[skew_ms][name].append(values[name])
        for skew_ms in SKEWS_MS:
            count = sum(len(x) for x in rows[skew_ms]['today'])
            print(f'| {sequence} | {skew_ms:+.0f} | {count} | ' +
                  ' | '.join(_cell(rows[skew_ms][name]) for name in names) + ' |', flush=True)
    for skew_ms in SKEWS_MS:
        count = sum(len(x) for x in together[skew_ms]['today'])
        print(f'| all five | {skew_ms:+.0f} | {count} | ' +
              ' | '.join(_cell(together[skew_ms][name]) for name in names) + ' |')


if __name__ == '__main__':
    main()
