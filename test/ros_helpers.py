"""rclpy helpers shared by the tests that run nodes: a private context and spinning."""

import contextlib
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from st_stereo.nodes.conversions import image_to_msg
from std_msgs.msg import Header


def new_context():
    """Return an initialised rclpy Context and a single-threaded executor on it."""
    context = rclpy.Context()
    rclpy.init(context=context)
    return context, SingleThreadedExecutor(context=context)


def spin_for(executor, seconds):
    """Spin ``executor`` for ``seconds`` of wall time."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.02)


def spin_until(executor, predicate, timeout_s):
    """Spin until ``predicate()`` is true or ``timeout_s`` of wall time passed."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not predicate():
        executor.spin_once(timeout_sec=0.05)


def keep_statuses(statuses, msg):
    """Store each DiagnosticStatus of ``msg`` in ``statuses``: {name: {key: value}}."""
    for status in msg.status:
        statuses[status.name] = {kv.key: kv.value for kv in status.values}


def spin_until_finished(executor, driver, timeout_s):
    """Spin until the driver has read its whole source (or ``timeout_s`` passes)."""
    deadline = time.monotonic() + timeout_s
    while not driver.finished.is_set() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)


@contextlib.contextmanager
def ros_nodes():
    """Yield a private rclpy context, its executor, and a function adding nodes to it."""
    context, executor = new_context()
    nodes = []

    def add(node):
        nodes.append(node)
        executor.add_node(node)
        return node
    try:
        yield context, executor, add
    finally:
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def ideal_camera_info(tx, header=None, width=80, height=60):
    """Return the CameraInfo of an ideal rectified Lepton camera (fx 83.9, P[0, 3] = ``tx``)."""
    info = CameraInfo()
    if header is not None:
        info.header = header
    info.width, info.height = width, height
    info.k = [83.9, 0.0, 39.5, 0.0, 83.9, 29.5, 0.0, 0.0, 1.0]
    info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    info.d = [0.0] * 5
    info.distortion_model = 'plumb_bob'
    info.p = [83.9, 0.0, 39.5, tx, 0.0, 83.9, 29.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    return info


class GatedMatch:
    """Wraps StereoMatcher.match: the first call waits until ``release`` (a slow matcher)."""

    def __init__(self, match):
        self.match, self.entered, self.gate = match, threading.Event(), threading.Event()

    def __call__(self, *args, **kwargs):
        self.entered.set()
        self.gate.wait(60.0)
        return self.match(*args, **kwargs)


class RectifiedPairs(Node):
    """Publishes rectified pairs with the raw camera_infos, as the rectifier and driver do."""

    def __init__(self, context, name='rectified_pairs', namespace='stereo'):
        super().__init__(name, context=context, namespace=namespace)
        sensor = qos_profile_sensor_data
        self.images = [self.create_publisher(Image, f'{side}/image_rect', sensor)
                       for side in ('left', 'right')]
        self.infos = [self.create_publisher(CameraInfo, f'{side}/camera_info', sensor)
                      for side in ('left', 'right')]

    def publish_images(self, sec, left, right, info_size=(80, 60)):
        """Publish a pair stamped ``sec`` s, camera_infos of ``info_size`` (width, height)."""
        header = Header(frame_id='stereo_left_optical_frame')
        header.stamp.sec = sec
        for publisher, image in zip(self.images, (left, right)):
            publisher.publish(image_to_msg(image, header))
        for publisher, tx in zip(self.infos, (0.0, -46.3)):
            publisher.publish(ideal_camera_info(tx, header, *info_size))


class Clouds(Node):
    """Collects ``points2``: the raw bytes of each cloud by its stamp."""

    def __init__(self, context):
        super().__init__('clouds', context=context, namespace='stereo')
        self.by_stamp = {}
        self.create_subscription(PointCloud2, 'points2', self._on_cloud,
                                 qos_profile_sensor_data)

    def _on_cloud(self, msg):
        self.by_stamp[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = bytes(msg.data)


def replay_through_matcher(bag, rate=0.5, use_sim_time=False, keep_latest=True):
    """
    Play ``bag`` (BagPlayer) into a rectifier and a matcher; return what came out.

    With ``use_sim_time`` the player publishes ``/clock`` and the nodes run on it; without
    ``keep_latest`` the matcher matches every pair in order (a loaded machine cannot make it
    drop a stale one). Returns ``(clouds {stamp: bytes}, messages published, the matcher
    node)``.
    """
    from st_stereo.nodes.bags import BagPlayer
    from st_stereo.nodes.matcher_node import MatcherNode
    from st_stereo.nodes.rectifier_node import RectifierNode
    context, executor = new_context()
    overrides = [Parameter('use_sim_time', value=use_sim_time)]
    matcher = MatcherNode(context=context, parameter_overrides=overrides + [
        Parameter('keep_latest', value=keep_latest)])
    nodes = [RectifierNode(context=context, parameter_overrides=overrides), matcher,
             Clouds(context)]
    player = BagPlayer(bag, rate=rate, publish_clock=use_sim_time, context=context)
    for node in nodes + [player]:
        executor.add_node(node)
    try:
        spin_for(executor, 1.0)      # discovery
        player.play(spin=lambda s: executor.spin_once(timeout_sec=s))
        spin_for(executor, 1.5)      # drain
        return dict(nodes[2].by_stamp), player.published, matcher
    finally:
        player.close()
        for node in nodes + [player]:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def subscribe_replay_topics(node):
    """
    Subscribe ``node`` (in the driver's namespace) to every topic a replay waits for.

    A bag or capture replay waits up to ``replay_wait`` (5 s) for a subscriber on each of
    left/right image_raw and camera_info: a test listening to one of them alone paid those
    5 s. No-op callbacks; QoS as the driver offers (sensor data).
    """
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo, Image
    for side in ('left', 'right'):
        node.create_subscription(Image, f'{side}/image_raw', lambda msg: None,
                                 qos_profile_sensor_data)
        node.create_subscription(CameraInfo, f'{side}/camera_info', lambda msg: None,
                                 qos_profile_sensor_data)
