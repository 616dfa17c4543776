"""The body every node's ``main()`` shares (STYLE.md: ros2/demos ``talker.py``)."""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node

from sfs_ros.ros.params import ParameterError

__all__ = ["run_node"]


def run_node(prog: str, make_node: Callable[[], Node], args=None, *, threads: int = 1) -> None:
    """Initialise rclpy, build the node and spin it until SIGINT or shutdown.

    A parameter refused at start-up prints one line ``prog: reason`` and exits
    with status 2. ``threads`` > 1 spins a multi-threaded executor (for nodes
    whose services wait on worker threads). The node is destroyed and rclpy
    shut down on every way out.
    """
    rclpy.init(args=args)
    try:
        node = make_node()
    except ParameterError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(2)
    executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
