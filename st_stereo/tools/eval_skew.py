"""
Camera skew on moving people (``st-stereo eval skew``).

The simulated sequences are rendered with the right camera exposing ``skew`` after the left
one (``SequenceRenderer.frame(t, right_t=t + skew)``; the ground truth is the scene at the left
instant). ST matches each rectified pair; every match on a person (visible to the right camera)
is scored by its signed disparity error against the true disparity at its left pixel, without
and with the skew correction of ``st_stereo.core.skew`` (each feature's image velocity tracked
from the previous unique frame, one frame period earlier, of the camera whose two frames
bracket the other camera's instant: the right camera for a positive skew, the left one for a
negative skew; ``left camera only`` is the correction before 2026-12-03, the left camera's
velocity whatever the sign). The same left frames
are also matched against a synchronized right frame (skew 0): the reference the correction
must reach. Errors are split by skew and by the person's image speed (its head's horizontal
speed in the rectified image). The held-out sequence is reported apart.
"""

import time

import numpy as np

from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.rectification import StereoRectifier
from st_stereo.core.skew import bracketing_motion, CameraFrames, feature_motion, \
    skew_corrected_disparity
from st_stereo.sim.scoring import match_pixels, people_disparity_errors, PERSON_LABEL_BASE, \
    SPEED_BINS_PX_S as SPEED_BINS

SKEWS_MS = (-55.0, -25.0, 10.0, 25.0, 40.0, 55.0)
TUNING_SEQUENCES = ('walk_across', 'two_people', 'sit_down')
HELD_OUT_SEQUENCES = ('meeting_room',)


def head_velocity_of_matches(truth, result, head_velocities):
    """Signed image velocity (px/s) of the head of the person each match lies on (0 off people)."""
    u, v = match_pixels(truth, result.x_left, result.y)
    person = truth.labels[v, u] - PERSON_LABEL_BASE
    on_person = (person >= 0) & (person < len(head_velocities))
    out = np.zeros(len(u))
    out[on_person] = np.asarray(head_velocities)[person[on_person]]
    return out


def head_speeds_px(renderer, model, t):
    """Horizontal speed (px/s) of each person's head in the rectified left image at ``t``."""
    return np.abs(renderer.head_image_velocity(t, model.fx))


def evaluate_sequence(spec, skews_ms=SKEWS_MS, config=None, stride=4, max_frames=None,
                      textures=None):
    """
    Return rows ``{skew_ms, condition, error, speed}`` of one sequence.

    Conditions: ``synchronized`` (skew 0), ``skewed`` and ``compensated`` per skew.
    """
    from st_stereo.sim.sequences import SequenceRenderer
    renderer = SequenceRenderer(spec, textures=textures)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    model = rectifier.model
    matcher = StereoMatcher(config or STConfig(), model=model)
    period = 1.0 / spec.fps
    records = []
    times = spec.frame_times[1::stride][:max_frames]
    for t in times:
        speeds = head_speeds_px(renderer, model, t)
        previous_raw = renderer.camera_frame('left', t - period)
        previous = rectifier.rectify(previous_raw, previous_raw)[0]
        frame = renderer.frame(t, with_truth=True)          # both cameras at t
        for skew_ms in (0.0,) + tuple(skews_ms):
            right_raw = frame['right'] if skew_ms == 0.0 else \
                renderer.camera_frame('right', t + skew_ms * 1e-3)
            left, right = rectifier.rectify(frame['left'], right_raw)
            result = matcher.match(left, right, **rectifier.valid_keywords())
            error, speed = people_disparity_errors(model, frame['truth'], result.x_left,
                                                   result.y, result.disparity, speeds)
            if skew_ms == 0.0:
                records.append({'skew_ms': 0.0, 'condition': 'synchronized',
                                'error': error, 'speed': speed})
                continue
            previous_right_raw = renderer.camera_frame('right', t + skew_ms * 1e-3 - period)
            previous_right = rectifier.rectify(previous_right_raw, previous_right_raw)[1]
            tick = time.perf_counter()
            motion, _ = bracketing_motion(result.x_left, result.y, result.disparity,
                                          skew_ms * 1e-3, CameraFrames(previous, left, period),
                                          CameraFrames(previous_right, right, period))
            corrected = skew_corrected_disparity(result.disparity, motion.velocity_x,
                                                 skew_ms * 1e-3)
            elapsed_ms = 1e3 * (time.perf_counter() - tick)
            corrected_error, _ = people_disparity_errors(model, frame['truth'], result.x_left,
                                                         result.y, corrected, speeds)
            left_only = skew_corrected_disparity(
                result.disparity,
                feature_motion(previous, left, result.x_left, result.y, period).velocity_x,
                skew_ms * 1e-3)
            records.append({'skew_ms': skew_ms, 'condition': 'left camera only',
                            'error': people_disparity_errors(model, frame['truth'],
                                                             result.x_left, result.y,
                                                             left_only, speeds)[0],
                            'speed': speed})
            records.append({'skew_ms': skew_ms, 'condition': 'skewed',
                            'error': error, 'speed': speed})
            records.append({'skew_ms': skew_ms, 'condition': 'compensated',
                            'error': corrected_error, 'speed': speed, 'ms': elapsed_ms,
                            'matches': len(result)})
            # The reference for the velocity estimate: each person's match corrected by the
            # true image velocity of that person's head.
            head_error, _ = people_disparity_errors(
                model, frame['truth'], result.x_left, result.y,
                result.disparity + head_velocity_of_matches(
                    frame['truth'], result, renderer.head_image_velocity(t, model.fx)) *
                skew_ms * 1e-3, speeds)
            records.append({'skew_ms': skew_ms, 'condition': 'head velocity',
                            'error': head_error, 'speed': speed})
    return records


def _stats(errors):
    errors = np.concatenate(errors) if errors else np.zeros(0)
    if not len(errors):
        return 0, float('nan'), float('nan')
    return len(errors), float(np.median(errors)), float(np.percentile(np.abs(errors), 90))


def skew_table(records, min_speed=0.0):
    """Markdown table by skew: n, median, p90 |error| per condition, people >= min_speed."""
    def pick(skew, condition):
        return [r['error'][r['speed'] >= min_speed] for r in records
                if r['skew_ms'] == skew and r['condition'] == condition]
    n0, median0, p90_0 = _stats(pick(0.0, 'synchronized'))
    lines = ['| skew (ms) | matches | median error, skewed | p90 abs, skewed | median, '
             'compensated | p90 abs, compensated | median, synchronized | p90 abs, '
             'synchronized |', '|---:|---:|---:|---:|---:|---:|---:|---:|']
    for skew in sorted({r['skew_ms'] for r in records if r['skew_ms'] != 0.0}):
        n, median, p90 = _stats(pick(skew, 'skewed'))
        _, median_c, p90_c = _stats(pick(skew, 'compensated'))
        lines.append(f'| {skew:+.0f} | {n} | {median:+.3f} | {p90:.3f} | {median_c:+.3f} | '
                     f'{p90_c:.3f} | {median0:+.3f} | {p90_0:.3f} |')
    return '\n'.join(lines)


def speed_table(records):
    """
    Markdown table by the person's image speed: median error and median |error|.

    Signed medians of people walking either way partly cancel; the median of the absolute
    error does not.
    """
    lines = ['| head speed (px/s) | skew (ms) | matches | median, skewed | median, compensated '
             '| median, synchronized | median abs, skewed | median abs, compensated | median '
             'abs, left camera only | median abs, corrected by the true head velocity | '
             'median abs, synchronized |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    for low, high in SPEED_BINS:
        def pick(skew, condition):
            return [r['error'][(r['speed'] >= low) & (r['speed'] < high)] for r in records
                    if r['skew_ms'] == skew and r['condition'] == condition]

        def median_abs(errors):
            errors = np.concatenate(errors) if errors else np.zeros(0)
            return float(np.median(np.abs(errors))) if len(errors) else float('nan')
        _, median0, _ = _stats(pick(0.0, 'synchronized'))
        abs0 = median_abs(pick(0.0, 'synchronized'))
        for skew in sorted({r['skew_ms'] for r in records if r['skew_ms'] != 0.0}):
            n, median, _ = _stats(pick(skew, 'skewed'))
            _, median_c, _ = _stats(pick(skew, 'compensated'))
            lines.append(f'| {low:.0f}-{high:.0f} | {skew:+.0f} | {n} | {median:+.3f} | '
                         f'{median_c:+.3f} | {median0:+.3f} | '
                         f'{median_abs(pick(skew, "skewed")):.3f} | '
                         f'{median_abs(pick(skew, "compensated")):.3f} | '
                         f'{median_abs(pick(skew, "left camera only")):.3f} | '
                         f'{median_abs(pick(skew, "head velocity")):.3f} | {abs0:.3f} |')
    return '\n'.join(lines)


def evaluate(sequences=TUNING_SEQUENCES + HELD_OUT_SEQUENCES, skews_ms=SKEWS_MS, config=None,
             stride=4, max_frames=None, log=None):
    """Return {'tuning': records, 'held_out': records} over the named sequences."""
    from st_stereo.sim.sequences import load_textures, standard_sequences
    specs, textures = standard_sequences(), load_textures()
    report = {'tuning': [], 'held_out': []}
    for name in sequences:
        if log is not None:
            log(f'eval skew: {name}')
        group = 'held_out' if name in HELD_OUT_SEQUENCES else 'tuning'
        report[group] += evaluate_sequence(specs[name], skews_ms, config, stride, max_frames,
                                           textures)
    return report


def cost_line(records):
    """One line: the compensation's cost per pair (median and max ms, matches per pair)."""
    timed = [r for r in records if 'ms' in r]
    if not timed:
        return ''
    times = np.array([r['ms'] for r in timed])
    matches = np.array([r['matches'] for r in timed])
    return (f'Compensation cost (feature tracking + correction) per pair: median '
            f'{np.median(times):.2f} ms, max {times.max():.2f} ms, for a median of '
            f'{np.median(matches):.0f} matches ({len(timed)} pairs).')


def markdown_report(report):
    """Markdown: by skew (all people; people faster than 10 px/s) and by speed, per group."""
    out = []
    for group, title in (('tuning', 'Tuning sequences (walk_across, two_people, sit_down)'),
                         ('held_out', 'Held out (meeting_room)')):
        records = report[group]
        if not records:
            continue
        out += [f'#### {title}: people, all speeds', '', skew_table(records), '',
                f'#### {title}: people moving faster than 10 px/s', '',
                skew_table(records, 10.0), '', f'#### {title}: by image speed', '',
                speed_table(records), '', cost_line(records), '']
    return '\n'.join(out)
