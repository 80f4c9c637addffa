"""
Fault matrix: every fault kind at several rates through simulator -> reader.

For each case: zero corrupt frames (every emitted frame equals, pixel by pixel, what the camera
meant to send for it), frames in order, every fault that reached the host counted in its own
counter, and recovery (the next intact frame after the last fault) within 300 ms of simulated
time; a stuck camera recovers through K resyncs and a CCI reboot. Each case is bounded by a
timeout in simulated time (60 s) and in wall time (pytest-timeout).
"""

import numpy as np
import pytest
from st_stereo.lepton.cci import FakeCciRegisters, LeptonCCI
from st_stereo.lepton.reader import LeptonReader, RESYNC_IDLE_S
from st_stereo.lepton.simulator import FAULT_KINDS, FaultPlan, LeptonSimulator, \
    SyntheticSceneSource

SIMULATED_S = 60.0
# Which counter each fault kind must show up in, one count per delivered fault.
EXPECTED_COUNTER = {'crc': 'crc_errors', 'payload': 'crc_errors', 'id': 'gaps',
                    'missing': 'gaps', 'reorder': 'gaps', 'repeat': 'repeats',
                    'discard_burst': None, 'misalign': None, 'stall': None, 'stuck': 'reboots',
                    'ffc_freeze': None}


class TimedCCI(LeptonCCI):
    """The CCI of a simulated camera, remembering when it rebooted the camera."""

    def __init__(self, camera):
        super().__init__(FakeCciRegisters(camera), sleep=lambda s: None)
        self.camera = camera
        self.reboot_times = []

    def reboot(self):
        self.reboot_times.append(self.camera.now())
        super().reboot()


def run_case(kind, rate, telemetry, seed=11):
    camera = LeptonSimulator(SyntheticSceneSource(seed), telemetry=telemetry, phase_s=0.013,
                             faults=FaultPlan({kind: rate}), seed=seed)
    completions = []
    cci = TimedCCI(camera)
    reader = LeptonReader(camera, telemetry=telemetry, cci=cci,
                          completion_hook=completions.append)
    frames = []
    while camera.now() < SIMULATED_S:
        frame = reader.read_frame(3.0)
        if frame is not None:
            frames.append(frame)
    reader.reboot_times = cci.reboot_times
    return camera, reader, frames, np.array(completions)


def identify(camera, frames, telemetry):
    if telemetry != 'off':
        return [f.telemetry.frame_counter for f in frames]
    lookup = {}
    for unique, pixels in sorted(camera.intended.items(), reverse=True):
        lookup[pixels.tobytes()] = unique       # first unique index with these pixels
    return [lookup.get(f.pixels.tobytes()) for f in frames]


def recovery_times(camera, completions, reboot_times):
    """Time from each fault to the next intact frame: (by resync, through a reboot)."""
    log = [time for time, _ in camera.delivery_log]
    by_resync, through_reboot = [], []
    for i, fault_time in enumerate(log):
        later = completions[completions > fault_time]
        if len(later) == 0:
            continue
        if i + 1 < len(log) and log[i + 1] < later[0]:
            continue        # another fault came first: measure from that one
        rebooted = any(fault_time <= t <= later[0] for t in reboot_times)
        (through_reboot if rebooted else by_resync).append(later[0] - fault_time)
    return by_resync, through_reboot


@pytest.mark.timeout(120)
@pytest.mark.parametrize('rate', [0.01, 0.05, 0.15])
@pytest.mark.parametrize('kind', FAULT_KINDS)
def test_fault_matrix(kind, rate):
    telemetry = 'footer' if kind == 'ffc_freeze' else 'off'
    camera, reader, frames, completions = run_case(kind, rate, telemetry)
    counters = reader.counters
    delivered = camera.delivered[kind]
    assert delivered > 0, 'the case injected nothing: raise the rate or the duration'
    indices = identify(camera, frames, telemetry)
    for frame, unique in zip(frames, indices):
        assert unique is not None, 'a frame that the camera never sent was emitted'
        assert np.array_equal(frame.pixels, camera.intended[unique])
    assert all(a < b for a, b in zip(indices, indices[1:])), 'frames out of order'
    assert counters.unique_frames == len(frames)
    counter = EXPECTED_COUNTER[kind]
    if counter is not None:
        assert getattr(counters, counter) == delivered
    if kind == 'discard_burst':
        assert counters.discards_in_frame > 0 and counters.frames_aborted == 0
    if kind in ('misalign', 'stall'):
        detected = counters.crc_errors + counters.gaps + counters.repeats + counters.bad_ids
        assert detected == delivered
        assert counters.resyncs + counters.reboots >= delivered   # a reboot replaces a resync
    if kind == 'ffc_freeze':
        assert counters.ffc_frames > 0
        assert all(f.ffc_in_progress == (f.telemetry.ffc_state == 'in_progress')
                   for f in frames)
    by_resync, through_reboot = recovery_times(camera, completions, reader.reboot_times)
    # A fault cleared by a resync: back within 300 ms. Faults dense enough to defeat K
    # resyncs in a row (and a stuck camera) are cleared by a CCI reboot, within its bound.
    reboot_bound = (reader.max_resyncs + 1) * (reader.no_video_s + RESYNC_IDLE_S + 0.05) + \
        reader.reboot_wait_s + 0.1
    assert by_resync or through_reboot
    assert max(by_resync, default=0.0) <= 0.3
    assert max(through_reboot, default=0.0) <= reboot_bound
    if kind == 'stuck':
        assert through_reboot and counters.reboots == delivered


@pytest.mark.timeout(120)
def test_ffc_freeze_without_telemetry_is_flagged_as_frozen():
    camera, reader, frames, _ = run_case('ffc_freeze', 0.05, 'off')
    assert camera.delivered['ffc_freeze'] > 0
    # The frozen copies repeat the last content: suppressed, counted as frozen, not lost.
    assert reader.counters.frozen >= 3 * camera.delivered['ffc_freeze']


@pytest.mark.timeout(120)
def test_header_telemetry_under_mixed_faults():
    rates = {'crc': 0.03, 'missing': 0.03, 'misalign': 0.02, 'stall': 0.01}
    camera = LeptonSimulator(SyntheticSceneSource(9), telemetry='header', phase_s=0.02,
                             faults=FaultPlan(rates), seed=5)
    reader = LeptonReader(camera, telemetry='header')
    frames = []
    while camera.now() < SIMULATED_S:
        frame = reader.read_frame(3.0)
        if frame is not None:
            frames.append(frame)
    for frame in frames:
        assert np.array_equal(frame.pixels, camera.intended[frame.telemetry.frame_counter])
    assert len(frames) > 0.5 * SIMULATED_S * 26.4 / 3
    assert sum(camera.delivered.values()) > 20


def test_fault_plan_is_validated():
    with pytest.raises(ValueError, match='unknown fault'):
        FaultPlan({'cosmic_ray': 0.1})
    with pytest.raises(ValueError, match='sum to at most 1'):
        FaultPlan({'crc': 0.7, 'missing': 0.7})
