"""The driver's ``bag`` source: the raw image topics of a rosbag2 as two frame streams."""

import bisect

from st_stereo.bag_streams import raw_image_messages, recorded_pair_info
from st_stereo.lepton.assembler import LeptonCounters
from st_stereo.lepton.pairing import pair_times_from_values
from st_stereo.lepton.reader import EndOfStream, LeptonFrame
from st_stereo.nodes.conversions import msg_to_image


class _BagTime:
    def __init__(self, side):
        self.side = side
        self.device = f'bag:{side.topic}'

    def now(self):
        return self.side.next_time()


class BagSide:
    """One camera's frames of a bag, with the reader's interface."""

    def __init__(self, topic, messages, start=None):
        self.topic = topic
        self.messages = messages           # [(stamp ns, Image)], in bag order
        self.position = 0
        self.counters = LeptonCounters()
        self.transport = _BagTime(self)
        # Both sides' times count from one start (the earlier side's first stamp): a camera
        # recorded a second later must wait that second, not start with the other one.
        self.start = start if start is not None else \
            (messages[0][0] * 1e-9 if messages else 0.0)
        self.last_problem = ''             # why the last refused frame was refused

    def next_time(self):
        """Time of the next frame relative to the first (for pacing and interleaving)."""
        if self.position >= len(self.messages):
            return float('inf')
        return self.messages[self.position][0] * 1e-9 - self.start

    def read_frame(self, timeout_s=1.0):
        """Return the next frame; EndOfStream after the last."""
        if self.position >= len(self.messages):
            raise EndOfStream()
        stamp_ns, msg = self.messages[self.position]
        self.position += 1
        self.counters.frames_completed += 1
        try:
            pixels = msg_to_image(msg, 'mono16')
        except ValueError as error:
            self.counters.frames_aborted += 1
            self.last_problem = f'{self.topic} message {self.position - 1}: {error}'
            return None
        self.counters.unique_frames += 1
        return LeptonFrame(pixels.copy(), stamp_ns * 1e-9, self.position - 1,
                           stamp_ns=stamp_ns)


def open_bag_sides(path):
    """Open the left and right image_raw streams of a bag (topics ending in side/image_raw)."""
    streams = {'left': [], 'right': []}
    for side, stamp_ns, msg in raw_image_messages(path):
        streams[side].append((stamp_ns, msg))
    firsts = [streams[side][0][0] * 1e-9 for side in ('left', 'right') if streams[side]]
    start = min(firsts) if firsts else 0.0
    return [BagSide(f'{side}/image_raw', streams[side], start) for side in ('left', 'right')]


class RecordedPairInfo:
    """
    A bag's ``pair_info`` by pair stamp, for republishing with the replayed pairs.

    A recorded pair's images share its stamp (the midpoint of the two acquisitions), so pairing
    them again gives a skew of zero: the cameras' real skew and acquisition stamps are only in
    the recorded ``pair_info``. ``values`` looks a pair stamp up (within a microsecond: replay
    passes stamps through float seconds) and counts what it found.
    """

    TOLERANCE_NS = 1000

    def __init__(self, path):
        self.by_stamp = recorded_pair_info(path)
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
