"""
Stereo pairing of two free-running cameras by nearest stamp.

Two Leptons run on independent clocks and cannot be hardware-locked, so their unique frames
(period ~113 ms) arrive with an arbitrary, slowly drifting offset. ``PairSynchronizer`` makes
one-to-one pairs of the nearest stamps within ``max_delta``, gives both images one stamp (the
midpoint), drops the unmatched frames and counts them, and keeps skew statistics. Each queue
holds at most ``max_queue`` frames (a silent camera never makes the other side's queue grow),
and a frame whose stamp goes back in time is dropped and counted, never an exception: stamps
should come from a monotonic clock, and a reader thread must not die of one bad stamp.
"""

import collections
import dataclasses
import math


@dataclasses.dataclass
class StereoPair:
    """Left and right frames of one pair, with the pair's single stamp and its skew."""

    left: object
    right: object
    stamp: float
    skew: float          # right stamp - left stamp, seconds


@dataclasses.dataclass
class PairingCounters:
    """Pairs made, frames dropped per side, and skew statistics (seconds)."""

    pairs: int = 0
    dropped_left: int = 0
    dropped_right: int = 0
    overflow_left: int = 0       # of the dropped: pushed out of a full queue
    overflow_right: int = 0
    backward_left: int = 0       # of the dropped: stamp earlier than that side's last
    backward_right: int = 0
    skew_sum: float = 0.0
    skew_abs_max: float = 0.0

    @property
    def skew_mean(self):
        """Mean skew (right - left) of the pairs made."""
        return self.skew_sum / self.pairs if self.pairs else float('nan')

    def as_dict(self):
        """Return the counters as a plain dict."""
        out = dataclasses.asdict(self)
        out['skew_mean'] = self.skew_mean
        return out


class PairSynchronizer:
    """
    One-to-one nearest-stamp pairing of two frame streams.

    Frames are pushed per side in stamp order (each object has a ``stamp`` attribute).
    A pair is made as soon as no better partner can still come. ``min_period`` (seconds, 0 =
    unknown) is the shortest gap between two frames of one camera: with it a pair is decided
    when it arrives instead of when the next frame arrives (the Lepton's unique frames are
    113.6 ms apart, so 0.1 is safe).
    """

    def __init__(self, max_delta=0.05, min_period=0.0, max_queue=4):
        if not (max_delta > 0 and math.isfinite(max_delta)):
            raise ValueError(f'max_delta: expected a positive number of seconds, got '
                             f'{max_delta!r}')
        if not (min_period >= 0 and math.isfinite(min_period)):
            raise ValueError(f'min_period: expected seconds >= 0, got {min_period!r}')
        if not (isinstance(max_queue, int) and max_queue >= 2):
            raise ValueError(f'max_queue: expected an integer >= 2, got {max_queue!r}')
        self.max_delta = max_delta
        self.min_period = min_period
        self.max_queue = max_queue
        self.queues = {'left': collections.deque(), 'right': collections.deque()}
        self.counters = PairingCounters()
        self._last = {'left': -math.inf, 'right': -math.inf}

    def push(self, side, frame):
        """Add a frame of one side; returns the list of pairs that became decidable."""
        if side not in self.queues:
            raise ValueError(f'side: expected left or right, got {side!r}')
        counters = self.counters
        if frame.stamp < self._last[side]:
            setattr(counters, f'dropped_{side}', getattr(counters, f'dropped_{side}') + 1)
            setattr(counters, f'backward_{side}', getattr(counters, f'backward_{side}') + 1)
            return []
        self._last[side] = frame.stamp
        queue = self.queues[side]
        if len(queue) >= self.max_queue:
            queue.popleft()
            setattr(counters, f'dropped_{side}', getattr(counters, f'dropped_{side}') + 1)
            setattr(counters, f'overflow_{side}', getattr(counters, f'overflow_{side}') + 1)
        queue.append(frame)
        return self._drain()

    def _drain(self):
        pairs = []
        left, right = self.queues['left'], self.queues['right']
        while left and right:
            a, b = left[0], right[0]
            if abs(a.stamp - b.stamp) <= self.max_delta:
                # Each head may have a nearer partner next in the other queue.
                if len(right) > 1 and abs(right[1].stamp - a.stamp) < abs(b.stamp - a.stamp):
                    right.popleft()
                    self.counters.dropped_right += 1
                    continue
                if len(left) > 1 and abs(left[1].stamp - b.stamp) < abs(a.stamp - b.stamp):
                    left.popleft()
                    self.counters.dropped_left += 1
                    continue
                if not self._settled(a, 'right') or not self._settled(b, 'left'):
                    break
                left.popleft()
                right.popleft()
                pairs.append(self._pair(a, b))
            elif a.stamp < b.stamp:
                left.popleft()
                self.counters.dropped_left += 1
            else:
                right.popleft()
                self.counters.dropped_right += 1
        return pairs

    def _settled(self, frame, other_side):
        # Stamps arrive in order, so distances to the other side's frames fall then rise: the
        # head's partner is final once the other side holds a second frame, or has already
        # seen a stamp at or after this frame's, or when its next frame (at least min_period
        # later) would be farther than the current partner: decided without waiting.
        queue = self.queues[other_side]
        if len(queue) > 1 or self._last[other_side] >= frame.stamp:
            return True
        partner = queue[0]
        return partner.stamp + self.min_period - frame.stamp > abs(partner.stamp - frame.stamp)

    def _pair(self, left, right):
        skew = right.stamp - left.stamp
        counters = self.counters
        counters.pairs += 1
        counters.skew_sum += skew
        counters.skew_abs_max = max(counters.skew_abs_max, abs(skew))
        return StereoPair(left, right, 0.5 * (left.stamp + right.stamp), skew)

    def flush(self):
        """
        End of stream: return the pairs still waiting for a frame that will not come.

        A head whose partner could still have been beaten by a nearer frame is paired now
        (nothing nearer can arrive); what is left unpaired is dropped and counted.
        """
        seen, self._last = self._last, {'left': math.inf, 'right': math.inf}
        pairs = self._drain()
        self._last = seen
        self.counters.dropped_left += len(self.queues['left'])
        self.counters.dropped_right += len(self.queues['right'])
        self.queues['left'].clear()
        self.queues['right'].clear()
        return pairs


class PairFfcFlags:
    """
    Whether each camera of a pair was in FFC, counting the frames the pairing dropped.

    A Lepton announces an FFC on a few unique frames ("imminent") and then freezes. When
    those frames find no partner (the other camera was resyncing, say) the first pair after
    the FFC would say nothing, yet its image differs from the camera's last published one by
    the FFC's offset. ``seen`` records, per side, the stamps of frames in FFC; ``of_pair``
    flags a side when the pair's frame or any frame of that side since the previous pair was
    in FFC. The driver notes every frame it reads, also those it
    drops before the pairing (acquisition time unknown). Not seen: frames the driver's queue
    dropped, an FFC while a stream reopens, and everything without telemetry.
    """

    def __init__(self, max_pending=16):
        self._pending = {side: collections.deque(maxlen=max_pending)
                         for side in ('left', 'right')}

    def seen(self, side, frame):
        """Note a frame the driver read (``ffc_in_progress`` and ``stamp`` are used)."""
        if frame.ffc_in_progress:
            self._pending[side].append(frame.stamp)

    def of_pair(self, pair):
        """Return (left, right): was that camera in FFC for this pair (see the class)."""
        flags = []
        for side, frame in (('left', pair.left), ('right', pair.right)):
            pending = self._pending[side]
            flags.append(bool(frame.ffc_in_progress) or
                         any(stamp <= frame.stamp for stamp in pending))
            while pending and pending[0] <= frame.stamp:
                pending.popleft()
        return tuple(flags)


# --- pair_info: what a pair says about its two acquisitions -------------------------------------
# The driver publishes them as the KeyValues of a diagnostic_msgs/DiagnosticArray on
# ``pair_info`` (stamped with the pair's stamp); recordings carry the same topic, the matcher
# reads the skew and the left acquisition time back.
SKEW_KEY = 'skew (ms)'


def stamp_text(stamp_s):
    """Render seconds as ROS ``sec.nanosec`` text (nine digits of nanoseconds)."""
    total_ns = int(round(stamp_s * 1e9))
    sec, nanosec = divmod(total_ns, 1_000_000_000)
    return f'{sec}.{nanosec:09d}'


def pair_info_values(skew_s, stamps_s, frame_indices, ffc):
    """
    Return the ordered key -> value dict of one pair's ``pair_info``.

    ``stamps_s``, ``frame_indices`` and ``ffc`` are (left, right): each camera's acquisition
    stamp (seconds on the pair's clock), unique-frame index and FFC flag.
    """
    values = {SKEW_KEY: round(1e3 * skew_s, 3)}
    for side, stamp, index, in_ffc in zip(('left', 'right'), stamps_s, frame_indices, ffc):
        values[f'{side} acquisition stamp'] = stamp_text(stamp)
        values[f'{side} frame index'] = index
        values[f'{side} ffc'] = bool(in_ffc)
    return values


def pair_ffc_from_values(values):
    """
    Return ``(left in FFC, right in FFC)`` from ``pair_info`` key -> value text.

    A camera is flagged when its telemetry said the correction is imminent or in progress on
    the pair's frame or on one since its previous pair (the first frame after a freeze is
    flagged: its level moved); a missing key (an older recording) is taken as not.
    """
    return tuple(values.get(f'{side} ffc') == 'True' for side in ('left', 'right'))


def pair_times_from_values(values):
    """
    Return ``(left acquisition time s, skew s)`` from ``pair_info`` key -> value text.

    Raises ValueError naming the key when one is missing or is not a number.
    """
    out = []
    for key, scale in (('left acquisition stamp', 1.0), (SKEW_KEY, 1e-3)):
        if key not in values:
            raise ValueError(f'pair_info: no {key!r} value (keys: {sorted(values)})')
        try:
            number = float(values[key])
        except ValueError:
            raise ValueError(f'pair_info: {key!r} is {values[key]!r}, expected a number') \
                from None
        if not math.isfinite(number):
            raise ValueError(f'pair_info: {key!r} is {values[key]!r}, expected a finite number')
        out.append(number * scale)
    return tuple(out)
