#!/usr/bin/env python3
"""
Coverage-guided fuzzing (atheris, libFuzzer) of the readers of untrusted bytes.

    .ci/fuzz.py [TARGET ...] [--seconds N] [--runs N] [--rss-mb MB] [--jobs N] [--keep DIR]

Targets (default all):
  vospi        the VoSPI packet/frame decoder (LeptonReader + FrameAssembler) on any bytes,
               as a plain SPI byte capture
  capture      capture file parsing and decoding (our STLEPCAP format and plain bytes)
  calibration  camera_calibration YAML loading (bytes, any encoding)
  bag_metadata a rosbag2 bag's metadata.yaml (opened with the rosbags-based reader)

Each target runs in its own process under libFuzzer, seeded with valid inputs, and may only
raise its documented exception (CaptureError, CalibrationError, BagError); anything else is
a crash (the input is saved as crash-* in the working folder). Memory is bounded by
``-rss_limit_mb`` per fuzzing process; the growth of the code under test is measured by
replaying the final corpus without instrumentation. Prints a table: inputs, seconds,
inputs/s, peak RSS, replay growth, crashes. Exit status 1 when any target crashed. Run it
with the project's virtual environment (.venv/bin/python).
"""

import argparse
import os
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
TARGETS = ('vospi', 'capture', 'calibration', 'bag_metadata')
# Inputs up to a little more than one frame with telemetry (63 packets of 164 bytes).
MAX_LEN = {'vospi': 12000, 'capture': 12000, 'calibration': 8192, 'bag_metadata': 8192}
# Modules instrumented for coverage: the code under test (the YAML parser of calibration files
# is PyYAML's: fuzzed through our loader, not instrumented, which would make it 4x slower).
INSTRUMENT = {'vospi': ['st_stereo'], 'capture': ['st_stereo'], 'calibration': ['st_stereo'],
              'bag_metadata': ['st_stereo', 'rosbags.rosbag2']}
EAGER_IMPORTS = {'bag_metadata': ['rosbags.rosbag2', 'rosbags.rosbag2.metadata',
                                  'rosbags.rosbag2.storage_mcap']}


# --- seeds ----------------------------------------------------------------------------------
def write_seeds(target, folder):
    """Write valid inputs of ``target`` into ``folder`` (the starting corpus)."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if target in ('vospi', 'capture'):
        import numpy as np
        from st_stereo.lepton.capture import CaptureWriter, valid_packet_starts
        from st_stereo.lepton.simulator import FaultPlan
        from st_stereo.lepton.cli import simulate_capture
        with tempfile.TemporaryDirectory() as work:
            for index, mode in enumerate(('off', 'footer', 'header')):
                path = pathlib.Path(work) / f'seed{index}'
                simulate_capture(path, 0.2, mode, FaultPlan({'crc': 0.2, 'misalign': 0.2}),
                                 seed=index, plain=True)
                blob = path.read_bytes()
                # A few discards, then the first frame (the reader polls discards until it).
                starts = valid_packet_starts(blob)
                numbers = np.array([blob[s + 1] | (blob[s] & 0x0F) << 8 for s in starts])
                first = int(starts[numbers == 0][0]) if (numbers == 0).any() else 0
                blob = blob[max(first - 4 * 164, first % 164):][:MAX_LEN['vospi'] - 400]
                if target == 'vospi':
                    (folder / f'seed{index}').write_bytes(blob)
                    continue
                writer = CaptureWriter(folder / f'seed{index}',
                                       {'packet_bytes': 164, 'telemetry': mode,
                                        'spi_hz': 20e6})
                for record, offset in enumerate(range(0, len(blob), 1312)):
                    writer.read(0.001 * record, blob[offset:offset + 1312])
                writer.idle(0.001 * record, 0.19)
                writer.close()
    elif target == 'calibration':
        for path in sorted((ROOT / 'config' / 'calibration').glob('*.yaml')):
            shutil.copy(path, folder / path.name)
    elif target == 'bag_metadata':
        shutil.copy(ROOT / 'data' / 'recordings' / 'office' / 'bag' / 'metadata.yaml',
                    folder / 'recording.yaml')
        talker = ROOT.parent / 'shared' / 'data' / 'rosbag2' / 'talker_mcap_v4'
        if (talker / 'metadata.yaml').exists():
            shutil.copy(talker / 'metadata.yaml', folder / 'talker_v4.yaml')


# --- targets (in the child process) ---------------------------------------------------------
def vospi_target():
    from st_stereo.lepton.capture import CaptureError, decode_parsed_capture

    def one(data):
        try:
            decode_parsed_capture(({}, data, None, 0), '<fuzz>')
        except CaptureError:
            pass
    return one


def capture_target():
    from st_stereo.lepton.capture import CaptureError, decode_parsed_capture, parse_capture

    def one(data):
        try:
            decode_parsed_capture(parse_capture(data, '<fuzz>'), '<fuzz>')
        except CaptureError:
            pass
    return one


def calibration_target():
    from st_stereo.core.calibration.files import calibration_from_bytes, CalibrationError

    def one(data):
        try:
            calibration_from_bytes(data, '<fuzz>')
        except CalibrationError:
            pass
    return one


def bag_metadata_target():
    # The bag folder lives in /dev/shm when there is one: a file write per input.
    from st_stereo.bag_reading import BagError, message_class, open_bag
    base = '/dev/shm' if os.path.isdir('/dev/shm') else None
    folder = pathlib.Path(tempfile.mkdtemp(prefix='fuzz_bag_', dir=base))
    source = ROOT / 'data' / 'recordings' / 'office' / 'bag'
    for path in source.iterdir():
        if path.name != 'metadata.yaml':
            shutil.copy(path, folder / path.name)
    metadata = folder / 'metadata.yaml'

    def one(data):
        metadata.write_bytes(data)
        try:
            reader = open_bag(folder)
        except BagError:
            return
        try:
            for connection in reader.connections:
                try:
                    message_class(connection.msgtype)
                except ImportError:
                    pass
        finally:
            reader.close()
    return one


def child(target, libfuzzer_args):
    import atheris
    import importlib
    with atheris.instrument_imports(include=INSTRUMENT[target]):
        # Modules the code under test imports lazily (inside functions) are imported here, so
        # that they are instrumented too.
        for module in EAGER_IMPORTS.get(target, ()):
            importlib.import_module(module)
        one = globals()[f'{target}_target']()
    atheris.Setup([sys.argv[0]] + libfuzzer_args, one)
    atheris.Fuzz()


# --- the parent: run, parse libFuzzer's report, print the table ----------------------------
# atheris' instrumentation itself grows the fuzzing process by up to ~90 kB an input (measured:
# 685 MB after 7,759 VoSPI inputs; 54 MB uninstrumented, and 29 MB flat when the same corpus
# is replayed by plain Python): each child process runs at most CHUNK_RUNS inputs and the
# next one resumes from the corpus on disk. The memory of the code under test is measured
# apart, by replaying the final corpus uninstrumented (``replay_growth_mb``).
CHUNK_RUNS = 10000


def run_child(target, corpus, work, seconds, runs, rss_mb):
    args = [f'-max_total_time={seconds}', f'-rss_limit_mb={rss_mb}',
            f'-max_len={MAX_LEN[target]}', '-print_final_stats=1', '-timeout=30',
            f'-artifact_prefix={work}/crash-{target}-', f'-runs={runs}']
    command = [sys.executable, str(pathlib.Path(__file__).resolve()), '--child', target,
               *args, str(corpus)]
    result = subprocess.run(command, capture_output=True, text=True, cwd=work)
    log = result.stdout + result.stderr
    done = re.findall(r'stat::number_of_executed_units:\s*(\d+)', log)
    # libFuzzer counts the replay of the corpus a child starts from (up to the INITED line):
    # only the inputs after it are new ones.
    inited = re.findall(r'^#(\d+)\s+INITED', log, re.MULTILINE)
    new_inputs = int(done[-1]) - int(inited[0]) if done and inited else 0
    peak = re.findall(r'stat::peak_rss_mb:\s*(\d+)', log)
    return (new_inputs, int(peak[-1]) if peak else 0, result.returncode,
            '\n'.join(log.strip().splitlines()[-25:]))


def replay_growth_mb(target, corpus):
    """Replay a corpus twice in a fresh, uninstrumented process: RSS growth, MB."""
    code = (f'import os, resource, sys; sys.path.insert(0, {str(ROOT / ".ci")!r}); '
            f'import fuzz; one = fuzz.{target}_target(); '
            f'files = sorted(os.listdir({str(corpus)!r})); '
            f'rss = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024; '
            f'[one(open(os.path.join({str(corpus)!r}, f), "rb").read()) for f in files]; '
            f'first = rss(); '
            f'[one(open(os.path.join({str(corpus)!r}, f), "rb").read()) for f in files]; '
            f'print(rss() - first, len(files))')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=ROOT)
    if result.returncode != 0:
        return None, result.stderr.strip().splitlines()[-1:]
    growth, files = result.stdout.split()
    return float(growth), int(files)


def run_target(target, seconds, runs, rss_mb, work):
    corpus = pathlib.Path(work) / f'corpus_{target}'
    write_seeds(target, corpus)
    start = time.monotonic()
    total, peak, row = 0, 0, {'target': target, 'exit': 0, 'log_tail': ''}
    while time.monotonic() - start < seconds and (not runs or total < runs):
        left = seconds - (time.monotonic() - start)
        chunk = CHUNK_RUNS if not runs else min(CHUNK_RUNS, runs - total)
        # -runs counts the replay of the corpus too: add its size, so a child runs ``chunk``
        # new inputs (fewer when the time is up).
        done, child_peak, code, tail = run_child(target, corpus, work, max(int(left), 1),
                                                 chunk + len(os.listdir(corpus)), rss_mb)
        total, peak = total + done, max(peak, child_peak)
        if code != 0 or not done:
            row.update(exit=code, log_tail=tail)
            break
    crashes = sorted(pathlib.Path(work).glob(f'crash-{target}-*'))
    growth, files = replay_growth_mb(target, corpus)
    row.update(runs=total, seconds=round(time.monotonic() - start), peak_rss_mb=peak,
               crashes=[str(path) for path in crashes], replay_growth_mb=growth,
               corpus_files=files)
    return row


def main(argv=None):
    """Fuzz the targets (or, with --child, be one libFuzzer process)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['--child']:
        child(argv[1], argv[2:])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('targets', nargs='*', help=f'of {", ".join(TARGETS)} (default: all)')
    parser.add_argument('--seconds', type=int, default=60, help='time per target')
    parser.add_argument('--runs', type=int, default=0,
                        help='stop a target after N inputs (0: only --seconds)')
    parser.add_argument('--rss-mb', type=int, default=2048,
                        help='memory bound of each fuzzing process')
    parser.add_argument('--jobs', type=int, default=1, help='targets fuzzed at once')
    parser.add_argument('--keep', help='folder for corpora and crash inputs (default: a '
                                       'temporary one, removed unless a target crashed)')
    args = parser.parse_args(argv)
    unknown = sorted(set(args.targets) - set(TARGETS))
    if unknown:
        parser.error(f'unknown target {", ".join(unknown)}; known: {", ".join(TARGETS)}')
    targets = args.targets or list(TARGETS)
    work = os.path.abspath(args.keep or tempfile.mkdtemp(prefix='st_stereo_fuzz_'))
    os.makedirs(work, exist_ok=True)
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        rows = list(pool.map(lambda target: run_target(target, args.seconds, args.runs,
                                                       args.rss_mb, work), targets))
    print('| target | inputs run | seconds | inputs/s | peak RSS of a fuzzing process (MB) | '
          'RSS growth replaying the corpus (MB) | corpus | crashes |')
    print('|---|---:|---:|---:|---:|---:|---:|---:|')
    for row in rows:
        rate = row['runs'] / max(row['seconds'], 1)
        print(f"| {row['target']} | {row['runs']:,} | {row['seconds']} | {rate:.0f} | "
              f"{row['peak_rss_mb']} | {row['replay_growth_mb']} | {row['corpus_files']} | "
              f"{len(row['crashes'])} |")
    failed = [row for row in rows if row['exit'] != 0 or row['crashes'] or not row['runs']
              or row['replay_growth_mb'] is None]
    for row in failed:
        print(f"\n{row['target']}: exit {row['exit']}, crash inputs {row['crashes']}, replay "
              f"{row['corpus_files']}\n{row['log_tail']}", file=sys.stderr)
    if not failed and not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
