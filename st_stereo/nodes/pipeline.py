"""
``stereo_pipeline``: driver, rectifier, matcher and people in one process on one executor.

Python has no intra-process transport; several nodes on one executor is its form of
composition. The same parameter file as the separate nodes applies (node names unchanged).
"""

import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2

from st_stereo.nodes.conversions import point_cloud_array, point_cloud_fields
from st_stereo.nodes.driver_node import DriverNode
from st_stereo.nodes.matcher_node import MatcherNode
from st_stereo.nodes.people_messages import DETECTION_FIELDS
from st_stereo.nodes.people_node import PeopleNode
from st_stereo.nodes.rectifier_node import RectifierNode
from st_stereo.nodes.runtime import run_nodes, with_default_namespace


def build_nodes(args=None):
    """Create the four nodes of the pipeline (rclpy must be initialised)."""
    # The driver last: it starts publishing at once, and the matcher loads its kernels first.
    matcher = MatcherNode()
    rectifier = RectifierNode()
    people = PeopleNode()
    return [DriverNode(), rectifier, matcher, people]


class SuiteMonitor(Node):
    """
    Watches ``points2``: frequency, latency, matches, points.

    ``latencies``: receipt minus the time the pair went out, from the in-process driver's
    ``publish_wall_times`` when given (a bag's stamps are not wall time), else minus the stamp.
    ``stamp_latencies``: receipt minus the stamp (wall-clock stamps: live or simulated cameras).
    ``pair_latencies`` (with ``watch_raw``, or a driver): receipt minus the moment the pair was
    published (the driver's record, or this node's receipt of ``left/image_raw``): what
    rectifying, matching and the transports add, without the cameras' readout.
    """

    def __init__(self, driver=None, watch_raw=False, watch_people=False, **kwargs):
        super().__init__('suite_monitor', **with_default_namespace(kwargs))
        # Reliable: what the monitor counts as lost must be the suite's loss, not its own (a
        # best-effort reader on a loaded machine may miss samples the suite delivered).
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(PointCloud2, 'points2', self._on_points, qos)
        self.people = {}          # stamp in ns -> people/detections rows (with watch_people)
        self.people_times = []    # wall times people/detections arrived
        if watch_people:
            self.create_subscription(PointCloud2, 'people/detections', self._on_people, qos)
        self.driver = driver
        self.raw_received = {}    # stamp key -> wall time left/image_raw arrived here
        self.raw_count = 0        # left/image_raw messages received (with watch_raw)
        self.matcher_values = {}  # the matcher's last diagnostics (with watch_raw)
        if watch_raw:
            self.create_subscription(Image, 'left/image_raw', self._on_raw, qos)
            self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.times, self.latencies, self.matches, self.depths = [], [], [], []
        self.stamp_latencies, self.pair_latencies = [], []
        self.clouds = {}          # stamp in ns -> points (n, 3)

    def _on_people(self, msg):
        self.people_times.append(time.time())
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        fields = point_cloud_fields(msg, DETECTION_FIELDS)
        self.people[key] = np.column_stack([fields[name] for name in DETECTION_FIELDS]) \
            .reshape(-1, len(DETECTION_FIELDS))

    def _on_diagnostics(self, msg):
        # The matcher of this monitor's namespace (``diagnostics.status_name``): other rigs'
        # matchers publish on the same /diagnostics.
        namespace = self.get_namespace().strip('/')
        for status in msg.status:
            node, _, task = status.name.rpartition(': ')
            if task == 'ST matching' and node.rpartition('/')[0] == namespace:
                self.matcher_values = {kv.key: kv.value for kv in status.values}

    def _on_raw(self, msg):
        self.raw_count += 1
        self.raw_received[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = time.time()
        while len(self.raw_received) > 256:
            self.raw_received.pop(next(iter(self.raw_received)))

    def _on_points(self, msg):
        now = time.time()
        self.times.append(now)
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        by_driver = self.driver.publish_wall_times.get(key) if self.driver else None
        self.latencies.append(now - (stamp if by_driver is None else by_driver))
        self.stamp_latencies.append(now - stamp)
        published = by_driver if by_driver is not None else self.raw_received.get(key)
        if published is not None:
            self.pair_latencies.append(now - published)
        points = point_cloud_array(msg)
        self.clouds[key[0] * 1_000_000_000 + key[1]] = points[:, :3]
        self.matches.append(len(points))
        if len(points):
            self.depths.append(float(np.nanmedian(points[:, 2])))


def main(args=None):
    """Run the pipeline until Ctrl-C; exits non-zero when the driver could not recover."""
    return run_nodes(build_nodes, args)
