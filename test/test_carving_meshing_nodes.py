"""The carving and meshing nodes as separate OS processes, driven over ROS topics and services."""

import json
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseArray
from sensor_msgs.msg import Image, JointState, PointCloud2
from shape_msgs.msg import Mesh
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker

from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.result_files import write_result
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.cell_client import CellClient, wait_for_pictures
from sfs_ros.ros.convert import cloud_to_points, image_to_msg, joint_state, shape_to_mesh
from sfs_ros.ros.names import DIAGNOSTICS, SERVICES

from ros_harness import MESSAGE_TIMEOUT_S, NAMESPACE, NodeProcess, NodeUnderTest, keep_ours
from tolerances import MUG_IOU_29_VIEWS_MIN

MODULE = "sfs_ros.nodes.carving_node"
MESHING = "sfs_ros.nodes.meshing_node"
RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=700.0, fy=700.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
PLAN = ring_plan([20.0, 55.0], 14, top_view=True)        # 29 views
RESOLUTION = 64


@pytest.fixture(scope="module")
def mug():
    return make_object("mug")


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("reconstruction_out")


@pytest.fixture(scope="module")
def params_file(tmp_path_factory, mug, out_dir):
    box = carving_box(mug)
    params = {"projection": RIG.projection, "width": RIG.width, "height": RIG.height,
              "fx": RIG.fx, "fy": RIG.fy, "camera_distance_m": RIG.camera_distance_m,
              "aim_point_m": list(RIG.aim_point_m), "bounds_m": box.ravel().tolist(),
              "resolution": RESOLUTION, "output_dir": str(out_dir), "hull_rate_hz": 0.0,
              "queue_depth": 64}
    path = tmp_path_factory.mktemp("params") / "reconstruction.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    return path


@pytest.fixture(scope="module")
def masks(mug):
    return [rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces, rig_camera(t, p, RIG))
            for t, p in PLAN]


class Cell(NodeUnderTest):
    """The carving and meshing node processes plus the probe's publishers, recorders and
    service clients."""

    def __init__(self, params_file):
        super().__init__(MODULE, params_file=params_file)
        self.meshing = NodeProcess(MESHING, params_file=params_file)
        node, qos = self.probe.node, capture_qos(100)
        self.mask_pub = node.create_publisher(Image, "capture/mask", qos)
        self.joints_pub = node.create_publisher(JointState, "capture/mask_joint_state", qos)
        self.hulls, self.markers, self.shapes, self.diagnostics = [], [], [], []
        self.receipts, self.poses = [], []
        subs = [node.create_subscription(PointCloud2, "hull", self.hulls.append, result_qos()),
                node.create_subscription(PoseArray, "camera_poses", self.poses.append,
                                         result_qos()),
                node.create_subscription(Header, "capture/stored", self.receipts.append, qos),
                node.create_subscription(Marker, "mesh", self.markers.append, result_qos()),
                node.create_subscription(Mesh, "mesh_shape", self.shapes.append, result_qos()),
                node.create_subscription(DiagnosticArray, DIAGNOSTICS,
                                         keep_ours(self.diagnostics), 10)]
        self.clients = {name: node.create_client(Trigger, SERVICES[name])
                        for name in ("reconstruct", "reset")}
        self.probe.wait_connected([self.mask_pub, self.joints_pub], subs, process=self.process)
        self.probe.spin_until(lambda: all(c.service_is_ready() for c in self.clients.values()),
                              what="services", process=self.process)

    def close(self) -> tuple[int, str]:
        """Both nodes stopped (SIGINT first): the first non-zero exit code, both outputs."""
        code, output = super().close()
        meshing_code, meshing_output = self.meshing.stop_and_read()
        return code or meshing_code, output + meshing_output

    def kill_meshing(self, params_file) -> None:
        """SIGKILL the meshing node and start another with ``params_file`` (not waited for)."""
        self.meshing.process.send_signal(signal.SIGKILL)
        assert self.meshing.process.wait(timeout=30) == -signal.SIGKILL
        self.meshing.cleanup()
        self.meshing = NodeProcess(MESHING, params_file=params_file)

    def wait_meshing_up(self) -> None:
        """Until the (new) meshing node says it is meshing."""
        self.probe.spin_until(lambda: "meshing into" in self.meshing.output(),
                              what="the new meshing node", process=self.meshing)

    def send(self, stamp, mask, theta, phi, *, joints_first=False, encoding=None):
        image = image_to_msg(mask, stamp=stamp, frame_id="camera_optical")
        if encoding is not None:
            image = image_to_msg(np.repeat(mask.astype(np.uint8)[:, :, None] * 255, 3, axis=2),
                                 stamp=stamp, frame_id="camera_optical", encoding=encoding)
        joints = joint_state(theta, phi, stamp=stamp)
        if joints_first:
            self.joints_pub.publish(joints)
        self.mask_pub.publish(image)
        if not joints_first:
            self.joints_pub.publish(joints)

    def call(self, name: str, timeout: float = 30.0) -> Trigger.Response:
        future = self.clients[name].call_async(Trigger.Request())
        self.probe.spin_until(future.done, timeout=timeout, what=f"{name} answer",
                              process=self.process)
        return future.result()

    def call_until_answered(self, name: str, *, attempt_s: float = 15.0,
                            attempts: int = 8) -> Trigger.Response:
        """``call``, sent again while no answer comes: a request sent when a restarted
        server is in the graph but not yet matched with the client is lost (the dead
        server's endpoints stay in the graph until their lease ends)."""
        return self.probe.call_resending(self.clients[name], Trigger.Request(),
                                         resend_after_s=attempt_s, attempts=attempts,
                                         process=self.process, timeout=attempt_s)

    def statuses(self, node: str = "carving"):
        """The diagnostic statuses of the node named ``node``, oldest first."""
        return [s for array in self.diagnostics for s in array.status
                if s.name.endswith(f": {node}")]

    def last_values(self, node: str = "carving") -> dict:
        """The latest diagnostic values of the node named ``node`` (as strings)."""
        statuses = self.statuses(node)
        return {kv.key: kv.value for kv in statuses[-1].values} if statuses else {}

    def wait_values(self, what: str, **expected) -> None:
        """Spin until the latest diagnostics hold ``expected`` (values as strings)."""
        self.probe.spin_until(
            lambda: all(self.last_values().get(k) == str(v) for k, v in expected.items()),
            what=what, process=self.process)


@pytest.fixture(scope="module")
def cell(start_node_for_module, params_file):
    return start_node_for_module(Cell, params_file)


def _stamp(i):
    return 1000 + i, 250_000 * i


@pytest.fixture(scope="module")
def scan(cell, masks):
    """Publish the scan (shuffled; joint state first for every other view), then reconstruct."""
    order = np.random.default_rng(0).permutation(len(PLAN))
    for k, i in enumerate(order):
        cell.send(_stamp(i), masks[i], *PLAN[i], joints_first=bool(k % 2))
    cell.wait_values(f"{len(PLAN)} carved views", scan_views=len(PLAN), carved=len(PLAN))
    return cell.call("reconstruct")


def test_reconstruct_writes_the_mug_inside_output_dir(scan, mug, out_dir, cell):
    assert scan.success, scan.message
    summary = json.loads(scan.message)
    path, report = Path(summary["path"]), Path(summary["report_path"])
    assert path.is_file() and report.is_file()
    assert path.resolve().is_relative_to(out_dir.resolve())
    assert report.resolve().is_relative_to(out_dir.resolve())
    wait_for_pictures(summary, timeout_s=60.0)      # they follow the answer
    preview = Path(summary["preview_path"])
    assert preview.is_file() and preview.resolve().is_relative_to(out_dir.resolve())
    # Each node's rehearsal at start runs beside the views (seconds), in a folder removed
    # after it.
    deadline = time.monotonic() + MESSAGE_TIMEOUT_S
    for node in (cell.process, cell.meshing):
        while "rehearsal reconstruction done" not in node.output():
            assert time.monotonic() < deadline, "no rehearsal reconstruction in a node's log"
            time.sleep(0.1)
    assert not [p.name for p in out_dir.iterdir() if p.name.startswith(".rehearsal")]
    assert summary["views_received"] == summary["views_used"] == len(PLAN)
    assert summary["views_rejected"] == [] and summary["watertight"]
    assert summary["seconds"] > 0 and summary["volume_m3"] > 0
    vertices, faces = load_mesh(path)
    grid = VoxelGrid.cube(*carving_box(mug), RESOLUTION)
    assert score_against_truth(mug, vertices, faces, grid)["volume_iou"] >= MUG_IOU_29_VIEWS_MIN


def test_mesh_is_latched_for_late_subscribers(scan, cell):
    assert scan.success
    cell.probe.spin_until(lambda: cell.markers and cell.shapes, what="mesh",
                          process=cell.process)
    summary = json.loads(scan.message)
    marker = cell.markers[-1]
    assert marker.type == Marker.TRIANGLE_LIST and marker.header.frame_id == "turntable"
    display = 10000      # display_triangles' default: a larger mesh is simplified
    assert len(marker.points) % 3 == 0 and len(marker.points) <= 3 * display
    assert summary["n_faces"] > display or len(marker.points) == 3 * summary["n_faces"]
    vertices, faces = shape_to_mesh(cell.shapes[-1])
    assert len(faces) == summary["n_faces"] and len(vertices) == summary["n_vertices"]
    late = []
    cell.probe.node.create_subscription(Marker, "mesh", late.append, result_qos())
    cell.probe.spin_until(lambda: late, what="the mesh on a late subscription",
                          process=cell.process)
    assert len(late[0].points) == len(marker.points)


@pytest.fixture(scope="module")
def meshing_restarted(scan, cell, params_file):
    """The scan's mesh file and its bytes; then the meshing node killed (SIGKILL) and
    started again (a module fixture: the new node outlives the test)."""
    first = json.loads(scan.message)
    wait_for_pictures(first, timeout_s=60.0)
    mesh_file = Path(first["path"])
    before = mesh_file.read_bytes()
    cell.kill_meshing(params_file)
    cell.wait_meshing_up()
    return mesh_file, before


def test_a_meshing_node_killed_and_started_again_makes_the_offline_mesh(meshing_restarted,
                                                                       cell, tmp_path):
    """SIGKILL of the meshing node between the scan and reconstruct: its successor asks the
    carving node again, every view is used once, and the mesh is the one the offline path
    makes of the stored views, byte for byte."""
    mesh_file, before = meshing_restarted
    again = cell.call_until_answered("reconstruct")
    assert again.success, again.message
    summary = json.loads(again.message)
    assert summary["views_used"] == summary["views_received"] == len(PLAN)
    assert mesh_file.read_bytes() == before
    offline = reconstruct(load_views(summary["session"]),
                          ReconstructionParams(resolution=RESOLUTION))
    write_result(offline, tmp_path / "offline.ply")
    assert (tmp_path / "offline.ply").read_bytes() == before


def test_reconstruct_called_again_at_once_answers_and_its_pictures_follow(scan, cell):
    # The pictures and mesh messages after an answer wait until it is sent; a request that
    # comes first must release them, not wait behind them.
    assert scan.success
    again = [cell.call("reconstruct") for _ in range(2)]
    assert all(answer.success for answer in again), [a.message for a in again]
    summaries = [json.loads(answer.message) for answer in again]
    assert summaries[0]["n_faces"] == summaries[1]["n_faces"] == json.loads(scan.message)["n_faces"]
    wait_for_pictures(summaries[1], timeout_s=60.0)


def test_camera_poses_are_the_views_cameras(scan, cell):
    cell.probe.spin_until(lambda: cell.poses and len(cell.poses[-1].poses) >= len(PLAN),
                          what="camera poses of every view", process=cell.process)
    msg = cell.poses[-1]
    assert msg.header.frame_id == "turntable" and len(msg.poses) == len(PLAN)
    centres = sorted(tuple(np.round([p.position.x, p.position.y, p.position.z], 9))
                     for p in msg.poses)
    expected = sorted(tuple(np.round(rig_camera(t, p, RIG).center, 9)) for t, p in PLAN)
    np.testing.assert_allclose(centres, expected, atol=1e-9)


def test_hull_cloud_lies_in_the_box(scan, cell, mug):
    cell.probe.spin_until(lambda: cell.hulls, what="hull", process=cell.process)
    points = cloud_to_points(cell.hulls[-1])
    box = carving_box(mug)
    assert cell.hulls[-1].header.frame_id == "turntable" and len(points) > 100
    assert np.all(points >= box[0]) and np.all(points <= box[1])


def _receipts(cell, stamp) -> int:
    return sum((r.stamp.sec, r.stamp.nanosec) == stamp for r in cell.receipts)


def test_every_view_gets_one_receipt(scan, cell):
    cell.probe.spin_until(lambda: len(cell.receipts) >= len(PLAN), what="receipts",
                          process=cell.process)
    assert sorted((r.stamp.sec, r.stamp.nanosec) for r in cell.receipts[:len(PLAN)]) == \
        sorted(_stamp(i) for i in range(len(PLAN)))
    assert cell.receipts[0].frame_id == "camera_optical"


def test_a_view_sent_again_is_receipted_not_carved_twice(scan, cell, masks):
    cell.probe.spin_until(lambda: _receipts(cell, _stamp(3)) == 1, what="the first receipt",
                          process=cell.process)
    cell.send(_stamp(3), masks[3], *PLAN[3])                           # a resend
    cell.probe.spin_until(lambda: _receipts(cell, _stamp(3)) == 2, what="a second receipt",
                          process=cell.process)
    cell.wait_values("the repeat counted", repeats=1, scan_views=len(PLAN), carved=len(PLAN))
    assert cell.statuses()[-1].level == DiagnosticStatus.OK


def test_malformed_mask_is_reported_and_the_node_carries_on(scan, cell, masks):
    cell.diagnostics.clear()
    cell.send((2000, 0), masks[0], *PLAN[0], encoding="rgb8")          # wrong encoding

    def reported() -> bool:
        return any("malformed mask at stamp 2000.000000000" in s.message and "rgb8" in s.message
                   for s in cell.statuses() if s.level == DiagnosticStatus.ERROR)

    cell.probe.spin_until(reported, what="the malformed mask's ERROR", process=cell.process)
    # A good view after the bad one is carved, and clears the error; a mask sent twice
    # before its joint state is one view.
    n = len(PLAN)
    cell.mask_pub.publish(image_to_msg(masks[5], stamp=(2001, 0), frame_id="c"))
    cell.send((2001, 0), masks[5], *PLAN[5])
    cell.wait_values("the good view", scan_views=n + 1, carved=n + 1)
    assert cell.statuses()[-1].level == DiagnosticStatus.OK
    assert cell.last_values()["malformed"] == "1"


def test_reset_then_reconstruct_without_views_fails_clearly(scan, cell):
    answer = cell.call("reset")
    assert answer.success
    cell.probe.spin_until(lambda: len(cloud_to_points(cell.hulls[-1])) == 0,
                          what="an empty hull after reset", process=cell.process)
    answer = cell.call("reconstruct")
    assert not answer.success
    assert "no views" in answer.message
    assert cell.process.alive()


def test_a_late_copy_of_an_earlier_scans_view_is_not_stored_in_the_next(scan, cell, masks):
    assert cell.call("reset").success           # the scan fixture's views: an earlier scan's
    cell.wait_values("the new scan", scan_views=0)
    before = _receipts(cell, _stamp(4))
    cell.send(_stamp(4), masks[4], *PLAN[4])    # a resend that crossed its receipt
    cell.probe.spin_until(lambda: _receipts(cell, _stamp(4)) == before + 1,
                          what="the receipt of the late copy", process=cell.process)
    cell.wait_values("the late copy counted, not stored", stale=1, scan_views=0)
    cell.send((4000, 0), masks[4], *PLAN[4])    # a new capture of that viewpoint is stored
    cell.wait_values("the new scan's first view", scan_views=1)
    assert cell.call("reset").success


def test_missing_output_dir_exits_with_one_line():
    process = NodeProcess(MODULE)
    code, lines = process.exit_lines()
    assert code != 0
    assert len(lines) == 1 and "'output_dir'" in lines[0], lines


def test_per_scan_settings_change_between_scans_and_bad_values_are_refused(scan, cell, masks,
                                                                           mug, out_dir):
    def set_one(name, value):
        return cell.set_parameter("carving", name, value)

    taken = Path(json.loads(scan.message)["path"]).stem          # the first scan's folder
    for name, value, words in [
            ("bounds_m", [0.1, -0.1, 0.0, -0.1, 0.1, 0.2], "finite min < max"),
            ("bounds_m", [0.0, 0.0, 0.1], "expected [xmin, ymin, zmin, xmax, ymax, zmax]"),
            ("resolution", 4, "resolution"),
            ("mesher", "voxels", "mesher"),
            ("scan_name", "../elsewhere", "must be 1-100 letters"),
            ("scan_name", taken, "already exists")]:
        refused = set_one(name, value)
        assert not refused.successful and words in refused.reason, (name, refused.reason)
    assert not set_one("output_dir", str(out_dir / "other")).successful       # read-only

    # A second scan with other settings: a coarser grid, the other mesher, a name.
    box = carving_box(mug).ravel() + [-0.01, -0.01, 0.0, 0.01, 0.01, 0.01]    # 1 cm margin
    assert set_one("bounds_m", box.tolist()).successful
    assert set_one("resolution", 48).successful
    assert set_one("mesher", "advancing-front").successful
    assert set_one("scan_name", "mug_coarse").successful
    assert cell.call("reset").success
    for i in range(len(PLAN)):
        cell.send((3000 + i, 0), masks[i], *PLAN[i])
    # The new views' receipts: the diagnostics of the first scan, taken before the reset,
    # also said scan_views=len(PLAN).
    cell.probe.spin_until(lambda: all(_receipts(cell, (3000 + i, 0)) for i in range(len(PLAN))),
                          what="the second scan's receipts", process=cell.process)
    # The advancing front compiles its kernels on first use: a bound against a hang only.
    answer = cell.call("reconstruct", timeout=MESSAGE_TIMEOUT_S)
    assert answer.success, answer.message
    summary = json.loads(answer.message)
    assert Path(summary["path"]).name == "mug_coarse.ply"
    assert (out_dir / "mug_coarse").is_dir()
    # The new resolution and mesher; the grid (refined to the silhouettes by the pipeline)
    # has its longest side in 48 voxels and lies in the new box, to a voxel's rounding.
    report = json.loads(Path(summary["report_path"]).read_text())
    assert report["parameters"]["resolution"] == 48 and max(report["grid"]["shape"]) == 48
    assert report["mesher"]["name"] == "advancing-front"
    low, high = (np.array(b) for b in report["grid"]["bounds_m"])
    voxel = report["grid"]["voxel_size_m"]
    assert np.all(low >= box[:3] - voxel) and np.all(high <= box[3:] + voxel)

    # The name is used: the next reset is refused with the reason, and nothing changes.
    answer = cell.call("reset")
    assert not answer.success and "mug_coarse already exists" in answer.message
    assert cell.last_values()["scan_views"] == str(len(PLAN))
    assert set_one("scan_name", "").successful                        # scan_NNN again
    assert cell.call("reset").success


@pytest.fixture(scope="module")
def meshing_just_restarted(cell, masks, params_file):
    """A new scan of the mug's views; then the meshing node killed (SIGKILL) and another
    started, not waited for (a module fixture: the new node outlives the test; the last of
    the module's tests: the probe's clients are not matched with the new node)."""
    assert cell.call("reset").success
    for i, (theta, phi) in enumerate(PLAN):
        cell.send(_stamp(500 + i), masks[i], theta, phi)
    cell.probe.spin_until(lambda: all(_receipts(cell, _stamp(500 + i)) for i in range(len(PLAN))),
                          what=f"the receipts of a new scan's {len(PLAN)} views",
                          process=cell.process)
    cell.kill_meshing(params_file)


def test_reconstruct_sent_at_once_to_a_restarted_meshing_node_is_answered_and_made_once(
        meshing_just_restarted, cell):
    """``CellClient.reconstruct`` called twice at once as soon as a restarted meshing node's
    service shows (its endpoints may not be matched yet: a request then is lost, and the
    client sends it again until answered). Both get the same answer, made once: the copies
    that arrive after the first are answered as it was (one mesh written)."""
    with CellClient(NAMESPACE, name="resending_client") as client, \
            ThreadPoolExecutor(max_workers=2) as callers:
        answers = list(callers.map(
            lambda _: client.reconstruct(timeout_s=MESSAGE_TIMEOUT_S, pictures=False),
            range(2)))
    assert answers[0]["path"] == answers[1]["path"] and Path(answers[0]["path"]).is_file()
    assert answers[0]["seconds"] == answers[1]["seconds"]     # one answer, given twice
    assert answers[0]["views_used"] == len(PLAN)
    output = cell.meshing.output()
    assert output.count("mesh written to") == 1, output
    assert "the same request again: answered as before" in output, output
