"""Shared fixtures (a simulated scan of a known object, written as a session folder; ROS
nodes started for a test and stopped cleanly), the ``ros`` marker, put automatically
on every test of a module that uses ROS 2 (see :func:`uses_ros`), and the kernels of the
``sfs_ros`` the tests import compiled before a session that starts nodes
(:func:`pytest_collection_finish`)."""

import inspect
import os
import subprocess
import sys
import time

import pytest

from sfs_ros.cli import warm_up
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan
from sfs_ros.process import configure_process

from ros_harness import SOURCE_ROOT, leftovers_stopped, node_starter

#: Small pinhole camera so the end-to-end tests stay fast: 320 x 240 px, 0.6 m away.
TEST_RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=700.0, fy=700.0,
                          camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
#: Three rings of 16 views plus one from above.
TEST_PLAN = ring_plan([15.0, 40.0, 65.0], 16, top_view=True)


@pytest.fixture(scope="session")
def mug():
    return make_object("mug")


@pytest.fixture(scope="session")
def mug_captures(mug):
    return simulate_scan(mug, TEST_RIG, TEST_PLAN, seed=1)


def write_mug_session(folder, mug, captures):
    """Write the scan as a session folder with a carving box 1 cm around the mug."""
    write_session(folder, [(c.name, c.image) for c in captures],
                  [(c.theta_rad, c.phi_rad) for c in captures], TEST_RIG,
                  bounds_m=carving_box(mug))
    return folder


@pytest.fixture()
def mug_session(tmp_path, mug, mug_captures):
    """A fresh session folder of the mug scan (tests may damage it)."""
    return write_mug_session(tmp_path / "mug_session", mug, mug_captures)


@pytest.fixture(scope="session")
def mug_views(tmp_path_factory, mug, mug_captures):
    """The mug scan loaded as a ViewSet (shared: do not modify its files)."""
    return load_views(write_mug_session(tmp_path_factory.mktemp("scan") / "session", mug,
                                       mug_captures))


@pytest.fixture()
def start_node():
    """``start_node(NodeClass, *args)``: a node under test (:class:`ros_harness.NodeUnderTest`)
    for one test; it must exit with 0 on SIGINT, without a traceback, when the test ends."""
    yield from node_starter()


@pytest.fixture(scope="module")
def start_node_for_module():
    """The same for a node the tests of a module share, stopped when the module ends."""
    yield from node_starter()


@pytest.fixture(autouse=True)
def no_node_outlives_its_test():
    """Whatever a test started and lost (it failed before stopping a node), stopped after it;
    nodes of module fixtures, started before, are left running."""
    with leftovers_stopped():
        yield


#: Where a module's names come from when it uses ROS 2: rclpy, the node harness and the
#: mock cell (which start node processes), and sfs_ros's ROS layers; message and service
#: packages are recognised by their names (``*_msgs``, ``*_srvs``, ``*_interfaces``).
ROS_MODULES = ("rclpy", "ros_harness", "mock_cell", "sfs_ros.ros", "sfs_ros.nodes")


def uses_ros(module) -> bool:
    """Whether a test module imports anything from ROS 2 or the ROS layers."""
    for value in vars(module).values():
        origin = value.__name__ if inspect.ismodule(value) else getattr(value, "__module__", None)
        if not isinstance(origin, str) or origin == "builtins":
            continue
        package = origin.partition(".")[0]
        if package.endswith(("_msgs", "_srvs", "_interfaces")) or any(
                origin == name or origin.startswith(name + ".") for name in ROS_MODULES):
            return True
    return False


def pytest_collection_modifyitems(config, items):
    """Mark every test of a module that uses ROS 2 with ``ros`` (``-m "not ros"`` skips them)."""
    verdicts = {}
    for item in items:
        module = getattr(item, "module", None)
        if module is None:
            continue
        if module.__name__ not in verdicts:
            verdicts[module.__name__] = uses_ros(module)
        if verdicts[module.__name__]:
            item.add_marker(pytest.mark.ros)


#: A cold warm-up compiles every kernel: one to two minutes on 2 busy cores; the bound only
#: catches a hang.
WARM_UP_TIMEOUT_S = 900


def warm_kernels(config) -> None:
    """Compile and cache the kernels of the ``sfs_ros`` the tests import (``sfs-warm-up``
    in a process of its own, importing that copy: the source tree under ``colcon test``
    and a plain pytest run, not the installed package) unless they are already
    (:func:`sfs_ros.cli.warm_up.is_warm`); says so on the terminal, with the seconds. A
    warm-up that fails is reported, and the tests compile what they use."""
    if warm_up.is_warm():
        return
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    say = reporter.write_line if reporter is not None else print
    say(f"compiling the kernels of {warm_up.PACKAGE} (sfs-warm-up: not cached for these "
        "sources yet) ...")
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.warm_up"], cwd=SOURCE_ROOT,
                          env=dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [
                              str(SOURCE_ROOT), os.environ.get("PYTHONPATH")]))),
                          stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=WARM_UP_TIMEOUT_S)
    if done.returncode != 0:
        say(f"the warm-up failed (exit {done.returncode}); the tests compile what they use:\n"
            f"{done.stderr[-3000:]}")
        return
    say(f"kernels compiled and cached in {time.monotonic() - start:.0f} s")


def pytest_collection_finish(session):
    """Before a session in which node processes start (a ``ros`` test selected): the
    kernels warmed (:func:`warm_kernels`), so that each node loads them from the cache
    instead of compiling them under its test's deadlines (a cold reconstruction node on
    a loaded machine answered its first request later than its test waited)."""
    if not session.config.option.collectonly and any(
            item.get_closest_marker("ros") for item in session.items):
        warm_kernels(session.config)


@pytest.fixture(scope="session")
def kernels_warmed(request):
    """The same for a session of tests that need the cache warm without a ``ros`` test."""
    warm_kernels(request.config)


def pytest_configure(config):
    """The test session's process set up as the tools' are (one BLAS thread)."""
    configure_process()
