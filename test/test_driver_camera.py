"""A scan through a camera driver as it is: best-effort JPEG ``CompressedImage`` frames and
a ``camera_info`` whose intrinsics differ from the rig's by 2 %.

The mock cell with ``camera_topic`` (the simulated controller, no mock camera) and, in
this process, a plain rclpy publisher standing in for the driver (:class:`DeskDriver`): at
:data:`STREAM_HZ` it renders the mug with the mock's renderer at the angles the motor node
reports on ``joint_states``, through a camera whose focal length is the rig's plus 2 %
(the true camera), and publishes it as a JPEG on ``<image topic>/compressed`` with the
sensor-data QoS (best effort) and its ``camera_info`` (the true intrinsics) beside it.

With ``intrinsics_source`` rig (the default) the scan goes through and the difference is
a WARN naming fx and fy; with ``driver`` the scan carves with the driver's intrinsics and
the mesh matches the true mug as closely as the mock camera's does
(``MUG_IOU_SPARSE_MIN``, as in test_any_camera).
"""

import io
import math
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from PIL import Image as PILImage
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, JointState

from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth
from sfs_ros.hardware.cameras import RenderedSource
from sfs_ros.ros.convert import angles_from_joint_state, camera_info
from sfs_ros.ros.rig_params import rig_calibration

from mock_cell import PLAN, RESOLUTION, SCAN_TIMEOUT_S, no_fault, running_cell
from ros_harness import NAMESPACE, RosProbe, set_node_parameters
from tolerances import MUG_IOU_SPARSE_MIN

pytestmark = pytest.mark.cell

#: The driver's image topic (its compressed frames on ``.../compressed``, its calibration
#: on ``desk_cam/camera_info``).
IMAGE_TOPIC = f"{NAMESPACE}/desk_cam/image_raw"
#: Frames per second of the driver.
STREAM_HZ = 10.0
#: The true camera's focal lengths against the rig's.
FOCAL_SCALE = 1.02


class DeskDriver:
    """A plain publisher of best-effort JPEG frames and their camera_info (module
    docstring), spinning in its own thread until :meth:`close`."""

    def __init__(self, calibration):
        self.probe = RosProbe("desk_driver")
        node = self.probe.node
        self.calibration = calibration
        self._angles = None
        self.published = 0
        self.source = RenderedSource(make_object("mug"), calibration, lambda: self._angles,
                                     seed=5)
        self.images = node.create_publisher(CompressedImage, IMAGE_TOPIC + "/compressed",
                                            qos_profile_sensor_data)
        self.info = node.create_publisher(CameraInfo, IMAGE_TOPIC.rsplit("/", 1)[0]
                                          + "/camera_info", qos_profile_sensor_data)
        node.create_subscription(JointState, "joint_states", self._on_joints, 10)
        node.create_timer(1.0 / STREAM_HZ, self._publish)
        self._executor = SingleThreadedExecutor(context=self.probe.context)
        self._executor.add_node(node)
        self._thread = threading.Thread(target=self._executor.spin, daemon=True)
        self._thread.start()

    def _on_joints(self, msg: JointState) -> None:
        self._angles = angles_from_joint_state(msg)

    def _publish(self) -> None:
        if self._angles is None:
            return
        stamp = self.probe.node.get_clock().now().to_msg()
        buffer = io.BytesIO()
        PILImage.fromarray(self.source.grab()).save(buffer, format="JPEG", quality=95)
        msg = CompressedImage(format="jpeg", data=buffer.getvalue())
        msg.header.stamp, msg.header.frame_id = stamp, "desk_cam_optical"
        info = camera_info(rig_camera(0.0, 0.0, self.calibration), stamp=stamp,
                           frame_id="desk_cam_optical")
        self.images.publish(msg)
        self.info.publish(info)
        self.published += 1

    def wait_heard(self, timeout_s: float) -> None:
        """Until the scan node takes the frames and the camera_info (its subscriptions
        matched; the frames' follows the driver's QoS within a second) and a few frames
        went out since."""
        deadline = time.monotonic() + timeout_s
        start = None
        while start is None or self.published < start + 5:
            if start is None and self.images.get_subscription_count() \
                    and self.info.get_subscription_count():
                start = self.published
            assert time.monotonic() < deadline, "the scan node never took the driver's frames"
            time.sleep(0.05)

    def close(self) -> None:
        self._executor.shutdown()
        self._thread.join(timeout=10.0)
        self.probe.close()


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    more = no_fault({"scan.yaml": {"image_transport": "compressed", "exposure_delay_s": 0.05}})
    root = tmp_path_factory.mktemp("driver_camera")
    with running_cell(root, "driver_camera_client", more, camera_topic=IMAGE_TOPIC) as up:
        values = yaml.safe_load((root / "config" / "rig.yaml").read_text())
        rig = rig_calibration(values["/**"]["ros__parameters"])
        true_camera = replace(rig, fx=rig.fx * FOCAL_SCALE, fy=rig.fy * FOCAL_SCALE)
        driver = DeskDriver(true_camera)
        try:
            driver.wait_heard(SCAN_TIMEOUT_S)
            yield up
        finally:
            driver.close()


class ScanDiagnostics:
    """The scan node's diagnostics statuses, kept by scan number."""

    def __init__(self):
        self.probe = RosProbe("driver_camera_diagnostics")
        self.statuses: list[tuple[DiagnosticStatus, dict]] = []
        self.probe.node.create_subscription(DiagnosticArray, "/diagnostics", self._keep, 50)

    def _keep(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == f"{NAMESPACE}/scan: scan":
                self.statuses.append((status, {kv.key: kv.value for kv in status.values}))

    def of_scan(self, scan: int) -> list[tuple[DiagnosticStatus, dict]]:
        return [(s, v) for s, v in self.statuses if v.get("scan") == str(scan)]


def test_a_driver_with_best_effort_jpeg_and_its_own_calibration(cell):
    client = cell["client"]
    diagnostics = ScanDiagnostics()
    try:
        # intrinsics_source rig: a one-view scan goes through; the difference is a WARN.
        result = client.scan_goal(theta_rad=[0.0], phi_rad=[math.radians(30.0)],
                                  timeout_s=SCAN_TIMEOUT_S)
        assert result.success and result.views_stored == 1, result.message
        diagnostics.probe.spin_until(
            lambda: any(s.level == DiagnosticStatus.WARN and "fx +2.00 %, fy +2.00 %"
                        in s.message for s, _ in diagnostics.of_scan(result.scan)),
            what="the WARN of the driver's intrinsics")

        # intrinsics_source driver: the whole plan, carved with the driver's intrinsics.
        set_node_parameters("scan", intrinsics_source="driver")
        scan = client.start_scan()
        client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
        diagnostics.probe.spin_until(lambda: diagnostics.of_scan(scan),
                                     what=f"the diagnostics of scan {scan}")
        _, values = diagnostics.of_scan(scan)[-1]
        assert values["trigger"] == "stream" and values["intrinsics_source"] == "driver"
        assert values["intrinsics_difference"] == "2.00 %"
    finally:
        diagnostics.probe.close()
    summary = client.reconstruct()
    assert summary["views_received"] == summary["views_used"] == len(PLAN)

    mug = make_object("mug")
    grid = VoxelGrid.cube(*carving_box(mug), RESOLUTION)
    vertices, faces = load_mesh(Path(summary["path"]))
    iou = score_against_truth(mug, vertices, faces, grid)["volume_iou"]
    assert iou >= MUG_IOU_SPARSE_MIN, iou
