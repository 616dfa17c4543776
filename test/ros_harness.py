"""Multi-process ROS 2 test harness (no launch_testing on PyPI).

* Importing this module isolates the test run: ``ROS_DOMAIN_ID`` derived
  from the process id (1..101, the range the ROS docs call safe on every
  platform; 0, the default, is left to interactive use) and
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, in ``os.environ`` before any
  rclpy context exists, so the test process and every child share them.
  Nodes and the probe also run in the namespace ``/sfs_test_<pid>``: two
  test runs that draw the same domain id still cannot see each other's
  topics (all of the cell's names are relative).
* :class:`NodeProcess` runs a node module as a separate OS process
  (``sys.executable -m <module> --ros-args ...``) importing the same
  ``sfs_ros`` as the tests, with message field checks on, logs to a file,
  and stops it with SIGINT (a node killed with SIGKILL leaves Fast DDS
  shared-memory files in /dev/shm; SIGTERM then SIGKILL only if SIGINT is
  ignored for ``grace_s`` seconds, the node's threads' stacks written first).
* :class:`RosProbe` is the test side: an rclpy node in its own context with
  helpers to spin until a condition holds (timeouts generous for a loaded
  2-core machine: node start-up including imports takes several seconds).
* :class:`NodeUnderTest` is one node process with its probe; the test files
  subclass it with their topics and services, and the ``start_node`` /
  ``start_node_for_module`` fixtures of ``conftest.py`` start them and stop
  them at the end, checking that each exited cleanly on SIGINT.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

import sfs_ros
from sfs_ros.cell_logic.message_fields import status_namespace
from sfs_ros.cli.bringup import stop_process

from waiting import wait  # noqa: F401  (for a probe spinning in its own thread)

#: Seconds to wait for a process to come up / for a message. Deadlines that only bound a
#: hang: under a load of ~20 on 2 cores, a node's start-up alone (imports: rclpy, numpy,
#: OpenCV, numba) has taken over 20 s.
STARTUP_TIMEOUT_S = 120.0
MESSAGE_TIMEOUT_S = 120.0

DOMAIN_ID = 1 + os.getpid() % 101
os.environ["ROS_DOMAIN_ID"] = str(DOMAIN_ID)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

#: Namespace of the nodes and the probe of this test run.
NAMESPACE = f"/sfs_test_{os.getpid()}"

#: The directory holding the ``sfs_ros`` package the tests import.
SOURCE_ROOT = Path(sfs_ros.__file__).resolve().parent.parent


def keep_ours(store: list):
    """A ``/diagnostics`` callback appending to ``store`` the arrays of this test run's nodes
    (statuses named ``<namespace>/<node>: ...``): the topic is absolute, shared with any
    other run that drew the same domain id."""
    def keep(array) -> None:
        if array.status and all(status_namespace(s.name) == NAMESPACE for s in array.status):
            store.append(array)
    return keep


class NodeProcess:
    """A node module running in its own process.

    module : str, e.g. ``"sfs_ros.nodes.segmentation_node"`` (run with ``-m``)
    params_file : path, optional (``--params-file``)
    parameters : dict, optional, ``-p name:=value`` overrides (values in
        YAML syntax: ``True`` -> ``true``, lists as ``[a, b]``)
    """

    def __init__(self, module: str, *, params_file=None, parameters: dict | None = None):
        self.module = module
        args = [sys.executable, "-m", module, "--ros-args", "-r", f"__ns:={NAMESPACE}"]
        if params_file is not None:
            args += ["--params-file", str(params_file)]
        for name, value in (parameters or {}).items():
            args += ["-p", f"{name}:={_yaml(value)}"]
        self.args = args
        self._log = tempfile.NamedTemporaryFile(prefix="node_", suffix=".log", delete=False)
        # ROS_PYTHON_CHECK_FIELDS: messages check their fields (a misspelt keyword
        # argument is otherwise silently ignored).
        env = dict(os.environ, PYTHONUNBUFFERED="1", ROS_PYTHON_CHECK_FIELDS="1")
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SOURCE_ROOT),
                                                          env.get("PYTHONPATH")]))
        self.process = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=self._log,
                                        stderr=subprocess.STDOUT, env=env, cwd=SOURCE_ROOT)
        _STARTED.append(self)

    def alive(self) -> bool:
        return self.process.poll() is None

    def output(self) -> str:
        """Everything the process wrote so far (stdout and stderr)."""
        return Path(self._log.name).read_text(errors="replace")

    def wait_exit(self, timeout: float = STARTUP_TIMEOUT_S) -> int:
        """Wait for the process to end by itself; returns its exit code."""
        return self.process.wait(timeout=timeout)

    def stop(self, grace_s: float = 60.0) -> int:
        """SIGINT, then SIGTERM and (after its threads' stacks) SIGKILL only for a node
        held in its stop (:func:`~sfs_ros.cli.bringup.stop_process`); the exit code.

        The grace bounds a hang only: on SIGINT a node finishes the work it has queued
        (a carving, a mesh), seconds on a loaded 2-core machine."""
        code = stop_process(self.process, grace_s)
        self._log.close()
        return code

    def exit_lines(self, timeout: float = STARTUP_TIMEOUT_S) -> tuple[int, list[str]]:
        """For a process expected to end by itself: its exit code and output lines; cleans up."""
        try:
            code = self.wait_exit(timeout)
            return code, self.output().strip().splitlines()
        finally:
            self.cleanup()

    def stop_and_read(self) -> tuple[int, str]:
        """Stop (SIGINT first) and return the exit code and everything written; cleans up."""
        code = self.stop()
        output = self.output()
        self.cleanup()
        return code, output

    def cleanup(self) -> None:
        """Stop the process if running and delete its log."""
        if self.alive():
            self.stop()
        self._log.close()
        Path(self._log.name).unlink(missing_ok=True)


#: Every node process this test run started, so that none outlives the test that lost it.
_STARTED: list[NodeProcess] = []


def stop_leftovers(first: int = 0) -> None:
    """Stop (SIGINT first) and clean up every still running node process among those
    started from the ``first``-th on: a node whose test failed before stopping it would
    otherwise go on publishing into the next tests' namespace."""
    for process in _STARTED[first:]:
        if process.alive():
            process.cleanup()


atexit.register(stop_leftovers)


@contextmanager
def leftovers_stopped():
    """On leaving the block, stop every node process started in it that is still running."""
    first = len(_STARTED)
    try:
        yield
    finally:
        stop_leftovers(first)


def _yaml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_yaml(v) for v in value) + "]"
    return str(value)


class RosProbe:
    """The test process's ROS node, in a private context; call :meth:`close` at the end."""

    def __init__(self, name: str = "test_probe"):
        import rclpy
        from rclpy.context import Context

        from sfs_ros.ros.executor import SingleThreadedExecutor  # safe against a destroy

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, namespace=NAMESPACE, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, condition: Callable[[], bool], *, timeout: float = MESSAGE_TIMEOUT_S,
                   what: str = "condition", process: NodeProcess | None = None) -> None:
        """Spin the probe until ``condition()`` is true; ``AssertionError`` on timeout or if
        ``process`` ends meanwhile (with its output in the message)."""
        deadline = time.monotonic() + timeout
        while not condition():
            if process is not None and not process.alive():
                raise AssertionError(f"{process.module} exited with code "
                                     f"{process.process.returncode} while waiting for {what}:\n"
                                     f"{process.output()}")
            if time.monotonic() > deadline:
                log = f"\nnode output:\n{process.output()}" if process is not None else ""
                raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}{log}")
            self.executor.spin_once(timeout_sec=0.05)

    def call_resending(self, client, request, *, resend_after_s: float, attempts: int,
                       process: NodeProcess | None = None, timeout: float = MESSAGE_TIMEOUT_S):
        """The first answer to ``request`` on ``client``, the request sent again each
        ``resend_after_s`` without an answer, ``attempts`` times in all (the last one
        waited on for ``timeout``). A request can go unanswered through no fault of the
        server: Fast DDS drops a response when the server has not matched a just-made
        client's reply reader yet, and a request sent to a restarted server before it is
        matched is lost. The caller makes sure the request may run twice, or reads a
        second answer for what it is."""
        futures = []
        for attempt in range(attempts):
            futures.append(client.call_async(request))
            last = attempt == attempts - 1
            due = time.monotonic() + (timeout if last else resend_after_s)
            self.spin_until(lambda: any(f.done() for f in futures) or time.monotonic() > due,
                            timeout=timeout + 1.0, what=f"answer of {client.srv_name}",
                            process=process)
            answered = next((f for f in futures if f.done()), None)
            if answered is not None:
                return answered.result()
        raise AssertionError(f"no answer of {client.srv_name} in {attempts} attempts")

    def spin_for(self, seconds: float) -> None:
        """Spin the probe for ``seconds`` (to catch messages that should not come)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def wait_connected(self, publishers=(), subscriptions=(), *, process: NodeProcess | None = None,
                       timeout: float = STARTUP_TIMEOUT_S) -> None:
        """Until every publisher has a matched subscription and every subscription a matched
        publisher (the node under test is up and its QoS compatible)."""
        self.spin_until(lambda: all(p.get_subscription_count() > 0 for p in publishers)
                        and all(s.get_publisher_count() > 0 for s in subscriptions),
                        timeout=timeout, what="the node's topics", process=process)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def set_node_parameters(node_name: str, **values) -> None:
    """Set parameters of ``node_name`` (in the tests' namespace) through its parameter
    services from a probe of its own, as a user would at run time; ``AssertionError``
    with the node's reasons if it refuses any."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    probe = RosProbe(f"set_{node_name}_parameters")
    try:
        client = AsyncParameterClient(probe.node, node_name)
        probe.spin_until(client.services_are_ready, what=f"{node_name}'s parameter services")
        future = client.set_parameters([Parameter(k, value=v) for k, v in values.items()])
        probe.spin_until(future.done, what=f"setting {node_name}'s parameters")
        results = future.result().results
        assert all(r.successful for r in results), results
    finally:
        probe.close()


class NodeUnderTest:
    """A node process and the test's probe; subclasses add the probe's publishers,
    subscriptions and clients, and wait until the node is up.

    module : str, the node module (see :class:`NodeProcess`)
    params_file, parameters : passed to :class:`NodeProcess`
    """

    def __init__(self, module: str, *, params_file=None, parameters: dict | None = None,
                 probe_name: str = "test_probe"):
        self.process = NodeProcess(module, params_file=params_file, parameters=parameters)
        self.probe = RosProbe(probe_name)
        self._parameter_clients: dict = {}

    def parameter_client(self, node_name: str):
        """The probe's ``AsyncParameterClient`` of ``node_name``, its services ready."""
        from rclpy.parameter_client import AsyncParameterClient

        client = self._parameter_clients.get(node_name)
        if client is None:
            client = AsyncParameterClient(self.probe.node, node_name)
            self.probe.spin_until(client.services_are_ready, process=self.process,
                                  what=f"{node_name}'s parameter services")
            self._parameter_clients[node_name] = client
        return client

    def set_parameter(self, node_name: str, name: str, value):
        """Set one parameter of ``node_name`` through its parameter services, as a user
        would at run time; the ``SetParametersResult`` (``successful``, ``reason``)."""
        from rclpy.parameter import Parameter

        future = self.parameter_client(node_name).set_parameters([Parameter(name, value=value)])
        self.probe.spin_until(future.done, what=f"setting {name}", process=self.process)
        return future.result().results[0]

    def close(self) -> tuple[int, str]:
        """Close the probe and stop the node (SIGINT first); its exit code and output."""
        self.probe.close()
        return self.process.stop_and_read()


def node_starter():
    """Generator behind the ``start_node`` fixtures: yields ``start(make, *args, **kwargs)``,
    which returns ``make(*args, **kwargs)`` (a :class:`NodeUnderTest` that waits until its
    node is up); afterwards closes every node started, and fails naming each that did not
    exit with 0 on SIGINT or wrote a traceback. A node whose start failed is stopped too."""
    nodes = []

    def start(make, *args, **kwargs):
        first = len(_STARTED)
        try:
            nodes.append(make(*args, **kwargs))
        except BaseException:
            stop_leftovers(first)
            raise
        return nodes[-1]

    yield start
    failures = []
    for node in nodes:
        code, output = node.close()
        if code != 0 or "Traceback" in output:
            failures.append(f"{node.process.module} exited with code {code} on SIGINT:\n{output}")
    assert not failures, "\n".join(failures)
