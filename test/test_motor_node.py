"""The motor node as a separate OS process, driving a simulated GRBL controller in the test.

The simulator runs in the test process on a pseudo-terminal; the node opens it
by path as it would open the real controller's port.
"""

import math
import os

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from sfs_ros.hardware.driver import GrblClient
from sfs_ros.hardware.simulator import SimulatedGrbl
from sfs_ros.ros import result_qos
from sfs_ros.ros.convert import joint_state
from sfs_ros.ros.names import DIAGNOSTICS, SERVICES

from ros_harness import STARTUP_TIMEOUT_S, NodeProcess, NodeUnderTest, RosProbe, keep_ours
from tolerances import (
    ENCODER_NOISE_DEG,
    ENCODER_OFFSET_DEG,
    PRINT_ROUNDING_DEG,
    READBACK_TOL_RAD,
    ROUND_OFF,
)
from waiting import wait

MODULE = "sfs_ros.nodes.motor_node"
# Targets go on the wire in degrees with 3 decimals: GRBL's step counters end within
# PRINT_ROUNDING_DEG of the target; joint_states, the encoder's read-back, within
# READBACK_TOL_RAD.
SPEED_DEG_S = (720.0, 360.0)      # fast axes keep the test short


@pytest.fixture(scope="module")
def simulator():
    sim = SimulatedGrbl(max_speed_deg_s=SPEED_DEG_S, accel_deg_s2=(3600.0, 1800.0),
                        homing_speed_deg_s=600.0, encoder_offset_deg=ENCODER_OFFSET_DEG,
                        encoder_noise_deg=ENCODER_NOISE_DEG, power_up_true_deg=(30.0, 10.0),
                        start_locked=True, seed=1).start()
    yield sim
    sim.close()


class Cell(NodeUnderTest):
    """The node process plus the probe's publisher, service clients and recorders."""

    def __init__(self, port: str):
        super().__init__(MODULE, parameters={
            "port": port, "status_rate_hz": 20.0, "reconnect_period_s": 0.5,
            "move_timeout_s": 10.0, "home_timeout_s": 5.0})
        node = self.probe.node
        self.command_pub = node.create_publisher(JointState, "joint_command", 10)
        self.joints, self.diagnostics = [], []
        subs = [node.create_subscription(JointState, "joint_states", self.joints.append, 10),
                node.create_subscription(DiagnosticArray, DIAGNOSTICS,
                                         keep_ours(self.diagnostics), 10)]
        self.home_client = node.create_client(Trigger, SERVICES["home"])
        self.stop_client = node.create_client(Trigger, SERVICES["stop"])
        self.probe.wait_connected([self.command_pub], subs, process=self.process)
        self.probe.spin_until(lambda: self.home_client.service_is_ready()
                              and self.stop_client.service_is_ready(),
                              what="home and stop services", process=self.process)

    def call(self, client) -> Trigger.Response:
        """Call a Trigger service, sent again once if unanswered for 10 s
        (``RosProbe.call_resending``); home and stop may safely run twice."""
        return self.probe.call_resending(client, Trigger.Request(), resend_after_s=10.0,
                                         attempts=2, process=self.process)

    def command(self, theta: float, phi: float) -> None:
        self.command_pub.publish(joint_state(theta, phi, stamp=(0, 0)))

    def position(self) -> np.ndarray:
        return np.array(self.joints[-1].position) if self.joints else np.full(2, np.nan)

    def wait_at(self, theta: float, phi: float) -> None:
        target = np.array([theta, phi])
        self.probe.spin_until(lambda: np.all(np.abs(self.position() - target) <= READBACK_TOL_RAD),
                              what=f"joint_states at {target}", process=self.process)

    def errors(self) -> list[str]:
        return [s.message for a in self.diagnostics for s in a.status
                if s.level == DiagnosticStatus.ERROR]

    def wait_error(self, text: str) -> None:
        self.probe.spin_until(lambda: any(text in e for e in self.errors()),
                              what=f"an ERROR diagnostic with {text!r}", process=self.process)


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


@pytest.fixture(scope="module")
def device(simulator, tmp_path_factory):
    """A stable device name (like a udev symlink) pointing at the simulator's pty."""
    link = tmp_path_factory.mktemp("dev") / "ttyGRBL"
    link.symlink_to(simulator.port)
    return link


@pytest.fixture(scope="module")
def cell(start_node_for_module, device):
    return start_node_for_module(Cell, str(device))


def test_home_then_move_converges(cell, simulator):
    answer = cell.call(cell.home_client)
    assert answer.success, answer.message
    assert simulator.state == "Idle"
    cell.wait_at(0.0, 0.0)
    cell.command(1.2, 0.6)
    cell.wait_at(1.2, 0.6)
    cell.probe.spin_for(0.3)                 # and it stays there
    assert np.all(np.abs(cell.position() - [1.2, 0.6]) <= READBACK_TOL_RAD)
    last = cell.joints[-1]
    assert list(last.name) == ["turntable", "carriage"]
    assert last.header.stamp.sec > 0         # stamped now, not the command's stamp
    np.testing.assert_allclose(simulator.true_position_rad(), [1.2, 0.6],
                               atol=math.radians(PRINT_ROUNDING_DEG) + ROUND_OFF)


def test_bad_commands_are_refused(cell, simulator):
    before = simulator.machine_position_deg()
    cell.diagnostics.clear()
    cell.command_pub.publish(joint_state(math.nan, 0.3, stamp=(0, 0)))
    cell.command_pub.publish(JointState(name=["turntable"], position=[0.5]))
    cell.wait_error("expected a finite angle")   # each refusal names what was wrong
    cell.wait_error("carriage")
    assert all("joint_command refused" in e for e in cell.errors())
    assert simulator.machine_position_deg() == before
    cell.command(1.0, 0.5)                   # still obeys good commands
    cell.wait_at(1.0, 0.5)


def test_new_command_preempts_and_stop_interrupts(cell, simulator):
    cell.command(60.0, 0.5)                  # ~3400 deg: ~5 s at 720 deg/s
    cell.probe.spin_until(lambda: cell.position()[0] > 3.0, what="the long move under way",
                          process=cell.process)
    cell.command(2.0, 0.2)                   # behind the axis now: stop, then come back
    cell.wait_at(2.0, 0.2)

    cell.command(60.0, 0.5)
    cell.probe.spin_until(lambda: cell.position()[0] > 5.0, what="the long move under way",
                          process=cell.process)
    answer = cell.call(cell.stop_client)
    assert answer.success, answer.message
    stopped = simulator.machine_position_deg()
    cell.probe.spin_for(0.5)
    assert simulator.machine_position_deg() == stopped        # at rest
    assert math.radians(stopped[0]) < 50.0                    # well short of the target
    assert simulator.state == "Idle"                          # a controlled stop: no alarm
    cell.wait_at(*np.radians(stopped))


def test_limit_alarm_is_reported_and_home_recovers(cell, simulator):
    cell.diagnostics.clear()
    simulator.faults.limit_at_fraction = 0.5
    cell.command(3.0, 0.8)
    cell.wait_error("ALARM:1")
    assert simulator.state == "Alarm"
    cell.probe.spin_for(0.5)
    assert cell.process.alive()
    answer = cell.call(cell.home_client)
    assert answer.success, answer.message
    assert simulator.state == "Idle"
    cell.command(0.4, 0.3)
    cell.wait_at(0.4, 0.3)
    cell.diagnostics.clear()
    cell.probe.spin_until(lambda: cell.diagnostics, what="diagnostics", process=cell.process)
    assert cell.diagnostics[-1].status[0].level == DiagnosticStatus.OK


def test_stall_is_reported_and_home_recovers(cell, simulator):
    cell.diagnostics.clear()
    simulator.faults.stall_axis = "X"        # the turntable slips half way; GRBL goes on
    try:
        cell.command(2.0, 0.5)
        cell.wait_error("short of the target")
    finally:
        simulator.faults.stall_axis = None
    assert cell.process.alive()
    answer = cell.call(cell.home_client)     # homing finds the true position again
    assert answer.success, answer.message
    cell.command(1.5, 0.2)
    cell.wait_at(1.5, 0.2)


def test_a_home_asked_while_homing_joins_it(cell, simulator):
    """A caller may send ``home`` again when its answer is late: one cycle, two answers."""
    # A first call (sent again if its answer is lost) matches the client at the node, so
    # the two calls below are answered whatever the order the tests run in.
    assert cell.call(cell.home_client).success
    simulator.faults.homing_hold = True      # the cycle stays open until released
    simulator.clear_received()
    try:
        first = cell.home_client.call_async(Trigger.Request())
        cell.probe.spin_until(lambda: simulator.state == "Home", what="homing under way",
                              process=cell.process)
        second = cell.home_client.call_async(Trigger.Request())
        cell.probe.spin_until(lambda: "joining the homing under way" in cell.process.output(),
                              what="the second home joining the first", process=cell.process)
    finally:
        simulator.faults.homing_hold = False
    cell.probe.spin_until(lambda: first.done() and second.done(), what="both answers",
                          process=cell.process)
    assert first.result().success and second.result().success, \
        (first.result().message, second.result().message)
    assert simulator.received().count(b"$H") == 1
    assert simulator.state == "Idle"


def test_lost_connection_is_reported_and_the_port_reopened(cell, simulator, device):
    cell.diagnostics.clear()
    simulator.disconnect()
    cell.wait_error("connection lost")
    reported_ns = min(_ns(a.header.stamp) for a in cell.diagnostics
                      if any("connection lost" in s.message for s in a.status))
    cell.joints.clear()
    cell.probe.spin_for(1.0)                 # several reconnect attempts (every 0.5 s)
    assert cell.process.alive()
    # No position while disconnected: nothing stamped after the loss was reported (one
    # published before it may arrive after it: the topics are not ordered with each other).
    assert all(_ns(j.header.stamp) <= reported_ns for j in cell.joints)
    answer = cell.call(cell.home_client)
    assert not answer.success and "not connected" in answer.message
    # The controller comes back (cable plugged in again): same device name, new pty.
    with SimulatedGrbl(max_speed_deg_s=SPEED_DEG_S, homing_speed_deg_s=600.0,
                       encoder_offset_deg=ENCODER_OFFSET_DEG,
                       encoder_noise_deg=ENCODER_NOISE_DEG,
                       seed=2) as replugged:
        device.unlink()
        device.symlink_to(replugged.port)
        cell.probe.spin_until(lambda: any(_ns(j.header.stamp) > reported_ns
                                          for j in cell.joints),
                              what="joint_states after reconnecting", process=cell.process)
        answer = cell.call(cell.home_client)
        assert answer.success, answer.message
        cell.command(0.7, 0.1)
        cell.wait_at(0.7, 0.1)
        device.unlink()                      # a later pty may reuse the number


def test_empty_port_exits_with_one_line():
    process = NodeProcess(MODULE, parameters={"port": "''"})
    code, lines = process.exit_lines()
    assert code != 0
    assert len(lines) == 1 and "'port'" in lines[0], lines


def test_the_mock_port_link_leads_nowhere_once_the_mock_is_killed(tmp_path):
    """A pty number freed by a SIGKILL is soon another process's: the link must not follow."""
    link = tmp_path / "ttyMOCK"
    process = NodeProcess("sfs_ros.nodes.mock_hardware_node",
                          parameters={"port_link": str(link), "seed": 3})
    try:
        wait(lambda: link.is_symlink() or not process.alive(), what="the port link",
             timeout=STARTUP_TIMEOUT_S)
        with GrblClient(str(link)) as client:              # the link opens the controller
            assert client.status().state == "Alarm"
    finally:
        process.process.kill()
        process.process.wait()
    assert link.is_symlink() and not link.exists()          # dangling, not another's pty


def test_mock_hardware_refuses_a_wrong_world_it_cannot_make():
    # The wrong world spoils a pinhole rig; the rig parameters' default is orthographic.
    process = NodeProcess("sfs_ros.nodes.mock_hardware_node", parameters={"world": "wrong"})
    code, lines = process.exit_lines()
    assert code != 0
    assert len(lines) == 1 and "'world'" in lines[0] and "pinhole" in lines[0], lines


def test_mock_hardware_publishes_a_usable_port_and_stops_cleanly():
    process = NodeProcess("sfs_ros.nodes.mock_hardware_node",
                          parameters={"max_speed_deg_s": [720.0, 360.0], "seed": 3})
    probe = RosProbe("mock_probe")
    try:
        ports = []
        # Subscribed after the node published: transient-local still delivers the path.
        probe.node.create_subscription(String, "mock/port", ports.append, result_qos())
        probe.spin_until(lambda: ports, what="mock/port", process=process)
        port = ports[0].data
        probe.spin_until(lambda: port in process.output(), what="the port in the log",
                         process=process)
        # The pty's creation time: once it is closed, its number may go to a pty another
        # process opens (suites run side by side), which is a newer one.
        created_ns = os.stat(port).st_ctime_ns
        with GrblClient(port) as client:
            assert client.status().state == "Alarm"        # start_locked: home first
            assert client.home(timeout_s=5.0).state == "Idle"
            final = client.move_to(0.5, 0.25, timeout_s=5.0)
        assert abs(final.theta_rad - 0.5) <= READBACK_TOL_RAD[0]
        assert abs(final.phi_rad - 0.25) <= READBACK_TOL_RAD[1]
    finally:
        probe.close()
        code, output = process.stop_and_read()
    assert code == 0, f"mock hardware did not exit cleanly on SIGINT (code {code}):\n{output}"
    assert _pty_gone(port, created_ns)                      # the pty is closed


def _pty_gone(port: str, created_ns: int) -> bool:
    """Whether the pty created at ``created_ns`` at ``port`` no longer exists."""
    try:
        return os.stat(port).st_ctime_ns > created_ns       # the number reused since
    except FileNotFoundError:
        return True
