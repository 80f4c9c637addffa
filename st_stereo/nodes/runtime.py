"""The standard life of a node process: init, spin, clean shutdown on Ctrl-C or shutdown."""

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
