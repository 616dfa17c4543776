"""The body every node's ``main()`` shares (STYLE.md: ros2/demos ``talker.py``)."""

from __future__ import annotations

import faulthandler
import sys
from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node

from sfs_ros.ros.params import ParameterError

__all__ = ["run_node"]


def run_node(prog: str, make_node: Callable[[], Node | list[Node]], args=None, *,
             threads: int = 1) -> None:
    """Initialise rclpy, build the node (or nodes, composed in one process) and spin until
    SIGINT or shutdown.

    A parameter refused at start-up prints one line ``prog: reason`` and exits
    with status 2. ``threads`` > 1 spins a multi-threaded executor (for nodes
    whose services wait on worker threads). The nodes are destroyed (in
    reverse order) and rclpy shut down on every way out. A fatal signal (SIGSEGV,
    SIGABRT, ...) prints every thread's Python stack to stderr before the process
    dies, so a crash in native code names where it happened.
    """
    faulthandler.enable()
    rclpy.init(args=args)
    try:
        made = make_node()
    except ParameterError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(2)
    nodes = made if isinstance(made, list) else [made]
    executor = MultiThreadedExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown()
