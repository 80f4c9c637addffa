"""
The standard life of a node process: init, spin, clean shutdown on Ctrl-C or shutdown.

Also the QoS every publisher uses and the hand-over of work to a node's worker thread.
"""

import threading

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy

# Topics are relative: by default they live under this namespace (``-r __ns:=/x`` moves them).
DEFAULT_NAMESPACE = 'stereo'

# What the suite's nodes publish with (images, camera_info, pair_info, points2, disparity):
# reliable, keep the last 5; every publisher also accepts qos_overrides (README).
RELIABLE = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)


def with_default_namespace(kwargs):
    """Node keyword arguments with ``namespace`` defaulting to ``DEFAULT_NAMESPACE``."""
    kwargs = dict(kwargs)
    kwargs.setdefault('namespace', DEFAULT_NAMESPACE)
    return kwargs


def spin_node(factory, args=None):
    """
    Create a node with ``factory()`` and spin it until Ctrl-C or an external shutdown.

    Returns the node's ``exit_code`` (0 when it has none): a node that shuts itself down
    because it cannot go on sets it, so the process exits non-zero and launch can respawn it.
    A node that cannot start from its configuration (a parameter of the wrong type or out of
    range, a calibration file missing or invalid: ValueError, OSError) is one line on standard
    error naming the problem, and exit code 2.
    """
    import sys
    rclpy.init(args=args)
    try:
        node = factory()
    except (ValueError, OSError) as error:
        print(f'{sys.argv[0].rsplit("/", 1)[-1]}: cannot start: {error}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return getattr(node, 'exit_code', 0)


class LatestSlot:
    """
    Hand-over of work from the executor to one worker thread, keeping only the newest item.

    ``put`` never blocks: an item still waiting when a newer one arrives is replaced and
    counted in ``replaced`` (a slow consumer skips stale work instead of queueing it, which
    would add a period of latency per queued item). ``take`` waits for an item; after
    ``close`` it returns None.
    """

    def __init__(self):
        self._condition = threading.Condition()
        self._item = None
        self._closed = False
        self.replaced = 0

    def put(self, item):
        """Offer an item; returns True when it replaced an older one still waiting."""
        with self._condition:
            replaced = self._item is not None
            if replaced:
                self.replaced += 1
            self._item = item
            self._condition.notify()
            return replaced

    def take(self, timeout=None):
        """Return the newest item (and empty the slot), or None once closed or on timeout."""
        with self._condition:
            self._condition.wait_for(lambda: self._item is not None or self._closed, timeout)
            item, self._item = self._item, None
            return None if self._closed else item

    def close(self):
        """Wake and stop the consumer; returns True when an item was still waiting (dropped)."""
        with self._condition:
            self._closed = True
            pending, self._item = self._item is not None, None
            self._condition.notify_all()
            return pending
