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
from st_stereo.lepton.faultbench import run_fault_case
from st_stereo.lepton.reader import LeptonReader
from st_stereo.lepton.simulator import FAULT_KINDS, FaultPlan, LeptonSimulator, \
    SyntheticSceneSource

pytestmark = pytest.mark.slow

SIMULATED_S = 60.0
# Which counter each fault kind must show up in, one count per delivered fault.
EXPECTED_COUNTER = {'crc': 'crc_errors', 'payload': 'crc_errors', 'id': 'gaps',
                    'missing': 'gaps', 'reorder': 'gaps', 'repeat': 'repeats',
                    'discard_burst': None, 'misalign': None, 'stall': None, 'stuck': 'reboots',
                    'ffc_freeze': None}


@pytest.mark.timeout(120)
@pytest.mark.parametrize('rate', [0.01, 0.05, 0.15])
@pytest.mark.parametrize('kind', FAULT_KINDS)
def test_fault_matrix(kind, rate):
    telemetry = 'footer' if kind == 'ffc_freeze' else 'off'
    case = run_fault_case(kind, rate, telemetry, SIMULATED_S)
    counters = case.counters
    delivered = case.delivered
    assert delivered > 0, 'the case injected nothing: raise the rate or the duration'
    assert case.corrupt == 0, 'a frame the camera never sent (or sent otherwise) was emitted'
    assert case.ordered, 'frames out of order'
    assert counters['unique_frames'] == len(case.frames)
    counter = EXPECTED_COUNTER[kind]
    if counter is not None:
        assert counters[counter] == delivered
    if kind == 'discard_burst':
        assert counters['discards_in_frame'] > 0 and counters['frames_aborted'] == 0
    if kind in ('misalign', 'stall'):
        detected = counters['crc_errors'] + counters['gaps'] + counters['repeats'] + \
            counters['bad_ids']
        # The CRC error inside the frame drops it; the misaligned packets after it are found
        # again (bad ID or CRC outside a frame) and resync: one or two detections per fault.
        assert delivered <= detected <= 2 * delivered
        assert counters['resyncs'] + counters['reboots'] >= delivered   # reboot replaces one
    if kind == 'ffc_freeze':
        assert counters['ffc_frames'] > 0
        # Flagged: a frame the camera sent in FFC, and the first one after frozen frames
        # (skipped, the camera's frame counter jumps over them; its level has moved), so a
        # consumer never compares it with the frame before the FFC unawares.
        for before, frame in zip(case.frames, case.frames[1:]):
            skipped = frame.telemetry.frame_counter > before.telemetry.frame_counter + 1
            assert frame.ffc_in_progress == (frame.telemetry.ffc_state == 'in_progress' or
                                             skipped), frame.telemetry.frame_counter
        assert any(f.ffc_in_progress for f in case.frames)
        # The frozen frames repeat pixels already sent: never published a second time.
        sent = {f.pixels.tobytes() for f in case.frames}
        assert len(sent) == len(case.frames) and counters['frozen'] > 0
    # A fault cleared by a resync: back within 300 ms. Faults dense enough to defeat K
    # resyncs in a row (and a stuck camera) are cleared by a CCI reboot, within its bound.
    assert case.recovery_by_resync or case.recovery_through_reboot
    assert max(case.recovery_by_resync, default=0.0) <= 0.3
    assert max(case.recovery_through_reboot, default=0.0) <= case.reboot_bound_s
    if kind == 'stuck':
        assert case.recovery_through_reboot and counters['reboots'] == delivered


@pytest.mark.timeout(120)
def test_ffc_freeze_without_telemetry_is_flagged_as_frozen():
    case = run_fault_case('ffc_freeze', 0.05, 'off', SIMULATED_S)
    assert case.delivered > 0 and case.corrupt == 0
    # The frozen copies repeat the last content: suppressed, counted as frozen, not lost.
    assert case.counters['frozen'] >= 3 * case.delivered


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
