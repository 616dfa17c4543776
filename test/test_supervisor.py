"""The bring-up's supervisor: a node that ends by itself is started again after a back-off;
a crash loop stops the cell. Plain processes stand in for nodes (no ROS needed)."""

import io
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

from sfs_ros.cli.bringup import Cell, RestartPolicy, wait_until_signal

#: Bounds a hang only; nothing here measures speed.
DEADLINE_S = 60.0


@dataclass
class ScriptSpec:
    """A stand-in node: a command with the interface ``Cell`` uses."""

    name: str
    argv: list
    environment: dict = field(default_factory=dict)

    def command(self, namespace: str = "") -> list[str]:
        return list(self.argv)

    def applied_rig_file(self) -> str:
        return ""


def poll(condition, what: str):
    deadline = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_back_off_doubles_and_a_crash_loop_gives_up():
    policy = RestartPolicy(first_delay_s=0.5, max_delay_s=3.0, max_restarts=4, window_s=100.0)
    assert [policy.delay("scan", t) for t in (0.0, 1.0, 2.0, 3.0)] == [0.5, 1.0, 2.0, 3.0]
    assert policy.delay("scan", 4.0) is None           # a fifth end within the window
    assert policy.delay("motor", 4.0) == 0.5           # counted per node
    assert policy.delay("scan", 103.5) == 0.5          # all four left the 100 s window
    fresh = RestartPolicy(first_delay_s=1.0, max_restarts=2, window_s=10.0)
    assert fresh.delay("a", 0.0) == 1.0 and fresh.delay("a", 5.0) == 2.0
    assert fresh.delay("a", 20.0) == 1.0               # both earlier restarts left the window


def test_a_killed_node_is_started_again_and_the_cell_stops_cleanly():
    # sleep(1) ends on SIGINT at any moment of its life, which counts as a clean stop
    # (a Python stand-in could be interrupted before it installs its handler).
    spec = ScriptSpec("sleeper", ["sleep", "600"])
    cell = Cell([spec], log=None).start()
    first = cell.processes["sleeper"]
    stopping = threading.Event()
    log = io.StringIO()
    result = {}
    supervisor = threading.Thread(target=lambda: result.update(
        status=wait_until_signal(cell, policy=RestartPolicy(first_delay_s=0.1),
                                 stopping=stopping, log=log)))
    supervisor.start()
    try:
        os.kill(first.pid, signal.SIGKILL)
        poll(lambda: cell.processes["sleeper"] is not first
             and cell.processes["sleeper"].poll() is None, "the restarted node")
    finally:
        stopping.set()
        supervisor.join(DEADLINE_S)
    assert result["status"] == 0
    assert "node sleeper ended by itself (exit status -9); restarting it in 0.1 s" in log.getvalue()
    assert all(p.poll() is not None for p in cell.processes.values())


def test_a_crash_loop_stops_the_cell_with_status_1():
    cell = Cell([ScriptSpec("crasher", [sys.executable, "-c", "raise SystemExit(3)"])],
                log=None).start()
    log = io.StringIO()
    status = wait_until_signal(cell, policy=RestartPolicy(first_delay_s=0.01, max_restarts=3),
                               stopping=threading.Event(), log=log)
    assert status == 1
    assert log.getvalue().count("restarting it") == 3
    assert "node crasher ended 3 times within 120 s (last exit status 3)" in log.getvalue()
