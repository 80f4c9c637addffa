"""
``stereo_pipeline``: driver, rectifier and matcher in one process on one executor.

Python has no intra-process transport; several nodes on one executor is its form of
composition. The same parameter file as the separate nodes applies (node names unchanged).
"""

import time

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from st_stereo.nodes.conversions import point_cloud_array
from st_stereo.nodes.driver_node import DriverNode
from st_stereo.nodes.matcher_node import MatcherNode
from st_stereo.nodes.rectifier_node import RectifierNode
from st_stereo.nodes.runtime import with_default_namespace


def build_nodes(args=None):
    """Create the three nodes of the pipeline (rclpy must be initialised)."""
    return [DriverNode(), RectifierNode(), MatcherNode()]


class SuiteMonitor(Node):
    """Watches ``points2``: frequency, publish-to-receipt latency, matches, points."""

    def __init__(self, driver=None, **kwargs):
        super().__init__('suite_monitor', **with_default_namespace(kwargs))
        self.create_subscription(PointCloud2, 'points2', self._on_points,
                                 qos_profile_sensor_data)
        self.driver = driver
        self.times, self.latencies, self.matches, self.depths = [], [], [], []
        self.clouds = {}          # stamp in ns -> points (n, 3)

    def _on_points(self, msg):
        now = time.time()
        self.times.append(now)
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        published = self.driver.publish_wall_times.get(key) if self.driver else None
        if published is None:     # stamps are wall time (live or simulated cameras)
            published = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self.latencies.append(now - published)
        points = point_cloud_array(msg)
        self.clouds[key[0] * 1_000_000_000 + key[1]] = points[:, :3]
        self.matches.append(len(points))
        if len(points):
            self.depths.append(float(np.nanmedian(points[:, 2])))


def main(args=None):
    """Run the pipeline until Ctrl-C; exits non-zero when the driver could not recover."""
    rclpy.init(args=args)
    nodes = build_nodes()
    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return max(getattr(node, 'exit_code', 0) for node in nodes)
