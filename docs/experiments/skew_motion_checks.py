"""
Which skew-corrected matches are wrong? (issue 12 on the skewed sequences; docs/skew.md).

For every 4th pair of the tuning sequences (rendered with their camera skew, as
``st-stereo eval points``), ST matches the pair, the features are tracked on the camera
whose frames bracket the other's instant and, for the moving ones, on the other camera too;
each match is scored in 3-D against the ground truth (``st_stereo.sim.scoring``) after the
correction, with nothing dropped. Prints the 3-D outlier rate by tracking state, by the two
cameras' velocity disagreement, and the cost of ``SkewCompensator.correct`` per pair without
and with the two-camera check and the POC velocities.
Run: ``.venv/bin/python docs/experiments/skew_motion_checks.py`` (about two minutes).
"""

import time

import numpy as np
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.rectification import StereoRectifier
from st_stereo.core.skew import bracketing_motion, camera_motion, CameraFrames, \
    compensation_options, skew_corrected_disparity, SkewCompensator
from st_stereo.core.triangulation import triangulate
from st_stereo.sim.scoring import score_points
from st_stereo.sim.sequences import load_textures, SequenceRenderer, standard_sequences

SEQUENCES = ('walk_across', 'two_people', 'sit_down')
STRIDE = 4
OUTLIER_M = 0.3
DISAGREEMENT_BINS = ((0, 2), (2, 4), (4, 8), (8, 16), (16, np.inf))


def rate(outlier, selected):
    """Return ``'n (p %)'`` of the selected matches that are outliers."""
    count = int(selected.sum())
    share = 100.0 * outlier[selected].mean() if count else 0.0
    return f'{count} ({share:.1f} %)'


def diagnose(name, textures):
    """Print the outlier rates of one sequence's matches by tracking state and agreement."""
    spec = standard_sequences()[name]
    renderer = SequenceRenderer(spec, textures=textures)
    rectifier = StereoRectifier(*spec.rig.calibrations())
    matcher = StereoMatcher(STConfig(), model=rectifier.model)
    previous = None
    columns = {key: [] for key in ('outlier', 'changed', 'tracked', 'moving',
                                   'disagreement', 'other_tracked')}
    for index, (t_left, t_right) in enumerate(spec.pair_times()):
        if index % STRIDE not in (0, STRIDE - 1):
            continue
        frame = renderer.frame(t_left, right_t=t_right)
        left, right = rectifier.rectify(frame['left'], frame['right'])
        if index % STRIDE:
            previous = (left, right, t_left, t_right)
            continue
        if previous is None:
            continue
        skew = t_right - t_left
        result = matcher.match(left, right, **rectifier.valid_keywords())
        left_frames = CameraFrames(previous[0], left, t_left - previous[2])
        right_frames = CameraFrames(previous[1], right, t_right - previous[3])
        motion, camera = bracketing_motion(result.x_left, result.y, result.disparity, skew,
                                           left_frames, right_frames)
        other_frames, other_camera = (left_frames, 'left') if camera == 'right' else \
            (right_frames, 'right')
        other = camera_motion(other_frames, other_camera, result.x_left, result.y,
                              result.disparity)
        disparity = skew_corrected_disparity(result.disparity, motion.velocity_x, skew)
        points = triangulate(rectifier.model, result.x_left, result.y, disparity)
        score = score_points(rectifier.model, frame['truth'], result.x_left, result.y,
                             disparity, points)
        columns['outlier'].append(score['distance_3d'] > OUTLIER_M)
        columns['changed'].append(motion.changed)
        columns['tracked'].append(motion.tracked)
        columns['moving'].append(motion.moving)
        columns['disagreement'].append(np.abs(motion.velocity_x - other.velocity_x))
        columns['other_tracked'].append(other.tracked)
        previous = None
    c = {key: np.concatenate(value) for key, value in columns.items()}
    outlier = c['outlier']
    print(f'\n#### {name} (skew {1e3 * skew:+.0f} ms)\n')
    print('| matches | count (3-D outliers) |\n|---|---:|')
    print(f'| all | {rate(outlier, np.ones_like(outlier))} |')
    print(f'| window unchanged | {rate(outlier, ~c["changed"])} |')
    print(f'| changed, tracked, static | {rate(outlier, c["tracked"] & ~c["moving"])} |')
    print(f'| changed, tracked, moving | {rate(outlier, c["moving"])} |')
    print(f'| changed, not tracked | {rate(outlier, c["changed"] & ~c["tracked"])} |')
    for low, high in DISAGREEMENT_BINS:
        selected = c['moving'] & c['other_tracked'] & (c['disagreement'] >= low) & \
            (c['disagreement'] < high)
        print(f'| moving, cameras disagree by {low}-{high} px/s | {rate(outlier, selected)} |')
    print(f'| moving, other camera could not track | '
          f'{rate(outlier, c["moving"] & ~c["other_tracked"])} |')


def correction_cost(textures, pairs=60):
    """Print the per-pair cost of SkewCompensator.correct as each option adds to it."""
    options = {'ncc, no two-camera check': STConfig(skew_velocity='ncc', skew_agreement_px=0.0),
               'ncc, skew_agreement_px 0.5': STConfig(skew_velocity='ncc'),
               'poc, skew_agreement_px 0.5 (default)': STConfig()}
    elapsed = {label: [] for label in options}
    for name in SEQUENCES:
        spec = standard_sequences()[name]
        renderer = SequenceRenderer(spec, textures=textures)
        rectifier = StereoRectifier(*spec.rig.calibrations())
        matcher = StereoMatcher(STConfig(), model=rectifier.model)
        compensators = {label: SkewCompensator() for label in options}
        for t_left, t_right in spec.pair_times()[:pairs]:
            frame = renderer.frame(t_left, right_t=t_right)
            left, right = rectifier.rectify(frame['left'], frame['right'])
            result = matcher.match(left, right, **rectifier.valid_keywords())
            for label, compensator in compensators.items():
                start = time.perf_counter()
                compensator.correct(result, left, t_left, t_right - t_left, rectifier.model,
                                    matcher.disparity_bounds(), right=right,
                                    **compensation_options(options[label]))
                elapsed[label].append(1e3 * (time.perf_counter() - start))
    print('\n| compensation | pairs | median ms | p90 ms | max ms |\n'
          '|---|---:|---:|---:|---:|')
    for label, values in elapsed.items():
        print(f'| {label} | {len(values)} | {np.median(values):.2f} | '
              f'{np.percentile(values, 90):.2f} | {max(values):.2f} |')


def main():
    """Diagnose the tuning sequences, then time the correction."""
    textures = load_textures()
    for name in SEQUENCES:
        diagnose(name, textures)
    correction_cost(textures)


if __name__ == '__main__':
    main()
