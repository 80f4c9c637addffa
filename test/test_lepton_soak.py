"""
Soak: half a simulated hour of two free-running cameras through the readers and the pairing.

15,500+ unique frames per camera (8.8 Hz for 1800 s) with rare faults: no exception, memory
flat (RSS measured after warm-up and at the end), and the counters consistent with each other.
The clocks drift 110 ppm apart (crystals of +-55 ppm), so the cameras' phase slides through
the whole unique-frame period and every pair offset occurs.
"""

import psutil
import pytest
from st_stereo.lepton.pairing import PairSynchronizer
from st_stereo.lepton.reader import LeptonReader
from st_stereo.lepton.simulator import FaultPlan, LeptonSimulator, SyntheticSceneSource

pytestmark = pytest.mark.slow

SOAK_S = 1800.0
RARE_FAULTS = {'crc': 0.001, 'missing': 0.0005, 'misalign': 0.0005, 'stall': 0.0002}


@pytest.mark.timeout(900)
def test_half_an_hour_two_cameras_memory_flat_counters_consistent():
    cameras = {
        'left': LeptonSimulator(SyntheticSceneSource(1), drift_ppm=35.0, phase_s=0.004,
                                faults=FaultPlan(RARE_FAULTS), seed=1, keep_intended=False),
        'right': LeptonSimulator(SyntheticSceneSource(2), drift_ppm=-75.0, phase_s=0.057,
                                 faults=FaultPlan(RARE_FAULTS), seed=2, keep_intended=False),
    }
    readers = {side: LeptonReader(camera) for side, camera in cameras.items()}
    sync = PairSynchronizer(max_delta=0.05)
    process = psutil.Process()
    emitted = {'left': 0, 'right': 0}
    pairs = 0
    rss_warm = None
    while min(camera.now() for camera in cameras.values()) < SOAK_S:
        side = min(cameras, key=lambda s: cameras[s].now())     # the camera that is behind
        frame = readers[side].read_frame(timeout_s=2.0)
        if frame is None:
            continue
        emitted[side] += 1
        pairs += len(sync.push(side, frame))
        if rss_warm is None and emitted[side] == 2000:
            rss_warm = process.memory_info().rss
    pairs += len(sync.flush())     # the end of the stream pairs what still waits
    rss_end = process.memory_info().rss
    growth_mib = (rss_end - rss_warm) / 2 ** 20
    print(f'\nsoak: {emitted} unique frames, {pairs} pairs, RSS {rss_warm / 2 ** 20:.1f} -> '
          f'{rss_end / 2 ** 20:.1f} MiB ({growth_mib:+.1f}), pairing {sync.counters.as_dict()}')
    assert min(emitted.values()) >= 15500
    assert growth_mib < 5.0
    for side, reader in readers.items():
        c = reader.counters
        print(f'{side}: {c.as_dict()} faults delivered {dict(cameras[side].delivered)}')
        assert c.unique_frames == emitted[side]
        assert c.unique_frames + c.duplicates + c.frozen == c.frames_completed
        assert c.frames_completed + c.frames_aborted in (c.frames_started, c.frames_started - 1)
        errors = c.crc_errors + c.gaps + c.repeats + c.bad_ids + c.stalled_frames
        assert errors >= sum(cameras[side].delivered.values())
        assert c.resyncs + c.reboots + c.crc_frames_dropped >= errors
    counters = sync.counters
    assert counters.pairs == pairs
    assert counters.pairs + counters.dropped_left == emitted['left']
    assert counters.pairs + counters.dropped_right == emitted['right']
    assert counters.skew_abs_max <= 0.05
    # The cameras drift 110 ppm apart: over the half hour their phase slides 198 ms, through
    # the whole unique-frame period (113.6 ms), so offsets are spread over +-56.8 ms and the
    # share beyond max_delta (50 ms) cannot pair: about 6.8 / 56.8 = 12 % of the frames.
    assert pairs >= 0.82 * min(emitted.values())
