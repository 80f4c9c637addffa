"""
The main job (``st-stereo-suite``): the node suite in one process on a finite stream.

Driver, rectifier, matcher and people (``st_stereo.nodes``) on one executor with a
``SuiteMonitor``, fed by the bundled recording (or a simulated plane); prints a status line per
second, a summary, and, when the recording has ground truth, every received point scored
against it (``st_stereo.sim.scoring``) and the people found against the true ones
(``st_stereo.tools.eval_people``; the rig pose is the recording's ``rig_pose.yaml``).
Composition alone is ``st_stereo.nodes.pipeline``.
"""

import time

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from st_stereo.nodes.driver_node import DriverNode
from st_stereo.nodes.matcher_node import MatcherNode
from st_stereo.nodes.people_node import PeopleNode
from st_stereo.nodes.pipeline import SuiteMonitor
from st_stereo.nodes.rectifier_node import RectifierNode


def run_suite(argv=None):
    """
    Run the main job: the whole suite in one process on a finite stream.

    By default the driver replays the bundled recording (a simulated office with two people,
    with ground truth); ``--sim`` uses the simulated textured plane instead. Prints a status
    line per second and a summary, compared with the ground truth when there is one; exits at
    the end of the stream or on Ctrl-C.
    """
    import argparse
    parser = argparse.ArgumentParser(prog='st-stereo-suite', description=run_suite.__doc__)
    parser.add_argument('--recording', default=None,
                        help='recording directory (bag/, left.yaml, right.yaml and optionally '
                             'ground_truth.npz); default: the bundled recording')
    parser.add_argument('--sim', action='store_true',
                        help='simulated cameras looking at a textured plane instead')
    parser.add_argument('--seconds', type=float, default=10.0,
                        help='--sim: stream duration, seconds')
    parser.add_argument('--depth', type=float, default=3.5, help='--sim: plane depth, metres')
    args, ros_args = parser.parse_known_args(argv)
    rclpy.init(args=['st-stereo-suite', *ros_args] if ros_args else None)
    truth = None
    people_overrides = []
    if args.sim:
        driver_overrides = [Parameter('duration', value=float(args.seconds)),
                            Parameter('sim_depth', value=float(args.depth))]
        source = f'simulated rig (plane at {args.depth} m), {args.seconds} s of stream'
    else:
        import pathlib

        from st_stereo.package_data import bundled_recording
        from st_stereo.sim.recording import load_ground_truth
        recording = pathlib.Path(args.recording) if args.recording else bundled_recording()
        if not (recording / 'bag').is_dir():
            raise SystemExit(f'st-stereo-suite: {recording}: not a recording directory (no '
                             f'bag/ in it)')
        driver_overrides = [Parameter('source', value='bag'),
                            Parameter('bag', value=str(recording / 'bag'))] + [
            Parameter(f'{side}.camera_info_url', value=f'file://{recording / side}.yaml')
            for side in ('left', 'right') if (recording / f'{side}.yaml').is_file()]
        if (recording / 'ground_truth.npz').is_file():
            truth = load_ground_truth(recording)
        if (recording / 'rig_pose.yaml').is_file():
            from st_stereo.core.rig_pose import load_rig_pose, POSE_FIELDS
            pose = load_rig_pose(recording / 'rig_pose.yaml')
            people_overrides = [Parameter('world_frame', value=pose.world_frame)] + [
                Parameter(field, value=float(getattr(pose, field)))
                for field in POSE_FIELDS[2:]]
        source = f'recording {recording}'
    # Every pair of the replay is matched, in order (keep_latest off): the summary is the
    # same on every run, whatever else the machine is doing. The matcher (its kernels load at
    # start) and the rectifier exist before the driver starts publishing.
    matcher = MatcherNode(parameter_overrides=[Parameter('keep_latest', value=False)])
    rectifier = RectifierNode()
    people = PeopleNode(parameter_overrides=people_overrides)
    driver = DriverNode(parameter_overrides=driver_overrides)
    nodes = [driver, rectifier, matcher, people, SuiteMonitor(driver, watch_people=True)]
    monitor = nodes[-1]
    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    print(f'st_stereo suite: {source}: lepton_driver -> rectifier -> matcher -> people',
          flush=True)
    started = time.monotonic()
    next_report = started + 1.0
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if now >= next_report:
                next_report += 1.0
                recent = [t for t in monitor.times if t > time.time() - 1.0]
                latency = np.median(monitor.latencies[-len(recent):]) * 1e3 if recent else 0
                matches = monitor.matches[-1] if monitor.matches else 0
                found = len(monitor.people[max(monitor.people)]) if monitor.people else 0
                print(f't={now - started:5.1f}s  {len(recent):2d} fps  latency '
                      f'{latency:6.1f} ms  matches {matches:4d}  people {found}  pairs '
                      f'{driver.published:4d}', flush=True)
            if driver.finished.is_set() and now - started > 1.0:
                # Let the last pair go through the pipeline.
                end = time.monotonic() + 0.5
                while time.monotonic() < end:
                    executor.spin_once(timeout_sec=0.05)
                break
    except KeyboardInterrupt:
        print('interrupted', flush=True)
    finally:
        print_summary(driver, matcher, monitor, args.depth if args.sim else None)
        print_people_summary(monitor, people)
        if truth is not None:
            print_truth_comparison(monitor, truth, matcher)
            print_people_truth(monitor, truth, people)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0 if monitor.times and not driver.last_error else 1


def print_truth_comparison(monitor, truth, matcher):
    """Score every received point against a recording's ground truth, per surface."""
    from st_stereo.core.triangulation import project
    from st_stereo.sim.recording import frame_truth
    from st_stereo.sim.scoring import MotionTally, people_disparity_errors, PointTally, \
        score_points
    model = matcher.matcher.model
    if model is None:
        return
    stamps = np.asarray(truth['stamp_ns'], dtype=np.int64)
    tally, motion = PointTally(), MotionTally()
    for stamp, points in monitor.clouds.items():
        # Replayed stamps go through float seconds: match within a microsecond.
        index = int(np.argmin(np.abs(stamps - stamp)))
        if abs(int(stamps[index]) - stamp) > 1000:
            continue
        points = np.asarray(points, dtype=np.float64)[:, :3]
        u, v, disparity = project(model, points)
        one = frame_truth(truth, index)
        tally.add(score_points(model, one, u, v, disparity, points))
        if 'heads_image_velocity' in truth:
            motion.add(*people_disparity_errors(model, one, u, v, disparity,
                                                truth['heads_image_velocity'][index]),
                       1e-6 * (int(truth['right_stamp_ns'][index]) -
                               int(truth['left_stamp_ns'][index])))
    if not tally.frames:
        print('  ground truth: no point cloud matched a ground-truth stamp')
        return
    print(f'  ground truth, {tally.frames} clouds, every point (outlier: farther than 0.3 m '
          f'from the true surface of its pixel and its 8 neighbours):')
    for row in tally.rows(truth['label_names']):
        print(f'    {row["surface"]:>9}: {row["points"]:6d} points, outliers '
              f'{100 * row["outliers_3d"]:5.1f} %, median |dZ|/Z '
              f'{100 * row["relative_error_median"]:5.2f} %, correct per cloud '
              f'{row["correct_per_frame"]:6.1f}')
    rows = motion.rows()
    if rows:
        print("  disparity error on people (the scene at the left camera's instant), by pair "
              'skew and head speed in the image:')
    for row in rows:
        low, high = row['speed_px_s']
        speed = 'all speeds' if (low, high) == (0.0, np.inf) else \
            f'>= {low:.0f} px/s' if high == np.inf else f'{low:.0f}-{high:.0f} px/s'
        print(f'    skew {row["skew_ms"][0]:+.0f} to {row["skew_ms"][1]:+.0f} ms, '
              f'{speed:>11}: {row["matches"]:6d} matches, median {row["median"]:+.3f} px, '
              f'median abs {row["median_abs"]:.3f} px, p90 abs {row["p90_abs"]:.3f} px')


def print_people_summary(monitor, people):
    """Print the people topics as received: rate, people per pair, ids."""
    times = monitor.people_times
    rate = f', {(len(times) - 1) / (times[-1] - times[0]):.2f} per second' \
        if len(times) > 1 and times[-1] > times[0] else ''
    counts = [len(rows) for rows in monitor.people.values()]
    ids = sorted({int(i) for rows in monitor.people.values() for i in rows[:, 3]})
    print(f'  people/detections received: {len(times)}{rate}; people per pair: median '
          f'{np.median(counts) if counts else 0:.0f}, max {max(counts, default=0)}; '
          f'track ids {ids}')
    print(f'  people node: {people.counts}; tracks {people.estimator.tracker.counts}'
          if people.estimator is not None else f'  people node: {people.counts}')


def print_people_truth(monitor, truth, people):
    """Print the people received against a recording's true heads (tools.eval_people)."""
    import types

    from st_stereo.tools.eval_people import HIT_M, PeopleTally
    if 'heads_world' not in truth or people.camera_info is None:
        return
    stamps = np.asarray(truth['stamp_ns'], dtype=np.int64)
    p = np.array(people.camera_info.p, dtype=np.float64).reshape(3, 4)
    model = types.SimpleNamespace(fx=p[0, 0], fy=p[1, 1], cx=p[0, 2], cy=p[1, 2])
    shape = (people.camera_info.height, people.camera_info.width)
    tally = PeopleTally()
    for stamp in sorted(monitor.people):
        index = int(np.argmin(np.abs(stamps - stamp)))
        if abs(int(stamps[index]) - stamp) > 1000:
            continue
        tracks = [types.SimpleNamespace(position=row[[0, 1]], head_height=float(row[6]),
                                        track_id=int(row[3]), depth_spread_m=float('nan'))
                  for row in monitor.people[stamp]]
        tally.add_labelled(truth['labels'][index], truth['heads_world'][index],
                           truth['heads_rectified'][index], model, shape, tracks)
    if not tally.pairs:
        print('  people against the truth: no people/detections matched a ground-truth stamp')
        return
    row = tally.row()
    print(f'  people against the truth ({tally.pairs} pairs, a hit within {HIT_M} m of a head '
          f'centre): recall {row["recall"]:.1%}, precision {row["precision"]:.1%} '
          f'({row["on_hidden"]} tracks kept on people hidden in view not scored; '
          f'{row["precision_strict"]:.1%} counting them false), horizontal '
          f'error median {row["horizontal_median_m"]:.3f} m / p95 {row["horizontal_p95_m"]:.3f}'
          f' m, head height error median {row["height_median_m"]:.3f} m, MOTA '
          f'{row["mota"]:.3f}, id switches {row["id_switches"]}')


def print_summary(driver, matcher, monitor, depth):
    """Summary of a suite run."""
    latencies = np.array(monitor.latencies) * 1e3
    print('\nsummary')
    print(f'  pairs published: {driver.published}, point clouds received: '
          f'{len(monitor.times)}, pairs dropped by pairing: '
          f'{driver.pairing.counters.dropped_left} left / '
          f'{driver.pairing.counters.dropped_right} right')
    if len(monitor.times) > 1:
        span = monitor.times[-1] - monitor.times[0]
        print(f'  point clouds per second: {(len(monitor.times) - 1) / span:.2f}')
    if len(latencies):
        print(f'  latency (pair published -> points2 received): median '
              f'{np.median(latencies):.1f} ms, p99 {np.percentile(latencies, 99):.1f} ms')
    if monitor.matches:
        print(f'  matches per pair: median {np.median(monitor.matches):.0f}')
    skews = sorted(abs(skew) for skew in driver.recent_skews)
    if skews:
        print(f'  pair skew (from pair_info): |skew| median {1e3 * skews[len(skews) // 2]:.1f} '
              f'ms, max {1e3 * skews[-1]:.1f} ms (last {len(skews)} pairs)')
    counts = matcher.skew.counts
    print(f'  skew compensation: {counts["pairs_skew_compensated"]} pairs corrected, '
          f'{counts["pairs_without_skew"]} without pair_info, '
          f'{counts["pairs_without_previous"]} without a previous pair, '
          f'{counts["pairs_tracked_on_right"]} tracked on the right camera (positive skew), '
          f'{counts["pairs_extrapolated"]} extrapolated, {counts["pairs_in_ffc"]} in FFC, '
          f'{counts["pairs_calibration_changed"]} after a new calibration; '
          f'{counts["features_moving"]} moving features corrected '
          f'({counts["features_poc_velocity"]} by their POC velocity), '
          f'{counts["rejected_skew_untracked"]} dropped (changed, untracked), '
          f'{counts["rejected_skew_poc"]} dropped (not found again by the POC), '
          f'{counts["rejected_skew_disagreement"]} dropped (the cameras disagree)')
    if monitor.depths and depth is not None:
        print(f'  median depth: {np.median(monitor.depths):.3f} m (true plane: {depth:.3f} m)')
    for index, counters in enumerate(driver.camera_counters_list()):
        print(f'  camera {index}: {counters.unique_frames} unique frames, '
              f'{counters.frames_aborted} aborted, {counters.resyncs} resyncs')
    if driver.last_error:
        print(f'  driver error: {driver.last_error}')
