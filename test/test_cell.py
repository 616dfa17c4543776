"""The whole cell as separate OS processes: a scan of the mock mug, and the faults it survives.

The cell is brought up by :mod:`sfs_ros.cli.bringup` (mock hardware with
its mock camera, motor, segmentation, reconstruction, recorder and scan
nodes) in the test run's private namespace and domain, with a small camera
and fast axes so a scan takes seconds (:mod:`mock_cell`). A probe records every capture the scan node
publishes; :class:`CellClient` drives the scan as a user's program would.
The tests share one cell and pass in any order, each alone too: each
starts a new scan (a fault test injects its fault mid-scan, checks that it is
reported, mends it and resumes) and checks that every planned view reached
the reconstruction exactly once. When the module's tests are done, whichever
ran, no node may have ended.
"""

import threading
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Header
from std_srvs.srv import SetBool, Trigger

from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth
from sfs_ros.ros import capture_qos
from sfs_ros.ros.cell_client import ScanFailed
from sfs_ros.ros.convert import image_to_msg
from sfs_ros.ros.names import DIAGNOSTICS

from mock_cell import PLAN, RESOLUTION, SCAN_TIMEOUT_S, SMALL_CAMERA, running_cell
from ros_harness import MESSAGE_TIMEOUT_S, RosProbe, keep_ours, wait
from tolerances import CAPTURE_TOL_RAD, MUG_IOU_SPARSE_MIN

pytestmark = pytest.mark.cell


class Recorder:
    """The probe's view of the captures, the diagnostics and the fault switches.

    The probe spins in a background thread for the whole module, so nothing
    queues up (and nothing is dropped) while the test waits on the client.
    """

    def __init__(self, probe: RosProbe):
        self.probe = probe
        node = probe.node
        qos = capture_qos(100)
        self.joints, self.diagnostics, self.encoders = [], [], []
        self.since_ns = 0
        node.create_subscription(JointState, "joint_states", self.encoders.append, 10)
        self.captures = node.create_subscription(JointState, "capture/joint_state",
                                                 self._on_capture, qos)
        node.create_subscription(DiagnosticArray, DIAGNOSTICS, keep_ours(self.diagnostics),
                                 100)
        self.bad_image_pub = node.create_publisher(Image, "capture/image", qos)
        self.bad_joints_pub = node.create_publisher(JointState, "joint_states", 10)
        self.bad_mask_pub = node.create_publisher(Image, "capture/mask", qos)
        self.bad_frame_pub = node.create_publisher(Image, "image_raw", capture_qos(10))
        self.bad_receipt_pub = node.create_publisher(Header, "capture/stored", qos)
        self.switches = {name: node.create_client(SetBool, f"mock/{name}")
                         for name in ("unplug", "hang")}
        self.drop_frame = node.create_client(Trigger, "mock/drop_frame")
        threading.Thread(target=probe.executor.spin, daemon=True).start()

    def wait_matched(self) -> None:
        """Wait until the scan node's captures reach the probe: a capture published before
        the probe's reader matched would never reach it (two loaded test runs at once
        took long enough to match that the first scan's first capture was lost so)."""
        wait(lambda: self.captures.get_publisher_count() >= 1,
             what="the scan node's capture/joint_state matched", timeout=MESSAGE_TIMEOUT_S)

    def _on_capture(self, msg: JointState) -> None:
        # A late resend of an earlier test's scan is stamped before this test's clear():
        # it is that scan's capture, not this one's (the cell's clock is the system's).
        stamp = msg.header.stamp
        if stamp.sec * 1_000_000_000 + stamp.nanosec >= self.since_ns:
            self.joints.append(msg)

    def set(self, switch: str, on: bool) -> None:
        future = self.switches[switch].call_async(SetBool.Request(data=on))
        wait(future.done, what=f"mock/{switch} answer")
        assert future.result().success, future.result().message

    def drop_next_frame(self) -> None:
        future = self.drop_frame.call_async(Trigger.Request())
        wait(future.done, what="mock/drop_frame answer")

    def clear(self) -> None:
        self.since_ns = time.time_ns()
        self.joints.clear()
        self.diagnostics.clear()

    def statuses(self, node: str, level=None) -> list[DiagnosticStatus]:
        return [s for a in self.diagnostics for s in a.status
                if s.name.endswith(f": {node}") and (level is None or s.level == level)]

    def wait_status(self, node: str, text: str, level=DiagnosticStatus.ERROR) -> str:
        """Spin until ``node`` reports ``text`` at ``level``; that message."""
        def found():
            return [s.message for s in self.statuses(node, level) if text in s.message]
        wait(found, what=f"{node} diagnostics with {text!r}")
        return found()[0]

    def wait_encoders(self) -> None:
        """Spin until the motor node publishes joint states again (after a fault is mended)."""
        self.encoders.clear()
        wait(lambda: len(self.encoders) >= 3, what="joint_states from the motor node")

    def wait_captures(self, n: int) -> None:
        wait(lambda: len(self.joints) >= n, what=f"{n} captures")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    with running_cell(tmp_path_factory.mktemp("cell"), "test_cell_client") as up:
        probe = RosProbe("cell_probe")
        try:
            recorder = Recorder(probe)
            recorder.wait_matched()
            yield {**up, "recorder": recorder}
            assert up["cell"].exited() == {}, "a node ended while the tests ran"
        finally:
            probe.close()


def _stamps(messages) -> list[tuple[int, int]]:
    return [(m.header.stamp.sec, m.header.stamp.nanosec) for m in messages]


def _matched_views(joints) -> list[int]:
    """The plan view each capture's encoder angles belong to (asserting they are close)."""
    views = []
    for msg in joints:
        # Tagged with an encoder reading of the settled axes: within the settle tolerance
        # of the G-code target, plus the encoder's offset and noise.
        angles = np.array(msg.position)
        error = np.abs(PLAN.views - angles)
        best = int(np.argmin(error.max(axis=1)))
        assert np.all(error[best] <= CAPTURE_TOL_RAD), \
            f"capture angles {angles} are {error[best]} rad from the nearest planned view"
        views.append(best)
    return views


def _reconstruction_views(rec: Recorder) -> int:
    """Views in the carving node's current scan, by its latest report (-1: none yet)."""
    statuses = rec.statuses("carving")
    if not statuses:
        return -1
    return int({kv.key: kv.value for kv in statuses[-1].values}["scan_views"])


def _scan_diagnostics(rec: Recorder, status) -> DiagnosticStatus:
    """The scan node's diagnostics of the finished scan ``status`` (the typed status's twin:
    the counts of retries and resends are only there)."""
    def finished():
        return [s for s in rec.statuses("scan")
                if {kv.key: kv.value for kv in s.values}.get("scan") == str(status.msg.scan)
                and {kv.key: kv.value for kv in s.values}.get("receipted")
                == str(status.msg.total)]
    wait(finished, what=f"the diagnostics of scan {status.msg.scan} done")
    return finished()[-1]


def _count(diagnostics: DiagnosticStatus, key: str) -> int:
    return int({kv.key: kv.value for kv in diagnostics.values}[key])


def _check_every_view_once(rec: Recorder, status) -> None:
    """Every planned view captured once: one stamp each, tagged with that view's angles;
    any further message on the capture topic repeats one of those stamps and is one of
    the scan node's counted resends (a receipt late under load, a restarted node). And
    every view stored once by the reconstruction.

    The probe waits for one message of every view, not for every resend: a resend is
    counted when it is decided, and the probe is one more reader that may see it late
    (its arrival proves nothing about delivery, which the receipts and the
    reconstruction's view count below do prove)."""
    assert status.complete and status.count("total") == len(PLAN)
    resends = _count(_scan_diagnostics(rec, status), "resends")
    wait(lambda: len(set(_stamps(rec.joints))) >= len(PLAN), what="a capture of every view",
         timeout=MESSAGE_TIMEOUT_S)
    stamps = _stamps(rec.joints)
    unique = sorted(set(stamps))
    assert len(unique) == len(PLAN) and len(stamps) <= len(PLAN) + resends
    by_stamp = dict(zip(stamps, rec.joints))
    assert sorted(_matched_views(by_stamp[s] for s in unique)) == list(range(len(PLAN)))
    wait(lambda: _reconstruction_views(rec) == len(PLAN), timeout=MESSAGE_TIMEOUT_S,
         what=f"the reconstruction holding {len(PLAN)} views")


def _scan(cell, *, midway=None, at: int = 4):
    """Start a scan; once ``at`` captures are out, call ``midway()``. Returns the scan number."""
    rec, client = cell["recorder"], cell["client"]
    rec.clear()
    left = client.scan
    if left is not None and left.state in ("starting", "running", "waiting"):
        client.call("scan/cancel")      # left under way by a test that failed: not this one's
    scan = client.start_scan()
    if midway is not None:
        rec.wait_captures(at)
        midway()
    return scan


def test_reconstruct_without_views_fails_clearly(cell):
    client = cell["client"]
    assert client.call("reset").success
    with pytest.raises(ScanFailed, match="no views"):
        client.reconstruct()


def test_full_scan_reconstructs_the_mug_from_every_view_once(cell):
    rec, client = cell["recorder"], cell["client"]
    scan = _scan(cell)
    status = client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    _check_every_view_once(rec, status)
    # A retry under load is only a WARN.
    assert _scan_diagnostics(rec, status).level != DiagnosticStatus.ERROR
    summary = client.reconstruct()
    path = Path(summary["path"])
    assert path.is_file() and path.resolve().is_relative_to(cell["output"].resolve())
    assert Path(summary["preview_path"]).is_file()
    assert summary["views_received"] == summary["views_used"] == len(PLAN)
    assert summary["watertight"]
    assert summary["coloured_from_views"] == len(PLAN)          # the captures reached it too
    # The meshing node, up since before the scan, held the images as the views were
    # stored: the carved scan carried the masks and the hull, and (at most) the few images
    # a loaded reader missed.
    def meshed():
        return [values for values in ({kv.key: kv.value for kv in s.values}
                                      for s in rec.statuses("meshing"))
                if int(values["reconstructions"]) >= 1]
    wait(meshed, what="the meshing node's diagnostics after the mesh")
    values = meshed()[-1]
    held, carried = int(values["images_held"]), int(values["images_carried"])
    assert held + carried == len(PLAN) and held > carried
    mug = make_object("mug")
    vertices, faces, colours = load_mesh(path, with_colors=True)
    assert colours is not None and len(colours) == len(vertices)
    grid = VoxelGrid.cube(*carving_box(mug), RESOLUTION)
    assert score_against_truth(mug, vertices, faces, grid)["volume_iou"] >= MUG_IOU_SPARSE_MIN


def test_a_missing_frame_is_retaken(cell):
    rec, client = cell["recorder"], cell["client"]
    scan = _scan(cell, midway=rec.drop_next_frame)
    status = client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    warning = rec.wait_status("scan", "frame missing", DiagnosticStatus.WARN)
    assert "retrying" in warning
    assert _count(_scan_diagnostics(rec, status), "capture_retries") == 1
    _check_every_view_once(rec, status)


def _fault_pauses_then_resumes(cell, switch: str, *, paused: str, motor_says: str) -> None:
    """Switch a mock fault on mid-scan: the scan pauses (``paused`` in its reason) and the
    motor node reports ``motor_says``; switched off again, the scan resumes and completes."""
    rec, client = cell["recorder"], cell["client"]
    try:
        scan = _scan(cell, midway=lambda: rec.set(switch, True))
        with pytest.raises(ScanFailed, match=paused):
            client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
        rec.wait_status("motor", motor_says)
    finally:
        rec.set(switch, False)          # even when this test failed: the next one's cell works
    rec.wait_encoders()                                         # the motor node is back
    client.resume_scan()
    status = client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    _check_every_view_once(rec, status)


def test_serial_device_unplugged_mid_scan_pauses_then_resumes(cell):
    _fault_pauses_then_resumes(cell, "unplug", paused="paused at view",
                               motor_says="connection lost")


def test_a_move_that_times_out_pauses_then_resumes(cell):
    _fault_pauses_then_resumes(cell, "hang", paused="move timeout", motor_says="no answer")


def test_cancel_then_resume(cell):
    rec, client = cell["recorder"], cell["client"]
    scan = _scan(cell)
    rec.wait_captures(3)
    answer = client.call("scan/cancel")
    assert answer.success and "cancelled at view" in answer.message
    with pytest.raises(ScanFailed):
        client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    client.resume_scan()
    status = client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    _check_every_view_once(rec, status)


def _restarted_mid_scan(cell, node: str):
    """Stop ``node`` (SIGINT) after 6 captures and start it again; the finished scan's status,
    every view checked to have reached the reconstruction once."""
    rec, bringup = cell["recorder"], cell["cell"]

    def restart():
        assert bringup.stop_node(node) == 0
        bringup.start_node(node)

    scan = _scan(cell, midway=restart, at=6)
    status = cell["client"].wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    _check_every_view_once(rec, status)
    return status


def test_carving_restarted_mid_scan_loses_no_view(cell):
    status = _restarted_mid_scan(cell, "carving")
    # The scan node sent every capture again to the new carving node.
    assert _count(_scan_diagnostics(cell["recorder"], status), "resends") >= 6
    summary = cell["client"].reconstruct()
    assert summary["views_received"] == summary["views_used"] == len(PLAN)


def test_segmentation_restarted_mid_scan_loses_no_view(cell):
    _restarted_mid_scan(cell, "segmentation")


def test_malformed_messages_are_reported_and_the_scan_goes_on(cell):
    rec, client = cell["recorder"], cell["client"]

    def garbage():
        # The rig's size (another is refused for that first), an encoding the cell reads not.
        size = (SMALL_CAMERA["height"], SMALL_CAMERA["width"], 3)
        bad = image_to_msg(np.zeros(size, np.uint8), stamp=(5, 0), frame_id="c")
        bad.encoding = "yuv422"
        rec.bad_image_pub.publish(bad)
        rec.bad_joints_pub.publish(JointState(name=["turntable"], position=[0.1]))
        # A stamp outside builtin_interfaces/Time's range (nanosec >= 1e9), everywhere.
        bad = image_to_msg(np.zeros((4, 4, 3), np.uint8), stamp=(6, 0), frame_id="c")
        bad.header.stamp.nanosec = 2_000_000_000
        for pub in (rec.bad_image_pub, rec.bad_mask_pub, rec.bad_frame_pub):
            pub.publish(bad)
        rec.bad_receipt_pub.publish(bad.header)

    scan = _scan(cell, midway=garbage)
    status = client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    rec.wait_status("segmentation", "yuv422")
    rec.wait_status("segmentation", "nanosec")
    rec.wait_status("carving", "nanosec")
    _check_every_view_once(rec, status)
    assert cell["cell"].exited() == {}
    assert cell["client"].reconstruct()["views_used"] == len(PLAN)
