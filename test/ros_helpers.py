"""rclpy helpers shared by the tests that run nodes: a private context and spinning."""

import time

import rclpy
from rclpy.executors import SingleThreadedExecutor


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


def spin_until_finished(executor, driver, timeout_s):
    """Spin until the driver has read its whole source (or ``timeout_s`` passes)."""
    deadline = time.monotonic() + timeout_s
    while not driver.finished.is_set() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
