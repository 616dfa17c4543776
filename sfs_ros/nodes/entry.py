"""The body every node's ``main()`` shares (STYLE.md: ros2/demos ``talker.py``)."""

from __future__ import annotations

import faulthandler
import os
import re
import signal
import sys
import tempfile
from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from sfs_ros.ros.executor import DrainingExecutor, SingleThreadedExecutor
from sfs_ros.ros.names import CONFIGURATION_ERROR
from sfs_ros.ros.params import ParameterError

__all__ = ["run_node"]

#: Longest wait of the spinning main thread before it looks for a stop signal, seconds.
SIGNAL_POLL_S = 0.1


class _StopSignals:
    """SIGINT and SIGTERM ask the main thread to stop spinning; a second one while it
    stops acts as if this handler were not there (SIGINT: KeyboardInterrupt; SIGTERM: the
    process ends), an escape from a stop that hangs."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.requested = False
        self._previous = {sig: signal.signal(sig, self._on_signal) for sig in self.SIGNALS}

    def _on_signal(self, signum, _frame) -> None:
        if not self.requested:
            self.requested = True
            return
        self.restore()
        signal.raise_signal(signum)

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def run_node(prog: str, make_node: Callable[[], Node | list[Node]], args=None, *,
             threads: int = 1) -> None:
    """Initialise rclpy, build the node (or nodes, composed in one process) and spin until
    SIGINT, SIGTERM or shutdown.

    A parameter refused at start-up, or arguments rcl cannot parse (a parameters file
    it cannot read), print one line ``prog: reason`` and exit with status
    :data:`~sfs_ros.ros.names.CONFIGURATION_ERROR`. ``threads`` > 1 spins a multi-threaded executor (for nodes
    whose services wait on worker threads). On a stop signal the executor is shut
    down (the callbacks running end, none starts), then the nodes are destroyed
    (in reverse order; a managed node's destroy releases its hardware from any
    state) while rcl is still up, so that what they log on the way reaches
    ``rosout``, then rcl is shut down: all in the main thread, one after the
    other. rclpy's own signal handling would shut rcl down from a thread of its
    own, which then triggers the executors' guard conditions, and that raced the
    executor's shutdown (now and then a SIGSEGV in
    ``rcl_trigger_guard_condition`` as the node stopped). A fatal signal
    (SIGSEGV, SIGABRT, ...) prints every thread's Python stack to stderr
    before the process dies, so a crash in native code names where it happened;
    SIGUSR1 prints them and the node runs on, so a node that does not stop names
    where it is held, even in native code (``sfs-cell`` asks for them before it
    kills a node).
    """
    faulthandler.enable()
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    _init_rclpy(prog, args)
    stop = _StopSignals()     # from here on: a signal during the start-up ends it cleanly too
    try:
        made = make_node()
    except ParameterError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(CONFIGURATION_ERROR)
    nodes = made if isinstance(made, list) else [made]
    executor = DrainingExecutor(num_threads=threads) if threads > 1 else SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    try:
        # A signal's Python handler runs only between waits: they are kept short.
        while not stop.requested and rclpy.ok():
            executor.spin_once(timeout_sec=SIGNAL_POLL_S)
    except ExternalShutdownException:
        pass
    finally:
        executor.shutdown()
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()


def _init_rclpy(prog: str, args) -> None:
    """``rclpy.init`` with ``args``; arguments rcl cannot parse (a parameters file that is
    not valid, a bad ``--ros-args`` option) print one line ``prog: configuration error: ...``
    and exit with :data:`~sfs_ros.ros.names.CONFIGURATION_ERROR`. rcl logs its own lines about them to the
    process's stderr (file descriptor 2): held back while it parses, given back if it
    succeeds."""
    error = None
    with tempfile.TemporaryFile() as held:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(held.fileno(), 2)
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except RuntimeError as exc:     # rclpy's RCLError
            error = exc
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if error is None:
            held.seek(0)
            sys.stderr.write(held.read().decode("utf-8", "replace"))
            return
    print(f"{prog}: configuration error: {_rcl_reason(error)}", file=sys.stderr)
    sys.exit(CONFIGURATION_ERROR)


def _rcl_reason(error: Exception) -> str:
    """rcl's error text on one line, without its source locations (``at parse.c:835``)."""
    text = re.sub(r",?\s*at \S+\.c:\d+", "", str(error))
    text = re.sub(r"^failed to initialize rcl:\s*", "", " ".join(text.split()))
    if "params file" not in text:
        return f"ROS arguments rcl cannot read: {text}"
    return text.rstrip(" ,.") + " (expected a parameters file of the form "\
        "'NODE: {ros__parameters: {NAME: VALUE}}', each list of one type)"
