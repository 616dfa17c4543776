"""The issue's acceptance: a Calibrate goal makes a running cell in the wrong world scan true.

The small mock cell (:mod:`mock_cell`: 320 x 240, fast axes, the 17-view plan) in the
mock's wrong world (:mod:`sfs_ros.hardware.mock_world`), every node a process, nothing
restarted between the steps:

1. the mug is scanned with the nominal rig (``config/rig.yaml``) and reconstructed;
2. the board is put on the plate (the mock's ``object`` set at run time) and a
   ``Calibrate`` goal with ``apply`` runs (the board scan on ``calibration/*``, the fit,
   the rig set on the nodes that hold it);
3. the mug is put back and scanned again.

Checked: the volume IoU of the mesh against the true mug rises (figures and margin at
:data:`IOU_RISE_MIN`); the result names the rig file, the views and the nodes that took
it; the TF chain turntable -> camera_optical (composed from ``/tf`` + ``/tf_static``) at
the second scan's last joint state is the calibrated rig's camera; the board's captures
never reached segmentation or reconstruction (the board scan's session folder is the
calibration's); no ERROR in the log after start-up.
"""

from pathlib import Path

import numpy as np
import pytest
import yaml
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth
from sfs_ros.ros import capture_qos
from sfs_ros.ros.rig_apply import read_rig_file
from sfs_ros.ros.rig_params import rig_calibration

from mock_cell import RESOLUTION, SCAN_TIMEOUT_S, no_fault, running_cell
from ros_harness import NAMESPACE
from test_frames import chain
from test_tf_node import matrix, static_listener_qos
from waiting import wait

pytestmark = pytest.mark.cell

#: Frames of this run only (/tf is global).
PREFIX = NAMESPACE.strip("/") + "/"
#: The calibration plan: the board from 35 viewpoints, theta -75..75 deg in 25 deg steps
#: at phi 0..60 deg in 15 deg steps (config/calibration_plan.yaml's spread, thinned).
PLAN = {"views": [[theta, phi] for phi in (0, 15, 30, 45, 60)
                  for theta in range(-75, 76, 25)], "reorder": True}
#: The rise of the volume IoU the calibration must bring, 17 views at 64^3 (doc/calibration.md
#: gives the figures measured): about 0.16. The bar keeps 0.06 below it, several times the
#: run-to-run spread of one scan's IoU (encoder and image noise, about 0.01).
IOU_RISE_MIN = 0.1
#: Pose agreement of the TF chain with the rig model, metres and matrix entries (float64
#: messages, round-off ~1e-15).
POSE_TOL = 1e-6
CALIBRATE_TIMEOUT_S = 600.0


def _set_object(client, name: str) -> None:
    """Put ``name`` on the mock's plate (its ``object`` parameter), as a user would."""
    parameters = AsyncParameterClient(client.node, f"{NAMESPACE}/mock_hardware")
    wait(parameters.services_are_ready, what="the mock's parameter services")
    future = parameters.set_parameters([Parameter("object", value=name)])
    wait(future.done, what=f"object {name} set")
    assert future.result().results[0].successful, future.result().results[0].reason


def _scan_mug(client, name: str) -> float:
    """Scan the mug, reconstruct it; its volume IoU against the true mug."""
    client.scan_goal(scan_name=name, timeout_s=SCAN_TIMEOUT_S)
    summary = client.reconstruct(resolution=RESOLUTION, output_name=f"{name}.ply",
                                 pictures=False)
    mug = make_object("mug")
    vertices, faces = load_mesh(Path(summary["path"]))
    grid = VoxelGrid.cube(*carving_box(mug), RESOLUTION)
    return score_against_truth(mug, vertices, faces, grid)["volume_iou"]


class _Tf:
    """``/tf``, ``/tf_static`` (this run's frames) and ``joint_states`` as received."""

    def __init__(self, node):
        self.tf, self.static, self.joints = [], [], {}
        node.create_subscription(TFMessage, "/tf", self._keep(self.tf), capture_qos(100))
        node.create_subscription(TFMessage, "/tf_static", self._keep(self.static),
                                 static_listener_qos())
        node.create_subscription(JointState, "joint_states", self._on_joints, 10)

    @staticmethod
    def _keep(store: list):
        def keep(msg) -> None:
            if any(t.child_frame_id.startswith(PREFIX) for t in msg.transforms):
                store.append(msg)
        return keep

    def _on_joints(self, msg: JointState) -> None:
        angles = dict(zip(msg.name, msg.position))
        self.joints[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = \
            (angles["turntable"], angles["carriage"])

    def camera_in_turntable(self):
        """(4x4 object -> camera, (theta, phi)) at the latest /tf with a known joint state."""
        static = [(t.header.frame_id, t.child_frame_id, matrix(t.transform))
                  for t in self.static[-1].transforms]
        for msg in reversed(self.tf):
            stamp = (msg.transforms[0].header.stamp.sec, msg.transforms[0].header.stamp.nanosec)
            if stamp in self.joints:
                tree = static + [(t.header.frame_id, t.child_frame_id, matrix(t.transform))
                                 for t in msg.transforms]
                base = PREFIX + "base_link"
                camera = chain(tree, base, PREFIX + "camera_optical")
                turntable = chain(tree, base, PREFIX + "turntable")
                return np.linalg.inv(camera) @ turntable, self.joints[stamp]
        raise AssertionError("no /tf message with a joint state of the same stamp")


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    root = tmp_path_factory.mktemp("calibrate_action")
    plan = root / "calibration_plan.yaml"
    plan.write_text(yaml.safe_dump(PLAN))
    overrides = {"mock_hardware.yaml": {"world": "wrong", "object": "mug"},
                 "frames.yaml": {"frame_prefix": PREFIX}}
    with running_cell(root, "calibrate_action_client", no_fault(overrides)) as cell:
        client, started = cell["client"], len(cell["log"].read_text())
        tf = _Tf(client.node)
        result = {"nominal": _scan_mug(client, "nominal")}
        _set_object(client, "board")
        feedback = []
        result["answer"] = client.calibrate(plan_file=str(plan), apply=True,
                                            feedback=feedback.append,
                                            timeout_s=CALIBRATE_TIMEOUT_S)
        _set_object(client, "mug")
        result["calibrated"] = _scan_mug(client, "calibrated")
        wait(lambda: tf.static and tf.tf, what="/tf and /tf_static")
        result["pose"], result["angles"] = tf.camera_in_turntable()
        result.update(feedback=feedback, output=cell["output"],
                      log=cell["log"].read_text()[started:])
    print(f"\nvolume IoU against the true mug, 17 views at {RESOLUTION}^3, wrong world: "
          f"nominal rig {result['nominal']:.4f}, calibrated {result['calibrated']:.4f}")
    return result


def test_the_calibration_applied_to_the_running_cell_wins_the_accuracy_back(calibrated):
    assert calibrated["calibrated"] >= calibrated["nominal"] + IOU_RISE_MIN


def test_the_result_names_the_rig_the_views_and_the_nodes(calibrated):
    answer = calibrated["answer"]
    assert answer.success and answer.applied
    assert {f"{NAMESPACE}/{n}" for n in ("carving", "camera", "state_publisher")} \
        <= set(answer.applied_nodes)
    assert answer.views_used + len(answer.views_rejected) == len(PLAN["views"])
    assert answer.views_used >= 30 and answer.rms_px < 0.5
    kept = calibrated["output"] / "calibration" / "rig.yaml"
    assert read_rig_file(kept) == read_rig_file(answer.rig_file)
    assert Path(answer.report_file).parent == Path(answer.rig_file).parent
    phases = [f.phase for f in calibrated["feedback"]]
    assert phases[0] == "scanning" and phases[-1] == "applying" and "fitting" in phases
    # Views without the board are named with the detector's reason; boards_detected counted
    # the others as they came.
    unreadable = [r for r in answer.views_rejected
                  if r.split(": ", 1)[1].startswith(("no marker", "only "))]
    print("\nrejected:", answer.views_rejected)
    assert max(f.boards_detected for f in calibrated["feedback"]) == \
        len(PLAN["views"]) - len(unreadable)


def test_the_tf_chain_moved_with_the_calibration(calibrated):
    rig = rig_calibration(read_rig_file(calibrated["answer"].rig_file))
    theta, phi = calibrated["angles"]
    camera = rig_camera(theta, phi, rig)
    pose = calibrated["pose"]
    assert np.abs(pose[:3, :3] - camera.R).max() < POSE_TOL
    assert np.abs(pose[:3, 3] - camera.t).max() < POSE_TOL
    nominal = rig_camera(theta, phi, rig_calibration(yaml.safe_load(
        (calibrated["output"].parent / "config" / "rig.yaml").read_text())
        ["/**"]["ros__parameters"]))
    assert np.abs(pose[:3, 3] - nominal.t).max() > 1e-3      # it did move: millimetres


def test_the_board_never_reached_the_reconstruction(calibrated):
    # The reconstruction's session folders are the two mug scans'; the board's captures
    # are in the calibration's, and segmentation never saw them (no empty silhouette).
    scans = sorted(p.parent.name for p in calibrated["output"].glob("*/session.yaml"))
    assert scans == ["calibrated", "nominal"], scans
    [board] = calibrated["output"].glob("calibration_*/session/views.csv")
    assert len(board.read_text().splitlines()) == 1 + len(PLAN["views"])
    assert "empty silhouette" not in calibrated["log"]


def test_a_calibration_logs_no_error(calibrated):
    errors = [line for line in calibrated["log"].splitlines() if "[ERROR]" in line]
    assert not errors, errors
