"""
The Lepton layer's command line (``st-stereo lepton``): simulate, decode, benchmark captures.

``st-stereo lepton simulate`` writes a raw capture of one simulated camera (optionally with
faults); ``st-stereo lepton decode`` turns any capture (ours, or plain concatenated SPI bytes)
into frames, stamps, telemetry and counters; ``st-stereo lepton bench`` measures parsing and
assembly speed against real time for two cameras.
"""

import json
import time

from st_stereo.lepton.capture import decode_capture, record_camera, save_frames_npz
from st_stereo.lepton.simulator import FAULT_KINDS, FaultPlan, LeptonSimulator, \
    SyntheticSceneSource


def parse_faults(text):
    """Parse ``kind=rate,kind=rate`` into a FaultPlan."""
    rates = {}
    for item in filter(None, (text or '').split(',')):
        kind, sep, rate = item.partition('=')
        if not sep:
            raise ValueError(f'--faults: expected kind=rate, got {item!r} (kinds: '
                             f'{", ".join(FAULT_KINDS)})')
        rates[kind.strip()] = float(rate)
    return FaultPlan(rates)


def simulate_capture(path, seconds, telemetry='off', faults=None, seed=0, plain=False):
    """Record ``seconds`` of one simulated camera read by the reader; returns the counters."""
    camera = LeptonSimulator(SyntheticSceneSource(seed), telemetry=telemetry, faults=faults,
                             seed=seed, phase_s=0.011)
    return record_camera(camera, path, seconds, telemetry, plain,
                         source='st-stereo lepton simulate')


def command_simulate(args):
    """``st-stereo lepton simulate``."""
    counters = simulate_capture(args.out, args.seconds, args.telemetry,
                                parse_faults(args.faults), args.seed, args.plain)
    print(json.dumps(counters, indent=1))
    return 0


def command_decode(args):
    """``st-stereo lepton decode``: frames, stamps, telemetry and counters to an .npz file."""
    frames, counters, mode = decode_capture(args.capture, telemetry=args.telemetry)
    if args.out:
        save_frames_npz(args.out, frames, counters, mode)
    print(json.dumps({'capture': args.capture, 'telemetry': mode, 'frames': len(frames),
                      'counters': counters}, indent=1))
    return 0


def bench_two_cameras(seconds):
    """Parse and assemble ``seconds`` of two recorded camera streams; returns timings."""
    import os
    import tempfile
    results = {}
    with tempfile.TemporaryDirectory() as folder:
        paths = []
        for side, seed in (('left', 1), ('right', 2)):
            path = os.path.join(folder, f'{side}.stcap')
            simulate_capture(path, seconds, 'footer', None, seed)
            paths.append(path)
        started = time.process_time()
        frames = 0
        for path in paths:
            decoded, _, _ = decode_capture(path, telemetry='footer')
            frames += len(decoded)
        elapsed = time.process_time() - started
    results['stream_seconds'] = seconds
    results['cameras'] = 2
    results['unique_frames'] = frames
    results['cpu_seconds'] = elapsed
    # Both cameras stream at once: `seconds` of real time cost `elapsed` CPU seconds.
    results['real_time_factor'] = seconds / elapsed
    return results


def command_bench(args):
    """``st-stereo lepton bench``: parsing + assembly speed vs real time, two cameras."""
    result = bench_two_cameras(args.seconds)
    print('| stream | cameras | unique frames | CPU s (one core) | x real time, both cameras |')
    print('|---|---|---|---|---|')
    print(f'| {result["stream_seconds"]} s | 2 | {result["unique_frames"]} | '
          f'{result["cpu_seconds"]:.2f} | {result["real_time_factor"]:.1f} |')
    return 0


def command_faults(args):
    """``st-stereo lepton faults``: the fault matrix as a Markdown table."""
    from st_stereo.lepton.faultbench import fault_matrix_markdown, run_fault_case
    cases = []
    for kind in FAULT_KINDS:
        for rate in (float(r) for r in args.rates.split(',')):
            telemetry = 'footer' if kind == 'ffc_freeze' else 'off'
            cases.append(run_fault_case(kind, rate, telemetry, args.seconds))
    print(fault_matrix_markdown(cases))
    return 0 if all(c.corrupt == 0 and c.ordered for c in cases) else 1


def command_realign(args):
    """``st-stereo lepton realign``: the table of docs/lepton.md (Captures)."""
    from st_stereo.lepton.faultbench import realign_table
    cases = [(0.05, 3, 'off'), (0.05, 4, 'off'), (0.20, 3, 'off'), (0.20, 4, 'off'),
             (0.20, 5, 'footer'), (0.20, 6, 'footer'), (0.20, 5, 'header'),
             (0.20, 6, 'header'), (0.40, 7, 'off')]
    print(realign_table(cases, args.seconds))
    return 0


def add_parser(sub):
    """Add ``lepton`` and its subcommands to the ``st-stereo`` parser."""
    lepton = sub.add_parser('lepton', help='Lepton captures: simulate, decode, bench')
    tools = lepton.add_subparsers(dest='lepton_command', required=True)
    p = tools.add_parser('simulate', help='write a raw capture of a simulated camera')
    p.add_argument('--out', required=True, help='capture file to write')
    p.add_argument('--seconds', type=float, default=10.0)
    p.add_argument('--telemetry', choices=('off', 'header', 'footer'), default='off')
    p.add_argument('--faults', default='', help='kind=rate,... per core frame (kinds: '
                   + ', '.join(FAULT_KINDS) + ')')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--plain', action='store_true',
                   help='write plain concatenated SPI bytes (no header, no stamps)')
    p.set_defaults(handler=command_simulate)
    p = tools.add_parser('decode', help='decode a capture into frames (.npz)')
    p.add_argument('capture')
    p.add_argument('--out', help='frames.npz to write')
    p.add_argument('--telemetry', choices=('off', 'header', 'footer'), default=None,
                   help='telemetry mode (default: from the capture header, or detected)')
    p.set_defaults(handler=command_decode)
    p = tools.add_parser('faults', help='the fault matrix (simulated camera), as a table')
    p.add_argument('--rates', default='0.01,0.05,0.15', help='fault rates per core frame')
    p.add_argument('--seconds', type=float, default=60.0, help='simulated seconds per case')
    p.set_defaults(handler=command_faults)
    p = tools.add_parser('realign', help='plain SPI byte files with lost and extra bytes: '
                         'frames decoded against the simulator ground truth, as a table')
    p.add_argument('--seconds', type=float, default=60.0, help='simulated seconds per case')
    p.set_defaults(handler=command_realign)
    p = tools.add_parser('bench', help='parsing + assembly speed, two cameras')
    p.add_argument('--seconds', type=float, default=60.0, help='seconds of stream per camera')
    p.set_defaults(handler=command_bench)
    return lepton
