"""
Every point a tracker receives, scored per surface (``st-stereo eval points``).

ST matches the rectified pairs of the simulated sequences and of the bundled recording
(rectified with their true calibration). The two cameras free-run: each image shows the scene
at its own camera's instant (each sequence has its own camera phase, 20-45 ms; the recording's
right camera exposes 33 ms after the left one), and the skew is corrected as the matcher node
corrects it (``st_stereo.core.skew``). Every published point is scored against the rendered
ground truth (the scene at the left camera's instant) by ``st_stereo.sim.scoring`` (3-D
distance to the true surface of its pixel and its 8 neighbours, strict per-pixel depth range,
disparity range), per surface label. The held-out
sequence (``meeting_room``, another room) was never used to choose a parameter or a mechanism;
it is reported apart.
"""

import pathlib

import numpy as np

from st_stereo.core.calibration.files import load_calibration
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import fill_invalid, StereoMatcher
from st_stereo.core.rectification import StereoRectifier
from st_stereo.core.skew import compensation_options, SkewCompensator
from st_stereo.core.temporal import TemporalCheck
from st_stereo.sim.scoring import (markdown_motion_table, markdown_surface_table, MotionTally,
                                   people_disparity_errors, PointTally, score_points)

TUNING_SEQUENCES = ('walk_across', 'two_people', 'sit_down')
HELD_OUT_SEQUENCES = ('meeting_room',)


def score_result(tally, model, truth, result):
    """Add one MatchResult's points to a tally."""
    tally.add(score_points(model, truth, result.x_point, result.y_point, result.disparity,
                           result.points))


class PairMatching:
    """
    What the rectifier and matcher nodes do to each pair, offline.

    Rectify, match, correct the camera skew (``SkewCompensator``, as the matcher node does with
    the driver's ``pair_info``).

    Pairs come in order; ``observe`` hands over the images of a pair that is not scored
    (every ``stride``-th pair is), so the next one is corrected against the pair before it.
    """

    def __init__(self, rectifier, config=None):
        self.rectifier = rectifier
        self.config = config or STConfig()
        self.matcher = StereoMatcher(self.config, model=rectifier.model)
        self.skew = SkewCompensator()
        self.temporal = TemporalCheck(self.config.temporal_tolerance_px) \
            if self.config.temporal_tolerance_px > 0 else None    # off by default

    def observe(self, left_raw, right_raw, left_time_s, skew_s):
        """Remember a pair's images (with the temporal check, its matches too): not scored."""
        if self.temporal is not None:
            self.match(left_raw, right_raw, left_time_s, skew_s)
            return
        left, right = self.rectifier.rectify(left_raw, right_raw)
        self.skew.remember(left, left_time_s, right, skew_s,
                           **self.rectifier.valid_keywords())

    def match(self, left_raw, right_raw, left_time_s, skew_s):
        """Return the pair's MatchResult, skew-corrected and checked as configured."""
        left, right = self.rectifier.rectify(left_raw, right_raw)
        valid = self.rectifier.valid_keywords()
        result = self.matcher.match(left, right, **valid)
        if self.config.skew_compensation:
            result = self.skew.correct(result, left, left_time_s, skew_s, self.rectifier.model,
                                       self.matcher.disparity_bounds(), right=right, **valid,
                                       **compensation_options(self.config))
        if self.temporal is not None:
            result = self.temporal.check(result, fill_invalid(left, valid['left_valid']),
                                         left_time_s, self.rectifier.model)
        return result


def evaluate_sequence(spec, config=None, stride=2, textures=None, max_frames=None):
    """
    Score ST's points on every ``stride``-th pair of a simulated sequence.

    Each camera is rendered at its own instant (``spec.pair_times``: the driver's pairing of the
    two free-running cameras) and the skew corrected as the matcher node does. Returns the
    PointTally, the label names and a MotionTally of the errors on people.
    """
    from st_stereo.sim.sequences import SequenceRenderer
    renderer = SequenceRenderer(spec, textures=textures)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    matching = PairMatching(rectifier, config)
    tally, motion = PointTally(), MotionTally()
    pairs = spec.pair_times()
    for index, (t_left, t_right) in enumerate(pairs):
        if index % stride:
            if (index + 1) % stride == 0:      # the next scored pair's previous pair
                matching.observe(renderer.camera_frame('left', t_left),
                                 renderer.camera_frame('right', t_right), t_left,
                                 t_right - t_left)
            continue
        if max_frames and tally.frames >= max_frames:
            break
        frame = renderer.frame(t_left, right_t=t_right)
        result = matching.match(frame['left'], frame['right'], t_left, t_right - t_left)
        score_result(tally, rectifier.model, frame['truth'], result)
        speeds = renderer.head_image_velocity(t_left, rectifier.model.fx)
        motion.add(*people_disparity_errors(rectifier.model, frame['truth'], result.x_point,
                                            result.y_point, result.disparity, speeds),
                   1e3 * (t_right - t_left))
    return tally, renderer.scene(0.0)[0].label_names, motion


def recording_pairs(recording):
    """Yield ``(stamp_ns, left, right)`` raw uint16 pairs of a recording's bag, stamp order."""
    from st_stereo.bag_streams import raw_image_messages
    from st_stereo.core.image_io import image_from_buffer
    pending = {}
    for side, stamp, msg in raw_image_messages(pathlib.Path(recording) / 'bag'):
        image = image_from_buffer(msg.data, msg.encoding, msg.width, msg.height, msg.step,
                                  msg.is_bigendian, 'mono16')
        pending.setdefault(stamp, {})[side] = image
        if len(pending[stamp]) == 2:
            pair = pending.pop(stamp)
            yield stamp, pair['left'], pair['right']


def evaluate_recording(recording, config=None, stride=1, max_frames=None):
    """
    Score ST's points on a recording with ground truth (bag, left/right.yaml, npz).

    The instants each pair's images show come from the ground truth (``left_stamp_ns``,
    ``right_stamp_ns``; a recording without them is taken as synchronized). Returns the
    PointTally, the label names and a MotionTally of the errors on people.
    """
    from st_stereo.sim.recording import frame_truth, load_ground_truth
    recording = pathlib.Path(recording)
    truth = load_ground_truth(recording)
    rectifier = StereoRectifier(load_calibration(recording / 'left.yaml'),
                                load_calibration(recording / 'right.yaml'))
    matching = PairMatching(rectifier, config)
    stamps = np.asarray(truth['stamp_ns'], dtype=np.int64)
    acquired = [np.asarray(truth.get(key, stamps), dtype=np.int64)
                for key in ('left_stamp_ns', 'right_stamp_ns')]
    tally, motion = PointTally(), MotionTally()
    for index, (stamp, left, right) in enumerate(recording_pairs(recording)):
        frame = int(np.argmin(np.abs(stamps - stamp)))
        if stamps[frame] != stamp:
            raise ValueError(f'{recording}: pair at {stamp} ns has no ground-truth frame')
        left_time = (acquired[0][frame] - stamps[0]) * 1e-9
        skew = (acquired[1][frame] - acquired[0][frame]) * 1e-9
        if index % stride:
            matching.observe(left, right, left_time, skew)
            continue
        if max_frames and tally.frames >= max_frames:
            break
        result = matching.match(left, right, left_time, skew)
        one = frame_truth(truth, frame)
        score_result(tally, rectifier.model, one, result)
        if 'heads_image_velocity' in truth:
            motion.add(*people_disparity_errors(rectifier.model, one, result.x_point,
                                                result.y_point, result.disparity,
                                                truth['heads_image_velocity'][frame]),
                       1e3 * skew)
    return tally, truth['label_names'], motion


def evaluate(config=None, stride=2, sequences=TUNING_SEQUENCES + HELD_OUT_SEQUENCES,
             recording=None, max_frames=None, log=None):
    """
    Score every named sequence and the recording.

    Returns ``(report, motion)``: ``{name: per-surface rows}`` and ``{name: MotionTally rows}``
    (disparity errors on people by pair skew and image speed).
    """
    from st_stereo.sim.sequences import load_textures, standard_sequences
    textures = load_textures()
    specs = standard_sequences()
    report, motion = {}, {}
    for name in sequences:
        tally, names, people = evaluate_sequence(specs[name], config, stride, textures,
                                                 max_frames)
        report[name], motion[name] = tally.rows(names), people.rows()
        if log:
            log(f'{name}: {tally.frames} frames scored')
    if recording is not None:
        tally, names, people = evaluate_recording(recording, config, 1, max_frames)
        report['recording'], motion['recording'] = tally.rows(names), people.rows()
        if log:
            log(f'recording: {tally.frames} frames scored')
    return report, motion


def markdown_report(report):
    """Return one per-surface table per sequence; the held-out sequence under its own title."""
    blocks = []
    for name, rows in report.items():
        title = f'held out (never tuned on): {name}' if name in HELD_OUT_SEQUENCES else name
        blocks.append(f'#### {title}\n\n{markdown_surface_table(rows)}')
    return '\n\n'.join(blocks)


def markdown_motion_report(motion):
    """Return one table per sequence: disparity error on people by pair skew and speed."""
    blocks = []
    for name, rows in motion.items():
        title = f'held out (never tuned on): {name}' if name in HELD_OUT_SEQUENCES else name
        blocks.append(f'#### {title}: people, by pair skew and image speed\n\n'
                      f'{markdown_motion_table(rows)}')
    return '\n\n'.join(blocks)


def checks(report):
    """Return the issue's criteria per sequence: (sequence, criterion, value, target, met)."""
    out = []
    for name, rows in report.items():
        by = {row['surface']: row for row in rows}
        for surface, key, target, label in (
                ('all', 'outliers_3d', 0.02, 'outliers, all points (3-D)'),
                ('people', 'outliers_3d', 0.01, 'outliers on people (3-D)'),
                ('all', 'relative_error_median', 0.01, 'median abs dZ / Z, all points')):
            value = by[surface][key]
            out.append((name, label, value, f'<= {target:.0%}', bool(value <= target)))
    return out


def error_figure(path, times=(3.0,), config=None):
    """
    Write a figure: each sequence's and the recording's points over the left image.

    Points are coloured by their 3-D error (green <= 0.1 m, yellow <= 0.3 m, red beyond).
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from st_stereo.package_data import bundled_recording
    from st_stereo.sim.recording import frame_truth, load_ground_truth
    from st_stereo.sim.sequences import load_textures, SequenceRenderer, standard_sequences
    textures = load_textures()
    specs = standard_sequences()
    panels = []
    for name in TUNING_SEQUENCES + HELD_OUT_SEQUENCES:
        # The pair nearest ``times[0]``, its cameras at their own instants, skew-corrected
        # against the left frame before it (as the matcher node does).
        spec = specs[name]
        renderer = SequenceRenderer(spec, textures=textures)
        rectifier = StereoRectifier(*spec.rig.calibrations())
        matching = PairMatching(rectifier, config)
        pairs = spec.pair_times()
        index = max(1, int(np.argmin([abs(t_left - times[0]) for t_left, _ in pairs])))
        previous_left, previous_right = pairs[index - 1]
        matching.observe(renderer.camera_frame('left', previous_left),
                         renderer.camera_frame('right', previous_right), previous_left,
                         previous_right - previous_left)
        t_left, t_right = pairs[index]
        frame = renderer.frame(t_left, right_t=t_right)
        result = matching.match(frame['left'], frame['right'], t_left, t_right - t_left)
        left = rectifier.rectify(frame['left'], frame['left'])[0]
        panels.append((name, rectifier, left, result, frame['truth']))
    recording = bundled_recording()
    truth = load_ground_truth(recording)
    rectifier = StereoRectifier(load_calibration(recording / 'left.yaml'),
                                load_calibration(recording / 'right.yaml'))
    matching = PairMatching(rectifier, config)
    stamps = np.asarray(truth['stamp_ns'], dtype=np.int64)
    for index, (stamp, left, right) in enumerate(recording_pairs(recording)):
        frame = int(np.argmin(np.abs(stamps - stamp)))
        left_time = (int(truth['left_stamp_ns'][frame]) - int(stamps[0])) * 1e-9
        skew = (int(truth['right_stamp_ns'][frame]) - int(truth['left_stamp_ns'][frame])) * 1e-9
        if index < 40:
            matching.observe(left, right, left_time, skew)
            continue
        result = matching.match(left, right, left_time, skew)
        panels.append(('recording', rectifier, rectifier.rectify(left, left)[0], result,
                       frame_truth(truth, frame)))
        break
    figure, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 2.8))
    for axis, (name, rectifier, left, result, truth) in zip(np.atleast_1d(axes), panels):
        scores = score_points(rectifier.model, truth, result.x_point, result.y_point,
                              result.disparity, result.points)
        error = scores['distance_3d']
        colours = np.where(error[:, None] <= 0.1, [[0.1, 0.8, 0.1]],
                           np.where(error[:, None] <= 0.3, [[0.95, 0.85, 0.1]],
                                    [[0.9, 0.1, 0.1]]))
        axis.imshow(left, cmap='gray')
        axis.scatter(result.x_point, result.y_point, s=4, c=colours, linewidths=0)
        axis.set_title(f'{name}: {np.mean(error > 0.3):.1%} > 0.3 m', fontsize=8)
        axis.axis('off')
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
