"""
The standard life of a node process: init, spin, clean shutdown on Ctrl-C or shutdown.

Also the QoS every publisher uses and the hand-over of work to a node's worker thread.
"""

import contextlib
import os
import signal
import threading
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

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


@contextlib.contextmanager
def until_shutdown(context=None):
    """
    Let a spin end quietly on Ctrl-C or an external shutdown.

    rclpy's signal handler shuts the context down while the executor may be taking a message;
    the take then fails with a RuntimeError (seen once in CI: "Unable to convert call argument
    '0' to Python object", exit code 1 after a clean Ctrl-C). A RuntimeError once the context
    is shut down is that shutdown; one while it is still up is raised. ``context``: the one
    spun (rclpy's default one when None).
    """
    try:
        yield
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        if rclpy.ok(context=context):
            raise


EXECUTOR_VARIABLE = 'ST_STEREO_EXECUTOR'
EXECUTOR_CHOICES = ('events', 'single')


def node_executor(context=None):
    """
    Return the executor a node process spins on.

    rclpy's ``EventsExecutor`` (``rclpy.experimental``, where this rclpy has it) by default:
    the ``SingleThreadedExecutor`` rebuilds its wait set from every entity of the node at each
    wake-up, in Python (measured, the matcher on one rig replaying the recording: 5.5 ms of
    CPU per pair in the executor, 1.5 ms with the events executor). ``ST_STEREO_EXECUTOR=single``
    in the environment chooses the ``SingleThreadedExecutor``, as does an rclpy without the
    events executor.
    """
    choice = os.environ.get(EXECUTOR_VARIABLE, 'events')
    if choice not in EXECUTOR_CHOICES:
        raise ValueError(f'{EXECUTOR_VARIABLE}: expected one of {", ".join(EXECUTOR_CHOICES)}, '
                         f'got {choice!r}')
    if choice == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            pass
        else:
            return EventsExecutor(context=context)
    from rclpy.executors import SingleThreadedExecutor
    return SingleThreadedExecutor(context=context)


def spin_until_shutdown(executor, stop=None):
    """
    Spin ``executor`` until Ctrl-C, ``stop`` is set or rclpy's default context shuts down.

    Not ``executor.spin()``: the events executor's does not return when a signal shuts the
    context down (rclpy 7.1.6); the timeout bounds the wait for that, or for ``stop``
    (``stop_on_signals``), to 0.2 s.
    """
    with until_shutdown():
        while rclpy.ok() and not (stop is not None and stop.is_set()):
            executor.spin_once(timeout_sec=0.2)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
REPEAT_WINDOW_S = 1.0       # a signal this soon after the first is the same request
FORCED_EXIT_CODE = 130      # the stop was forced by a second signal (128 + SIGINT)


@contextlib.contextmanager
def stop_on_signals(signals=STOP_SIGNALS):
    """
    Turn Ctrl-C and SIGTERM into a request to stop: yields the Event the first one sets.

    rclpy's own handler shuts the context down at once, from inside the signal: a node thread
    between two publishes of one stereo pair (the driver: left image and camera_info, right
    image and camera_info, pair_info) then fails the rest, and subscribers and bag recorders
    get half a pair. With this handler (and rclpy's off: ``init_for_signals``) the spin ends,
    the nodes are destroyed (the driver joins its reading thread, which finishes the pair it
    is publishing; the matcher finishes the pair it is matching) and only then is the context
    shut down. A signal within ``REPEAT_WINDOW_S`` of the first is the same request (launch
    and a terminal may both send one); a later one raises KeyboardInterrupt: stop waiting.
    Must run in the main thread (Python delivers signals there). Restores the previous
    handlers on exit.
    """
    stop = threading.Event()
    first = []

    def request_stop(signum, frame):
        if not first:
            first.append(time.monotonic())
            stop.set()
        elif time.monotonic() - first[0] > REPEAT_WINDOW_S:
            raise KeyboardInterrupt
    previous = {number: signal.signal(number, request_stop) for number in signals}
    try:
        yield stop
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def init_for_signals(args=None):
    """``rclpy.init`` without rclpy's signal handlers (``stop_on_signals`` handles them)."""
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)


def run_nodes(build, args=None):
    """
    Create nodes with ``build()`` (a list) and spin them until Ctrl-C, SIGTERM or a shutdown.

    The process's life for every executable: rclpy without its signal handlers, the nodes
    stopped in order on the first signal (``stop_on_signals``: a pair being published is
    finished), then the context shut down. Returns the largest of the nodes' ``exit_code``
    (0 when none has one): a node that shuts itself down because it cannot go on sets it, so
    the process exits non-zero and launch can respawn it. A node that cannot start from its
    configuration (a parameter of the wrong type or out of range, a calibration file missing
    or invalid: ValueError, OSError) is one line on standard error naming the problem, and
    exit code 2. A second signal (``stop_on_signals``) while the nodes start or stop ends
    the process without waiting for them, with exit code ``FORCED_EXIT_CODE``, said on
    standard error.
    """
    import sys
    name = sys.argv[0].rsplit('/', 1)[-1]
    with stop_on_signals() as stop:
        init_for_signals(args)
        try:
            executor = node_executor()
            nodes = build()
        except (ValueError, OSError) as error:
            print(f'{name}: cannot start: {error}', file=sys.stderr)
            rclpy.try_shutdown()
            return 2
        except KeyboardInterrupt:
            print(f'{name}: stopped by a second signal while starting', file=sys.stderr)
            rclpy.try_shutdown()
            return FORCED_EXIT_CODE
        forced = False
        try:
            for node in nodes:
                executor.add_node(node)
            spin_until_shutdown(executor, stop)
        finally:
            if stop.is_set():
                print(f'{name}: stopping (a second Ctrl-C stops without waiting)',
                      file=sys.stderr)
            try:
                for node in nodes:
                    node.destroy_node()
            except KeyboardInterrupt:
                forced = True
                print(f'{name}: stopped by a second signal before every node had stopped',
                      file=sys.stderr)
            rclpy.try_shutdown()
    if forced:
        return FORCED_EXIT_CODE
    return max((getattr(node, 'exit_code', 0) for node in nodes), default=0)


def spin_node(factory, args=None):
    """Run one node made by ``factory()`` as a process (``run_nodes``)."""
    return run_nodes(lambda: [factory()], args)


class LatestSlot:
    """
    Hand-over of work from the executor to one worker thread, keeping only the newest item.

    ``put`` never blocks. While the consumer is busy with an item, a newer one replaces any
    still waiting, counted in ``replaced`` (a slow consumer skips stale work instead of
    queueing it, which would add a period of latency per queued item). While it is idle (it
    has not taken the waiting item yet) items are kept, at most ``IDLE_DEPTH``, and taken in
    order: an executor callback that hands over two items at once (a pair released from a
    wait, then the next one) loses neither. ``take`` waits for an item; after ``close`` it
    returns None.
    """

    IDLE_DEPTH = 2

    def __init__(self):
        self._condition = threading.Condition()
        self._items = []
        self._busy = False
        self._closed = False
        self.replaced = 0

    def put(self, item):
        """Offer an item; returns the number of older items it replaced (dropped)."""
        with self._condition:
            if self._busy:
                dropped, self._items = len(self._items), [item]
            else:
                self._items.append(item)
                dropped = max(len(self._items) - self.IDLE_DEPTH, 0)
                del self._items[:dropped]
            self.replaced += dropped
            self._condition.notify()
            return dropped

    def take(self, timeout=None):
        """
        Return the next item (oldest kept first), or None once closed or on timeout.

        Calling ``take`` again means the consumer is done with the previous item.
        """
        with self._condition:
            self._busy = False
            self._condition.wait_for(lambda: self._items or self._closed, timeout)
            if self._closed or not self._items:
                return None
            self._busy = True
            return self._items.pop(0)

    def close(self):
        """Wake and stop the consumer; returns how many items were still waiting (dropped)."""
        with self._condition:
            self._closed = True
            pending, self._items = len(self._items), []
            self._condition.notify_all()
            return pending
