"""The frame reader on clean simulated streams: intact frames, stamps, copies, modes."""

import numpy as np
import pytest
from st_stereo.lepton.assembler import FrameAssembler, FrameLayout, LeptonCounters
from st_stereo.lepton.packets import make_discard_packet, make_packet
from st_stereo.lepton.reader import LeptonReader
from st_stereo.lepton.simulator import ArraySource, LeptonSimulator, SyntheticSceneSource


@pytest.mark.parametrize('telemetry', ['off', 'header', 'footer'])
def test_clean_stream_gives_every_unique_frame_intact_and_in_order(telemetry):
    camera = LeptonSimulator(SyntheticSceneSource(3), telemetry=telemetry, phase_s=0.02)
    reader = LeptonReader(camera, telemetry=telemetry)
    frames = [reader.read_frame(1.0) for _ in range(60)]
    for index, frame in enumerate(frames):
        assert frame.index == index
        assert np.array_equal(frame.pixels, camera.intended[index])
        if telemetry != 'off':
            assert frame.telemetry.frame_counter == index
    counters = reader.counters
    assert counters.unique_frames == 60 and counters.frames_aborted == 0
    assert counters.duplicates == counters.frames_completed - 60   # the two copies of each
    assert counters.crc_errors == counters.gaps == counters.resyncs == 0


def test_stamp_is_the_time_packet_0_of_the_unique_frame_was_read():
    camera = LeptonSimulator(SyntheticSceneSource(4), phase_s=0.005)
    reader = LeptonReader(camera)
    for _ in range(30):
        frame = reader.read_frame(1.0)
        ready = camera.phase + 3 * frame.index * camera.period   # first copy's ready time
        assert 0.0 <= frame.stamp - ready < 0.001


def test_raw_counts_are_never_rescaled():
    frames = np.full((4, 60, 80), 16000.0)
    frames[:, 10, 10] = np.arange(4) * 100 + 3
    camera = LeptonSimulator(ArraySource(frames))
    frame = LeptonReader(camera).read_frame(1.0)
    assert frame.pixels.dtype == np.uint16 and frame.pixels[0, 0] == 16000
    assert frame.pixels[10, 10] == 3


def test_agc_mode_gives_8_bit_values():
    camera = LeptonSimulator(SyntheticSceneSource(5), agc=True)
    frame = LeptonReader(camera).read_frame(1.0)
    assert frame.pixels.max() <= 255 and frame.pixels.max() > 100


def test_timeout_returns_none_and_is_counted():
    camera = LeptonSimulator(SyntheticSceneSource(6), phase_s=5.0)   # first frame at t = 5 s
    reader = LeptonReader(camera)
    assert reader.read_frame(0.5) is None
    assert reader.counters.timeouts == 1
    assert camera.now() < 1.0       # the wait was bounded


def _assembler(mode='off'):
    counters = LeptonCounters()
    return FrameAssembler(FrameLayout.for_mode(mode), counters), counters


def test_assembler_discards_between_frames_and_skips_a_partial_first_frame():
    assembler, counters = _assembler()
    assert assembler.feed(make_discard_packet(), 0x0F00, 0.0) is None
    assert assembler.feed(make_packet(7, np.zeros(80)), 7, 0.0) is None   # joined mid-frame
    assert counters.discards == 1 and counters.skipped_packets == 1
    result = None
    for number in range(60):
        result = assembler.feed(make_packet(number, np.full(80, number)), number, 1.0)
    assert result.pixels[59, 0] == 59 and result.stamp == 1.0


@pytest.mark.parametrize('sequence, counter', [
    ([0, 1, 2, 2], 'repeats'), ([0, 1, 3], 'gaps'), ([0, 2, 1], 'gaps'), ([0, 1, 70], 'bad_ids'),
])
def test_assembler_aborts_on_broken_sequences(sequence, counter):
    assembler, counters = _assembler()
    results = [assembler.feed(make_packet(n, np.zeros(80)), n, 0.0) for n in sequence]
    assert FrameAssembler.ABORT in results
    assert getattr(counters, counter) == 1 and counters.frames_aborted == 1


def test_layouts():
    assert FrameLayout.for_mode('header').image_packets[0] == 3
    assert FrameLayout.for_mode('footer').telemetry_packets == (60, 61, 62)
    with pytest.raises(ValueError, match='telemetry mode'):
        FrameLayout.for_mode('sideways')


def test_image_files_and_recordings_feed_the_simulator(thermal_dir, tmp_path):
    from st_stereo.lepton.simulator import RecordingSource
    from st_stereo.sim.plane import ImageFileSource
    source = ImageFileSource([thermal_dir / 'people_lab_180x180.png',
                              thermal_dir / 'ducks.png'])
    camera = LeptonSimulator(source)
    frames = [LeptonReader(camera).read_frame(1.0) for _ in range(1)]
    assert 7800 <= frames[0].pixels.min() and frames[0].pixels.max() <= 8600
    path = tmp_path / 'rec.npz'
    np.savez(path, frames=np.stack([camera.intended[0]] * 3))
    replay = LeptonSimulator(RecordingSource(path))
    assert np.array_equal(LeptonReader(replay).read_frame(1.0).pixels, camera.intended[0])
