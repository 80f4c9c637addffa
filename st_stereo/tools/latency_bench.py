"""
Latency and CPU of the node suite: pair published (and image stamp) -> ``points2`` received.

One process: driver (sim), rectifier, matcher and a monitor on one executor. Across processes:
the three nodes as separate processes, the monitor here. Two latencies per point cloud:

- from the stamp: its receipt time minus its header stamp (the stamp is the time packet 0 of
  the pair's frames was read, so reading, pairing, rectifying, matching and transport are all
  in it);
- from the pair's publication (issue 17's measure): receipt minus the moment the driver
  published the raw pair (in one process the driver's own record; across processes the
  monitor's receipt of ``left/image_raw``, a transport later), i.e. what the rectifier, the
  matcher and the transports add.

CPU is the CPU time of the node processes over the scored clouds (not their start-up), in %
of one core; the drivers start once the rest of their rig is up.
"""

import contextlib
import os
import subprocess
import sys
import time

import numpy as np
import psutil
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from st_stereo.lepton.packets import UNIQUE_FRAME_HZ
from st_stereo.nodes.driver_node import DriverNode
from st_stereo.nodes.matcher_node import MatcherNode
from st_stereo.nodes.pipeline import SuiteMonitor
from st_stereo.nodes.rectifier_node import RectifierNode

NODE_MODULES = ('st_stereo.nodes.driver_node', 'st_stereo.nodes.rectifier_node',
                'st_stereo.nodes.matcher_node')


def _cpu_seconds(process):
    times = process.cpu_times()
    return times.user + times.system


def _stop_processes(processes):
    """Terminate node processes, killing any still running after 10 s."""
    for process in processes:
        process.terminate()
    for process in processes:
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()


def _percentile_ms(values, warmup, q):
    values = np.array(values[warmup:]) * 1e3
    return float(np.percentile(values, q)) if len(values) else float('nan')


def _summary(monitor, cpu_seconds, wall_seconds, warmup, matcher_counts=None):
    rate = 0.0
    if len(monitor.times) > warmup + 1:
        rate = (len(monitor.times) - warmup - 1) / (monitor.times[-1] - monitor.times[warmup])
    return {'clouds': len(monitor.times), 'rate_hz': rate,
            'latency_median_ms': _percentile_ms(monitor.stamp_latencies, warmup, 50),
            'latency_p99_ms': _percentile_ms(monitor.stamp_latencies, warmup, 99),
            'pair_latency_median_ms': _percentile_ms(monitor.pair_latencies, warmup, 50),
            'pair_latency_p99_ms': _percentile_ms(monitor.pair_latencies, warmup, 99),
            'dropped_stale': (matcher_counts or {}).get('dropped_stale', 'n/a'),
            'cpu_percent_of_one_core': 100.0 * cpu_seconds / wall_seconds}


def one_process(seconds, warmup=8):
    """Run the suite in this process for ``seconds``; returns the summary."""
    rclpy.init()
    matcher, rectifier = MatcherNode(), RectifierNode()    # before the driver publishes
    nodes = [DriverNode(parameter_overrides=[Parameter('duration', value=float(seconds))]),
             rectifier, matcher]
    nodes.append(SuiteMonitor(driver=nodes[0]))
    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    process = psutil.Process()
    cpu_start, wall_start = _cpu_seconds(process), time.monotonic()
    try:
        while not nodes[0].finished.is_set():
            executor.spin_once(timeout_sec=0.05)
        cpu = _cpu_seconds(process) - cpu_start
        wall = time.monotonic() - wall_start
        return _summary(nodes[-1], cpu, wall, warmup, nodes[2].counts)
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


def _rig_ready(monitor):
    """
    Tell whether the monitor's rig can take a pair.

    It can once its matcher publishes ``points2`` (it does so after loading its kernels) and
    its rectifier and this monitor subscribe to ``image_raw``.
    """
    namespace = monitor.get_namespace().rstrip('/')
    return monitor.count_publishers(f'{namespace}/points2') >= 1 and \
        monitor.count_subscribers(f'{namespace}/left/image_raw') >= 2


def _cpu_over(samples, start, end):
    """CPU seconds of the node processes between wall times ``start`` and ``end``."""
    times, cpu = np.array(samples).T
    return float(np.interp(end, times, cpu) - np.interp(start, times, cpu))


def _run_node_processes(commands, drivers, executor, monitors, seconds, grace_s,
                        ready_timeout_s=60.0):
    """
    Run node processes while ``executor`` spins the ``monitors``; stop them all.

    ``commands`` (rectifiers, matchers) start first; the ``drivers`` start once every
    monitor's rig is ready (``_rig_ready``) or after ``ready_timeout_s``, so that the pairs
    scored are not those that arrive while the other processes still import and load their
    kernels. The run ends once ``seconds`` have passed since the drivers started and no cloud
    came for 3 s (the recordings ended), or ``grace_s`` later at the latest. Returns the CPU
    samples ``[(wall time, CPU seconds of all the processes)]`` (every 0.25 s; scored over a
    window with ``_cpu_over``), whether every rig was ready before its driver started, and
    how many of the processes had exited by themselves before the end (crashed).
    """
    processes = [subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                 for command in commands]
    handles = [psutil.Process(p.pid) for p in processes]
    samples = []

    def sample():
        total = 0.0
        for handle in handles:
            with contextlib.suppress(psutil.NoSuchProcess):
                total += _cpu_seconds(handle)
        samples.append((time.time(), total))

    try:
        deadline = time.monotonic() + ready_timeout_s
        while not all(_rig_ready(m) for m in monitors) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        ready = all(_rig_ready(m) for m in monitors)
        started = [subprocess.Popen(command, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL) for command in drivers]
        processes += started
        handles += [psutil.Process(p.pid) for p in started]
        wall_start = time.monotonic()
        last_cloud = last_sample = wall_start
        sample()
        while time.monotonic() < wall_start + seconds + grace_s:
            clouds = sum(len(m.times) for m in monitors)
            executor.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if now - last_sample >= 0.25:
                sample()
                last_sample = now
            if sum(len(m.times) for m in monitors) != clouds:
                last_cloud = now
            elif now - last_cloud > 3.0 and now - wall_start > seconds:
                break
        sample()
        # A node process that exited by itself (none should before it is stopped) crashed.
        exited = sum(process.poll() is not None for process in processes)
        return samples, ready, exited
    finally:
        _stop_processes(processes)


def three_processes(seconds, warmup=8):
    """Run driver, rectifier and matcher as processes, the monitor here; returns the summary."""
    commands, drivers = [], []
    for module in NODE_MODULES:
        extra = ['-p', f'duration:={float(seconds)}'] if 'driver' in module else []
        (drivers if 'driver' in module else commands).append(
            [sys.executable, '-c', f'from {module} import main; main()', '--ros-args', *extra])
    rclpy.init()
    monitor = SuiteMonitor(watch_raw=True)
    executor = SingleThreadedExecutor()
    executor.add_node(monitor)
    try:
        samples, _, _ = _run_node_processes(commands, drivers, executor, [monitor], seconds,
                                            20.0)
        stale = monitor.matcher_values.get('pairs dropped_stale', 'n/a')
        # CPU over the scored clouds only (after the warm-up), not the processes' start-up.
        window = (monitor.times[warmup], monitor.times[-1]) \
            if len(monitor.times) > warmup + 1 else (samples[0][0], samples[-1][0])
        cpu = _cpu_over(samples, *window)
        return _summary(monitor, cpu, max(window[1] - window[0], 1e-9), warmup,
                        {'dropped_stale': stale})
    finally:
        monitor.destroy_node()
        rclpy.try_shutdown()


def _rig_commands(rig, seconds):
    """
    Return the command lines of one rig replaying the bundled recording.

    ``(others, driver)``: the rectifier's and the matcher's, and the driver's (started last).
    """
    from st_stereo.package_data import bundled_recording
    recording = bundled_recording()
    commands = []
    for module in NODE_MODULES:
        extra = []
        if 'driver' in module:
            extra = ['-p', 'source:=bag', '-p', f'bag:={recording / "bag"}', '-p',
                     f'duration:={float(seconds)}']
            extra += [item for side in ('left', 'right') for item in
                      ('-p', f'{side}.camera_info_url:=file://{recording / side}.yaml')]
        commands.append([sys.executable, '-c', f'from {module} import main; main()',
                         '--ros-args', '-r', f'__ns:=/rig{rig}', *extra])
    return commands[1:], commands[:1]


def rig_losses(monitors, window):
    """
    Per rig, in a common wall-clock ``window`` (start, end): pairs published, pairs lost.

    A pair is published when its ``left/image_raw`` reached the monitor within the window,
    and lost when no cloud with its stamp came back. A rig whose first cloud came after the
    window's start has not started in time: all its pairs count as lost.
    """
    start, end = window
    rows = []
    for monitor in monitors:
        stamps = [sec * 1_000_000_000 + nanosec
                  for (sec, nanosec), seen in monitor.raw_received.items()
                  if start <= seen <= end]
        started = bool(monitor.times) and monitor.times[0] <= start
        lost = sum(not started or stamp not in monitor.clouds for stamp in stamps)
        rows.append((len(stamps), lost))
    return rows


# A rig whose images span this much less than the replay asked for stopped early. Its first
# images are no exact measure: the first 1-2 s of a replay can go out before its publisher
# has matched the monitor under load (spans of 12.8-14.9 s were seen for 15 s replays, 7
# rigs); nor are its last ones, relative to the other rigs': the drivers start up to 4 s
# apart with 10 rigs (their processes' start-up), and end as far apart.
REPLAY_SHORTFALL_S = 3.5


def replays_stopped_early(monitors, seconds):
    """
    Count the rigs whose replay stopped early.

    No image, or images spanning less than ``seconds - REPLAY_SHORTFALL_S``: such a rig (a
    driver that died or stalled) would pull the common window's end in with it
    (``many_rigs``) and hide its own failure. (A node process that exits is counted apart.)
    """
    return sum(not m.raw_received or max(m.raw_received.values()) -
               min(m.raw_received.values()) < seconds - REPLAY_SHORTFALL_S
               for m in monitors)


def many_rigs(count, seconds, warmup_s=2.0):
    """
    Run ``count`` rigs on this machine, each three processes replaying the bundled recording.

    The rectifiers and matchers start first; the drivers once every rig is ready
    (``_rig_ready``: its matcher has loaded its kernels). The rigs are scored over one common
    window, from ``warmup_s`` after the last rig's first cloud (the drivers' own start-up) to
    1 s before the first rig's last pair (every rig still replaying): a rig is held when every
    pair it published in the window came back as a cloud and it published at least 90 % of
    the cameras' unique frame rate there (a starved driver, or a monitor that missed images,
    is not held either); the window must last 3 s at least. A rig without any cloud is not
    held. The CPU is that of the window. ``end_spread_s``: how far apart the replays ended;
    ``stopped_early`` (``replays_stopped_early``: a driver that died or stalled) and
    ``exited`` (node processes that exited by themselves): neither is held.
    ``dropped_stale``: the pairs the matchers dropped as stale over the whole run (their
    diagnostics), which tells a busy matcher from a loss in transport.
    """
    rclpy.init()
    monitors = [SuiteMonitor(watch_raw=True, namespace=f'rig{k}') for k in range(1, count + 1)]
    executor = SingleThreadedExecutor()
    for monitor in monitors:
        executor.add_node(monitor)
    rigs = [_rig_commands(k, seconds) for k in range(1, count + 1)]
    launched = time.time()
    try:
        samples, ready, exited = _run_node_processes(
            [c for others, _ in rigs for c in others], [c for _, driver in rigs for c in driver],
            executor, monitors, seconds, 30.0)
    finally:
        for monitor in monitors:
            monitor.destroy_node()
        rclpy.try_shutdown()
    # The window closes 1 s before the first rig's replay ends: the drivers start a second or
    # two apart when there are many, and a rig whose recording had already ended would count
    # as starved (before 2026-12-07 the window ran to the last rig's end, and 9 rigs at 129 %
    # of one core "failed" on a replay that had finished).
    ends = [max(m.raw_received.values()) for m in monitors if m.raw_received]
    last = min(ends) if len(ends) == len(monitors) else \
        max(ends, default=launched)
    # The window opens when the last rig is up (its first cloud) plus ``warmup_s``.
    firsts = [m.times[0] for m in monitors if m.times]
    opened = max(firsts) if len(firsts) == len(monitors) else launched
    window = (opened + warmup_s, last - 1.0)
    length = max(window[1] - window[0], 1e-9)
    losses = rig_losses(monitors, window)
    lowest_rate = min(published / length for published, _ in losses)
    stopped_early = replays_stopped_early(monitors, seconds)
    held = length > 3.0 and not any(lost for _, lost in losses) and \
        lowest_rate >= 0.9 * UNIQUE_FRAME_HZ and not stopped_early and not exited
    # The matchers' own count of pairs they dropped as stale (keep_latest: busy when a newer
    # pair came), from each rig's last diagnostics: the whole run, not only the window.
    stale = [monitor.matcher_values.get('pairs dropped_stale') for monitor in monitors]
    return {'rigs': count, 'window_s': length, 'ready': ready,
            'end_spread_s': max(ends) - min(ends) if ends else float('nan'),
            'stopped_early': stopped_early, 'exited': exited,
            'dropped_stale': sum(int(v) for v in stale) if None not in stale else 'n/a',
            'published': sum(p for p, _ in losses), 'lost': sum(lost for _, lost in losses),
            'lowest_rate_hz': lowest_rate, 'held': held,
            'cpu_percent_of_one_core': 100.0 * _cpu_over(samples, *window) / length}


def main(argv=None):
    """Print the latency / CPU table of both layouts."""
    import argparse
    parser = argparse.ArgumentParser(prog='st-stereo-latency', description=__doc__)
    parser.add_argument('--seconds', type=float, default=20.0, help='stream per layout')
    parser.add_argument('--rigs', type=int, default=0, metavar='N',
                        help='also run 1..N rigs (three processes each, namespaces /rig1.., '
                             'each replaying the bundled recording) and print the largest '
                             'number held without a lost pair')
    parser.add_argument('--rigs-from', type=int, default=1, metavar='K',
                        help='start the rigs runs at K rigs instead of 1')
    parser.add_argument('--no-layouts', action='store_true',
                        help='skip the one-process and three-process latency runs')
    args = parser.parse_args(argv)
    if not 1 <= args.rigs_from <= max(args.rigs, 1):
        parser.error(f'--rigs-from: expected 1..{max(args.rigs, 1)} (--rigs), '
                     f'got {args.rigs_from}')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    rows = {} if args.no_layouts else {'one process': one_process(args.seconds),
                                       'three processes': three_processes(args.seconds)}
    if rows:
        print('| layout | point clouds | rate Hz | pair published -> points2 median ms | '
              'p99 ms | stamp -> points2 median ms | p99 ms | stale pairs dropped | '
              'CPU % of one core |')
        print('|---|---|---|---|---|---|---|---|---|')
    for name, row in rows.items():
        print(f'| {name} | {row["clouds"]} | {row["rate_hz"]:.2f} | '
              f'{row["pair_latency_median_ms"]:.1f} | {row["pair_latency_p99_ms"]:.1f} | '
              f'{row["latency_median_ms"]:.1f} | {row["latency_p99_ms"]:.1f} | '
              f'{row["dropped_stale"]} | {row["cpu_percent_of_one_core"]:.1f} |')
    if args.rigs:
        print()
        print('| rigs | all ready before their drivers | node processes exited | '
              'replays stopped early | '
              'replays end within s | '
              'scored window s | pairs published in it | pairs lost | '
              'stale pairs dropped by the matchers (run) | lowest published rate Hz | held | '
              'CPU % of one core |')
        print('|---|---|---|---|---|---|---|---|---|---|---|---|')
        largest = 0
        for count in range(args.rigs_from, args.rigs + 1):
            row = many_rigs(count, min(args.seconds, 15.0))
            print(f'| {count} | {"yes" if row["ready"] else "no"} | {row["exited"]} | '
                  f'{row["stopped_early"]} | '
                  f'{row["end_spread_s"]:.2f} | {row["window_s"]:.1f} | '
                  f'{row["published"]} | {row["lost"]} | {row["dropped_stale"]} | '
                  f'{row["lowest_rate_hz"]:.2f} | {"yes" if row["held"] else "no"} | '
                  f'{row["cpu_percent_of_one_core"]:.1f} |', flush=True)
            if not row['held']:
                break
            largest = count
        if args.rigs_from > 1 and not largest:
            largest = f'none from {args.rigs_from}'
        print(f'largest number of rigs held (every pair published in the window matched): '
              f'{largest}')
    return 0
