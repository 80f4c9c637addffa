"""
``st-stereo eval calibration``: calibrate simulated sessions whose truth is known, and check.

Each target is rendered at ``pairs`` random poses through the realistic simulated rig (barrel
distortion, the right camera rotated by (0.4, -0.3, 0.6) deg with a 0.6 % longer focal length,
Lepton blur and noise), calibrated exactly as ``st-stereo calibrate`` does, and compared with the
rig: focal lengths and principal points, baseline, rectified vertical disparity, and the
detection error of every target point against its true projection. Then ST runs on frames of a
simulated sequence rectified once with the true and once with the recovered calibration, and
each match's range is checked against the scene by ray casting (in the raw left camera frame, so
both rectifications are judged by the same truth).
"""

import dataclasses
import json
import pathlib
import time

import numpy as np

from st_stereo.core.calibration.targets import CalibrationTarget, grid_numberings
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.rectification import StereoRectifier
from st_stereo.core.triangulation import at_their_features
from st_stereo.tools.calibrate import calibrate, Collector, report
from st_stereo.tools.eval_pipeline import OUTLIER_M, RANGE_M

DEFAULT_TARGETS = (CalibrationTarget('circles', 5, 7, 0.1),
                   CalibrationTarget('chessboard', 5, 7, 0.09))
INTRINSICS_TOLERANCE = 0.01
BASELINE_TOLERANCE = 0.02
VERTICAL_DISPARITY_LIMIT_PX = 0.1
ST_TOLERANCE = 0.0025           # ST with the recovered calibration: median error + 0.25 point


@dataclasses.dataclass
class Session:
    """One calibration session: the target, what was found and the calibration."""

    target: CalibrationTarget
    collector: Collector
    result: object
    cells: dict
    detection_errors: np.ndarray     # |detected - true projection| of every found point, px
    seconds: dict


def render_and_calibrate(rig, target, pairs, seed=0, progress=None):
    """Render a session of ``pairs`` through ``rig``, detect, calibrate; return a Session."""
    from st_stereo.sim.targets import render_calibration_pairs
    started = time.perf_counter()
    images, poses = render_calibration_pairs(rig, target, pairs, seed=seed)
    rendered = time.perf_counter()
    collector = Collector(target)
    cameras = rig.cameras()
    model = target.object_points().astype(np.float64)
    errors = []
    for index, ((left, right), (origin, rotation)) in enumerate(zip(images, poses)):
        found = collector.add(f'pair {index}', left, right)
        world = origin + model @ rotation.T
        for detection, camera in zip(found, cameras):
            if detection is not None:
                # Against the numbering of the truth the detection took (a symmetric grid
                # may be numbered from any of its corners; calibration does not mind).
                errors.append(np.linalg.norm(detection.points - min(
                    grid_numberings(target, camera.project(world)),
                    key=lambda truth: np.abs(truth - detection.points).sum()), axis=1))
        if progress:
            progress()
    detected = time.perf_counter()
    result, cells = calibrate(collector)
    return Session(target=target, collector=collector, result=result, cells=cells,
                   detection_errors=np.concatenate(errors) if errors else np.zeros(0),
                   seconds={'render': rendered - started, 'detect': detected - rendered,
                            'calibrate': time.perf_counter() - detected})


def intrinsics_errors(result, rig, size):
    """Relative errors of fx, fy, cx, cy per camera against the rig (fractions)."""
    errors = {}
    for side, found, camera in zip(('left', 'right'), result.calibrations(size),
                                   rig.cameras()):
        k, true = found.camera_matrix, camera.camera_matrix
        errors[side] = {name: float(k[i, j] / true[i, j] - 1.0)
                        for name, (i, j) in (('fx', (0, 0)), ('fy', (1, 1)), ('cx', (0, 2)),
                                             ('cy', (1, 2)))}
    return errors


def range_errors(result, calibration, cameras, scene, supersample=4):
    """
    Range errors (m) of ST's matches, the true ranges, right visibility and the signed error.

    As in the 3-D table (``eval_pipeline``), a match is judged against the range of ranges the
    scene spans over its pixel: the rectified pixel of ``calibration`` is sampled
    ``supersample`` x ``supersample`` times, each sample's line of sight is turned back into
    the raw left camera (``R^T``) and the world, and cast from the true camera centre. The error
    is the distance of the estimated range ``|X|`` outside that span (0 inside it). A match
    whose true point (pixel centre) the right camera cannot see is occluded: the 3-D table
    counts those apart, and so does this.
    """
    camera, right_camera = cameras
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
    projection = np.asarray(calibration.projection)
    # Scored at the feature's pixel (MatchResult.x_left, y), the point put back on its ray at
    # its depth: points2 places it at its window's structure (point_location), where a
    # depth-edge pixel's truth holds either side's range and hides the calibration's error.
    points, _ = at_their_features(result.points, result.x_left, result.y, projection)
    u = (np.asarray(result.x_left, dtype=float)[:, None] + np.r_[0.0, du][None]).ravel()
    v = (np.asarray(result.y, dtype=float)[:, None] + np.r_[0.0, dv][None]).ravel()
    rectified = np.column_stack([(u - projection[0, 2]) / projection[0, 0],
                                 (v - projection[1, 2]) / projection[1, 1], np.ones(len(u))])
    directions = rectified @ np.asarray(calibration.rectification) @ camera.rotation
    hits = scene.cast(camera.centre, directions, with_temperature=False)
    ranges = np.linalg.norm(hits.points - camera.centre, axis=1).reshape(len(result), -1)
    estimated = np.linalg.norm(points, axis=1)
    low, high = ranges[:, 1:].min(axis=1), ranges[:, 1:].max(axis=1)
    centres = hits.points.reshape(len(result), -1, 3)[:, 0]
    seen = scene.cast(right_camera.centre, centres - right_camera.centre,
                      with_temperature=False)
    visible = np.linalg.norm(seen.points - centres, axis=1) < 0.01
    errors = np.maximum(np.maximum(low - estimated, estimated - high), 0.0)
    return errors, ranges[:, 0], visible, estimated / ranges[:, 0] - 1.0


def st_accuracy(rig, calibration_sets, sequence='walk_across', frames=6, config=None,
                progress=None):
    """
    ST on ``frames`` frames of ``sequence``, rectified with each named calibration pair.

    Returns ``{name: summary}`` with matches per frame, the median and p90 of the relative range
    error and the outlier share (error > ``OUTLIER_M``, as in the 3-D table), overall and at
    2.5-4.5 m.
    """
    from st_stereo.sim.sequences import SequenceRenderer, standard_sequences
    spec = dataclasses.replace(standard_sequences()[sequence], rig=rig)
    renderer = SequenceRenderer(spec)
    times = spec.frame_times[::max(1, len(spec.frame_times) // frames)][:frames]
    setups = {}
    for name, calibrations in calibration_sets.items():
        rectifier = StereoRectifier(*calibrations)
        setups[name] = (rectifier, StereoMatcher(config or STConfig(), model=rectifier.model),
                        calibrations[0])
    collected = {name: ([], [], [], []) for name in calibration_sets}
    cameras = rig.cameras()
    for t in times:
        frame = renderer.frame(t, with_truth=False)
        scene, _ = renderer.scene(t)
        for name, (rectifier, matcher, left_calibration) in setups.items():
            result = matcher.match(*rectifier.rectify(frame['left'], frame['right']),
                                   **rectifier.valid_keywords())
            for store, values in zip(collected[name],
                                     range_errors(result, left_calibration, cameras, scene)):
                store.append(values)
        if progress:
            progress()
    summary = {}
    for name, columns in collected.items():
        errors, ranges, visible, signed = (np.concatenate(c) for c in columns)
        occluded = int((~visible).sum())
        errors, ranges, signed = errors[visible], ranges[visible], signed[visible]
        relative = errors / ranges
        near = (ranges >= RANGE_M[0]) & (ranges <= RANGE_M[1])
        summary[name] = {
            'frames': len(times), 'matches_per_frame': (len(errors) + occluded) / len(times),
            'occluded_per_frame': occluded / len(times),
            'range_error_median': float(np.median(relative)),
            'range_error_p90': float(np.percentile(relative, 90)),
            'outlier_rate': float(np.mean(errors > OUTLIER_M)),
            'range_error_median_2_5_to_4_5_m': float(np.median(relative[near])),
            'outlier_rate_2_5_to_4_5_m': float(np.mean(errors[near] > OUTLIER_M)),
            # Signed |X| / true range - 1 at pixel centres: a scale error of the calibration
            # shows here (the errors above are distances outside the pixel's range span).
            'range_bias_median': float(np.median(signed)),
            'range_bias_median_2_5_to_4_5_m': float(np.median(signed[near])),
        }
    return summary


def evaluate(targets=DEFAULT_TARGETS, pairs=200, seed=0, st_frames=6, progress_factory=None,
             log=print):
    """Run every target's session and the ST check; return the report (JSON-ready)."""
    from st_stereo.sim.rig import realistic_rig
    rig = realistic_rig()
    size = (rig.width, rig.height)
    sessions, entries = {}, {}
    for target in targets:
        name = f'{target.kind} {target.rows}x{target.cols} {target.spacing_m * 100:g} cm'
        log(f'{name}: rendering and calibrating {pairs} pairs')
        bar = progress_factory(pairs, name) if progress_factory else None
        session = render_and_calibrate(rig, target, pairs, seed,
                                       bar.update if bar else None)
        if bar:
            bar.close()
        sessions[name] = session
        numbers = report(session.result, session.cells, session.collector)
        numbers['intrinsics_error'] = intrinsics_errors(session.result, rig, size)
        numbers['baseline_error'] = session.result.baseline_m / rig.baseline_m - 1.0
        numbers['true_baseline_m'] = rig.baseline_m
        errors = session.detection_errors
        numbers['detection_error_px'] = {'median': float(np.median(errors)),
                                         'p95': float(np.percentile(errors, 95)),
                                         'max': float(errors.max()), 'points': int(len(errors))}
        numbers['seconds'] = session.seconds
        entries[name] = numbers
    calibration_sets = {'true calibration': rig.calibrations()}
    for name, session in sessions.items():
        calibration_sets[f'recovered ({name})'] = session.result.calibrations(size)
    log(f'ST on {st_frames} frames of walk_across with each rectification')
    bar = progress_factory(st_frames, 'ST') if progress_factory else None
    st = st_accuracy(rig, calibration_sets, frames=st_frames,
                     progress=bar.update if bar else None)
    if bar:
        bar.close()
    return {'pairs': pairs, 'seed': seed, 'targets': entries, 'st': st}


def checks(report):
    """Return the issue's criteria: (target, criterion, value, limit, met)."""
    rows = []
    for name, numbers in report['targets'].items():
        worst = max(abs(v) for side in ('left', 'right')
                    for v in numbers['intrinsics_error'][side].values())
        vertical = numbers['rectified_vertical_disparity_px']['median']
        baseline = abs(numbers['baseline_error'])
        rows += [(name, 'fx, fy, cx, cy: largest error', f'{worst * 100:.2f} %', '<= 1 %',
                  worst <= INTRINSICS_TOLERANCE),
                 (name, 'baseline error', f'{baseline * 100:.2f} %', '<= 2 %',
                  baseline <= BASELINE_TOLERANCE),
                 (name, 'rectified vertical disparity, median', f'{vertical:.3f} px',
                  '<= 0.1 px', vertical <= VERTICAL_DISPARITY_LIMIT_PX)]
    true = report['st']['true calibration']
    for name, row in report['st'].items():
        if name == 'true calibration':
            continue
        for key, label in (('range_error_median_2_5_to_4_5_m', 'at 2.5-4.5 m'),
                           ('range_error_median', 'all depths')):
            rows.append((name, f'ST median range error {label}, vs the true calibration',
                         f'{row[key] * 100:.2f} % vs {true[key] * 100:.2f} %',
                         f'<= +{ST_TOLERANCE * 100:g} point',
                         row[key] <= true[key] + ST_TOLERANCE))
    return rows


def markdown(report):
    """Return the report's tables as Markdown."""
    lines = ['| target | pairs with the target in both / left only / right only | '
             'images rejected (left; right) | views dropped as outliers (left / right) | '
             'detection error median / p95 (px) | '
             'RMS left / right / stereo (px) | baseline (m, true) | '
             'vertical disparity median / p95 (px) |',
             '|---|---|---|---|---|---|---|---|']
    for name, n in report['targets'].items():
        rejected = '; '.join(
            ', '.join(f'{reason} {count}' for reason, count in n['rejected_images'][side].items()
                      if count) or 'none' for side in ('left', 'right'))
        d, r, v = n['detection_error_px'], n['rms_px'], n['rectified_vertical_disparity_px']
        lines.append(
            f'| {name} | {n["pairs"]["both"]} / {n["pairs"]["left_only"]} / '
            f'{n["pairs"]["right_only"]} of {n["pairs"]["pairs"]} | {rejected} | '
            f'{n["views_dropped_as_outliers"]["left"]} / '
            f'{n["views_dropped_as_outliers"]["right"]} | '
            f'{d["median"]:.3f} / {d["p95"]:.3f} | {r["left"]:.3f} / {r["right"]:.3f} / '
            f'{r["stereo"]:.3f} | {n["baseline_m"]:.4f} ({n["true_baseline_m"]:.4f}) | '
            f'{v["median"]:.3f} / {v["p95"]:.3f} |')
    lines += ['', '| target | camera | fx error | fy error | cx error | cy error |',
              '|---|---|---:|---:|---:|---:|']
    for name, n in report['targets'].items():
        for side in ('left', 'right'):
            e = n['intrinsics_error'][side]
            lines.append(f'| {name} | {side} | ' + ' | '.join(
                f'{e[key] * 100:+.2f} %' for key in ('fx', 'fy', 'cx', 'cy')) + ' |')
    lines += ['', '| rectification | matches / frame | occluded / frame | '
              'median range error / range | p90 | '
              f'outliers (> {OUTLIER_M:g} m) | median signed error | at 2.5-4.5 m: median | '
              'outliers | median signed error |',
              '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    for name, row in report['st'].items():
        lines.append(f'| {name} | {row["matches_per_frame"]:.1f} | '
                     f'{row["occluded_per_frame"]:.1f} | '
                     f'{row["range_error_median"] * 100:.2f} % | '
                     f'{row["range_error_p90"] * 100:.2f} % | '
                     f'{row["outlier_rate"] * 100:.1f} % | '
                     f'{row["range_bias_median"] * 100:+.2f} % | '
                     f'{row["range_error_median_2_5_to_4_5_m"] * 100:.2f} % | '
                     f'{row["outlier_rate_2_5_to_4_5_m"] * 100:.1f} % | '
                     f'{row["range_bias_median_2_5_to_4_5_m"] * 100:+.2f} % |')
    lines += ['', '| target | criterion | value | limit | met |', '|---|---|---:|---|---|']
    lines += [f'| {a} | {b} | {c} | {d} | {"yes" if e else "NO"} |'
              for a, b, c, d, e in checks(report)]
    return '\n'.join(lines)


def main(args):
    """Run ``st-stereo eval calibration``."""
    from tqdm import tqdm
    targets = DEFAULT_TARGETS
    if args.target:
        targets = (CalibrationTarget(args.target, args.rows, args.cols, args.spacing),)

    def bar(total, name):
        return tqdm(total=total, desc=name, unit='pair', disable=args.quiet, leave=False)
    numbers = evaluate(targets, args.pairs, args.seed, args.st_frames, bar,
                       log=(lambda *a: None) if args.quiet else print)
    text = markdown(numbers)
    print(text)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(numbers, indent=1))
    if args.markdown:
        pathlib.Path(args.markdown).write_text(text + '\n')
    return 0 if all(row[-1] for row in checks(numbers)) or not args.strict else 1
