"""The cell's typed interfaces through the whole mock cell, as a robot's program uses them.

One cell for the module (:mod:`mock_cell`); scans are small (six views given in the goal)
to keep the time down. A client finds the Scan action and the Reconstruct service by
their types, scans with feedback and a result, cancels mid-scan and scans again, is
refused a bad goal and a bad output name with the reason; ``sfs-ctl`` runs as a process
against the same cell. The cell's TF, as a robot's TF listener receives it, places the
camera where the rig model does.
"""

import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.action import get_action_names_and_types

from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.ros.cell_client import ScanFailed
from sfs_ros.ros.rig_params import rig_calibration

from mock_cell import SCAN_TIMEOUT_S, no_fault, running_cell
from ros_harness import NAMESPACE, SOURCE_ROOT, wait
from test_frames import chain
from tf_watch import TfWatch, camera_pose

pytestmark = pytest.mark.cell

#: Six views, visited in this order (radians).
SMALL = {"theta_rad": [0.0, 2.1, 4.2, 1.0, 3.1, 5.2],
         "phi_rad": [0.35, 0.35, 0.35, 0.96, 0.96, 0.96]}
CTL_TIMEOUT_S = 300.0
#: The cell's frames carry this run's prefix: /tf is global, shared with any test run in
#: the same ROS domain.
PREFIX = NAMESPACE.strip("/") + "/"
#: Pose agreement, metres and rotation-matrix entries: float64 translations and
#: quaternions in the messages (round-off ~1e-15); the bound is far above it.
POSE_TOL = 1e-6


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    with running_cell(tmp_path_factory.mktemp("typed"), "typed_api_client",
                      no_fault({"frames.yaml": {"frame_prefix": PREFIX}})) as up:
        yield up


@pytest.fixture(scope="module")
def scanned(cell):
    """The result of a small scan that succeeded, its feedback."""
    feedback = []
    result = cell["client"].scan_goal(feedback=feedback.append, timeout_s=SCAN_TIMEOUT_S,
                                      **SMALL)
    return result, feedback


def test_the_action_and_service_are_found_by_their_types(cell):
    node = cell["client"].node
    action = (f"{NAMESPACE}/scan", ["sfs_ros_interfaces/action/Scan"])
    service = (f"{NAMESPACE}/meshing/reconstruct_mesh",
               ["sfs_ros_interfaces/srv/Reconstruct"])
    wait(lambda: action in get_action_names_and_types(node), what="the Scan action")
    wait(lambda: service in node.get_service_names_and_types(), what="the Reconstruct service")


def test_a_scan_goal_gives_feedback_and_a_result(scanned, cell):
    result, feedback = scanned
    assert result.success, result.message
    assert result.views_total == result.views_captured == result.views_stored == 6
    assert result.views_rejected == []
    session = Path(result.session_dir)
    assert session.is_dir() and session.parent == cell["output"]
    assert {f.state for f in feedback} >= {"running", "done"}
    assert max(f.views_captured for f in feedback) == 6
    assert all(f.scan == result.scan for f in feedback)


def test_reconstruct_with_a_default_request_writes_the_mesh(scanned, cell):
    mesh = cell["client"].reconstruct()
    assert mesh["success"] and Path(mesh["mesh_path"]).is_file()
    assert Path(mesh["preview_path"]).is_file()        # wait_for_pictures: written already
    assert mesh["views_used"] == 6 and mesh["session_dir"] == scanned[0].session_dir
    assert mesh["n_faces"] > 0 and mesh["frame_id"] == PREFIX + "turntable"
    assert mesh["holdout_iou"] != mesh["holdout_iou"]  # NaN: no views held out


def test_tf_places_the_camera_where_the_rig_model_does(scanned, cell):
    """/tf and /tf_static, found by their types, hold the cell's chain from its root to
    the camera, stamped with the joint states; at the last of them the camera's pose in
    the turntable frame is rig_camera's at those encoder readings."""
    node = cell["client"].node
    tf = ("tf2_msgs/msg/TFMessage",)
    wait(lambda: {("/tf", tf), ("/tf_static", tf)} <= {
        (name, tuple(types)) for name, types in node.get_topic_names_and_types()},
        what="/tf and /tf_static in the graph")
    watch = TfWatch(node, [PREFIX], {PREFIX: f"{NAMESPACE}/joint_states"})
    try:
        wait(lambda: watch.tree_at_last_joint_state(PREFIX) is not None
             and any(c == PREFIX + "camera_optical" for _, c, _ in watch.static),
             what="/tf at a joint state and /tf_static", timeout=SCAN_TIMEOUT_S)
        theta, phi, tree = watch.tree_at_last_joint_state(PREFIX)
        moving, static = watch.frames()
    finally:
        watch.close()
    base, turntable, camera = (PREFIX + f for f in ("base_link", "turntable", "camera_optical"))
    assert moving == {(base, turntable), (base, PREFIX + "carriage")}
    assert static == {(PREFIX + "carriage", camera)}        # no parent_frame: base is a root
    in_turntable = np.linalg.inv(chain(tree, base, turntable)) @ chain(tree, base, camera)
    values = yaml.safe_load((cell["output"].parent / "config" / "rig.yaml").read_text())
    expected = camera_pose(rig_camera(theta, phi, rig_calibration(
        values["/**"]["ros__parameters"])))
    assert np.abs(in_turntable - expected).max() < POSE_TOL, (theta, phi)


def test_reconstruct_options_and_confined_names(scanned, cell):
    client = cell["client"]
    with pytest.raises(ScanFailed, match=r"request refused: output name '\.\./x\.ply' has a "
                                         "folder"):
        client.reconstruct(output_name="../x.ply")
    with pytest.raises(ScanFailed, match="mesher 'blob' is not one of"):
        client.reconstruct(mesher="blob")
    coarse = client.reconstruct(output_name="other.obj", resolution=32, colour="no",
                                pictures=False)
    assert coarse["mesh_path"] == str((cell["output"] / "other.obj").resolve())
    assert Path(coarse["mesh_path"]).is_file()
    assert coarse["coloured_from_views"] == 0
    default = client.reconstruct(pictures=False)
    assert coarse["voxel_size_m"] > default["voxel_size_m"]


def test_a_bad_goal_is_refused_with_the_reason(cell):
    with pytest.raises(ScanFailed, match="theta_rad has 2 values and phi_rad 1"):
        cell["client"].scan_goal(theta_rad=[0.0, 1.0], phi_rad=[0.3], timeout_s=SCAN_TIMEOUT_S)
    with pytest.raises(ScanFailed, match="outside the carriage's range"):
        cell["client"].scan_goal(theta_rad=[0.0], phi_rad=[2.0], timeout_s=SCAN_TIMEOUT_S)


def test_cancel_mid_scan_then_a_new_goal(cell):
    client = cell["client"]
    goal = client.send_scan(**SMALL)
    wait(lambda: goal.feedback is not None and goal.feedback.views_captured >= 1,
         what="a view captured", timeout=SCAN_TIMEOUT_S)
    with pytest.raises(ScanFailed, match="rejected: a scan is running"):
        client.send_scan(**SMALL)                       # one goal at a time
    goal.cancel()
    with pytest.raises(ScanFailed, match="scan cancelled") as ended:
        goal.wait(SCAN_TIMEOUT_S)
    assert 1 <= ended.value.result.views_captured < 6
    result = client.scan_goal(timeout_s=SCAN_TIMEOUT_S, **SMALL)
    assert result.success and result.views_stored == 6


def test_a_feedback_callback_that_raises_leaves_the_client_answering(cell):
    def faulty(_feedback):
        raise RuntimeError("a caller's bug")

    result = cell["client"].scan_goal(feedback=faulty, timeout_s=SCAN_TIMEOUT_S, **SMALL)
    assert result.success and result.views_stored == 6
    assert cell["client"].reconstruct(pictures=False)["success"]


def test_a_callback_on_the_clients_node_that_raises_leaves_it_answering(scanned, cell):
    client, raised = cell["client"], threading.Event()

    def faulty(_diagnostics):
        raised.set()
        raise RuntimeError("a callback's bug")

    sub = client.node.create_subscription(DiagnosticArray, "/diagnostics", faulty, 10)
    try:
        wait(raised.is_set, what="a diagnostics message", timeout=SCAN_TIMEOUT_S)
        assert client.reconstruct(pictures=False)["success"]
    finally:
        client.node.destroy_subscription(sub)


def _ctl(*args) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(SOURCE_ROOT))
    return subprocess.run([sys.executable, "-m", "sfs_ros.cli.ctl", "--namespace", NAMESPACE,
                           *args], capture_output=True, text=True, env=env,
                          timeout=CTL_TIMEOUT_S)


def test_sfs_ctl(cell, tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({"views": [[0, 20], [120, 20], [240, 20], [60, 55],
                                              [180, 55], [300, 55]]}))
    scan = _ctl("scan", "--plan", str(plan), "--name", "ctl_scan", "--wait")
    assert scan.returncode == 0, scan.stderr
    assert "6 stored in" in scan.stdout and "ctl_scan" in scan.stdout
    assert " running: view " in scan.stdout                     # the feedback lines
    mesh = _ctl("reconstruct", "--output", "ctl.ply", "--wait-pictures")
    assert mesh.returncode == 0, mesh.stderr
    assert (cell["output"] / "ctl.ply").is_file() and (cell["output"] / "ctl.png").is_file()
    assert _ctl("param", "set", "carving", "mesher", "advancing-front").returncode == 0
    got = _ctl("param", "get", "carving", "mesher")
    assert got.returncode == 0 and got.stdout.strip() == "advancing-front", got.stderr
    refused = _ctl("param", "set", "carving", "resolution", "5")
    assert refused.returncode == 1 and "resolution" in refused.stderr
    status = _ctl("status")
    assert status.returncode == 0 and "done" in status.stdout
    assert _ctl("bogus").returncode == 2
