"""The standard life of a node process: init, spin, clean shutdown on Ctrl-C or shutdown."""

import rclpy
from rclpy.executors import ExternalShutdownException


def spin_node(factory, args=None):
    """Create a node with ``factory()`` and spin it until Ctrl-C or an external shutdown."""
    rclpy.init(args=args)
    node = factory()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
