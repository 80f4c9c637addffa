"""
Frame assembly from VoSPI packets: a small state machine, fed one packet at a time.

States: ``waiting`` for packet 0, then ``in_frame`` expecting packets 1, 2, ... in order. A
CRC error, a gap (missing or out-of-order packet), a repeated packet or an impossible packet
number aborts the frame, is counted, and asks the reader to resynchronise; a frame is emitted
only when every packet of it arrived intact and in order. Nothing here does I/O.
"""

import dataclasses

import numpy as np

from st_stereo.lepton.packets import (crc_matches, DISCARD_MASK, IMAGE_ROWS, is_discard,
                                      NUMBER_MASK, packet_crc, packet_number, segment_number,
                                      TELEMETRY_ROWS)

TELEMETRY_MODES = ('off', 'header', 'footer')


@dataclasses.dataclass(frozen=True)
class FrameLayout:
    """Which packets of a frame carry image rows and which carry telemetry rows A, B, C."""

    telemetry: str
    packets: int
    image_packets: tuple
    telemetry_packets: tuple

    @classmethod
    def for_mode(cls, telemetry):
        """Layout of a Lepton 2 frame: 60 packets, or 63 with a telemetry header or footer."""
        if telemetry == 'off':
            return cls('off', IMAGE_ROWS, tuple(range(IMAGE_ROWS)), ())
        if telemetry == 'header':
            return cls('header', IMAGE_ROWS + TELEMETRY_ROWS,
                       tuple(range(TELEMETRY_ROWS, IMAGE_ROWS + TELEMETRY_ROWS)),
                       tuple(range(TELEMETRY_ROWS)))
        if telemetry == 'footer':
            return cls('footer', IMAGE_ROWS + TELEMETRY_ROWS, tuple(range(IMAGE_ROWS)),
                       tuple(range(IMAGE_ROWS, IMAGE_ROWS + TELEMETRY_ROWS)))
        raise ValueError(f'telemetry mode: expected one of {", ".join(TELEMETRY_MODES)}, got '
                         f'{telemetry!r}')


@dataclasses.dataclass
class LeptonCounters:
    """Every packet, frame and loss of one camera stream, by cause (diagnostics)."""

    bytes_read: int = 0
    packets: int = 0
    discards: int = 0
    discards_in_frame: int = 0
    skipped_packets: int = 0
    crc_errors: int = 0
    crc_frames_dropped: int = 0
    gaps: int = 0
    repeats: int = 0
    bad_ids: int = 0
    frames_started: int = 0
    frames_completed: int = 0
    frames_aborted: int = 0
    duplicates: int = 0
    frozen: int = 0
    ffc_frames: int = 0
    unique_frames: int = 0
    resyncs: int = 0
    reboots: int = 0
    no_video_timeouts: int = 0
    stalled_frames: int = 0
    timeouts: int = 0

    def as_dict(self):
        """Return the counters as a plain dict."""
        return dataclasses.asdict(self)


@dataclasses.dataclass
class AssembledFrame:
    """A complete, intact frame: image rows, telemetry payloads, stamp of packet 0."""

    pixels: np.ndarray
    telemetry_payloads: tuple
    stamp: float
    segment: int


class FrameAssembler:
    """
    Assemble frames from packets; ``feed`` returns a frame, ``ABORT`` or None.

    ``ABORT`` means the frame in progress (if any) was dropped and the stream should be
    resynchronised; the cause is in ``counters``.
    """

    ABORT = 'abort'

    def __init__(self, layout, counters):
        self.layout = layout
        self.counters = counters
        self.abort_cause = ''        # why the last ABORT: crc, bad_id, gap, repeat, stalled
        self.abort_in_frame = False  # whether a frame was in progress at that ABORT
        self._rows = [None] * layout.packets
        self._expected = 0
        self._in_frame = False
        self._stamp = 0.0
        self._segment = 0

    @property
    def in_frame(self):
        """Return True between packet 0 and the last packet of a frame."""
        return self._in_frame

    @property
    def frame_stamp(self):
        """Stamp of packet 0 of the frame in progress."""
        return self._stamp

    def abort(self):
        """Drop the frame in progress (counted) and ask for a resync."""
        return self._abort('stalled')

    def reset(self):
        """Forget any frame in progress (after a resync); it is counted as aborted."""
        if self._in_frame:
            self.counters.frames_aborted += 1
        self._in_frame = False
        self._expected = 0

    def _abort(self, cause):
        self.abort_cause = cause
        self.abort_in_frame = self._in_frame
        if self._in_frame:
            self.counters.frames_aborted += 1
        self._in_frame = False
        self._expected = 0
        return self.ABORT

    def feed(self, packet, packet_id, stamp):
        """Feed one packet (bytes) with its ID and read time; see the class docstring."""
        counters = self.counters
        counters.packets += 1
        if is_discard(packet_id):
            if self._in_frame:
                counters.discards_in_frame += 1
            else:
                counters.discards += 1
            return None
        if packet_crc(packet) != ((packet[2] << 8) | packet[3]):
            counters.crc_errors += 1
            return self._abort('crc')
        number = packet_number(packet_id)
        if number >= self.layout.packets:
            counters.bad_ids += 1
            return self._abort('bad_id')
        if not self._in_frame:
            if number != 0:
                counters.skipped_packets += 1
                return None
            self._in_frame = True
            self._expected = 0
            self._stamp = stamp
            self._segment = 0
            counters.frames_started += 1
        if number != self._expected:
            if number == self._expected - 1:
                counters.repeats += 1
                return self._abort('repeat')
            counters.gaps += 1
            return self._abort('gap')
        self._rows[number] = packet
        if number == 20:   # Lepton 3: the segment field is valid on packet 20 only
            self._segment = segment_number(packet_id)
        self._expected += 1
        if self._expected < self.layout.packets:
            return None
        self._in_frame = False
        self._expected = 0
        counters.frames_completed += 1
        return self._complete()

    def feed_chunk(self, chunk, ids, crcs, first, stamps_start, seconds_per_packet, size):
        """
        Feed packets ``first, first + 1, ...`` of a chunk; stop at the first result.

        Same decisions as calling ``feed`` packet by packet, faster (the ID tests of
        ``is_discard`` and ``packet_number`` are inlined on the masks): discards outside a
        frame are counted in bulk, and a run of in-sequence packets is checked with one CRC
        loop. Returns ``(next_index, result)`` with result None when the chunk is exhausted.
        """
        counters = self.counters
        count = len(ids)
        view = memoryview(chunk)
        i = first
        while i < count:
            packet_id = ids[i]
            if not self._in_frame and (packet_id & DISCARD_MASK) == DISCARD_MASK:
                j = i + 1
                while j < count and (ids[j] & DISCARD_MASK) == DISCARD_MASK:
                    j += 1
                counters.packets += j - i
                counters.discards += j - i
                i = j
                continue
            if self._in_frame and (packet_id & NUMBER_MASK) == self._expected \
                    and (packet_id & DISCARD_MASK) != DISCARD_MASK:
                expected = self._expected
                j = i
                limit = min(count, i + self.layout.packets - expected)
                while j < limit and (ids[j] & NUMBER_MASK) == expected + (j - i) \
                        and (ids[j] & DISCARD_MASK) != DISCARD_MASK:
                    j += 1
                good = i
                rows = self._rows
                for k in range(i, j):
                    if not crc_matches(view, k * size, ids[k], crcs[k], size):
                        break
                    rows[expected + k - i] = view[k * size:(k + 1) * size]
                    good = k + 1
                if expected <= 20 < expected + good - i:
                    self._segment = segment_number(ids[i + 20 - expected])
                counters.packets += good - i
                self._expected = expected + good - i
                i = good
                if self._expected == self.layout.packets:
                    self._in_frame = False
                    self._expected = 0
                    counters.frames_completed += 1
                    return i, self._complete()
                if good < j:
                    pass    # the packet at ``good`` fails its CRC: feed decides below
                else:
                    continue
            result = self.feed(bytes(view[i * size:(i + 1) * size]), packet_id,
                               stamps_start + i * seconds_per_packet)
            i += 1
            if result is not None:
                return i, result
        return i, None

    def _complete(self):
        layout = self.layout
        rows = b''.join(self._rows[i] for i in layout.image_packets)
        words = np.frombuffer(rows, dtype='>u2').reshape(len(layout.image_packets), -1)
        pixels = words[:, 2:].astype(np.uint16)
        telemetry = tuple(bytes(self._rows[i][4:]) for i in layout.telemetry_packets)
        return AssembledFrame(pixels, telemetry, self._stamp, self._segment)
