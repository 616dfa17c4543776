"""The motor node's link to its controller without ROS, against the simulated GRBL controller
on a real pseudo-terminal: the alarm lock, moves and homing, stops, a lost port, what the
diagnostics report."""

import math
import threading
import time

import pytest

from sfs_ros.cell_logic.motor_link import LOCKED, MotorLink
from sfs_ros.hardware.simulator import SimulatedGrbl

from tolerances import HANG_S, READBACK_TOL_RAD
from waiting import wait

#: Fast axes so that the moves are short: 900 deg/s, 18000 deg/s^2.
FAST = dict(max_speed_deg_s=(900.0, 900.0), accel_deg_s2=(18000.0, 18000.0),
            homing_speed_deg_s=900.0)
RECONNECT_S = 0.5


class Said:
    """The link's log lines and how often it said the diagnostics were due."""

    def __init__(self):
        self.lines: list[tuple[str, str]] = []
        self.changes = 0

    def log(self, level: str, text: str) -> None:
        self.lines.append((level, text))

    def changed(self) -> None:
        self.changes += 1

    def at(self, level: str) -> list[str]:
        return [text for lvl, text in self.lines if lvl == level]


@pytest.fixture()
def sim():
    with SimulatedGrbl(seed=1, **FAST) as s:
        yield s


@pytest.fixture()
def said():
    return Said()


@pytest.fixture()
def link(sim, said):
    link = MotorLink(sim.port, 115200, RECONNECT_S, log=said.log, changed=said.changed)
    assert link.open(first=True)
    yield link
    link.close()


def test_a_port_that_cannot_be_opened_is_a_warning_said_once_per_reason(tmp_path, said):
    link = MotorLink(str(tmp_path / "no_such_port"), 115200, RECONNECT_S, log=said.log,
                     changed=said.changed)
    assert not link.open(first=True)
    assert len(said.at("warning")) == 1 and said.at("warning")[0].startswith("configure failed")
    link.reconnect()
    link.reconnect()                      # the same reason: not said again
    assert said.at("error") == [] and len(said.at("warning")) == 1
    assert link.health("active") == (link.connection_error, "", "state unknown")


def test_the_power_up_lock_is_a_warning_and_homing_ends_it(link, said):
    link.poll(HANG_S, 2.0)                         # locked, the position read back
    assert (link.state, link.alarm) == ("Alarm", LOCKED)
    assert said.at("info")[-1] == LOCKED and said.at("error") == []
    assert link.health("active") == ("", LOCKED, "state Alarm")
    assert link.drive("home", lambda client: client.home(timeout_s=HANG_S)) is None
    position = link.poll(HANG_S, 2.0)
    assert link.alarm == "" and position is not None
    assert link.health("active") == ("", "", f"state {link.state}")


def test_a_move_is_driven_and_read_back(link, said):
    link.drive("home", lambda client: client.home(timeout_s=HANG_S))
    assert link.drive("move", lambda client: client.move_to(math.pi / 2, 0.5,
                                                            timeout_s=HANG_S)) is None
    assert said.at("info")[-1] == "move done"
    theta, phi = link.poll(HANG_S, 2.0)
    assert theta == pytest.approx(math.pi / 2, abs=READBACK_TOL_RAD[0])
    assert phi == pytest.approx(0.5, abs=READBACK_TOL_RAD[1])
    values = link.values("active", "")
    assert values["connected"] and values["theta_rad"] == f"{theta:.6f}"
    at_rest, text = link.stop()
    assert at_rest and text.startswith("stopped at theta=1.57")


def test_a_fault_lasts_until_the_next_good_move(link, said):
    link.report_fault("joint_command refused: no joints")
    assert link.health("active")[0] == "joint_command refused: no joints"
    assert link.faults == 1 and said.at("error") == ["joint_command refused: no joints"]
    link.drive("home", lambda client: client.home(timeout_s=HANG_S))
    assert link.health("active")[0] == "" and link.values("active", "")["last_fault"] == ""


def test_a_lost_port_is_reported_and_reopened(sim, link, said):
    link.drive("home", lambda client: client.home(timeout_s=HANG_S))
    sim.disconnect()
    wait(lambda: link.poll(HANG_S, 2.0) is None and link.client is None,
         what="the lost port noticed", timeout=HANG_S)
    assert link.state == "disconnected" and link.connection_error.startswith("connection lost")
    assert link.health("active")[0] == link.connection_error
    assert link.stop() == (False, f"not connected: {link.connection_error}")
    assert link.drive("move", lambda client: None) == \
        f"move refused: not connected ({link.connection_error})"
    link.port = sim.replug()                       # the cable back (on a new pty)
    link.reconnect()
    assert link.client is not None and link.connection_error == ""


def test_a_node_not_active_is_a_warning_naming_its_state(link):
    assert link.health("inactive") == (
        "", "the motor node is inactive: activate it (lifecycle change_state)", "")
    link.close()
    assert link.health("unconfigured")[1].endswith("(lifecycle change_state) (port closed)")



def test_two_faults_at_once_are_each_reported_with_their_own_text(tmp_path):
    """Two commands refused at once (two callback threads): the diagnostics published for
    each must carry that fault, not the other's. The first report's diagnostics wait until
    the second report has begun, which is when a fault written unguarded would be
    overwritten before it is published."""
    first_publishing, second_begun = threading.Event(), threading.Event()
    published: list[str] = []

    def changed() -> None:
        if not first_publishing.is_set():
            first_publishing.set()
            second_begun.wait(timeout=HANG_S)
            time.sleep(0.05)                 # the second report's chance to overwrite
        published.append(link.fault)

    link = MotorLink(str(tmp_path / "no_such_port"), 115200, RECONNECT_S,
                     log=lambda level, text: None, changed=changed)
    first = threading.Thread(target=link.report_fault, args=("first fault",))
    first.start()
    assert first_publishing.wait(timeout=HANG_S)
    second_begun.set()
    link.report_fault("second fault")
    first.join(timeout=HANG_S)
    assert published == ["first fault", "second fault"]
    assert link.faults == 2
