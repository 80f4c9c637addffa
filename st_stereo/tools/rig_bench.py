"""
Benchmarks of the driver on the wall-clock rig emulator, and the memory soak.

``st-stereo rig-bench`` runs the real driver node (alone, and as the whole suite in one
process with the matcher running) against two emulated Leptons on real time, for each spidev
buffer size asked, and prints per layout: unique frames per second of each camera, pairs per
second, the cameras' sync losses (as the emulated cameras count them), the driver's resyncs and
restarts, and the distribution of the pair skew. It also compares the reader's two CRC policies
on the emulator (drop the frame vs resync), and gives the share of time with no pair that
``max_pair_delta`` implies for two free-running cameras.

``st-stereo soak`` runs ``stereo_pipeline`` (driver, rectifier, matcher on one executor) on the
emulated rig or on ``source:=sim`` and prints the process RSS over time and its trend.
"""

import contextlib
import dataclasses
import os
import tempfile
import threading
import time

import numpy as np

from st_stereo.core.image_io import image_from_buffer
from st_stereo.lepton.emulator import CameraConfig, pixels_digest, RigEmulator
from st_stereo.lepton.packets import UNIQUE_FRAME_PERIOD_S


@dataclasses.dataclass
class Published:
    """What a subscriber received from the driver."""

    images: dict = dataclasses.field(default_factory=lambda: {'left': [], 'right': []})
    pair_info: list = dataclasses.field(default_factory=list)
    statuses: dict = dataclasses.field(default_factory=dict)
    history: list = dataclasses.field(default_factory=list)    # (monotonic, name, level)
    arrivals: list = dataclasses.field(default_factory=list)   # (monotonic, side)


def _subscriber_class():
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    class RigSubscriber(Node):
        """Records every raw image (stamp, digest of its pixels), pair_info and diagnostics."""

        def __init__(self, context, namespace='stereo'):
            super().__init__('rig_subscriber', context=context, namespace=namespace)
            self.got = Published()
            qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
            for side in ('left', 'right'):
                self.create_subscription(Image, f'{side}/image_raw',
                                         lambda msg, side=side: self._on_image(side, msg), qos)
            self.create_subscription(DiagnosticArray, 'pair_info', self.got.pair_info.append,
                                     qos)
            self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)

        def _on_image(self, side, msg):
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            pixels = image_from_buffer(msg.data, msg.encoding, msg.width, msg.height,
                                       msg.step, msg.is_bigendian, 'mono16')
            self.got.images[side].append((stamp, pixels_digest(pixels), msg.header.frame_id))
            self.got.arrivals.append((time.monotonic(), side))

        def _on_diagnostics(self, msg):
            now = time.monotonic()
            for status in msg.status:
                self.got.statuses[status.name] = (status.level, status.message,
                                                  {kv.key: kv.value for kv in status.values})
                self.got.history.append((now, status.name, status.level))
    return RigSubscriber


def _stepping_clock_class():
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    class SteppingClock(Node):
        """
        The rig's wall-clock step: publishes /clock = monotonic time + an offset to step.

        Nodes with ``use_sim_time`` see their clock jump when ``offset`` changes, as an NTP
        step moves the system clock under a real rig.
        """

        def __init__(self, context, period_s=0.005):
            super().__init__('stepping_clock', context=context)
            self.offset = 1.0e9 - time.monotonic()
            self.publisher = self.create_publisher(Clock, '/clock', 10)
            self.create_timer(period_s, self.tick)
            self.tick()

        def tick(self):
            """Publish the clock now."""
            now = time.monotonic() + self.offset
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = int(now), int((now % 1.0) * 1e9)
            self.publisher.publish(msg)
    return SteppingClock


def __getattr__(name):
    # The nodes are built on first use so that importing this module needs no rclpy.
    if name == 'RigSubscriber':
        return _subscriber_class()
    if name == 'SteppingClock':
        return _stepping_clock_class()
    raise AttributeError(name)


def spi_parameters(rig, **extra):
    """Driver parameters (rclpy Parameters) for the emulated rig on SPI, CCI on buses 0, 1."""
    from rclpy.parameter import Parameter
    values = {'source': 'spi', 'left_device': rig.devices['left'],
              'right_device': rig.devices['right'], 'telemetry': 'footer',
              'left_i2c_bus': 0, 'right_i2c_bus': 1}
    values.update(extra)
    return [Parameter(name, value=value) for name, value in values.items()]


def rig_configs(bufsiz, crc_fault_rate=0.0, sweep=False):
    """
    Return the two default emulated cameras, the host spidev buffer ``bufsiz`` bytes.

    ``sweep``: clocks +-3000 ppm apart instead of +30 / -20 ppm, so that their relative phase
    slides through the whole 113.6 ms unique-frame period in about 19 s (real Leptons take
    tens of minutes), to measure the share of time with no pair.
    """
    drifts = (3000.0, -3000.0) if sweep else (30.0, -20.0)
    return [CameraConfig('left', seed=1, phase_s=0.004, drift_ppm=drifts[0],
                         transfer_bytes=bufsiz, crc_fault_rate=crc_fault_rate),
            CameraConfig('right', seed=2, phase_s=0.015, drift_ppm=drifts[1],
                         disparity_px=10.0, transfer_bytes=bufsiz,
                         crc_fault_rate=crc_fault_rate)]


@contextlib.contextmanager
def kernel_bufsiz(bufsiz):
    """
    Make ``SpiTransport`` read ``bufsiz`` as the spidev module parameter (as a kernel would).

    In this process and in the reader processes it spawns (through the environment).
    """
    from st_stereo.lepton import spi
    saved = spi.BUFSIZ_PATH, os.environ.get('ST_STEREO_SPIDEV_BUFSIZ_PATH')
    with tempfile.TemporaryDirectory() as directory:
        path = os.path.join(directory, 'bufsiz')
        with open(path, 'w', encoding='ascii') as stream:
            stream.write(f'{bufsiz}\n')
        spi.BUFSIZ_PATH = os.environ['ST_STEREO_SPIDEV_BUFSIZ_PATH'] = path
        try:
            yield
        finally:
            spi.BUFSIZ_PATH = saved[0]
            if saved[1] is None:
                os.environ.pop('ST_STEREO_SPIDEV_BUFSIZ_PATH', None)
            else:
                os.environ['ST_STEREO_SPIDEV_BUFSIZ_PATH'] = saved[1]


def _hold_the_gil(stop):
    """Pure-Python work that gives the GIL up only when the interpreter forces it (5 ms)."""
    total = 0
    while not stop.is_set():
        for i in range(20000):
            total += i * i
    return total


def run_rig(seconds, layout='driver', bufsiz=4096, warmup_s=3.0, reader='process',
            max_pair_delta=None):
    """
    Run the driver (``layout='driver'``) or driver + rectifier + matcher (``'suite'``).

    ``'suite+gil'`` adds a thread of pure-Python work in the same process (the worst case for
    a reading thread: it waits up to the 5 ms switch interval for the GIL after each read).
    ``'sweep'`` is the driver alone with cameras whose phase slides through the whole
    period (``rig_configs``). ``reader`` is the driver's ``spi_reader`` (process or thread).
    Returns a dict of measurements over the run after ``warmup_s``.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from st_stereo.nodes.driver_node import DriverNode
    from st_stereo.nodes.matcher_node import MatcherNode
    from st_stereo.nodes.rectifier_node import RectifierNode
    configs = rig_configs(bufsiz, sweep=layout == 'sweep')
    with RigEmulator(configs) as rig, kernel_bufsiz(bufsiz), \
            rig.installed():
        context = rclpy.Context()
        rclpy.init(context=context)
        executor = SingleThreadedExecutor(context=context)
        subscriber = _subscriber_class()(context)
        extra = {} if max_pair_delta is None else {'max_pair_delta': max_pair_delta}
        driver = DriverNode(context=context, parameter_overrides=spi_parameters(
            rig, spi_reader=reader, **extra))
        nodes = [subscriber, driver]
        matcher = None
        if layout.startswith('suite'):
            matcher = MatcherNode(context=context)
            nodes += [RectifierNode(context=context), matcher]
        for node in nodes:
            executor.add_node(node)
        stop = threading.Event()
        if layout == 'suite+gil':
            threading.Thread(target=_hold_the_gil, args=(stop,), daemon=True).start()
        start = time.monotonic()
        snapshot = None
        while time.monotonic() - start < warmup_s + seconds:
            executor.spin_once(timeout_sec=0.01)
            if snapshot is None and time.monotonic() - start >= warmup_s:
                snapshot = _rig_counts(rig, driver)
                matched_before = matcher.counts['matched'] if matcher is not None else 0
        end = time.monotonic()
        stop.set()
        stats, counters, streams, pairing = _difference(_rig_counts(rig, driver), snapshot)
        matched = (matcher.counts['matched'] - matched_before) if matcher is not None else 0
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    got = subscriber.got
    window = end - start - warmup_s
    skews = []
    for array in got.pair_info:
        values = {kv.key: kv.value for kv in array.status[0].values}
        skews.append(abs(float(values['skew (ms)'])))
    out = {'reader': reader, 'layout': layout, 'bufsiz': bufsiz, 'seconds': round(window, 1)}
    for index, side in enumerate(('left', 'right')):
        unique = [t for t, s in got.arrivals if s == side and t >= start + warmup_s]
        out[f'{side} published /s'] = len(unique) / window
        out[f'{side} sync losses'] = stats[side].get('sync_lost', 0)
        out[f'{side} resyncs'] = counters[index]['resyncs']
        out[f'{side} restarts'] = streams[index]['restarts']
    out['pairs /s'] = out['left published /s']
    paired = pairing['pairs'] + pairing['dropped_left']
    out['left frames without pair'] = pairing['dropped_left'] / paired if paired else \
        float('nan')
    out['abs skew ms median'] = float(np.median(skews)) if skews else float('nan')
    out['abs skew ms p95'] = float(np.percentile(skews, 95)) if skews else float('nan')
    out['abs skew ms max'] = float(np.max(skews)) if skews else float('nan')
    out['matched /s'] = matched / window
    return out


def _rig_counts(rig, driver):
    return ({name: camera.stats() for name, camera in rig.cameras.items()},
            [dict(c.as_dict()) for c in driver.camera_counters],
            [dict(s.counters.as_dict()) for s in driver.streams],
            dict(driver.pairing.counters.as_dict()))


def _difference(after, before):
    """Return the counts of ``after`` minus ``before`` (the run after warm-up)."""
    stats = {name: {key: value - before[0][name].get(key, 0) for key, value in values.items()}
             for name, values in after[0].items()}
    counters = [{key: value - old[key] for key, value in new.items()
                 if isinstance(value, int)} for new, old in zip(after[1], before[1])]
    streams = [{key: value - old[key] for key, value in new.items()
                if isinstance(value, int)} for new, old in zip(after[2], before[2])]
    pairing = {key: value - before[3][key] for key, value in after[3].items()
               if isinstance(value, int)}
    return stats, counters, streams, pairing


def crc_policy_on_emulator(seconds, rate, policy, bufsiz=65536):
    """Measure one reader's unique frames/s with a CRC fault in ``rate`` of the frames."""
    from st_stereo.lepton import spi
    from st_stereo.lepton.cci import LeptonCCI, SMBus2Bus
    from st_stereo.lepton.reader import LeptonReader
    config = rig_configs(bufsiz, crc_fault_rate=rate)[0]
    with RigEmulator([config]) as rig, kernel_bufsiz(bufsiz), \
            rig.installed():
        LeptonCCI(SMBus2Bus(0)).start('footer')
        transport = spi.SpiTransport(rig.devices['left'], 16_000_000)
        reader = LeptonReader(transport, telemetry='footer', crc_policy=policy)
        reader.resync()
        start = time.monotonic()
        frames = 0
        while time.monotonic() - start < seconds:
            frames += reader.read_frame(0.5) is not None
        faults = rig.cameras['left'].stats().get('crc_faults', 0)
        transport.close()
    return {'policy': policy, 'crc faults': faults, 'unique /s': frames / seconds,
            'resyncs': reader.counters.resyncs,
            'frames dropped on CRC': reader.counters.crc_frames_dropped}


def no_pair_share(max_delta_s, period_s=UNIQUE_FRAME_PERIOD_S):
    """
    Share of time two free-running cameras give no pair, for a pairing window ``max_delta_s``.

    Their relative phase drifts uniformly over the unique-frame period T; a frame's nearest
    partner is then |skew| <= T/2 away, uniformly: none within ``max_delta`` for a share
    ``1 - 2 max_delta / T`` of the time (0 when ``max_delta >= T/2``).
    """
    return max(0.0, 1.0 - 2.0 * max_delta_s / period_s)


def print_table(rows, keys):
    """Print rows (dicts) as a Markdown table of ``keys``."""
    print('| ' + ' | '.join(keys) + ' |')
    print('|' + '---|' * len(keys))
    for row in rows:
        cells = [f'{row[k]:.2f}' if isinstance(row[k], float) else str(row[k]) for k in keys]
        print('| ' + ' | '.join(cells) + ' |')


def command_rig_bench(args):
    """``st-stereo rig-bench``."""
    rows = []
    for reader in args.readers.split(','):
        for bufsiz in [int(b) for b in args.bufsiz.split(',')]:
            for layout in args.layouts.split(','):
                rows.append(run_rig(args.seconds, layout, bufsiz, reader=reader,
                                    max_pair_delta=args.max_pair_delta))
                print(f'[rig-bench] reader {reader}, {layout}, bufsiz {bufsiz}: '
                      f'{rows[-1]["pairs /s"]:.2f} pairs/s', flush=True)
    print(f'\n## The driver on the emulated rig ({args.seconds:g} s each, after 3 s of start-up)')
    print_table(rows, ['reader', 'layout', 'bufsiz', 'left published /s', 'right published /s',
                       'pairs /s', 'left sync losses', 'right sync losses', 'left resyncs',
                       'right resyncs', 'left restarts', 'right restarts',
                       'abs skew ms median', 'abs skew ms p95', 'abs skew ms max',
                       'left frames without pair', 'matched /s'])
    if args.crc_rate > 0:
        crc_rows = [crc_policy_on_emulator(args.seconds, args.crc_rate, policy)
                    for policy in ('drop', 'resync')]
        print(f'\n## CRC policy (one reader, {args.crc_rate:.0%} of core frames with a bad CRC)')
        print_table(crc_rows, ['policy', 'crc faults', 'unique /s', 'resyncs',
                               'frames dropped on CRC'])
    print('\n## Time with no pair for two free-running cameras (relative phase drifts through '
          'the 113.6 ms period)')
    print('| max_pair_delta (ms) | share of time with no pair | largest skew of a pair (ms) |')
    print('|---|---|---|')
    for delta in (0.03, 0.04, 0.05, 0.057):
        print(f'| {delta * 1e3:.0f} | {no_pair_share(delta):.1%} | '
              f'{min(delta, UNIQUE_FRAME_PERIOD_S / 2) * 1e3:.1f} |')
    return 0


def command_soak(args):
    """``st-stereo soak``: RSS of stereo_pipeline over time."""
    import psutil
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from st_stereo.nodes.driver_node import DriverNode
    from st_stereo.nodes.matcher_node import MatcherNode
    from st_stereo.nodes.rectifier_node import RectifierNode
    process = psutil.Process()
    samples = []
    with contextlib.ExitStack() as stack:
        if args.source == 'spi':
            rig = stack.enter_context(RigEmulator())
            stack.enter_context(rig.installed())
            parameters = spi_parameters(rig)
        else:
            parameters = [Parameter('source', value='sim')]
        context = rclpy.Context()
        rclpy.init(context=context)
        executor = SingleThreadedExecutor(context=context)
        driver = DriverNode(context=context, parameter_overrides=parameters)
        nodes = [driver, RectifierNode(context=context), MatcherNode(context=context)]
        for node in nodes:
            executor.add_node(node)
        start = time.monotonic()
        next_sample = start
        try:
            while time.monotonic() - start < args.seconds:
                executor.spin_once(timeout_sec=0.05)
                now = time.monotonic()
                if now >= next_sample:
                    samples.append((now - start, process.memory_info().rss / 2 ** 20,
                                    driver.published))
                    print(f'[soak] t={now - start:7.1f} s  RSS {samples[-1][1]:7.1f} MiB  '
                          f'pairs {driver.published}', flush=True)
                    next_sample += args.sample
        finally:
            for node in reversed(nodes):
                node.destroy_node()
            rclpy.try_shutdown(context=context)
    slope = rss_trend(samples, args.warmup)
    first = next(rss for t, rss, _ in samples if t >= args.warmup)
    print(f'\nsoak of stereo_pipeline, source {args.source}, {args.seconds:g} s: RSS '
          f'{first:.1f} -> {samples[-1][1]:.1f} MiB after {args.warmup:g} s of warm-up, trend '
          f'{slope * 3600:+.1f} MiB/hour; {samples[-1][2]} pairs')
    return 0


def rss_trend(samples, warmup_s):
    """Least-squares slope (MiB per second) of RSS samples ``(t, rss, ...)`` after warm-up."""
    points = np.array([(t, rss) for t, rss, *_ in samples if t >= warmup_s])
    if len(points) < 2:
        return float('nan')
    return float(np.polyfit(points[:, 0], points[:, 1], 1)[0])


def add_parser(sub):
    """Add ``rig-bench`` and ``soak`` to the ``st-stereo`` parser."""
    p = sub.add_parser('rig-bench', help='the driver on the wall-clock rig emulator')
    p.add_argument('--seconds', type=float, default=20.0, help='measured seconds per run')
    p.add_argument('--bufsiz', default='4096,65536',
                   help='spidev buffer sizes (bytes) to emulate, comma separated')
    p.add_argument('--layouts', default='driver,suite,suite+gil,sweep',
                   help='driver (alone), suite (driver, rectifier, matcher in one process), '
                        'suite+gil (the suite and a thread of pure-Python work), sweep (the '
                        'driver, camera phases sliding through the whole period)')
    p.add_argument('--readers', default='process,thread',
                   help="the driver's spi_reader modes to run, comma separated")
    p.add_argument('--max-pair-delta', type=float, default=None,
                   help="the driver's max_pair_delta, seconds (default: the driver's default)")
    p.add_argument('--crc-rate', type=float, default=0.05,
                   help='CRC faults per core frame for the CRC-policy comparison (0 = skip)')
    p.set_defaults(handler=command_rig_bench)
    p = sub.add_parser('soak', help='RSS of stereo_pipeline over time (memory soak)')
    p.add_argument('--source', choices=('spi', 'sim'), default='spi',
                   help='spi: the wall-clock rig emulator; sim: the simulated rig')
    p.add_argument('--seconds', type=float, default=3600.0)
    p.add_argument('--sample', type=float, default=10.0, help='seconds between RSS samples')
    p.add_argument('--warmup', type=float, default=60.0,
                   help='seconds before the trend is measured')
    p.set_defaults(handler=command_soak)
