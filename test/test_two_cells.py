"""Two mock cells side by side in one ROS graph, each placed in the robot's world.

Two ``sfs-cell --mock`` processes in the same ROS domain, in namespaces
``<run>/cell_a`` and ``<run>/cell_b``, each with a params file giving its own
``frame_prefix`` and the same ``parent_frame`` (``world``) at a different
``parent_pose`` (one as roll, pitch, yaw, the other as a quaternion). Both scan at
the same time, each a small plan of its own given in the Scan goal through a
:class:`CellClient` of its namespace, and reconstruct. Then:

* each cell's result, status, diagnostics, receipts, session folder and output
  folder hold exactly its own views (four and five, at different angles);
* its mesh, hull, camera poses, receipts and ``camera_info`` carry its own
  prefixed frames;
* ``/tf`` and ``/tf_static`` hold both chains ``world -> <prefix>base_link -> ...``,
  no frame published by both cells and no message mixing them, and each camera's
  pose in ``world``, composed from the received transforms as tf2 does, is the
  cell's ``parent_pose`` composed with its rig model at its last joint state.

The frames carry this test run's name too: ``/tf`` is global, shared with any other
run in the same ROS domain. Kept small for CI: the mock cell's 320 x 240 camera,
fast axes and 64^3 grid (:mod:`mock_cell`), four and five views.
"""

import math
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from sfs_ros.cell_logic.message_fields import status_namespace
from sfs_ros.core.exchange.session import read_session
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.cell_client import CellClient
from sfs_ros.ros.rig_params import rig_calibration

from mock_cell import NO_FAULT, write_config
from ros_harness import NAMESPACE, SOURCE_ROOT
from test_frames import chain
from test_urdf import rpy_matrix
from tf_watch import TfWatch, camera_pose, transform_matrix
from tolerances import CAPTURE_TOL_RAD
from waiting import wait

pytestmark = pytest.mark.cell

RUN = NAMESPACE.strip("/")
#: Each cell: namespace, frame prefix, pose of its base in world, its plan and scan name.
CELLS = {
    "a": {"namespace": f"{NAMESPACE}/cell_a", "prefix": f"{RUN}/cell_a/",
          "parent_pose": [1.2, 0.4, 0.75, 0.0, 0.0, math.pi / 2],
          "theta_rad": [0.0, 1.6, 3.2, 4.8], "phi_rad": [0.35, 0.35, 0.35, 0.35],
          "scan_name": "part_a"},
    "b": {"namespace": f"{NAMESPACE}/cell_b", "prefix": f"{RUN}/cell_b/",
          # A quaternion [x, y, z, qx, qy, qz, qw]: -90 degrees about world Z.
          "parent_pose": [-1.2, 0.4, 0.75, 0.0, 0.0, -math.sqrt(0.5), math.sqrt(0.5)],
          "theta_rad": [0.5, 1.7, 2.9, 4.1, 5.3], "phi_rad": [0.6, 0.6, 0.6, 0.6, 0.6],
          "scan_name": "part_b"},
}
#: The rotation of each parent_pose, written out here (not the product's pose_rotation).
PARENT_ROTATION = {"a": rpy_matrix(0.0, 0.0, math.pi / 2),
                   "b": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])}
PARENT = "world"
#: Deadlines that only bound a hang: fourteen node processes starting on a loaded 2-core
#: machine (imports: rclpy, numpy, OpenCV, numba), a scan, a reconstruction, a stop.
UP_TIMEOUT_S = 300.0
SCAN_TIMEOUT_S = 300.0
STOP_TIMEOUT_S = 120.0
#: Pose agreement, metres and rotation-matrix entries: float64 translations and
#: quaternions in the messages, a few 4x4 products (round-off ~1e-15); far above it.
POSE_TOL = 1e-6


def frame(cell: str, name: str) -> str:
    return CELLS[cell]["prefix"] + name


class SfsCell:
    """``sfs-cell --mock`` of one cell in ``root``: its config, params file, output folder
    and log (the nodes' output, each line prefixed with the node's name)."""

    def __init__(self, key: str, root: Path, config: Path):
        spec = CELLS[key]
        self.key, self.namespace = key, spec["namespace"]
        root.mkdir()
        self.output_dir = root / "out"
        self.log = root / "sfs-cell.log"
        params = root / "frames.yaml"
        params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
            "frame_prefix": spec["prefix"], "parent_frame": PARENT,
            "parent_pose": [float(v) for v in spec["parent_pose"]]}}}))
        env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=os.pathsep.join(
            filter(None, [str(SOURCE_ROOT), os.environ.get("PYTHONPATH")])))
        with self.log.open("wb") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "sfs_ros.cli.cell", "--mock", "-o", str(self.output_dir),
                 "--config", str(config), "--namespace", self.namespace,
                 "--params-file", str(params)],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env,
                cwd=root)

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def stop(self) -> int:
        """SIGINT (sfs-cell stops its nodes, the last started first); its exit status."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            raise AssertionError(f"sfs-cell {self.namespace} still running "
                                 f"{STOP_TIMEOUT_S:.0f} s after SIGINT:\n"
                                 f"{self.output()[-5000:]}") from None


class Listener:
    """One cell's results, receipts and camera_info as received on ``node`` (absolute
    names), subscribed before the scans so none is missed."""

    def __init__(self, node, namespace: str):
        self._lock = threading.Lock()
        self.meshes, self.hulls, self.poses, self.receipts, self.infos = [], [], [], [], []
        topics = [(Marker, "mesh", self.meshes, result_qos()),
                  (PointCloud2, "hull", self.hulls, result_qos()),
                  (PoseArray, "camera_poses", self.poses, result_qos()),
                  (Header, "capture/stored", self.receipts, capture_qos()),
                  (CameraInfo, "camera_info", self.infos, 10)]
        self.subs = [node.create_subscription(kind, f"{namespace}/{name}",
                                              lambda msg, s=store: self._keep(s, msg), qos)
                     for kind, name, store, qos in topics]

    def _keep(self, store: list, msg) -> None:
        with self._lock:
            store.append(msg)

    def last(self, store: list):
        with self._lock:
            return store[-1] if store else None

    def connected(self) -> bool:
        return all(s.get_publisher_count() > 0 for s in self.subs)


@pytest.fixture(scope="module")
def cells(tmp_path_factory):
    """Both cells up, a client of each, and everything a test listens to subscribed."""
    root = tmp_path_factory.mktemp("two_cells")
    config = write_config(root / "config", NO_FAULT)
    up = {key: SfsCell(key, root / f"cell_{key}", config) for key in CELLS}
    clients, diagnostics, subscribed = {}, [], []
    try:
        for key, cell in up.items():
            clients[key] = CellClient(cell.namespace, name=f"two_cells_client_{key}")
        node = clients["a"].node
        watch = TfWatch(node, [spec["prefix"] for spec in CELLS.values()],
                        {spec["prefix"]: f"{spec['namespace']}/joint_states"
                         for spec in CELLS.values()})
        listeners = {key: Listener(clients[key].node, cell.namespace) for key, cell in up.items()}
        subscribed += [(node, watch.subscriptions), (node, [node.create_subscription(
            DiagnosticArray, "/diagnostics", diagnostics.append, 100)])]
        subscribed += [(clients[key].node, listener.subs) for key, listener in listeners.items()]
        for key, client in clients.items():
            try:
                client.wait_ready(timeout_s=UP_TIMEOUT_S)
            except Exception as exc:
                raise AssertionError(f"{exc}\n{up[key].output()[-5000:]}") from None
        wait(lambda: all(listener.connected() for listener in listeners.values()),
             what="the cells' result topics", timeout=UP_TIMEOUT_S)
        yield {"cells": up, "clients": clients, "watch": watch, "listeners": listeners,
               "diagnostics": diagnostics, "config": config}
    finally:
        for node, subs in subscribed:       # the tests' own first, while the nodes spin
            for sub in subs:
                node.destroy_subscription(sub)
        for client in clients.values():
            client.close()
        codes = {key: cell.stop() for key, cell in up.items()}
    logs = {key: cell.output() for key, cell in up.items()}
    assert codes == {"a": 0, "b": 0}, f"{codes}\n" + "\n".join(v[-5000:] for v in logs.values())
    for key, log in logs.items():
        assert "Traceback" not in log, log
        errors = [line for line in log.splitlines() if "ERROR" in line]
        assert not errors, f"cell {key}: {errors}"


@pytest.fixture(scope="module")
def scanned(cells):
    """Both cells scan their own plans at the same time, then reconstruct:
    ``{cell: (Scan.Result, its feedback, reconstruct answer)}``."""
    goals, feedback = {}, {key: [] for key in CELLS}
    for key, client in cells["clients"].items():
        spec = CELLS[key]
        goals[key] = client.send_scan(theta_rad=spec["theta_rad"], phi_rad=spec["phi_rad"],
                                      scan_name=spec["scan_name"], feedback=feedback[key].append)
    results = {key: goal.wait(SCAN_TIMEOUT_S) for key, goal in goals.items()}
    return {key: (results[key], feedback[key],
                  cells["clients"][key].reconstruct(timeout_s=SCAN_TIMEOUT_S))
            for key in CELLS}


def angle_gap(a: float, b: float) -> float:
    """|a - b| on the circle, radians."""
    return abs(math.remainder(a - b, math.tau))


def test_each_cell_scans_and_keeps_only_its_own_views(cells, scanned):
    receipt_stamps = {}
    for key, (result, feedback, mesh) in scanned.items():
        spec, cell = CELLS[key], cells["cells"][key]
        n = len(spec["theta_rad"])
        assert result.success, result.message
        assert result.views_total == result.views_captured == result.views_stored == n
        assert result.views_rejected == []
        assert {f.views_total for f in feedback} == {n} and all(f.scan == result.scan
                                                                for f in feedback)
        # The client follows its own cell's status (which may come just after the result).
        client = cells["clients"][key]
        wait(lambda: client.scan.state == "done" and client.scan.msg.receipted == n,
             what=f"cell {key}'s status done", timeout=SCAN_TIMEOUT_S)
        assert client.scan.msg.total == n and client.scan.count("scan") == result.scan

        session = Path(result.session_dir)
        assert session.parent == cell.output_dir.resolve() and session.name == spec["scan_name"]
        views = read_session(session).views
        assert len(views) == n
        for theta, phi in zip(spec["theta_rad"], spec["phi_rad"]):
            assert any(angle_gap(v.theta_rad, theta) <= CAPTURE_TOL_RAD[0]
                       and abs(v.phi_rad - phi) <= CAPTURE_TOL_RAD[1] for v in views), \
                (key, theta, phi, [(v.theta_rad, v.phi_rad) for v in views])
        other = CELLS["b" if key == "a" else "a"]["scan_name"]
        assert not (cell.output_dir / other).exists()
        assert mesh["success"] and mesh["views_used"] == n
        assert mesh["session_dir"] == result.session_dir
        assert Path(mesh["mesh_path"]).parent == cell.output_dir.resolve()

        listener = cells["listeners"][key]
        with listener._lock:
            stamps = {(h.stamp.sec, h.stamp.nanosec) for h in listener.receipts}
        assert len(stamps) == n                 # resends carry a stamp already receipted
        receipt_stamps[key] = stamps
    assert not receipt_stamps["a"] & receipt_stamps["b"]

    # /diagnostics is shared: each scan node's status, named after its full name, counts
    # its own views only.
    def last_scan_status(namespace: str):
        found = [s for array in list(cells["diagnostics"]) for s in array.status
                 if s.name == f"{namespace}/scan: scan"]
        return {kv.key: kv.value for kv in found[-1].values} if found else {}

    for key, spec in CELLS.items():
        n = str(len(spec["theta_rad"]))
        wait(lambda: last_scan_status(spec["namespace"]).get("receipted") == n,
             what=f"cell {key}'s scan diagnostics", timeout=SCAN_TIMEOUT_S)
        values = last_scan_status(spec["namespace"])
        assert values["total"] == values["captured"] == n and values["state"] == "done"
    namespaces = {status_namespace(s.name) for array in list(cells["diagnostics"])
                  for s in array.status if s.name.startswith(NAMESPACE + "/")}
    assert namespaces == {spec["namespace"] for spec in CELLS.values()}


def test_results_are_stamped_in_each_cells_own_frames(cells, scanned):
    for key, (_, _, mesh) in scanned.items():
        n = len(CELLS[key]["theta_rad"])
        turntable, camera = frame(key, "turntable"), frame(key, "camera_optical")
        listener = cells["listeners"][key]
        assert mesh["frame_id"] == turntable
        wait(lambda: listener.last(listener.meshes) is not None
             and listener.last(listener.hulls) is not None
             and len(getattr(listener.last(listener.poses), "poses", [])) == n,
             what=f"cell {key}'s mesh, hull and {n} camera poses", timeout=SCAN_TIMEOUT_S)
        marker = listener.last(listener.meshes)
        assert marker.header.frame_id == turntable and len(marker.points) > 0
        assert listener.last(listener.hulls).header.frame_id == turntable
        assert listener.last(listener.poses).header.frame_id == turntable
        with listener._lock:
            assert {h.frame_id for h in listener.receipts} == {camera}     # the images'
            assert len(listener.infos) >= n
            assert {i.header.frame_id for i in listener.infos} == {camera}


def test_tf_holds_both_cells_in_the_world_without_collisions(cells, scanned):
    watch = cells["watch"]
    wait(lambda: all(watch.tree_at_last_joint_state(spec["prefix"]) is not None
                     for spec in CELLS.values())
         and len(watch.frames()[1]) >= 4, what="both cells' /tf and /tf_static",
         timeout=SCAN_TIMEOUT_S)
    moving, static = watch.frames()
    assert static == {pair for key in CELLS for pair in (
        (PARENT, frame(key, "base_link")), (frame(key, "carriage"), frame(key, "camera_optical")))}
    assert moving == {(frame(key, "base_link"), frame(key, child)) for key in CELLS
                      for child in ("turntable", "carriage")}
    # No frame published by both cells, with two parents, or in one message with the
    # other cell's.
    children = [c for _, c in moving | static]
    assert len(children) == len(set(children)) == 8
    assert watch.mixed == []

    values = yaml.safe_load((cells["config"] / "rig.yaml").read_text())
    rig = rig_calibration(values["/**"]["ros__parameters"])
    # The turntable at its encoder zero is the base frame (the axis through the base's
    # origin, untilted): base -> turntable is a turn about Z by theta - theta_zero.
    assert rig.axis_point_m == (0.0, 0.0) and rig.axis_tilt_x_rad == rig.axis_tilt_y_rad == 0
    for key, spec in CELLS.items():
        theta, phi, tree = watch.tree_at_last_joint_state(spec["prefix"])
        world_camera = chain(tree, PARENT, frame(key, "camera_optical"))
        world_base = transform_matrix(PARENT_ROTATION[key], spec["parent_pose"][:3])
        base_turntable = transform_matrix(rpy_matrix(0.0, 0.0, theta - rig.theta_zero_rad),
                                          np.zeros(3))
        expected = world_base @ base_turntable @ camera_pose(rig_camera(theta, phi, rig))
        assert np.abs(world_camera - expected).max() < POSE_TOL, (key, theta, phi)
        # And the cell's base is where its parent_pose puts it.
        assert np.abs(chain(tree, PARENT, frame(key, "base_link")) - world_base).max() \
            < POSE_TOL, key
