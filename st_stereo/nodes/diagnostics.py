"""
Diagnostics with diagnostic_updater's conventions, without diagnostic_updater.

``FrequencyTracker`` keeps the event times of a sliding window and reports the keys of
diagnostic_updater's FrequencyStatus; ``status`` builds a DiagnosticStatus from a dict.
"""

import collections
import math
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)


def positive_number(name, value, unit):
    """Return a parameter's value as a float; ValueError naming it unless finite and > 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not (math.isfinite(value) and value > 0):
        raise ValueError(f'{name}: expected a finite number above 0 {unit}, got {value!r}')
    return float(value)


def non_negative_number(name, value, expected='seconds >= 0'):
    """Return a parameter's value as a float; ValueError naming it unless finite and >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not (math.isfinite(value) and value >= 0):
        raise ValueError(f'{name}: expected {expected}, got {value!r}')
    return float(value)


def target_frequency(value):
    """Return a ``target_frequency`` parameter as a float (``positive_number``, Hz)."""
    return positive_number('target_frequency', value, 'Hz')


class FrequencyTracker:
    """
    Events in a sliding window (default 5 s) against a target frequency and tolerance.

    Thread-safe: a reading thread ticks while the diagnostics timer reads.
    """

    def __init__(self, target_hz, tolerance=0.2, window_s=5.0):
        self.target_hz = target_hz
        self.tolerance = tolerance
        self.window_s = window_s
        self.events = collections.deque()
        self.total = 0
        self._lock = threading.Lock()

    def tick(self, now):
        """Record one event at ``now`` (seconds)."""
        with self._lock:
            self.events.append(now)
            self.total += 1
            self._trim(now)

    def _trim(self, now):
        while self.events and now - self.events[0] > self.window_s:
            self.events.popleft()

    def frequency(self, now):
        """Events per second over the window."""
        with self._lock:
            self._trim(now)
            return len(self.events) / self.window_s

    def values(self, now):
        """(level, summary, key-value dict) with diagnostic_updater's FrequencyStatus keys."""
        frequency = self.frequency(now)
        low = self.target_hz * (1.0 - self.tolerance)
        high = self.target_hz * (1.0 + self.tolerance)
        values = {'Events in window': len(self.events), 'Events since startup': self.total,
                  'Duration of window (s)': self.window_s,
                  'Actual frequency (Hz)': round(frequency, 3),
                  'Target frequency (Hz)': self.target_hz,
                  'Minimum acceptable frequency (Hz)': round(low, 3),
                  'Maximum acceptable frequency (Hz)': round(high, 3)}
        if not self.events:
            return ERROR, 'No events recorded.', values
        if frequency < low:
            return WARN, 'Frequency too low.', values
        if frequency > high:
            return WARN, 'Frequency too high.', values
        return OK, 'Desired frequency met', values


def key_values(msg):
    """Return every KeyValue of a DiagnosticArray's statuses as one dict (``pair_info``)."""
    return {item.key: item.value for status in msg.status for item in status.values}


def status_name(node, task):
    """
    Name a node's diagnostic status ``'<namespace>/<node>: <task>'``, namespace without '/'.

    ROS 2's diagnostic_updater names a status ``'<node>: <task>'`` (the node's name without
    its namespace), as these nodes did before 2026-12-07; in the root namespace the two are
    the same, under the suite's default ``/stereo`` this is ``'stereo/matcher: ST
    matching'``. With several rigs on one machine (``/rig1``, ``/rig2``, ...) the namespace
    tells their statuses apart on the one ``/diagnostics`` topic, where an aggregator (which
    keys its items by name) or a monitor would otherwise see N identical names (ros/diagnostics
    issue 318 asks the same of diagnostic_updater). An aggregator's analyzers match these
    names with ``startswith: ['stereo/']`` or a regex; the robot monitor shows the namespace
    as a level of its tree.
    """
    return f'{node.get_fully_qualified_name().lstrip("/")}: {task}'


def status(name, hardware_id, level, message, values):
    """Build a DiagnosticStatus from a dict of values (rendered as strings)."""
    out = DiagnosticStatus()
    out.name = name
    out.hardware_id = hardware_id
    out.level = level
    out.message = message
    out.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    return out


def publish(node, publisher, statuses):
    """Publish statuses as one DiagnosticArray stamped with the node's clock."""
    array = DiagnosticArray()
    array.header.stamp = node.get_clock().now().to_msg()
    array.status = list(statuses)
    publisher.publish(array)
