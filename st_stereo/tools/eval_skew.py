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
from st_stereo.core.skew import compensation_options, feature_motion, \
    skew_corrected_disparity, SkewCompensator
from st_stereo.sim.scoring import match_pixels, people_disparity_errors, PERSON_LABEL_BASE, \
    SPEED_BINS_PX_S as SPEED_BINS

SKEWS_MS = (-55.0, -25.0, 10.0, 25.0, 40.0, 55.0)
TUNING_SEQUENCES = ('walk_across', 'two_people', 'sit_down')
HELD_OUT_SEQUENCES = ('meeting_room',)
# Made for the people stage after the compensation's mechanisms were chosen, and first scored
# here on 2026-12-06, after the POC velocity was chosen: never seen by any skew choice.
UNSEEN_SEQUENCES = ('crossing', 'open_office')
GROUP_TITLES = {'tuning': 'Tuning sequences (walk_across, two_people, sit_down)',
                'held_out': 'Held out (meeting_room)',
                'unseen': 'Unseen by every skew choice (crossing, open_office)'}


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

    Conditions: ``synchronized`` (skew 0), ``skewed`` and ``compensated`` (every match
    corrected) per skew, and ``published``: what the matcher node publishes, the pair through
    ``SkewCompensator.correct`` with the configured drops (``skew_drop_untracked``,
    ``skew_agreement_px``); its records also carry ``synchronized_same``, the synchronized
    error of the same left features (those the synchronized matching also matched), so that
    the drops' selection is compared with the same features' no-skew error.
    """
    from st_stereo.sim.sequences import SequenceRenderer
    renderer = SequenceRenderer(spec, textures=textures)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    model = rectifier.model
    config = config or STConfig()
    matcher = StereoMatcher(config, model=model)
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
                synchronized = dict(zip(_feature_keys(result, left.shape).tolist(),
                                        result.disparity.tolist()))
                continue
            previous_right_raw = renderer.camera_frame('right', t + skew_ms * 1e-3 - period)
            previous_right = rectifier.rectify(previous_right_raw, previous_right_raw)[1]
            # Every match corrected (no drops), by the configured velocity (skew_velocity).
            compensator = _primed_compensator(model, (previous, left), (previous_right, right),
                                              t, period, skew_ms)
            corrected = compensator.correct(
                result, left, t, skew_ms * 1e-3, right=right,
                **dict(compensation_options(config), drop_untracked=False, agreement_px=0.0))
            corrected_error, _ = people_disparity_errors(model, frame['truth'], result.x_left,
                                                         result.y, corrected.disparity, speeds)
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
                            'error': corrected_error, 'speed': speed})
            records.append(_published_record(
                config, model, frame['truth'], speeds, result, (previous, left),
                (previous_right, right), t, period, skew_ms, matcher.disparity_bounds(),
                synchronized))
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


def _feature_keys(result, shape):
    """One integer per match: its left pixel (features are whole pixels of the left image)."""
    return np.rint(result.y).astype(np.int64) * shape[1] + np.rint(result.x_left).astype(
        np.int64)


def _published_record(config, model, truth, speeds, result, left_frames, right_frames, t,
                      period, skew_ms, bounds, synchronized):
    """
    Score what the matcher node publishes: the pair through ``SkewCompensator.correct``.

    The compensator is given the previous pair (both cameras one period earlier) and corrects
    this one with the configured drops. Returns the ``published`` record: errors on people of
    the kept matches, and ``synchronized_same``, the synchronized disparity error of the same
    left features (nan where the synchronized matching did not match that feature).
    """
    skew_s = skew_ms * 1e-3
    compensator = _primed_compensator(model, left_frames, right_frames, t, period, skew_ms)
    tick = time.perf_counter()
    published = compensator.correct(result, left_frames[1], t, skew_s, model, bounds,
                                    right=right_frames[1], **compensation_options(config))
    elapsed_ms = 1e3 * (time.perf_counter() - tick)
    error, speed, index = people_disparity_errors(model, truth, published.x_left, published.y,
                                                  published.disparity, speeds,
                                                  with_index=True)
    keys = _feature_keys(published, left_frames[1].shape)[index]
    same = np.array([synchronized.get(key, np.nan) for key in keys.tolist()], dtype=np.float64)
    synchronized_error, _ = people_disparity_errors(
        model, truth, published.x_left[index], published.y[index],
        np.where(np.isfinite(same), same, 0.0), speeds)
    return {'skew_ms': skew_ms, 'condition': 'published', 'error': error, 'speed': speed,
            'synchronized_same': np.where(np.isfinite(same), synchronized_error, np.nan),
            'ms': elapsed_ms, 'matches': len(result),
            'dropped': {key: compensator.counts[key] for key in
                        ('rejected_skew_untracked', 'rejected_skew_poc',
                         'rejected_skew_disagreement', 'rejected_skew_range')}}


def _primed_compensator(model, left_frames, right_frames, t, period, skew_ms):
    """Return a SkewCompensator that has seen the previous pair (both cameras a period earlier)."""
    compensator = SkewCompensator()
    compensator.remember(left_frames[0], t - period, right_frames[0], skew_ms * 1e-3, model)
    return compensator


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


def evaluate(sequences=TUNING_SEQUENCES + HELD_OUT_SEQUENCES + UNSEEN_SEQUENCES,
             skews_ms=SKEWS_MS, config=None, stride=4, max_frames=None, log=None):
    """Return ``{group: records}`` over the named sequences (groups: ``GROUP_TITLES``)."""
    from st_stereo.sim.sequences import load_textures, standard_sequences
    specs, textures = standard_sequences(), load_textures()
    report = {group: [] for group in GROUP_TITLES}
    for name in sequences:
        if log is not None:
            log(f'eval skew: {name}')
        group = 'held_out' if name in HELD_OUT_SEQUENCES else \
            'unseen' if name in UNSEEN_SEQUENCES else 'tuning'
        report[group] += evaluate_sequence(specs[name], skews_ms, config, stride, max_frames,
                                           textures)
    return report


def cost_line(records):
    """One line: the compensation's cost per pair (median and max ms, matches per pair)."""
    timed = [r for r in records if r['condition'] == 'published']
    if not timed:
        return ''
    times = np.array([r['ms'] for r in timed])
    matches = np.array([r['matches'] for r in timed])
    return (f'Compensation cost (SkewCompensator.correct as the matcher node calls it: '
            f'tracking, the skew_velocity velocities, both drops, correction, triangulation) '
            f'per pair: '
            f'median {np.median(times):.2f} ms, p90 {np.percentile(times, 90):.2f} ms, max '
            f'{times.max():.2f} ms, for a median of {np.median(matches):.0f} matches '
            f'({len(timed)} pairs).')


def published_table(records):
    """
    Markdown table of what is published (the drops applied), by image speed and skew.

    The published matches' errors against the synchronized errors of the same left features
    (the features both matchings matched): the comparison the drops cannot flatter by keeping
    only easy features. ``all speeds`` closes each skew.
    """
    lines = ['| head speed (px/s) | skew (ms) | matches, compensated | published | with a '
             'synchronized match | median, published | median, synchronized (same features) '
             '| median abs, published | median abs, synchronized (same features) | median '
             'abs, synchronized (all) | p90 abs, published | p90 abs, synchronized (same '
             'features) |', '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    skews = sorted({r['skew_ms'] for r in records if r['condition'] == 'published'})
    for low, high in SPEED_BINS + ((0.0, np.inf),):
        label = 'all speeds' if (low, high) == (0.0, np.inf) else f'{low:.0f}-{high:.0f}'

        def pick(skew, condition, field='error'):
            values = [r[field][(r['speed'] >= low) & (r['speed'] < high)] for r in records
                      if r['skew_ms'] == skew and r['condition'] == condition]
            return np.concatenate(values) if values else np.zeros(0)
        synchronized_all = pick(0.0, 'synchronized')
        for skew in skews:
            published = pick(skew, 'published')
            same = pick(skew, 'published', 'synchronized_same')
            both = np.isfinite(same)
            lines.append(
                f'| {label} | {skew:+.0f} | {len(pick(skew, "compensated"))} | '
                f'{len(published)} | {int(both.sum())} | {_median(published[both]):+.3f} | '
                f'{_median(same[both]):+.3f} | {_median(np.abs(published[both])):.3f} | '
                f'{_median(np.abs(same[both])):.3f} | '
                f'{_median(np.abs(synchronized_all)):.3f} | '
                f'{_percentile(np.abs(published[both]), 90):.3f} | '
                f'{_percentile(np.abs(same[both]), 90):.3f} |')
    return '\n'.join(lines)


def _median(values):
    return float(np.median(values)) if len(values) else float('nan')


def _percentile(values, q):
    return float(np.percentile(values, q)) if len(values) else float('nan')


def drop_line(records):
    """One line: the matches the compensation dropped, per reason, over the published pairs."""
    totals = {}
    for r in records:
        for key, count in r.get('dropped', {}).items():
            totals[key] = totals.get(key, 0) + count
    if not totals:
        return ''
    compensated = sum(r['matches'] for r in records if 'matches' in r)
    return ('Dropped by the compensation (all matches, not only people): '
            + ', '.join(f'{key} {count}' for key, count in totals.items())
            + f', of {compensated} matches.')


def markdown_report(report):
    """Markdown: by skew (all people; people faster than 10 px/s) and by speed, per group."""
    out = []
    for group, title in GROUP_TITLES.items():
        records = report.get(group, [])
        if not records:
            continue
        out += [f'#### {title}: people, all speeds', '', skew_table(records), '',
                f'#### {title}: people moving faster than 10 px/s', '',
                skew_table(records, 10.0), '', f'#### {title}: by image speed', '',
                speed_table(records), '', cost_line(records), '',
                f'#### {title}: published (the drops applied), against the same features '
                'synchronized', '', published_table(records), '', drop_line(records), '']
    return '\n'.join(out)
