"""Exact-stamp synchronisation of several topics (message_filters is not installable here)."""

import collections


def stamp_key(msg):
    """(sec, nanosec) of a message header: the key messages of one pair share."""
    return msg.header.stamp.sec, msg.header.stamp.nanosec


class ExactTimeSync:
    """
    Call back with one message of each topic when all carry the identical stamp.

    At most ``queue_size`` stamps wait; the oldest incomplete set is evicted (its messages are
    counted in ``dropped`` per topic), so a lost message never blocks the stream.
    """

    def __init__(self, topics, callback, queue_size=10):
        self.topics = topics
        self.callback = callback
        self.queue_size = queue_size
        self.pending = collections.OrderedDict()
        self.dropped = [0] * topics
        self.matched = 0

    def add(self, index, msg):
        """Add the message of topic ``index``; calls back when its set is complete."""
        key = stamp_key(msg)
        slots = self.pending.get(key)
        if slots is None:
            slots = self.pending[key] = [None] * self.topics
        if slots[index] is not None:
            self.dropped[index] += 1        # a repeated stamp on one topic: keep the newest
        slots[index] = msg
        if all(slot is not None for slot in slots):
            del self.pending[key]
            # Older incomplete sets can no longer complete: topics arrive in stamp order.
            for old in [k for k in self.pending if k < key]:
                self._evict(old)
            self.matched += 1
            self.callback(*slots)
            return
        while len(self.pending) > self.queue_size:
            self._evict(next(iter(self.pending)))

    def _evict(self, key):
        for index, slot in enumerate(self.pending.pop(key)):
            if slot is not None:
                self.dropped[index] += 1


class SyncDropWatch:
    """
    Whether an ExactTimeSync dropped messages since the last look while nothing got through.

    ``recent(passed)``: ``passed`` is the caller's count of pairs that got through; returns the
    messages dropped since the previous call when no pair passed in between (the four topics'
    stamps no longer meet), else 0.
    """

    def __init__(self, sync):
        self.sync = sync
        self._dropped = 0
        self._passed = 0

    def recent(self, passed):
        """Return the messages dropped since the last call if no pair passed meanwhile."""
        dropped = sum(self.sync.dropped)
        new, self._dropped = dropped - self._dropped, dropped
        stalled = passed == self._passed
        self._passed = passed
        return new if stalled else 0


def sync_drop_message(count, topics):
    """Return the status text of messages the exact-stamp sync dropped, no pair through."""
    return (f'no pair in the last period: {count} messages dropped by the exact-stamp sync of '
            f'{", ".join(topics)} (their stamps must be equal)')


def subscribe_exact(node, topics, callback, qos):
    """
    Subscribe to ``[(msg_type, topic), ...]`` and call back with one message of each topic.

    Returns the ExactTimeSync (its ``dropped`` counts go to diagnostics).
    """
    sync = ExactTimeSync(len(topics), callback)
    for index, (msg_type, topic) in enumerate(topics):
        node.create_subscription(msg_type, topic, lambda msg, i=index: sync.add(i, msg), qos)
    return sync
