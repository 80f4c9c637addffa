"""
Every point a tracker receives, scored per surface (``st-stereo eval points``).

ST matches the rectified pairs of the simulated sequences and of the bundled recording
(rectified with their true calibration); every published point is scored against the rendered
ground truth by ``st_stereo.sim.scoring`` (3-D distance to the true surface of its pixel and its
8 neighbours, strict per-pixel depth range, disparity range), per surface label. The held-out
sequence (``meeting_room``, another room) was never used to choose a parameter or a mechanism;
it is reported apart.
"""

import pathlib

import numpy as np

from st_stereo.core.camera_calibration import load_calibration
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.rectification import StereoRectifier
from st_stereo.sim.scoring import markdown_surface_table, PointTally, score_points

TUNING_SEQUENCES = ('walk_across', 'two_people', 'sit_down')
HELD_OUT_SEQUENCES = ('meeting_room',)


def score_result(tally, model, truth, result):
    """Add one MatchResult's points to a tally."""
    tally.add(score_points(model, truth, result.x_left, result.y, result.disparity,
                           result.points))


def evaluate_sequence(spec, config=None, stride=2, textures=None, max_frames=None):
    """Score ST's points on every ``stride``-th frame of a simulated sequence."""
    from st_stereo.sim.sequences import SequenceRenderer
    renderer = SequenceRenderer(spec, textures=textures)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    matcher = StereoMatcher(config or STConfig(), model=rectifier.model)
    tally = PointTally()
    times = spec.frame_times[::stride][:max_frames]
    for t in times:
        frame = renderer.frame(t)
        left, right = rectifier.rectify(frame['left'], frame['right'])
        score_result(tally, rectifier.model, frame['truth'],
                     matcher.match(left, right, **rectifier.valid_keywords()))
    return tally, renderer.scene(0.0)[0].label_names


def recording_pairs(recording):
    """Yield ``(stamp_ns, left, right)`` raw uint16 pairs of a recording's bag, stamp order."""
    from st_stereo.tools.bag_images import raw_image_messages
    pending = {}
    for side, stamp, msg in raw_image_messages(pathlib.Path(recording) / 'bag'):
        image = np.frombuffer(bytes(msg.data), dtype='<u2').reshape(msg.height, msg.width)
        pending.setdefault(stamp, {})[side] = image
        if len(pending[stamp]) == 2:
            pair = pending.pop(stamp)
            yield stamp, pair['left'], pair['right']


def evaluate_recording(recording, config=None, stride=1, max_frames=None):
    """Score ST's points on a recording with ground truth (bag, left/right.yaml, npz)."""
    from st_stereo.sim.recording import frame_truth, load_ground_truth
    recording = pathlib.Path(recording)
    truth = load_ground_truth(recording)
    rectifier = StereoRectifier(load_calibration(recording / 'left.yaml'),
                                load_calibration(recording / 'right.yaml'))
    matcher = StereoMatcher(config or STConfig(), model=rectifier.model)
    stamps = np.asarray(truth['stamp_ns'], dtype=np.int64)
    tally = PointTally()
    for index, (stamp, left, right) in enumerate(recording_pairs(recording)):
        if index % stride or (max_frames and tally.frames >= max_frames):
            continue
        frame = int(np.argmin(np.abs(stamps - stamp)))
        if stamps[frame] != stamp:
            raise ValueError(f'{recording}: pair at {stamp} ns has no ground-truth frame')
        left, right = rectifier.rectify(left, right)
        score_result(tally, rectifier.model, frame_truth(truth, frame),
                     matcher.match(left, right, **rectifier.valid_keywords()))
    return tally, truth['label_names']


def evaluate(config=None, stride=2, sequences=TUNING_SEQUENCES + HELD_OUT_SEQUENCES,
             recording=None, max_frames=None, log=None):
    """Score every named sequence and the recording; returns ``{name: rows}``."""
    from st_stereo.sim.sequences import load_textures, standard_sequences
    textures = load_textures()
    specs = standard_sequences()
    report = {}
    for name in sequences:
        tally, names = evaluate_sequence(specs[name], config, stride, textures, max_frames)
        report[name] = tally.rows(names)
        if log:
            log(f'{name}: {tally.frames} frames scored')
    if recording is not None:
        tally, names = evaluate_recording(recording, config, 1, max_frames)
        report['recording'] = tally.rows(names)
        if log:
            log(f'recording: {tally.frames} frames scored')
    return report


def markdown_report(report):
    """Return one per-surface table per sequence; the held-out sequence under its own title."""
    blocks = []
    for name, rows in report.items():
        title = f'held out (never tuned on): {name}' if name in HELD_OUT_SEQUENCES else name
        blocks.append(f'#### {title}\n\n{markdown_surface_table(rows)}')
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

    from st_stereo.tools.data import bundled_recording
    from st_stereo.sim.recording import frame_truth, load_ground_truth
    from st_stereo.sim.sequences import load_textures, SequenceRenderer, standard_sequences
    textures = load_textures()
    specs = standard_sequences()
    panels = []
    for name in TUNING_SEQUENCES + HELD_OUT_SEQUENCES:
        renderer = SequenceRenderer(specs[name], textures=textures)
        rectifier = StereoRectifier(*specs[name].rig.calibrations())
        frame = renderer.frame(times[0])
        left, right = rectifier.rectify(frame['left'], frame['right'])
        panels.append((name, rectifier, left, right, frame['truth']))
    recording = bundled_recording()
    truth = load_ground_truth(recording)
    rectifier = StereoRectifier(load_calibration(recording / 'left.yaml'),
                                load_calibration(recording / 'right.yaml'))
    for index, (stamp, left, right) in enumerate(recording_pairs(recording)):
        if index == 40:
            frame = int(np.argmin(np.abs(np.asarray(truth['stamp_ns']) - stamp)))
            panels.append(('recording', rectifier, *rectifier.rectify(left, right),
                           frame_truth(truth, frame)))
            break
    figure, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 2.8))
    for axis, (name, rectifier, left, right, truth) in zip(np.atleast_1d(axes), panels):
        result = StereoMatcher(config or STConfig(), model=rectifier.model).match(
            left, right, **rectifier.valid_keywords())
        scores = score_points(rectifier.model, truth, result.x_left, result.y,
                              result.disparity, result.points)
        error = scores['distance_3d']
        colours = np.where(error[:, None] <= 0.1, [[0.1, 0.8, 0.1]],
                           np.where(error[:, None] <= 0.3, [[0.95, 0.85, 0.1]],
                                    [[0.9, 0.1, 0.1]]))
        axis.imshow(left, cmap='gray')
        axis.scatter(result.x_left, result.y, s=4, c=colours, linewidths=0)
        axis.set_title(f'{name}: {np.mean(error > 0.3):.1%} > 0.3 m', fontsize=8)
        axis.axis('off')
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
