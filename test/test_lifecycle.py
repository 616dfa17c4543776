"""The motor and camera nodes as managed (lifecycle) nodes, each a separate OS process started
with ``autostart`` false and driven by a probe through ``<node>/change_state`` and
``<node>/get_state``: configure opens the port (or the camera), activate starts
``joint_states`` (or serves ``capture``), deactivate stops them, cleanup closes the port,
shutdown finalizes from any state.
"""

import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from sfs_ros.hardware.simulator import SimulatedGrbl
from sfs_ros.ros.names import SERVICES

from ros_harness import MESSAGE_TIMEOUT_S, NodeUnderTest
from tolerances import QUIET_S

#: A lifecycle query is asked this many times, waiting this long for each answer, s.
ATTEMPTS, ATTEMPT_S = 12, 10.0


class Managed(NodeUnderTest):
    """A managed node process (``autostart`` false) and the probe's lifecycle clients."""

    def __init__(self, module: str, name: str, **kwargs):
        super().__init__(module, **kwargs)
        node = self.probe.node
        self.get_state = node.create_client(GetState, f"{name}/get_state")
        self.change_state = node.create_client(ChangeState, f"{name}/change_state")
        self.probe.spin_until(lambda: self.get_state.service_is_ready()
                              and self.change_state.service_is_ready(),
                              what="the lifecycle services", process=self.process)

    def answer(self, client, request, *, timeout: float = MESSAGE_TIMEOUT_S):
        """The answer to ``request``; None when none came within ``timeout`` s."""
        future = client.call_async(request)
        deadline = time.monotonic() + timeout
        self.probe.spin_until(lambda: future.done() or time.monotonic() > deadline,
                              timeout=timeout + 1.0, what=f"answer of {client.srv_name}",
                              process=self.process)
        return future.result() if future.done() else None

    def state(self) -> str:
        """The node's state; asked again while no answer comes (Fast DDS drops an answer to
        a client it has not matched yet, after 100 ms: a loaded machine can be slower)."""
        for _ in range(ATTEMPTS):
            answer = self.answer(self.get_state, GetState.Request(), timeout=ATTEMPT_S)
            if answer is not None:
                return answer.current_state.label
        raise AssertionError(f"no answer of {self.get_state.srv_name} in {ATTEMPTS} attempts")

    def transition(self, transition_id: int) -> bool:
        """Whether the transition succeeded: its answer, or (the answer lost, see
        :meth:`state`) whether the node's state changed, as the lifecycle manager finds
        out (a transition is never asked twice)."""
        before = self.state()
        request = ChangeState.Request(transition=Transition(id=transition_id))
        answer = self.answer(self.change_state, request)
        return answer.success if answer is not None else self.state() != before


def write_params(path: Path, **camera) -> Path:
    """A camera params file: a 64 x 48 pinhole rig and ``camera``."""
    rig = {"projection": "pinhole", "width": 64, "height": 48, "fx": 100.0, "fy": 100.0}
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": {**rig, **camera}}}))
    return path


def write_frames(folder: Path, count: int) -> None:
    """``count`` 64 x 48 PNG frames of random content in ``folder``."""
    folder.mkdir()
    rng = np.random.default_rng(3)
    for k in range(count):
        cv2.imwrite(str(folder / f"frame_{k}.png"), rng.integers(0, 256, (48, 64, 3),
                                                                dtype=np.uint8))


def _opened(pid: int, device: str) -> bool:
    """Whether process ``pid`` holds ``device`` open."""
    target = os.path.realpath(device)
    folder = Path(f"/proc/{pid}/fd")
    for fd in folder.iterdir():
        try:
            if os.path.realpath(fd) == target:
                return True
        except OSError:                     # closed meanwhile
            continue
    return False


def _stamp_s(msg: JointState) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


@pytest.fixture()
def simulator():
    with SimulatedGrbl(max_speed_deg_s=(720.0, 360.0), start_locked=False, seed=4) as sim:
        yield sim


def test_the_motor_opens_its_port_on_configure_and_publishes_only_when_active(simulator,
                                                                              start_node):
    motor = start_node(Managed, "sfs_ros.nodes.motor_node", "motor", parameters={
        "port": simulator.port, "autostart": False, "status_rate_hz": 20.0})
    pid = motor.process.process.pid
    joints = []
    motor.probe.node.create_subscription(JointState, "joint_states", joints.append, 10)
    home = motor.probe.node.create_client(Trigger, SERVICES["home"])
    assert motor.state() == "unconfigured" and not _opened(pid, simulator.port)

    assert motor.transition(Transition.TRANSITION_CONFIGURE)
    assert motor.state() == "inactive" and _opened(pid, simulator.port)
    motor.probe.spin_for(QUIET_S)
    assert joints == [] and not home.service_is_ready()  # inactive: no readings, no commands

    assert motor.transition(Transition.TRANSITION_ACTIVATE)
    assert motor.state() == "active"
    motor.probe.spin_until(lambda: len(joints) >= 3, what="joint_states",
                           process=motor.process)
    motor.probe.spin_until(home.service_is_ready, what="home", process=motor.process)
    assert motor.answer(home, Trigger.Request()).success

    assert motor.transition(Transition.TRANSITION_DEACTIVATE)
    deactivated_s = time.time()
    assert motor.state() == "inactive" and _opened(pid, simulator.port)
    motor.probe.spin_for(QUIET_S)
    assert not [j for j in joints if _stamp_s(j) > deactivated_s]
    motor.probe.spin_until(lambda: not home.service_is_ready(), what="home withdrawn",
                           process=motor.process)

    assert motor.transition(Transition.TRANSITION_CLEANUP)
    assert motor.state() == "unconfigured"
    motor.probe.spin_until(lambda: not _opened(pid, simulator.port), what="the port closed",
                           process=motor.process)
    assert motor.transition(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert motor.state() == "finalized"


def test_the_camera_opens_on_configure_and_captures_only_when_active(tmp_path, start_node):
    write_frames(tmp_path / "frames", 3)
    camera = start_node(Managed, "sfs_ros.nodes.camera_node", "camera", params_file=write_params(
        tmp_path / "camera.yaml", backend="folder", folder=str(tmp_path / "frames"), loop=True,
        autostart=False))
    capture = camera.probe.node.create_client(Trigger, SERVICES["capture"])
    assert camera.state() == "unconfigured"
    assert camera.transition(Transition.TRANSITION_CONFIGURE)
    assert camera.state() == "inactive"
    camera.probe.spin_for(QUIET_S)
    assert not capture.service_is_ready()                # served only when active
    assert camera.transition(Transition.TRANSITION_ACTIVATE)
    camera.probe.spin_until(capture.service_is_ready, what="capture", process=camera.process)
    answer = camera.answer(capture, Trigger.Request())
    assert answer.success, answer.message

    assert camera.transition(Transition.TRANSITION_DEACTIVATE)
    camera.probe.spin_until(lambda: not capture.service_is_ready(), what="capture withdrawn",
                            process=camera.process)
    assert camera.transition(Transition.TRANSITION_CLEANUP)
    assert camera.state() == "unconfigured"
    # Configured again, the folder is opened again and serves from its first frame.
    assert camera.transition(Transition.TRANSITION_CONFIGURE)
    assert camera.transition(Transition.TRANSITION_ACTIVATE)
    camera.probe.spin_until(capture.service_is_ready, what="capture", process=camera.process)
    assert camera.answer(capture, Trigger.Request()).success
    assert camera.transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
    assert camera.state() == "finalized"


def test_a_camera_that_cannot_be_opened_refuses_configure(tmp_path, start_node):
    camera = start_node(Managed, "sfs_ros.nodes.camera_node", "camera", params_file=write_params(
        tmp_path / "camera.yaml", backend="folder", folder=str(tmp_path / "missing"),
        autostart=False))
    assert not camera.transition(Transition.TRANSITION_CONFIGURE)
    assert camera.state() == "unconfigured"
    camera.probe.spin_until(lambda: "configure failed" in camera.process.output(),
                            what="the reason in the log", process=camera.process)
