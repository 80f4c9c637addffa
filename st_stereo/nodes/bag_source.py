"""
The driver's ``bag`` source: the raw image topics of a rosbag2 as two frame streams.

The bag is read as the frames are needed, not whole before the first one: a camera's next
frame is pulled from the bag in its order (the other camera's frames met on the way are
kept for it), so memory holds the few frames between the two cameras' positions in the
bag, not the recording (an hour of two 80x60 cameras is 600 MB of images).
"""

import bisect
import collections

from st_stereo.bag_streams import raw_image_messages, recorded_pair_info, SIDES
from st_stereo.lepton.assembler import LeptonCounters
from st_stereo.lepton.pairing import pair_times_from_values
from st_stereo.lepton.reader import EndOfStream, LeptonFrame
from st_stereo.nodes.conversions import msg_to_image


class BagImageStream:
    """Both cameras' raw images of a bag, pulled in bag order as each camera asks for one."""

    def __init__(self, path, namespace=''):
        self.zero_stamped = dict.fromkeys(SIDES, 0)     # stamped 0: receive time used
        self._messages = raw_image_messages(path, self.zero_stamped, namespace)
        self.pending = {side: collections.deque() for side in SIDES}
        self.pulled = 0                    # messages read from the bag so far
        self.ended = False

    def peek(self, side):
        """Return the side's next ``(stamp ns, Image)`` without taking it; None at the end."""
        pending = self.pending[side]
        while not pending and not self.ended:
            try:
                other, stamp_ns, msg = next(self._messages)
            except StopIteration:
                self.ended = True
                break
            self.pulled += 1
            self.pending[other].append((stamp_ns, msg))
        return pending[0] if pending else None

    def take(self, side):
        """Return and remove the side's next ``(stamp ns, Image)``; None at the end."""
        item = self.peek(side)
        if item is not None:
            self.pending[side].popleft()
        return item

    def close(self):
        """Close the bag (also when the stream was not read to its end)."""
        self._messages.close()


class _BagTime:
    def __init__(self, side):
        self.side = side
        self.device = f'bag:{side.topic}'

    def now(self):
        return self.side.next_time()


class BagSide:
    """One camera's frames of a bag, with the reader's interface."""

    def __init__(self, side, stream, start):
        self.side = side
        self.topic = f'{side}/image_raw'
        self.stream = stream
        self.read = 0                      # messages of this camera taken so far
        self.counters = LeptonCounters()
        self.transport = _BagTime(self)
        # Both sides' times count from one start (the earlier side's first stamp): a camera
        # recorded a second later must wait that second, not start with the other one.
        self.start = start
        self.last_problem = ''             # why the last refused frame was refused
        self.last_time = 0.0               # time of the frame read last (from the start)

    def next_time(self):
        """Time of the next frame relative to the first (for pacing and interleaving)."""
        item = self.stream.peek(self.side)
        return float('inf') if item is None else item[0] * 1e-9 - self.start

    def read_frame(self, timeout_s=1.0):
        """Return the next frame; EndOfStream after the last."""
        item = self.stream.take(self.side)
        if item is None:
            raise EndOfStream()
        stamp_ns, msg = item
        self.last_time = stamp_ns * 1e-9 - self.start      # for pacing: this frame's moment
        index = self.read
        self.read += 1
        self.counters.frames_completed += 1
        try:
            pixels = msg_to_image(msg, 'mono16')
        except ValueError as error:
            self.counters.frames_aborted += 1
            self.last_problem = f'{self.topic} message {index}: {error}'
            return None
        self.counters.unique_frames += 1
        return LeptonFrame(pixels.copy(), stamp_ns * 1e-9, index, stamp_ns=stamp_ns)

    @property
    def zero_stamped(self):
        """Frames of this camera stamped 0 in the bag, given the recorder's receive time."""
        return self.stream.zero_stamped[self.side]

    def close(self):
        """Close the bag the two sides share."""
        self.stream.close()


def open_bag_sides(path, namespace=''):
    """
    Open the left and right image_raw streams of a bag (``bag_streams.pair_namespace``).

    Only the first frame of each camera is read here (for the common start): the rest is
    read as the driver asks for it.
    """
    stream = BagImageStream(path, namespace)
    firsts = [item[0] * 1e-9 for item in (stream.peek(side) for side in SIDES) if item]
    start = min(firsts) if firsts else 0.0
    return [BagSide(side, stream, start) for side in SIDES]


class RecordedPairInfo:
    """
    A bag's ``pair_info`` by pair stamp, for republishing with the replayed pairs.

    A recorded pair's images share its stamp (the midpoint of the two acquisitions), so pairing
    them again gives a skew of zero: the cameras' real skew and acquisition stamps are only in
    the recorded ``pair_info``. ``values`` looks a pair stamp up (within a microsecond: replay
    passes stamps through float seconds) and counts what it found.
    """

    TOLERANCE_NS = 1000

    def __init__(self, path, namespace=''):
        self.notes = []                  # what reading the bag worked around (open_bag)
        self.by_stamp = recorded_pair_info(path, namespace, self.notes)
        self.stamps = sorted(self.by_stamp)
        self.counts = {'pairs with recorded pair_info': 0,
                       'pairs without recorded pair_info (skew of the image stamps)': 0,
                       'recorded pair_info unreadable (skew of the image stamps)': 0}
        self.last_problem = ''

    def values(self, stamp_ns):
        """Return the recorded key -> value text of the pair at ``stamp_ns``, or None."""
        index = bisect.bisect_left(self.stamps, stamp_ns)
        near = [s for s in self.stamps[max(0, index - 1):index + 1]
                if abs(s - stamp_ns) <= self.TOLERANCE_NS]
        if not near:
            self.counts['pairs without recorded pair_info (skew of the image stamps)'] += 1
            return None
        values = self.by_stamp[near[0]]
        try:
            pair_times_from_values(values)
        except ValueError as error:
            self.counts['recorded pair_info unreadable (skew of the image stamps)'] += 1
            self.last_problem = f'pair at {near[0]} ns: {error}'
            return None
        self.counts['pairs with recorded pair_info'] += 1
        return values
