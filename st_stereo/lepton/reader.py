"""
The VoSPI frame reader: transport -> packets -> intact unique frames, never hanging.

``LeptonReader(transport).read_frame(timeout_s)`` returns the next unique frame or None when
the timeout passes; every wait is bounded by the transport's clock. On any broken frame the
reader resynchronises (deassert /CS, idle >= 185 ms, then discards until packet 0); after
``max_resyncs`` resyncs in a row without a good frame it reboots the camera over CCI (when a CCI
is given). Copies of a unique frame are suppressed (telemetry frame counter when present, else
identical content), and frozen frames of a flat-field correction are flagged and counted.

A transport provides ``read(nbytes) -> bytes``, ``idle(seconds)`` (/CS deasserted),
``wait(seconds)`` (no clocking, /CS held), ``now() -> seconds`` and the attributes
``packet_bytes``, ``max_read_bytes`` and ``seconds_per_byte``.
"""

import dataclasses

import numpy as np

from st_stereo.lepton.assembler import FrameAssembler, FrameLayout, LeptonCounters
from st_stereo.lepton.packets import packet_heads
from st_stereo.lepton.telemetry import parse_telemetry_row_a

RESYNC_IDLE_S = 0.2          # > 185 ms with /CS deasserted (datasheet)
CORE_FRAME_PERIOD_S = 1.0 / 26.4


class EndOfStream(Exception):
    """A recorded stream (capture file) has no more bytes."""


@dataclasses.dataclass
class LeptonFrame:
    """A unique frame: raw 14-bit counts, its stamp, telemetry, and flags."""

    pixels: np.ndarray          # (60, 80) uint16, raw counts, never rescaled
    stamp: float                # host time packet 0 of the frame was read, seconds
    index: int                  # unique frames emitted so far by this reader
    telemetry: object = None    # Telemetry or None
    ffc_in_progress: bool = False
    segment: int = 0


class DuplicateFilter:
    """
    Classify assembled frames as unique, duplicate copies, or frozen (FFC) repeats.

    With telemetry, a copy carries the frame counter of the frame it repeats. Without, a copy
    has identical pixels; more than ``copies`` identical frames in a row is a freeze.
    """

    def __init__(self, copies=2):
        self.copies = copies
        self._last_counter = None
        self._last_pixels = None
        self._run = 0

    def classify(self, pixels, telemetry):
        """Return 'unique', 'duplicate' or 'frozen'."""
        if telemetry is not None:
            if telemetry.frame_counter == self._last_counter:
                return 'duplicate'
            self._last_counter = telemetry.frame_counter
            return 'unique'
        if self._last_pixels is not None and np.array_equal(pixels, self._last_pixels):
            self._run += 1
            return 'duplicate' if self._run <= self.copies else 'frozen'
        self._last_pixels = pixels
        self._run = 0
        return 'unique'


class LeptonReader:
    """
    Read unique, intact frames from one Lepton 2 over a transport.

    Parameters
    ----------
    transport : object
        See the module docstring (SPI device, simulator, capture replay).
    telemetry : {'off', 'header', 'footer'}
        Telemetry mode the camera is in.
    cci : object, optional
        Camera control with a ``reboot()`` method, used after ``max_resyncs`` failed resyncs.
    max_resyncs : int
        Resyncs in a row without a good frame before a CCI reboot.
    reboot_wait_s : float
        Idle time after a reboot before reading again.
    no_video_s : float
        Resynchronise when no frame starts for this long (camera stuck on discards).
    frame_gap_wait : bool
        After a frame, wait most of the gap to the next one instead of clocking discards
        (saves CPU; the wait stays well inside the frame period).
    completion_hook : callable, optional
        Called with the stamp of every intact frame, copies included (recovery timing).

    """

    def __init__(self, transport, telemetry='off', cci=None, max_resyncs=3, reboot_wait_s=1.5,
                 no_video_s=0.3, frame_gap_wait=True, copies=2, completion_hook=None):
        self.transport = transport
        self.layout = FrameLayout.for_mode(telemetry)
        self.counters = LeptonCounters()
        self.assembler = FrameAssembler(self.layout, self.counters)
        self.duplicates = DuplicateFilter(copies)
        self.cci = cci
        self.max_resyncs = max_resyncs
        self.reboot_wait_s = reboot_wait_s
        self.no_video_s = no_video_s
        self.frame_gap_wait = frame_gap_wait
        self.completion_hook = completion_hook
        self._need_resync = False
        self._failed_resyncs = 0
        self._leftover = b''
        self._leftover_stamp = 0.0
        self._last_frame_start = None
        self._last_video = transport.now()
        self._unique_index = 0
        self._unique_stamp = None

    def resync(self):
        """Deassert /CS and idle > 185 ms; reboot over CCI after too many failed resyncs."""
        self.assembler.reset()
        self._leftover = b''
        self._failed_resyncs += 1
        if self._failed_resyncs > self.max_resyncs and self.cci is not None:
            self.cci.reboot()
            self.counters.reboots += 1
            self._failed_resyncs = 0
            self.transport.idle(self.reboot_wait_s)
        else:
            self.transport.idle(RESYNC_IDLE_S)
            self.counters.resyncs += 1
        self._need_resync = False
        self._last_frame_start = None
        self._last_video = self.transport.now()

    def _read_chunk(self):
        transport = self.transport
        size = transport.packet_bytes
        if self._leftover:
            chunk, start = self._leftover, self._leftover_stamp
            self._leftover = b''
            return chunk, start
        if self.assembler.in_frame:
            remaining = self.layout.packets - self.assembler._expected
            count = max(1, min(remaining, transport.max_read_bytes // size))
        else:
            if self.frame_gap_wait and self._last_frame_start is not None:
                # The next frame is ready about one period after the last one started; wake
                # 2 ms early and poll. Waking late is harmless (the camera holds a ready frame
                # until the one after it is ready) but would delay the stamp.
                gap = self._last_frame_start + CORE_FRAME_PERIOD_S - 0.002 - transport.now()
                if gap > 0:
                    transport.wait(gap)
                self._last_frame_start = None
            count = min(8, transport.max_read_bytes // size)
        start = transport.now()
        chunk = transport.read(count * size)
        self.counters.bytes_read += len(chunk)
        if len(chunk) < size:
            raise EndOfStream()
        whole = len(chunk) - len(chunk) % size
        return chunk[:whole], start

    def _handle(self, frame):
        telemetry = None
        if frame.telemetry_payloads:
            telemetry = parse_telemetry_row_a(frame.telemetry_payloads[0])
        kind = self.duplicates.classify(frame.pixels, telemetry)
        if kind == 'duplicate':
            self.counters.duplicates += 1
            return None
        if kind == 'frozen':
            self.counters.frozen += 1
            return None
        ffc = telemetry is not None and telemetry.ffc_state in ('imminent', 'in_progress')
        if ffc:
            self.counters.ffc_frames += 1
        self.counters.unique_frames += 1
        out = LeptonFrame(frame.pixels, frame.stamp, self._unique_index, telemetry, ffc,
                          frame.segment)
        self._unique_index += 1
        return out

    def read_frame(self, timeout_s=1.0):
        """Return the next unique intact frame, or None after ``timeout_s`` (counted)."""
        transport = self.transport
        deadline = transport.now() + timeout_s
        seconds_per_packet = transport.packet_bytes * transport.seconds_per_byte
        size = transport.packet_bytes
        while transport.now() < deadline:
            if self._need_resync:
                self.resync()
                continue
            chunk, start = self._read_chunk()
            ids, crcs = packet_heads(chunk, size)
            consumed, result = self.assembler.feed_chunk(chunk, ids, crcs, 0, start,
                                                         seconds_per_packet, size)
            if result is None:
                assembler = self.assembler
                now = transport.now()
                if assembler.in_frame:
                    # A frame takes ~4 ms; one still open after two core periods never ends
                    # (the camera went silent or stuck mid-frame).
                    if now - assembler.frame_stamp > 2.0 * CORE_FRAME_PERIOD_S:
                        self.counters.stalled_frames += 1
                        assembler.abort()
                        self._need_resync = True
                elif now - self._last_video > self.no_video_s:
                    self.counters.no_video_timeouts += 1
                    self._need_resync = True
                continue
            if result is FrameAssembler.ABORT:
                self._need_resync = True
                continue
            self._failed_resyncs = 0
            self._last_video = transport.now()
            self._last_frame_start = result.stamp
            if self.completion_hook is not None:
                self.completion_hook(result.stamp)
            if consumed < len(ids):
                self._leftover = chunk[consumed * size:]
                self._leftover_stamp = start + consumed * seconds_per_packet
            frame = self._handle(result)
            if frame is not None:
                return frame
        self.counters.timeouts += 1
        return None
