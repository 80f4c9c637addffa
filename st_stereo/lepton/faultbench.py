"""
The fault matrix: one simulated camera, one fault kind at one rate, through the reader.

``run_fault_case`` runs a case and measures what the issue asks: corrupt frames (compared
pixel by pixel with what the camera meant to send), order, the counters, and recovery (time
from the last fault to the next intact frame, by resync or through a CCI reboot).
``st-stereo lepton faults`` prints the whole matrix; the tests assert on the same function.
"""

import dataclasses

import numpy as np

from st_stereo.lepton.cci import LeptonCCI
from st_stereo.lepton.fakes import FakeCciRegisters
from st_stereo.lepton.reader import LeptonReader, RESYNC_IDLE_S
from st_stereo.lepton.simulator import FaultPlan, LeptonSimulator, SyntheticSceneSource


class TimedCCI(LeptonCCI):
    """The CCI of a simulated camera, remembering when it rebooted the camera."""

    def __init__(self, camera):
        super().__init__(FakeCciRegisters(camera), sleep=lambda seconds: None)
        self.camera = camera
        self.reboot_times = []

    def reboot(self):
        """Reboot the camera and remember when."""
        self.reboot_times.append(self.camera.now())
        super().reboot()


@dataclasses.dataclass
class FaultCase:
    """Outcome of one fault case."""

    kind: str
    rate: float
    telemetry: str
    delivered: int
    frames: list
    corrupt: int
    ordered: bool
    counters: dict
    recovery_by_resync: list
    recovery_through_reboot: list
    reboot_bound_s: float

    def row(self):
        """Summary row for the fault-matrix table."""
        return {'kind': self.kind, 'rate': self.rate, 'delivered': self.delivered,
                'frames': len(self.frames), 'corrupt': self.corrupt, 'ordered': self.ordered,
                'max_recovery_resync_s': max(self.recovery_by_resync, default=float('nan')),
                'max_recovery_reboot_s': max(self.recovery_through_reboot,
                                             default=float('nan'))}


def _identify(camera, frames, telemetry):
    if telemetry != 'off':
        return [f.telemetry.frame_counter for f in frames]
    lookup = {}
    for unique, pixels in sorted(camera.intended.items(), reverse=True):
        lookup[pixels.tobytes()] = unique       # the first unique index with these pixels
    return [lookup.get(f.pixels.tobytes()) for f in frames]


def _recoveries(camera, completions, reboot_times):
    log = [time for time, _ in camera.delivery_log]
    by_resync, through_reboot = [], []
    for i, fault_time in enumerate(log):
        later = completions[completions > fault_time]
        if len(later) == 0:
            continue
        if i + 1 < len(log) and log[i + 1] < later[0]:
            continue        # another fault came first: measured from that one
        rebooted = any(fault_time <= t <= later[0] for t in reboot_times)
        (through_reboot if rebooted else by_resync).append(float(later[0] - fault_time))
    return by_resync, through_reboot


def run_fault_case(kind, rate, telemetry='off', seconds=60.0, seed=11):
    """Run one fault kind at one rate for ``seconds`` of simulated time."""
    camera = LeptonSimulator(SyntheticSceneSource(seed), telemetry=telemetry, phase_s=0.013,
                             faults=FaultPlan({kind: rate}), seed=seed)
    completions = []
    cci = TimedCCI(camera)
    reader = LeptonReader(camera, telemetry=telemetry, cci=cci,
                          completion_hook=completions.append)
    frames = []
    while camera.now() < seconds:
        frame = reader.read_frame(3.0)
        if frame is not None:
            frames.append(frame)
    indices = _identify(camera, frames, telemetry)
    corrupt = sum(unique is None or not np.array_equal(frame.pixels, camera.intended[unique])
                  for frame, unique in zip(frames, indices))
    known = [i for i in indices if i is not None]
    by_resync, through_reboot = _recoveries(camera, np.array(completions), cci.reboot_times)
    bound = (reader.max_resyncs + 1) * (reader.no_video_s + RESYNC_IDLE_S + 0.05) + \
        reader.reboot_wait_s + 0.1
    return FaultCase(kind, rate, telemetry, camera.delivered[kind], frames, corrupt,
                     all(a < b for a, b in zip(known, known[1:])), reader.counters.as_dict(),
                     by_resync, through_reboot, bound)


def fault_matrix_markdown(cases):
    """Markdown table of fault cases."""
    lines = ['| fault | rate / frame | delivered | unique frames | corrupt | in order | '
             'counted as | max recovery by resync (s) | max recovery via reboot (s) |',
             '|---|---|---|---|---|---|---|---|---|']
    for case in cases:
        row = case.row()
        counted = ', '.join(f'{k} {v}' for k, v in case.counters.items()
                            if v and k in ('crc_errors', 'gaps', 'repeats', 'bad_ids',
                                           'discards_in_frame', 'frozen', 'ffc_frames',
                                           'stalled_frames', 'resyncs', 'reboots'))
        lines.append(f'| {case.kind} | {case.rate} | {case.delivered} | {row["frames"]} | '
                     f'{case.corrupt} | {"yes" if case.ordered else "NO"} | {counted} | '
                     f'{row["max_recovery_resync_s"]:.3f} | {row["max_recovery_reboot_s"]:.3f} |')
    return '\n'.join(lines)


# --- plain SPI byte files: realignment after lost or extra bytes --------------------------
REALIGN_FAULTS = ('crc', 'missing', 'misalign', 'repeat', 'discard_burst')


def write_plain_byte_capture(path, total_rate, seed, telemetry='off', seconds=60.0):
    """
    Write what a live reader read as plain concatenated SPI bytes (as other tools record).

    Faults ``REALIGN_FAULTS`` in equal shares of ``total_rate`` per core frame. Returns the
    simulated camera: its ``intended`` and ``intact`` are the ground truth of a decoder.
    """
    from st_stereo.lepton.capture import record_camera
    rates = {kind: total_rate / len(REALIGN_FAULTS) for kind in REALIGN_FAULTS}
    camera = LeptonSimulator(SyntheticSceneSource(seed), telemetry=telemetry,
                             faults=FaultPlan(rates), seed=seed, phase_s=0.011)
    record_camera(camera, path, seconds, telemetry, plain=True)
    return camera


def score_decoded(camera, decoded_pixels):
    """Return {intact, decoded_intact, corrupt, twice} of decoded frames against the camera."""
    sent = {pixels.tobytes() for pixels in camera.intended.values()}
    intact = {camera.intended[unique].tobytes() for unique, copies in camera.intact.items()
              if copies > 0}
    decoded = [pixels.tobytes() for pixels in decoded_pixels]
    return {'intact': len(intact), 'decoded_intact': len(intact & set(decoded)),
            'corrupt': sum(pixels not in sent for pixels in decoded),
            'twice': len(decoded) - len(set(decoded))}


def realign_table(cases, seconds=60.0):
    """Markdown table of plain-byte decoding for ``cases`` of (total_rate, seed, telemetry)."""
    import os
    import tempfile
    import time
    from st_stereo.lepton.capture import decode_capture
    lines = ['| total fault rate | seed | telemetry | frames with an intact copy | decoded of '
             'them | corrupt | twice | bytes skipped | decode time |',
             '|---:|---:|---|---:|---:|---:|---:|---:|---:|']
    with tempfile.TemporaryDirectory() as folder:
        for total_rate, seed, telemetry in cases:
            path = os.path.join(folder, 'plain.bin')
            camera = write_plain_byte_capture(path, total_rate, seed, telemetry, seconds)
            start = time.perf_counter()
            frames, counters, _ = decode_capture(path)
            elapsed = time.perf_counter() - start
            score = score_decoded(camera, [frame.pixels for frame in frames])
            share = score['decoded_intact'] / max(score['intact'], 1)
            lines.append(f'| {100 * total_rate:.0f} % | {seed} | {telemetry} | '
                         f'{score["intact"]} | {score["decoded_intact"]} ({100 * share:.1f} %)'
                         f' | {score["corrupt"]} | {score["twice"]} | '
                         f'{counters["bytes_skipped_realigning"]:,} | {elapsed:.1f} s |')
    return '\n'.join(lines)
