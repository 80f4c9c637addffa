"""
Byte-accurate simulator of a Lepton 2 on VoSPI, with seeded fault injection.

The simulator is a transport (``read``, ``idle``, ``wait``, ``now``): it returns exactly the
bytes a camera clocks out at the simulated time. Core frames are ready every ``1 / core_hz``
seconds of the camera's own clock (drift and phase per camera); every unique frame is output
three times (itself and two copies); between frames the camera sends discard packets. Every
frame must be read, each before the next one is ready: a skipped or unfinished frame loses
sync, and the camera then sends garbage until the host idles /CS for more than 185 ms.

Faults (``FaultPlan``) are drawn per core frame with a seeded generator; the ledger
``delivered`` counts only faults that reached the host (a fault in a frame the reader never
clocks out does not count), with the time each was delivered. ``intact`` counts, per unique
frame, the copies clocked out whole with every packet intact: the ground truth of what a decoder of
the recorded bytes could recover.
"""

import collections
import dataclasses

import numpy as np

from st_stereo.lepton.assembler import FrameLayout
from st_stereo.lepton.packets import (COPIES_PER_UNIQUE_FRAME, CORE_FRAME_HZ, encode_frame_packets,
                                      make_discard_packet, make_packet, PAYLOAD_BYTES,
                                      RAW14_PACKET_BYTES)
from st_stereo.lepton.telemetry import encode_telemetry_row_a

RESYNC_MIN_IDLE_S = 0.185
FAULT_KINDS = ('discard_burst', 'crc', 'id', 'payload', 'missing', 'repeat', 'reorder',
               'misalign', 'stall', 'stuck', 'ffc_freeze')
# Faults that damage or lose a packet of the frame. The others leave every packet intact (a
# repeated or reordered packet, discards inside the frame, a frozen image): such a copy counts
# as intact although this project's assembler drops a frame with a repeated or reordered
# packet, which makes ``intact`` a strict ground truth.
DAMAGING_FAULTS = ('crc', 'id', 'payload', 'missing', 'misalign', 'stall', 'stuck')


@dataclasses.dataclass(frozen=True)
class FaultPlan:
    """Probability per core frame of each fault kind (at most one fault per frame)."""

    rates: dict = dataclasses.field(default_factory=dict)
    stall_s: float = 0.09          # host stall mid-frame: longer than two frame periods
    misalign_max_bytes: int = 163
    discard_burst_max: int = 12
    ffc_core_frames: int = 23      # frozen core frames of a flat-field correction
    ffc_offset_counts: int = 25    # image level jump after the correction

    def __post_init__(self):
        """Check the fault names and rates."""
        for kind, rate in self.rates.items():
            if kind not in FAULT_KINDS:
                raise ValueError(f'fault plan: unknown fault {kind!r}; known: '
                                 f'{", ".join(FAULT_KINDS)}')
            if not 0.0 <= rate <= 1.0:
                raise ValueError(f'fault plan: rate of {kind} must be in [0, 1], got {rate}')
        if sum(self.rates.values()) > 1.0:
            raise ValueError('fault plan: the rates must sum to at most 1 (one fault a frame)')


class ArraySource:
    """Frames from an array (n, 60, 80), repeated cyclically."""

    def __init__(self, frames):
        frames = np.asarray(frames)
        if frames.ndim != 3 or frames.shape[1:] != (60, 80):
            raise ValueError(f'frame source: expected frames of 60x80, got shape {frames.shape}')
        self.frames = frames

    def frame(self, index):
        """Return frame ``index`` (cyclic) as float counts."""
        return self.frames[index % len(self.frames)]


class RecordingSource(ArraySource):
    """Frames of a decoded recording (``st-stereo lepton decode --out frames.npz``)."""

    def __init__(self, path):
        with np.load(path) as data:
            if 'frames' not in data:
                raise ValueError(f'{path}: no "frames" array (expected a decoded recording)')
            super().__init__(data['frames'])


class SyntheticSceneSource:
    """
    A warm blob walking over a textured background, with temporal noise.

    All frames differ, so copies can be told from new frames by content, as on a real sensor.
    """

    def __init__(self, seed=0, base_counts=8000.0, noise_counts=4.0):
        rng = np.random.default_rng(seed)
        y, x = np.mgrid[0:60, 0:80]
        self.background = base_counts + 30.0 * np.sin(x / 9.0) + 20.0 * np.cos(y / 7.0) + \
            rng.normal(0.0, 3.0, (60, 80))
        self.y, self.x = y, x
        # A bank of temporal-noise fields, drawn once; frame i uses field i mod 17 (prime, so
        # the noise never lines up with the blob's motion period).
        self.noise = rng.normal(0.0, noise_counts, (17, 60, 80))

    def frame(self, index):
        """Return frame ``index`` as float counts."""
        cx = 40.0 + 25.0 * np.sin(index / 40.0)
        cy = 30.0 + 12.0 * np.cos(index / 55.0)
        blob = 400.0 * np.exp(-((self.x - cx) ** 2 / 30.0 + (self.y - cy) ** 2 / 60.0))
        return self.background + blob + self.noise[index % 17]


class LeptonSimulator:
    """
    One simulated Lepton 2 behind a VoSPI transport interface.

    Parameters
    ----------
    source : object
        Has ``frame(index) -> (60, 80) counts``: ``ArraySource``, ``SyntheticSceneSource``,
        or any recording.
    telemetry : {'off', 'header', 'footer'}
    agc : bool
        AGC on: 8-bit values in the 16-bit words; off: raw 14-bit counts.
    core_hz : float
        Core frame rate (each unique frame is output three times).
    drift_ppm, phase_s : float
        Camera clock rate error and the time of its first frame, host seconds.
    spi_hz : float
        SPI clock: every byte read advances the simulated time by 8 / spi_hz.
    faults : FaultPlan, optional
    seed : int
    boot_s : float
        Time after a CCI reboot before video starts.
    keep_intended : bool
        Remember every unique frame sent (``intended``) and the copies of each sent intact
        (``intact``) for frame-by-frame checks; off for long runs (they grow by 9.6 kB a
        frame, and ``intact`` alone by about 70 bytes).

    """

    packet_bytes = RAW14_PACKET_BYTES

    def __init__(self, source, telemetry='off', agc=False, core_hz=CORE_FRAME_HZ, drift_ppm=0.0,
                 phase_s=0.0, spi_hz=20e6, faults=None, seed=0, boot_s=1.0,
                 max_read_bytes=4096, serial=0x1234, keep_intended=True):
        self.source = source
        self.layout = FrameLayout.for_mode(telemetry)
        self.agc = agc
        self.period = 1.0 / (core_hz * (1.0 + drift_ppm * 1e-6))
        self.phase = phase_s
        self.seconds_per_byte = 8.0 / spi_hz
        self.max_read_bytes = max_read_bytes
        self.faults = faults or FaultPlan()
        self.rng = np.random.default_rng(seed)
        self.boot_s = boot_s
        self.serial = serial
        self.time = 0.0
        self.delivered = collections.Counter()
        self.delivery_log = []       # (time, kind) of every fault that reached the host
        self.intended = {}           # unique index -> pixels the camera meant to send
        self.intact = collections.Counter()   # unique index -> copies sent whole, fault-free
        self._frame_unique = None    # unique index of the frame being clocked out
        self._frame_clean = False    # no transmission fault drawn for it
        self._done_unique = None     # a clean frame whose last packet is still being clocked
        self._keep_intended = keep_intended
        self._pending = b''
        self._frame_packets = None   # packets of the frame being clocked out
        self._frame_blob = None      # the same, joined, when the frame has no fault
        self._frame_faults = {}      # packet position -> fault kind (ledger on delivery)
        self._position = 0
        self._next_core = 0
        self._sync_lost = False
        self._stuck = False
        self._booted_at = 0.0
        self._ffc_left = 0
        self._ffc_pixels = None
        self._level_offset = 0
        self._cache = (None, None)
        self._blob_cache = (None, b'')

    # --- transport interface ------------------------------------------------------------
    def now(self):
        """Host time, seconds."""
        return self.time

    def wait(self, seconds):
        """Stop clocking with /CS held for ``seconds``."""
        self.time += max(0.0, seconds)

    def idle(self, seconds):
        """Deassert /CS and idle; more than 185 ms resynchronises the camera."""
        self.time += max(0.0, seconds)
        if seconds >= RESYNC_MIN_IDLE_S:
            self._sync_lost = False
            self._pending = b''
            self._done_unique = None       # a last packet cut short: not sent whole
            self._frame_packets = None
            self._next_core = max(self._next_core, self._core_index_ready(self.time) + 1)

    def read(self, nbytes):
        """Clock out ``nbytes`` bytes."""
        parts = []
        remaining = nbytes
        seconds_per_byte = self.seconds_per_byte
        while remaining > 0:
            if self._pending:
                piece = self._pending[:remaining]
                self._pending = self._pending[remaining:]
            else:
                piece = self._fast_bytes(remaining)
                if not piece:
                    packet = self._next_packet()
                    piece, self._pending = packet[:remaining], packet[remaining:]
            if self._done_unique is not None and not self._pending:
                if self._keep_intended:
                    self.intact[self._done_unique] += 1
                self._done_unique = None
            parts.append(piece)
            remaining -= len(piece)
            self.time += len(piece) * seconds_per_byte
        return b''.join(parts)

    def _fast_bytes(self, remaining):
        """
        Return whole packets that need no per-packet decision, or b'' when one is needed.

        That is discards before the next frame is ready, or a run of a fault-free frame that
        ends before the next frame is ready.
        """
        size = RAW14_PACKET_BYTES
        count = remaining // size
        if not count or self._stuck or self._sync_lost or self._booted_at > 0 and \
                self.time < self._booted_at + self.boot_s:
            return b''
        packet_time = size * self.seconds_per_byte
        if self._frame_packets is not None:
            if self._frame_blob is None or self._frame_faults:
                return b''
            count = min(count, len(self._frame_packets) - self._position)
            if self.time + count * packet_time >= self._core_time(self._next_core):
                return b''
            start = self._position * size
            self._position += count
            if self._position >= len(self._frame_packets):
                self._frame_done()
            return self._frame_blob[start:start + count * size]
        ready_at = self._core_time(self._next_core)
        if self.time >= ready_at:
            return b''
        count = min(count, int(np.ceil((ready_at - self.time) / packet_time)))
        return make_discard_packet(self._next_core & 0xFF) * count

    # --- camera control (the fake CCI calls these) ---------------------------------------
    def reboot(self):
        """Reboot: clears every stuck or lost state; video resumes after ``boot_s``."""
        self._stuck = False
        self._sync_lost = False
        self._pending = b''
        self._done_unique = None           # a last packet cut short: not sent whole
        self._frame_packets = None
        self._booted_at = self.time
        self._next_core = self._core_index_ready(self.time + self.boot_s) + 1

    def run_ffc(self):
        """Start a flat-field correction now (frozen frames, then a level jump)."""
        self._ffc_left = self.faults.ffc_core_frames

    # --- the camera ----------------------------------------------------------------------
    def _core_time(self, index):
        return self.phase + index * self.period

    def _core_index_ready(self, time):
        return int(np.floor((time - self.phase) / self.period))

    def _garbage(self):
        return self.rng.integers(0, 256, RAW14_PACKET_BYTES, dtype=np.uint8).tobytes()

    def _next_packet(self):
        now = self.time
        if self._stuck or now < self._booted_at + self.boot_s and self._booted_at > 0:
            return make_discard_packet()
        if self._sync_lost:
            return self._garbage()
        if self._frame_packets is not None:
            core = self._next_core - 1
            if now >= self._core_time(core + 1):
                return self._lose_sync()          # frame not finished before the next one
            return self._emit_frame_packet()
        ready = self._core_index_ready(now)
        if ready < self._next_core:
            return make_discard_packet(self._next_core & 0xFF)
        if ready > self._next_core:
            return self._lose_sync()              # a frame was skipped
        self._start_frame(self._next_core)
        self._next_core += 1
        return self._emit_frame_packet()

    def _lose_sync(self):
        self._sync_lost = True
        self._frame_packets = None
        return self._garbage()

    def _emit_frame_packet(self):
        position = self._position
        kind = self._frame_faults.pop(position, None)
        if kind is not None:
            if kind == 'stall':
                # The host stalls mid-frame (the fault is logged when it resumes).
                self.time += self.faults.stall_s
            self.delivered[kind] += 1
            self.delivery_log.append((self.time, kind))
            if kind == 'stall':
                return self._lose_sync()
            if kind == 'stuck':
                self._stuck = True
                self._frame_packets = None
                return make_discard_packet()
        packet = self._frame_packets[position]
        self._position += 1
        if self._position >= len(self._frame_packets):
            self._frame_done()
        return packet

    def _frame_done(self):
        # Counted in ``intact`` once the last byte is clocked out (``read``).
        self._frame_packets = None
        if self._frame_clean:
            self._done_unique = self._frame_unique

    def unique_pixels(self, unique):
        """Return the pixels of a unique frame as sent (raw 14-bit, or 8-bit with AGC)."""
        if self._ffc_left > 0 and self._ffc_pixels is not None:
            return self._ffc_pixels
        counts = np.asarray(self.source.frame(unique), dtype=np.float64) + self._level_offset
        if self.agc:
            low, high = np.percentile(counts, [1, 99])
            counts = (counts - low) * 255.0 / max(high - low, 1.0)
            return np.clip(np.round(counts), 0, 255).astype(np.uint16)
        return np.clip(np.round(counts), 0, 16383).astype(np.uint16)

    def _frame_packets_for(self, unique):
        cached_unique, packets = self._cache
        if cached_unique == unique:
            return packets
        pixels = self.unique_pixels(unique)
        ffc_state = 'in_progress' if self._ffc_left > 0 else 'complete'
        if self._keep_intended:
            self.intended[unique] = pixels
        layout = self.layout
        payloads = np.zeros((layout.packets, 80), dtype=np.uint16)
        payloads[list(layout.image_packets)] = pixels
        if layout.telemetry_packets:
            row_a = encode_telemetry_row_a(
                unique, uptime_ms=int(self.time * 1000), fpa_temperature_k=300.0 +
                0.001 * unique, ffc_state=ffc_state, agc=self.agc, serial=self.serial,
                frame_mean=int(pixels.mean()))
            payloads[layout.telemetry_packets[0]] = np.frombuffer(row_a, dtype='>u2')
        blob = encode_frame_packets(payloads)
        size = RAW14_PACKET_BYTES
        packets = [blob[i * size:(i + 1) * size] for i in range(layout.packets)]
        self._cache = (unique, packets)
        self._blob_cache = (unique, blob)
        return packets

    def _start_frame(self, core):
        unique, copy = divmod(core, COPIES_PER_UNIQUE_FRAME)
        if copy == 0 and self._ffc_left > 0:
            self._ffc_left -= COPIES_PER_UNIQUE_FRAME
            if self._ffc_left <= 0:
                self._level_offset += self.faults.ffc_offset_counts
                self._ffc_pixels = None
        packets = self._frame_packets_for(unique)
        self._frame_faults = {}
        self._frame_blob = self._blob_cache[1]
        kind = self._draw_fault()
        if kind is not None:
            packets = self._inject(kind, packets, unique, copy)
            if self._frame_faults:
                self._frame_blob = None
        self._frame_unique = unique
        self._frame_clean = kind not in DAMAGING_FAULTS
        self._frame_packets = packets
        self._position = 0

    def _draw_fault(self):
        rates = self.faults.rates
        if not rates:
            return None
        draw = self.rng.random()
        for kind, rate in rates.items():
            if draw < rate:
                return kind
            draw -= rate
        return None

    def _inject(self, kind, packets, unique, copy):
        rng = self.rng
        count = len(packets)
        position = int(rng.integers(1, count - 1))
        if kind == 'ffc_freeze':
            if copy == 0 and self._ffc_left <= 0:
                self._ffc_pixels = self.unique_pixels(unique)
                self._ffc_left = self.faults.ffc_core_frames
                self.delivered[kind] += 1
                self.delivery_log.append((self.time, kind))
            return packets
        packets = list(packets)
        if kind in ('stall', 'stuck'):
            self._frame_faults[position] = kind
            return packets
        if kind == 'crc':
            p = bytearray(packets[position])
            p[2] ^= 0x5A
            packets[position] = bytes(p)
        elif kind == 'payload':
            p = bytearray(packets[position])
            p[4 + int(rng.integers(0, PAYLOAD_BYTES))] ^= 0xFF
            packets[position] = bytes(p)
        elif kind == 'id':
            wrong = (position + int(rng.integers(2, count - 1))) % count
            payload = packets[position][4:]
            packets[position] = make_packet(wrong, payload)
        elif kind == 'missing':
            del packets[position]
        elif kind == 'repeat':
            packets.insert(position + 1, packets[position])
            position += 1
        elif kind == 'reorder':
            packets[position], packets[position + 1] = packets[position + 1], packets[position]
        elif kind == 'discard_burst':
            burst = [make_discard_packet() for _ in range(
                int(rng.integers(1, self.faults.discard_burst_max + 1)))]
            packets[position:position] = burst
        elif kind == 'misalign':
            shift = int(rng.integers(1, self.faults.misalign_max_bytes + 1))
            packets[position] = rng.integers(0, 256, shift, dtype=np.uint8).tobytes() + \
                packets[position]
        self._frame_faults[position] = kind
        # The ledger entry is made when the faulty packet is clocked out; the packet itself
        # is served by _emit_frame_packet from the modified list.
        return packets
