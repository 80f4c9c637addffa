"""
People on the floor against the simulator's truth (``st-stereo eval people``).

Every pair of a simulated sequence (each camera at its own instant, as the two free-running
cameras see it) goes through what the nodes do: rectification, ST with the skew correction,
then ``st_stereo.core.people`` (warm foreground, detection, tracking) with the rig's true pose.
The truth is each person's head centre (``heads_world``); a person counts in a pair when at
least ``VISIBLE_PX`` pixels of the left image show them (a person walking out of the image,
or standing far off with the head above the image's top edge, is still counted while that much
of the body is seen). Scores:

- per pair, estimates and truths paired by ``scipy.optimize.linear_sum_assignment`` on the
  horizontal distance, a pair within 0.5 m a hit: recall (hits / truths) and precision
  (hits / estimates);
- a person hidden in a pair (fewer than ``VISIBLE_PX`` pixels) with the head inside the
  view's columns (behind another person, not gone out at a side) is not a truth to find, and
  a track kept on them through a short occlusion is not a false person: a track left over
  after the pair's hits that lies within 0.5 m of such a person and was that person's hit
  at most ``SHORT_OCCLUSION_PAIRS`` pairs ago is left out of precision and CLEAR MOT (like a
  detection on KITTI's "DontCare" regions; MOTChallenge instead keeps occluded people as
  truths to find) and counted apart (``on_hidden``; the precision counting them as false is
  ``precision_strict``);
- horizontal error of the hits (median, p95) and head height error (|estimate - truth|, on
  the hits whose head centre is inside the image);
- CLEAR MOT with ``motmetrics`` (MOTA, MOTP, id switches, fragmentations), the same 0.5 m;
- the paper's measure: the spread (standard deviation) of camera depth over the points of a
  standing person's detection.

The held-out sequences (``meeting_room``, ``crossing``, ``open_office``) were never used to
choose a parameter. ``open_office`` was made after the legs of docs/people.md were chosen, to
test them; its first run showed the failure the column-gap guard then answered, so it is held
out for everything but that guard. The bundled recording was traced while the legs' guards
were chosen.
"""

import dataclasses

import numpy as np
from scipy.optimize import linear_sum_assignment

from st_stereo.core.people import PeopleConfig, PeopleEstimator, world_from_rectified
from st_stereo.core.triangulation import at_their_features

HIT_M = 0.5
VISIBLE_PX = 40     # a person with fewer labelled pixels in the left image is out of view
SHORT_OCCLUSION_PAIRS = 17      # about 2 s at 8.7 pairs/s
# meeting_room was held out until 2026-12-07, when it was traced (docs/people.md); from then
# on it is a tuning sequence, and stand_up_meeting, made before that tracing, is held out.
TUNING_SEQUENCES = ('walk_across', 'two_people', 'sit_down', 'far_standing', 'far_walker',
                    'meeting_room')
HELD_OUT_SEQUENCES = ('crossing', 'open_office', 'stand_up_meeting')
# What a held-out sequence was seen for (it is held out for everything else).
HELD_OUT_EXCEPT = {'open_office': 'held out but for the column-gap guard, the warm-object rule '
                                  "and the assignment's cost"}


def head_pixels(heads_rectified, model):
    """Image columns and rows ``u, v`` of head centres (rectified left frame); NaN behind."""
    heads = np.asarray(heads_rectified, dtype=np.float64).reshape(-1, 3)
    z = np.where(heads[:, 2] > 0, heads[:, 2], np.nan)
    return model.fx * heads[:, 0] / z + model.cx, model.fy * heads[:, 1] / z + model.cy


def heads_in_image(heads_rectified, model, shape, margin_px=0.0):
    """Whether each head centre (rectified left frame) projects inside the left image."""
    u, v = head_pixels(heads_rectified, model)
    inside = (u >= -0.5 + margin_px) & (u <= shape[1] - 0.5 - margin_px) & \
        (v >= -0.5 + margin_px) & (v <= shape[0] - 0.5 - margin_px)
    return np.nan_to_num(inside, nan=False).astype(bool)


def pair_estimates(truth_xy, estimate_xy, threshold=HIT_M):
    """Hits of one pair: ``[(truth index, estimate index, distance)]`` within ``threshold``."""
    if not len(truth_xy) or not len(estimate_xy):
        return []
    distance = np.linalg.norm(np.asarray(truth_xy)[:, None, :2] -
                              np.asarray(estimate_xy)[None, :, :2], axis=2)
    rows, cols = linear_sum_assignment(np.where(distance <= threshold, distance, 1e6))
    return [(int(r), int(c), float(distance[r, c])) for r, c in zip(rows, cols)
            if distance[r, c] <= threshold]


@dataclasses.dataclass
class PeopleTally:
    """Per-pair hits, misses, false detections and errors of one sequence."""

    truths: int = 0
    estimates: int = 0
    hits: int = 0
    on_hidden: int = 0          # estimates on a hidden person: not scored
    pairs: int = 0
    horizontal: list = dataclasses.field(default_factory=list)
    height: list = dataclasses.field(default_factory=list)
    depth_spread: list = dataclasses.field(default_factory=list)
    frames: list = dataclasses.field(default_factory=list)   # (truth ids, xy, track ids, xy)
    milliseconds: list = dataclasses.field(default_factory=list)   # people stage per pair
    last_hit: dict = dataclasses.field(default_factory=dict)   # track id -> (truth id, pair)
    strict_frames: list = dataclasses.field(default_factory=list)  # frames, nothing excused
    tracker_counts: dict = dataclasses.field(default_factory=dict)  # PeopleTracker.counts

    def add(self, truth_ids, truth_heads, tracks, head_seen=None, hidden_ids=(),
            hidden_heads=()):
        """
        Score one pair: visible truths (ids, head centres in the world) and the tracks.

        ``head_seen``: per truth, whether its head centre is in the image (height scored).
        ``hidden_ids, hidden_heads``: the people hidden in this pair inside the view's columns
        (``hidden_in_view``). A track left over after the hits that lies within ``HIT_M`` of
        one of them and was that person's hit at most ``SHORT_OCCLUSION_PAIRS`` pairs ago (a
        track kept through a short occlusion) is not scored (``on_hidden``).
        """
        estimate = np.array([[*t.position, t.head_height] for t in tracks]) \
            .reshape(-1, 3)
        truth = np.asarray(truth_heads, dtype=np.float64).reshape(-1, 3)
        hits = pair_estimates(truth[:, :2], estimate[:, :2])
        hidden = np.asarray(hidden_heads, dtype=np.float64).reshape(-1, 3)
        left_over = np.setdiff1d(np.arange(len(estimate)), [c for _, c, _ in hits])
        near_hidden = pair_estimates(hidden[:, :2], estimate[left_over, :2])
        excused = [left_over[c] for r, c, _ in near_hidden
                   if self._kept_through_occlusion(tracks[left_over[c]].track_id,
                                                   hidden_ids[r])]
        self.strict_frames.append((list(truth_ids), truth[:, :2].copy(),
                                   [t.track_id for t in tracks], estimate[:, :2].copy()))
        if excused:
            kept = np.setdiff1d(np.arange(len(estimate)), excused)
            estimate, tracks = estimate[kept], [tracks[i] for i in kept]
            hits = pair_estimates(truth[:, :2], estimate[:, :2])
            self.on_hidden += len(excused)
        for r, c, _ in hits:
            self.last_hit[tracks[c].track_id] = (truth_ids[r], self.pairs)
        self.pairs += 1
        self.truths += len(truth)
        self.estimates += len(estimate)
        self.hits += len(hits)
        for r, c, distance in hits:
            self.horizontal.append(distance)
            if head_seen is None or head_seen[r]:
                self.height.append(abs(estimate[c, 2] - truth[r, 2]))
                if np.isfinite(tracks[c].depth_spread_m):
                    self.depth_spread.append(tracks[c].depth_spread_m)
        self.frames.append((list(truth_ids), truth[:, :2].copy(), [t.track_id for t in tracks],
                            estimate[:, :2].copy()))

    def add_labelled(self, labels, heads_world, heads_rectified, model, shape, tracks):
        """
        Score one pair from the truth's labels and head centres (world and rectified frames).

        Visible people (``visible_people``) are the truths, their heights scored where the
        head is in the image (``shape``, the rectified left image's); the people hidden in
        view (``hidden_in_view``) go to ``add``.
        """
        heads_world = np.asarray(heads_world, dtype=np.float64).reshape(-1, 3)
        visible = visible_people(labels, len(heads_world))
        head_seen = heads_in_image(heads_rectified, model, shape)
        hidden = hidden_in_view(visible, heads_rectified, model, shape[1])
        self.add(np.flatnonzero(visible), heads_world[visible], tracks, head_seen[visible],
                 np.flatnonzero(hidden), heads_world[hidden])

    def _kept_through_occlusion(self, track_id, truth_id):
        """Whether ``track_id`` was ``truth_id``'s hit at most SHORT_OCCLUSION_PAIRS ago."""
        person, pair = self.last_hit.get(track_id, (None, -1))
        return person == truth_id and self.pairs - pair <= SHORT_OCCLUSION_PAIRS

    def mot(self, frames=None):
        """CLEAR MOT metrics (motmetrics) over the sequence: mota, motp, switches, fragments."""
        import motmetrics
        accumulator = motmetrics.MOTAccumulator(auto_id=True)
        for truth_ids, truth_xy, track_ids, track_xy in (self.frames if frames is None
                                                         else frames):
            distance = motmetrics.distances.norm2squared_matrix(
                truth_xy, track_xy, max_d2=HIT_M ** 2) if len(truth_xy) and len(track_xy) \
                else np.zeros((len(truth_xy), len(track_xy)))
            accumulator.update(truth_ids, track_ids, np.sqrt(distance))
        summary = motmetrics.metrics.create().compute(
            accumulator, metrics=['mota', 'motp', 'num_switches', 'num_fragmentations'],
            name='sequence')
        row = summary.iloc[0]
        return {'mota': float(row['mota']), 'motp_m': float(row['motp']),
                'id_switches': int(row['num_switches']),
                'fragmentations': int(row['num_fragmentations'])}

    def row(self):
        """Return the sequence's scores as one dict."""
        def stat(values, q):
            return float(np.percentile(values, q)) if values else float('nan')
        strict = self.estimates + self.on_hidden
        out = {'pairs': self.pairs, 'truths': self.truths, 'estimates': self.estimates,
               'on_hidden': self.on_hidden,
               'recall': self.hits / self.truths if self.truths else float('nan'),
               'precision': self.hits / self.estimates if self.estimates else float('nan'),
               'precision_strict': self.hits / strict if strict else float('nan'),
               'horizontal_median_m': stat(self.horizontal, 50),
               'horizontal_p95_m': stat(self.horizontal, 95),
               'height_median_m': stat(self.height, 50), 'height_p95_m': stat(self.height, 95),
               'depth_spread_median_m': stat(self.depth_spread, 50),
               'people_ms_median': stat(self.milliseconds, 50),
               'people_ms_p95': stat(self.milliseconds, 95),
               'tracks_started': self.tracker_counts.get('started', 0),
               'legs_lapsed': self.tracker_counts.get('legs_lapsed', 0),
               'object_detections': self.tracker_counts.get('object_detections', 0),
               'held_beside': self.tracker_counts.get('held_beside', 0)}
        out.update(self.mot())
        out['mota_strict'] = self.mot(self.strict_frames)['mota'] if self.on_hidden \
            else out['mota']
        return out


def held_out_title(name):
    """Return the sequence's name as the tables show it: what it is held out from."""
    if name not in HELD_OUT_SEQUENCES:
        return name
    return f'{name} ({HELD_OUT_EXCEPT.get(name, "held out")})'


def hidden_in_view(visible, heads_rectified, model, width):
    """
    Whether each person is hidden (not ``visible``) with the head inside the view's columns.

    A person behind another, or whose few pixels do not count, is hidden in view; one who has
    left the view at a side (or is not in the room yet) is not.
    """
    u, _ = head_pixels(heads_rectified, model)
    return ~np.asarray(visible, dtype=bool) & np.nan_to_num(
        (u >= -0.5) & (u <= width - 0.5), nan=False).astype(bool)


def visible_people(labels, count):
    """Whether each of ``count`` people shows at least ``VISIBLE_PX`` pixels in ``labels``."""
    from st_stereo.sim.sequences import PERSON_LABEL_BASE
    return np.array([np.count_nonzero(labels == PERSON_LABEL_BASE + i) >= VISIBLE_PX
                     for i in range(count)], dtype=bool)


class PeopleScoring:
    """One rig's pairs through rectification, ST and the people stage, scored (a PeopleTally)."""

    def __init__(self, rectifier, left_calibration, pose, config=None, people_config=None):
        from st_stereo.tools.eval_points import PairMatching
        self.rectifier = rectifier
        self.matching = PairMatching(rectifier, config)
        self.estimator = PeopleEstimator(
            world_from_rectified(pose, left_calibration.rectification),
            people_config or PeopleConfig())
        self.tally = PeopleTally()

    def pair(self, left_raw, right_raw, t_left, t_right, labels, heads_world, heads_rectified):
        """Match one pair, run the people stage and score it against the truth."""
        import time
        result = self.matching.match(left_raw, right_raw, t_left, t_right - t_left)
        left, right = self.rectifier.rectify(left_raw, right_raw)
        start = time.perf_counter()
        model = self.rectifier.model
        # At their features' pixels, whatever point_location placed them at for points2, as
        # the node places them (at_their_features: the fields u, v).
        projection = np.array([[model.fx, 0.0, model.cx, 0.0], [0.0, model.fy, model.cy, 0.0],
                               [0.0, 0.0, 1.0, 0.0]])
        points, _ = at_their_features(result.points, result.x_left, result.y, projection)
        people = self.estimator.process(t_left, points, result.x_left, result.y,
                                        result.disparity, result.confidence, left,
                                        intrinsics=(model.fx, model.fy, model.cx, model.cy),
                                        right_image=right,
                                        stereo=(model.fx * model.baseline,
                                                model.disparity_offset),
                                        skew_s=t_right - t_left)
        self.tally.milliseconds.append(1e3 * (time.perf_counter() - start))
        self.tally.add_labelled(labels, heads_world, heads_rectified, model, left.shape,
                                people.tracks)
        self.tally.tracker_counts = dict(self.estimator.tracker.counts)
        return people


def evaluate_sequence(spec, config=None, people_config=None, textures=None, max_pairs=None,
                      rig_pose=None):
    """
    Run one simulated sequence through ST and the people stage; return the PeopleTally.

    ``rig_pose``: the RigPose the people stage uses (default: the rig's true one).
    """
    from st_stereo.core.rectification import StereoRectifier
    from st_stereo.sim.sequences import SequenceRenderer
    renderer = SequenceRenderer(spec, textures=textures)
    calibrations = spec.rig.calibrations()
    scoring = PeopleScoring(StereoRectifier(*calibrations), calibrations[0],
                            rig_pose or spec.rig.rig_pose(), config, people_config)
    for index, (t_left, t_right) in enumerate(spec.pair_times()):
        if max_pairs and index >= max_pairs:
            break
        frame = renderer.frame(t_left, right_t=t_right)
        scoring.pair(frame['left'], frame['right'], t_left, t_right, frame['truth'].labels,
                     frame['heads_world'], frame['heads_rectified'])
    return scoring.tally


def evaluate_recording(recording, config=None, people_config=None, max_pairs=None,
                       rig_pose=None):
    """
    Run a recording with ground truth (bag, left/right.yaml, rig_pose.yaml, npz) through.

    The rig pose is the recording's ``rig_pose.yaml`` (the simulator's truth for the bundled
    one); the instants each image shows come from the ground truth.
    """
    import pathlib

    from st_stereo.core.calibration.files import load_calibration
    from st_stereo.core.rectification import StereoRectifier
    from st_stereo.core.rig_pose import load_rig_pose
    from st_stereo.sim.recording import load_ground_truth
    from st_stereo.tools.eval_points import recording_pairs
    recording = pathlib.Path(recording)
    truth = load_ground_truth(recording)
    left, right = (load_calibration(recording / f'{side}.yaml') for side in ('left', 'right'))
    scoring = PeopleScoring(StereoRectifier(left, right), left,
                            rig_pose or load_rig_pose(recording / 'rig_pose.yaml'), config,
                            people_config)
    stamps = np.asarray(truth['stamp_ns'], dtype=np.int64)
    for index, (stamp, left_raw, right_raw) in enumerate(recording_pairs(recording)):
        if max_pairs and index >= max_pairs:
            break
        frame = int(np.argmin(np.abs(stamps - stamp)))
        if stamps[frame] != stamp:
            raise ValueError(f'{recording}: pair at {stamp} ns has no ground-truth frame')
        t_left, t_right = ((int(truth[key][frame]) - int(stamps[0])) * 1e-9
                           for key in ('left_stamp_ns', 'right_stamp_ns'))
        scoring.pair(left_raw, right_raw, t_left, t_right, truth['labels'][frame],
                     truth['heads_world'][frame], truth['heads_rectified'][frame])
    return scoring.tally


def evaluate(sequences=TUNING_SEQUENCES + HELD_OUT_SEQUENCES, config=None, people_config=None,
             recording=None, max_pairs=None, log=None, rig_pose=None):
    """
    Score each named sequence (and the recording if given): ``({name: row}, tallies)``.

    ``rig_pose``: one RigPose for all of them instead of each one's truth (e.g. what
    ``st-stereo rig-pose`` fitted for the simulated rig; every sequence and the bundled
    recording use the same mount).
    """
    from st_stereo.sim.sequences import load_textures, standard_sequences
    textures, specs = load_textures(), standard_sequences()
    tallies = {}
    for name in sequences:
        tallies[name] = evaluate_sequence(specs[name], config, people_config, textures,
                                          max_pairs, rig_pose)
        if log:
            log(f'{name}: {tallies[name].pairs} pairs')
    if recording is not None:
        tallies['recording'] = evaluate_recording(recording, config, people_config, max_pairs,
                                                  rig_pose)
        if log:
            log(f'recording: {tallies["recording"].pairs} pairs')
    return {name: tally.row() for name, tally in tallies.items()}, tallies


def plot_floor_plans(tallies, path):
    """Write the floor plan of each sequence: true head tracks (lines), estimates (dots)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(1, len(tallies), figsize=(3.4 * len(tallies), 3.6),
                                squeeze=False)
    for axis, (name, tally) in zip(axes[0], tallies.items()):
        truths, estimates = {}, {}
        for truth_ids, truth_xy, track_ids, track_xy in tally.frames:
            for key, xy in zip(truth_ids, truth_xy):
                truths.setdefault(key, []).append(xy)
            for key, xy in zip(track_ids, track_xy):
                estimates.setdefault(key, []).append(xy)
        for key, xy in truths.items():
            xy = np.array(xy)
            axis.plot(xy[:, 0], xy[:, 1], '-', color='0.3', linewidth=3, alpha=0.4)
        for key, xy in estimates.items():
            xy = np.array(xy)
            axis.plot(xy[:, 0], xy[:, 1], '.', markersize=3, label=f'id {key}')
        axis.set_title(held_out_title(name), fontsize=9)
        axis.set_xlabel('x (m)')
        axis.set_ylabel('y (m), away from the rig')
        axis.set_aspect('equal')
        axis.grid(alpha=0.3)
        axis.legend(fontsize=6, loc='best')
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def checks(report):
    """Return the criteria per sequence: ``(sequence, criterion, value, target, met)``."""
    out = []
    for name, row in report.items():
        for key, label, target, better in (
                ('recall', 'recall', 0.98, 'high'), ('precision', 'precision', 0.98, 'high'),
                ('horizontal_median_m', 'horizontal error median (m)', 0.10, 'low'),
                ('horizontal_p95_m', 'horizontal error p95 (m)', 0.25, 'low'),
                ('height_median_m', 'head height error median (m)', 0.10, 'low'),
                ('id_switches', 'id switches', 0, 'low'), ('mota', 'MOTA', 0.95, 'high')):
            value = row[key]
            met = value >= target if better == 'high' else value <= target
            out.append((name, label, value, f'{">=" if better == "high" else "<="} {target}',
                        bool(met)))
    return out


def markdown_timing(report):
    """Return the people stage's wall time per pair (warm mask, detection, tracking)."""
    lines = ['| sequence | pairs | people stage per pair, median (ms) | p95 (ms) |',
             '|---|---:|---:|---:|']
    for name, row in report.items():
        lines.append(f'| {name} | {row["pairs"]} | {row["people_ms_median"]:.2f} | '
                     f'{row["people_ms_p95"]:.2f} |')
    return '\n'.join(lines)


def markdown_tracker(report):
    """Return what the tracker did per sequence (its counts, the node's diagnostics)."""
    lines = ['| sequence | tracks published | withdrawn when lent legs lapsed | detections '
             'withheld from a published track for a warm object | still tracks held beside a '
             'neighbour (track-pairs) |', '|---|---:|---:|---:|---:|']
    for name, row in report.items():
        lines.append(f'| {name} | {row["tracks_started"]} | {row["legs_lapsed"]} | '
                     f'{row["object_detections"]} | {row["held_beside"]} |')
    return '\n'.join(lines)


def markdown_table(report):
    """One row per sequence; the held-out ones marked."""
    lines = ['| sequence | pairs | people | recall | precision | tracks on people hidden in view '
             '(precision counting them false) | horizontal median / p95 (m) | '
             'head height median / p95 (m) | MOTA (counting them false) | MOTP (m) | '
             'id switches | fragmentations | depth spread on a person, median (m) |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    for name, row in report.items():
        title = held_out_title(name)
        mota_strict = f' ({row["mota_strict"]:.3f})' if row['on_hidden'] else ''
        lines.append(
            f'| {title} | {row["pairs"]} | {row["truths"]} | {row["recall"]:.1%} | '
            f'{row["precision"]:.1%} | {row["on_hidden"]} ({row["precision_strict"]:.1%}) | '
            f'{row["horizontal_median_m"]:.3f} / '
            f'{row["horizontal_p95_m"]:.3f} | {row["height_median_m"]:.3f} / '
            f'{row["height_p95_m"]:.3f} | {row["mota"]:.3f}{mota_strict} | '
            f'{row["motp_m"]:.3f} | {row["id_switches"]} | {row["fragmentations"]} | '
            f'{row["depth_spread_median_m"]:.3f} |')
    return '\n'.join(lines)
