"""
The VoSPI frame reader: transport -> packets -> intact unique frames, never hanging.

``LeptonReader(transport).read_frame(timeout_s)`` returns the next unique frame or None when
the timeout passes; every wait is bounded by the transport's clock. On a broken frame the
reader resynchronises (deassert /CS, idle >= 185 ms, then discards until packet 0), except for
a CRC error inside an otherwise in-sequence frame, which by default only drops that frame and
waits for the next packet 0 (sync is not lost by a CRC error, and the next core frame is 38 ms
away instead of a >= 185 ms resync; ``crc_policy='resync'`` restores the datasheet's
recommendation). After ``max_resyncs`` resyncs in a row without a good frame it reboots the
camera over CCI (when a CCI is given). Copies of a unique frame are suppressed by content (see
``DuplicateFilter``), and frozen frames of a flat-field correction are flagged and counted.

A transport provides ``read(nbytes) -> bytes``, ``idle(seconds)`` (/CS deasserted),
``wait(seconds)`` (no clocking, /CS held), ``now() -> seconds`` and the attributes
``packet_bytes``, ``max_read_bytes`` and ``seconds_per_byte``; a replay of a recording may also
offer ``unread(nbytes)`` to take back the bytes after a broken frame.
"""

import dataclasses

import numpy as np

from st_stereo.lepton.assembler import FrameAssembler, FrameLayout, LeptonCounters
from st_stereo.lepton.packets import CORE_FRAME_PERIOD_S, packet_heads
from st_stereo.lepton.telemetry import parse_telemetry_row_a

RESYNC_IDLE_S = 0.2          # > 185 ms with /CS deasserted (datasheet)


class EndOfStream(Exception):
    """A recorded stream (capture file) has no more bytes."""


@dataclasses.dataclass
class LeptonFrame:
    """A unique frame: raw 14-bit counts, its stamp, telemetry, and flags."""

    pixels: np.ndarray          # (60, 80) uint16, raw counts, never rescaled
    stamp: float                # host time packet 0 of the frame was read, seconds
    index: int                  # unique frames emitted so far by this reader
    telemetry: object = None    # Telemetry or None
    # The camera reported an FFC (imminent or running) on this frame or on a copy or frozen
    # frame read since the previous unique frame.
    ffc_in_progress: bool = False
    segment: int = 0
    # True when ``stamp`` is the acquisition of the unique frame's first copy: the core frame
    # just before it (the previous frame's last copy) was read too. After a resync, a CRC drop
    # or a lost frame the first frame seen may be its second or third copy (38 or 76 ms late).
    stamp_exact: bool = True
    # A recorded frame's own stamp, integer nanoseconds (a bag's header stamp), published as it
    # is: ``stamp`` in float seconds is off by up to a few hundred nanoseconds.
    stamp_ns: int = None


def first_copy_known(previous_stamp, stamp, period_s):
    """Whether a new unique frame at ``stamp`` follows a frame read one core period earlier."""
    return previous_stamp is not None and 0.5 * period_s < stamp - previous_stamp < \
        1.5 * period_s


def in_ffc(telemetry):
    """Whether a frame's telemetry (None without telemetry) says an FFC is imminent or running."""
    return telemetry is not None and telemetry.ffc_state in ('imminent', 'in_progress')


def count_new_frame(duplicates, counters, pixels, ffc):
    """
    Count an assembled frame in ``counters`` (LeptonCounters) and say whether to publish it.

    ``duplicates`` (a DuplicateFilter) tells a unique frame from a copy or an FFC freeze; each
    is counted (``unique_frames``, ``duplicates``, ``frozen``), and every frame the camera
    reports in FFC (``ffc``: its telemetry says imminent or in progress) in ``ffc_frames``.
    Returns ``(unique, ffc)``: whether it is a unique frame, the only kind published, and for
    one its FFC flag: its own ``ffc``, or that of a copy or frozen frame since the previous
    unique one (the first frame after a freeze is flagged: its level moved).
    """
    counters.ffc_frames += bool(ffc)
    duplicates.ffc_since_unique |= bool(ffc)
    kind = duplicates.classify(pixels)
    if kind == 'duplicate':
        counters.duplicates += 1
    elif kind == 'frozen':
        counters.frozen += 1
    else:
        counters.unique_frames += 1
        flag, duplicates.ffc_since_unique = duplicates.ffc_since_unique, False
        return True, flag
    return False, False


class DuplicateFilter:
    """
    Classify assembled frames as unique, duplicate copies, or frozen (FFC) repeats.

    By content: a copy has the pixels of the frame before it; more than ``copies`` identical
    frames in a row is a freeze (FFC). The telemetry frame counter is not trusted for this:
    whether it counts the 27 Hz core frames (then copies carry new counts) or unique frames
    could not be confirmed from a datasheet here, and either way the same pixels must never be
    published twice as two unique frames. (A scene so static that two unique 14-bit frames are
    bit-identical loses the second one, which carries no new information.)
    """

    def __init__(self, copies=2):
        self.copies = copies
        self._last_pixels = None
        self._run = 0
        self.ffc_since_unique = False   # a frame in FFC since the last unique (count_new_frame)

    def classify(self, pixels, telemetry=None):
        """Return 'unique', 'duplicate' or 'frozen' (``telemetry`` is not used, see above)."""
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
    counters : LeptonCounters, optional
        Counters to add to (a camera's counters across reader restarts); default new ones.
    crc_policy : {'drop', 'resync'}
        On a CRC error inside an in-sequence frame: drop the frame and wait for the next
        packet 0 (default; at most ``max_crc_drops`` in a row, then resync), or resync.

    """

    def __init__(self, transport, telemetry='off', cci=None, max_resyncs=3, reboot_wait_s=1.5,
                 no_video_s=0.3, frame_gap_wait=True, copies=2, completion_hook=None,
                 crc_policy='drop', max_crc_drops=3, counters=None):
        if crc_policy not in ('drop', 'resync'):
            raise ValueError(f'crc_policy: expected drop or resync, got {crc_policy!r}')
        self.crc_policy = crc_policy
        self.max_crc_drops = max_crc_drops
        self._crc_drops = 0
        self.transport = transport
        self.layout = FrameLayout.for_mode(telemetry)
        self.counters = counters if counters is not None else LeptonCounters()
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
        self._previous_stamp = None      # stamp of the last intact frame (copies included)

    def close(self):
        """Close the transport and the CCI bus (when they can be closed)."""
        for part in (self.transport, self.cci):
            close = getattr(part, 'close', None)
            if close is not None:
                close()

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
        previous, self._previous_stamp = self._previous_stamp, frame.stamp
        telemetry = None
        if frame.telemetry_payloads:
            telemetry = parse_telemetry_row_a(frame.telemetry_payloads[0])
        unique, ffc = count_new_frame(self.duplicates, self.counters, frame.pixels,
                                      in_ffc(telemetry))
        if not unique:
            return None
        out = LeptonFrame(frame.pixels, frame.stamp, self._unique_index, telemetry, ffc,
                          frame.segment, first_copy_known(previous, frame.stamp,
                                                          CORE_FRAME_PERIOD_S))
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
                assembler = self.assembler
                if self.crc_policy == 'drop' and assembler.abort_cause == 'crc' and \
                        assembler.abort_in_frame and self._crc_drops < self.max_crc_drops:
                    self._crc_drops += 1
                    self.counters.crc_frames_dropped += 1
                else:
                    self._need_resync = True
                    unread = getattr(transport, 'unread', None)
                    if unread is not None:
                        # A recording can take back bytes (a live bus cannot): the search for
                        # packet boundaries starts one byte into the packet before the one that
                        # failed, because a frame's first packet may begin inside a misaligned
                        # packet taken for a discard (discards carry no CRC).
                        unread(len(chunk) - consumed * size + 2 * size - 1)
                        continue
                if consumed < len(ids):
                    self._leftover = chunk[consumed * size:]
                    self._leftover_stamp = start + consumed * seconds_per_packet
                continue
            self._failed_resyncs = 0
            self._crc_drops = 0
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
