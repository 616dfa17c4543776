"""The scan node alone, as a separate OS process: start-up refusals, its services, and the
pauses when its peers (reconstruction, motor, encoders) are missing.

No other node of the cell runs here (the whole cell is tested with ``sfs-cell``):
the probe calls the scan services and watches ``/diagnostics`` and ``joint_command``.
"""

import functools
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.scan_plan import ScanPlan
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import image_to_msg, joint_state
from sfs_ros.ros.names import DIAGNOSTICS, SERVICES

from ros_harness import MESSAGE_TIMEOUT_S, NodeProcess, NodeUnderTest, keep_ours
from tolerances import QUIET_S

MODULE = "sfs_ros.nodes.scan_node"
#: A small ring plan: the ring listed second (20 deg) is staggered by half a step and taken
#: first, so the first view is (45, 20) deg, not (0, 20).
RINGS = {"rings_phi_deg": [50.0, 20.0], "per_ring": 4, "top_view": True}
PLAN = ScanPlan.from_rings(RINGS["rings_phi_deg"], RINGS["per_ring"], RINGS["top_view"],
                           stagger=True, reorder=True)
N = len(PLAN)                 # 9 views
SERVICE_TIMEOUT_S = 1.0       # service_timeout_s and home_timeout_s
MOVE_TIMEOUT_S = 1.0
MOVE_RETRIES = 2
FAST = {**RINGS, "service_timeout_s": SERVICE_TIMEOUT_S, "home_timeout_s": SERVICE_TIMEOUT_S,
        "move_timeout_s": MOVE_TIMEOUT_S, "move_retries": MOVE_RETRIES, "queue_depth": 20}


class ScanStatus:
    """One status of the scan node's diagnostics."""

    def __init__(self, status: DiagnosticStatus):
        self.level, self.message = status.level, status.message
        self.values = {kv.key: kv.value for kv in status.values}


class ScanNodeUnderTest(NodeUnderTest):
    """The node process, the probe's ``scan/*`` clients and its recorders."""

    def __init__(self, **parameters):
        super().__init__(MODULE, parameters={**FAST, **parameters})
        node = self.probe.node
        self.diagnostics, self.commands = [], []
        subs = [node.create_subscription(DiagnosticArray, DIAGNOSTICS,
                                         keep_ours(self.diagnostics), 10),
                node.create_subscription(JointState, "joint_command", self.commands.append, 10)]
        self.clients = {name: node.create_client(Trigger, SERVICES[f"scan/{name}"])
                        for name in ("start", "cancel", "resume")}
        self.probe.wait_connected(subscriptions=subs, process=self.process)
        # The services, and a first report (the node's writers have matched the probe too).
        self.probe.spin_until(lambda: all(c.service_is_ready() for c in self.clients.values())
                              and self.statuses(), what="scan services and a report", process=self.process)

    def call(self, name: str) -> Trigger.Response:
        future = self.clients[name].call_async(Trigger.Request())
        self.probe.spin_until(future.done, what=f"scan/{name} answer", process=self.process)
        return future.result()

    def statuses(self) -> list[ScanStatus]:
        return [ScanStatus(s) for array in self.diagnostics for s in array.status
                if s.name.endswith(": scan")]

    def wait_paused(self, scan: int, *, timeout: float = MESSAGE_TIMEOUT_S) -> ScanStatus:
        """Until scan number ``scan`` reports state paused; that status."""
        def paused():
            return [s for s in self.statuses()
                    if s.values["scan"] == str(scan) and s.values["state"] == "paused"]
        self.probe.spin_until(paused, timeout=timeout, what=f"scan {scan} paused",
                              process=self.process)
        return paused()[0]


@pytest.fixture()
def start(start_node):
    """``start(**parameters)`` -> a running node, stopped cleanly after the test."""
    return functools.partial(start_node, ScanNodeUnderTest)


@pytest.mark.parametrize("plan_text, parameters, name, words", [
    (None, {"plan_file": "no/such/plan.yaml"}, "plan_file",
     "cannot read scan plan no/such/plan.yaml"),
    ("views: [[0, 100]]\n", {}, "plan_file", "phi 100.0 deg, outside the carriage range"),
    # The default rings: 16 per ring x 3 rings + the top view = 49 views.
    (None, {"queue_depth": 10}, "queue_depth", "got 10, expected at least the 49 views"),
])
def test_invalid_start_up_exits_with_one_line_naming_the_parameter(tmp_path, plan_text,
                                                                   parameters, name, words):
    if plan_text is not None:
        (tmp_path / "plan.yaml").write_text(plan_text)
        parameters = {"plan_file": str(tmp_path / "plan.yaml")}
    code, lines = NodeProcess(MODULE, parameters=parameters).exit_lines()
    assert code == 2
    assert len(lines) == 1 and f"'{name}'" in lines[0] and words in lines[0], lines


def test_idle_services_and_a_start_without_the_reconstruction_pauses(start):
    node = start()
    idle = node.statuses()[0]
    assert idle.level == DiagnosticStatus.OK and idle.message.startswith(f"idle: 0 of {N} views")
    assert (idle.values["state"], idle.values["scan"], idle.values["total"]) == ("idle", "0", str(N))
    response = node.call("resume")
    assert not response.success and response.message.startswith("no scan to resume"), \
        response.message
    response = node.call("cancel")
    assert not response.success and response.message.startswith("no scan is running"), \
        response.message

    for scan in (1, 2):           # the node stays up and takes the next scan/start
        sent_s = time.monotonic()
        response = node.call("start")
        assert response.success and response.message == f"scan {scan} started: {N} views"
        status = node.wait_paused(scan)
        # The reset call gives up only after service_timeout_s (counted from before the call).
        assert time.monotonic() - sent_s >= SERVICE_TIMEOUT_S
        assert status.level == DiagnosticStatus.ERROR
        assert f"scan paused at view 1 of {N}" in status.message, status.message
        assert "service carving/new_scan is not available (waited 1 s)" in status.message
        assert node.process.alive()
    node.probe.spin_for(QUIET_S)
    assert node.commands == []                 # nothing moved before the reset


def test_a_start_without_the_motor_node_pauses_on_homing(start):
    node = start(reset_reconstruction=False, home_before_scan=True)
    response = node.call("start")
    assert response.success and response.message == f"scan 1 started: {N} views"
    status = node.wait_paused(1)
    assert status.level == DiagnosticStatus.ERROR
    assert "service motor/home is not available (waited 1 s)" in status.message, status.message
    node.probe.spin_for(QUIET_S)
    assert node.commands == [] and node.process.alive()


def test_the_first_view_is_commanded_and_the_scan_pauses_without_encoder_readings(start):
    node = start(reset_reconstruction=False, home_before_scan=False)
    sent_s = time.monotonic()
    response = node.call("start")
    assert response.success and response.message == f"scan 1 started: {N} views"
    attempts = MOVE_RETRIES + 1
    # Each attempt waits move_timeout_s for a reading that never comes; plus the usual margin.
    status = node.wait_paused(1, timeout=attempts * MOVE_TIMEOUT_S + MESSAGE_TIMEOUT_S)
    assert time.monotonic() - sent_s >= attempts * MOVE_TIMEOUT_S
    assert status.level == DiagnosticStatus.ERROR
    assert f"scan paused at view 1 of {N} (theta 45.00, phi 20.00 deg)" in status.message
    assert "timeout" in status.message and "no encoder reading" in status.message, \
        status.message
    assert f"after {attempts} attempts" in status.message
    assert status.values["move_retries"] == str(MOVE_RETRIES)
    assert status.values["captured"] == "0"

    # The first planned view, commanded once per attempt, exactly as planned (radians):
    # every command arrives, then a quiet while brings no extra one.
    node.probe.spin_until(lambda: len(node.commands) >= attempts, what=f"{attempts} commands",
                          process=node.process)
    node.probe.spin_for(QUIET_S)
    assert len(node.commands) == attempts
    for command in node.commands:
        assert list(command.name) == ["turntable", "carriage"]
        assert list(command.position) == [float(v) for v in PLAN.views[0]]
    retries = [s for s in node.statuses() if s.level == DiagnosticStatus.WARN]
    assert retries and all("retrying" in s.message for s in retries)


def test_joint_states_of_another_machine_are_ignored_with_one_info_line(start):
    node = start(reset_reconstruction=False, home_before_scan=False)
    arm = node.probe.node.create_publisher(JointState, "joint_states", 10)
    node.probe.wait_connected(publishers=[arm], process=node.process)
    for i in range(20):         # a robot arm's joint_state_broadcaster on the same topic
        arm.publish(JointState(name=["shoulder", "elbow"], position=[0.1 * i, 0.2]))
    cell_joint_missing = JointState(name=["turntable"], position=[0.5])   # the cell's, broken
    arm.publish(cell_joint_missing)

    def malformed() -> int:
        return int(node.statuses()[-1].values["malformed"])
    node.probe.spin_until(lambda: malformed() == 1, what="the broken joint state counted",
                          process=node.process)
    node.probe.spin_for(QUIET_S)
    assert malformed() == 1                   # only the cell's broken one
    output = node.process.output()
    assert output.count("joint state has none of the cell's joints") == 1, output
    assert output.count("ERROR") == 1 and "has no joint 'carriage'" in output, output


def test_the_camera_trigger_can_change_between_scans_and_a_bad_value_is_refused(start):
    node = start(reset_reconstruction=False, home_before_scan=False)

    def set_one(name, value):
        return node.set_parameter("scan", name, value)

    def trigger() -> str:
        future = node.parameter_client("scan").get_parameters(["camera_trigger"])
        node.probe.spin_until(future.done, what="reading camera_trigger", process=node.process)
        return future.result().values[0].string_value

    refused = set_one("camera_trigger", "video")
    assert not refused.successful
    assert "'camera_trigger'" in refused.reason and "one of ['shutter', 'stream']" in \
        refused.reason, refused.reason
    negative = set_one("exposure_delay_s", -1.0)
    # rclpy's own range check of the descriptor answers first, naming the parameter and range.
    assert not negative.successful and "exposure_delay_s" in negative.reason \
        and "0.0" in negative.reason, negative.reason
    assert not set_one("queue_depth", 50).successful                  # read-only
    assert trigger() == "shutter"                                     # the old one kept
    assert set_one("camera_trigger", "stream").successful
    assert set_one("exposure_delay_s", 0.05).successful
    assert trigger() == "stream"


class StreamingDriver:
    """A stand-in for a third-party camera driver and the cell's encoders, in the probe.

    Every ``PERIOD_S`` it publishes the encoders at the last commanded viewpoint (the axes
    reach it at once) and a frame on ``image_raw`` with the sensor-data QoS (best effort),
    as many drivers do. The driver has ``LATENCY_S`` of latency: a frame is stamped when
    exposed and published that much later, so when the axes settle, frames exposed on the
    way are still coming. ``seen[stamp]`` is the viewpoint a frame was exposed at.
    """

    PERIOD_S = 0.05
    LATENCY_S = 0.3

    def __init__(self, node):
        self.node = node
        self.target = (0.0, 0.0)
        self.seen: dict[tuple[int, int], tuple[float, float]] = {}
        self.exposed: list[tuple[float, tuple, tuple]] = []   # (publish at, stamp, viewpoint)
        self.encoders = node.create_publisher(JointState, "joint_states", 10)
        self.camera = node.create_publisher(Image, "image_raw", qos_profile_sensor_data)
        node.create_subscription(JointState, "joint_command", self._command, 10)
        node.create_timer(self.PERIOD_S, self._tick)

    def _command(self, msg: JointState) -> None:
        self.target = tuple(float(v) for v in msg.position)

    def _tick(self) -> None:
        now = self.node.get_clock().now()
        self.encoders.publish(joint_state(*self.target, stamp=now.to_msg()))
        stamp = now.to_msg()
        self.exposed.append((time.monotonic() + self.LATENCY_S, stamp, self.target))
        while self.exposed and self.exposed[0][0] <= time.monotonic():
            _, stamp, seen = self.exposed.pop(0)
            self.seen[(stamp.sec, stamp.nanosec)] = seen
            self.camera.publish(image_to_msg(np.zeros((6, 8, 3), np.uint8), stamp=stamp,
                                             frame_id="camera_optical"))


def test_a_streaming_driver_with_best_effort_frames_gives_every_view_at_its_viewpoint(start):
    node = start(reset_reconstruction=False, home_before_scan=False, camera_trigger="stream",
                 image_reliability="best_effort", exposure_delay_s=0.1)
    driver = StreamingDriver(node.probe.node)
    captures = []
    node.probe.node.create_subscription(Image, "capture/image", captures.append,
                                        capture_qos(20))
    node.probe.wait_connected(publishers=[driver.camera, driver.encoders],
                              process=node.process)
    assert node.call("start").success
    node.probe.spin_until(lambda: node.statuses()[-1].values["state"] == "done",
                          what="the scan done", process=node.process)
    # No reconstruction receipts the captures here: a scan slower than the receipt timeout
    # (a loaded machine) sends them again, so views are counted by their stamps.
    def views():
        return list(dict.fromkeys((c.header.stamp.sec, c.header.stamp.nanosec) for c in captures))

    node.probe.spin_until(lambda: len(views()) == N, what=f"{N} captures",
                          process=node.process)
    assert node.statuses()[-1].values["trigger"] == "stream"
    # Each view is a frame the driver streamed, exposed at that view's viewpoint (not on
    # the way to it, although such frames arrived after the axes had settled).
    for stamp, view in zip(views(), PLAN.views):
        seen = driver.seen[stamp]
        assert seen == tuple(float(v) for v in view)
