"""The rig at run time: the mock renders its own world, rig parameters change between scans.

In-process, small (a 64 x 48 camera): the mock hardware with the camera node it
composes, given a calibrated rig to believe; :class:`RigParameters` refusing a change
as a whole rig, for another size and during a scan; :func:`read_rig_file` naming the
file and the field of a bad ``rig.yaml``.
"""

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

from sfs_ros.core.calibration import rig_parameters
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.nodes.camera_node import CameraNode
from sfs_ros.nodes.mock_hardware_node import WORLD_RIG, MockHardwareNode
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import msg_to_image
from sfs_ros.ros.names import DIAGNOSTICS, SERVICES
from sfs_ros.ros.params import declare
from sfs_ros.ros.rig_apply import read_rig_file
from sfs_ros.ros.rig_params import WRITABLE_RIG_PARAMS, RigParameters

from ros_harness import NAMESPACE, RosProbe

#: The cell as built: a small pinhole camera.
BUILT = RigCalibration(projection="pinhole", width=64, height=48, fx=100.0, fy=100.0,
                       camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
#: What a calibration of the wrong world gives: a lens, an axis off, zeros (the rig the
#: wrong world used to refuse to be made from).
CALIBRATED = RigCalibration(projection="pinhole", width=64, height=48, fx=100.8, fy=101.1,
                            cx=32.4, cy=23.7, camera_distance_m=0.588,
                            aim_point_m=(0.0, 0.0, 0.04), theta_zero_rad=0.03,
                            phi_zero_rad=0.02, distortion=(-0.18, 0.08, 0.001, -0.0008, 0.0),
                            axis_point_m=(0.003, -0.002), axis_tilt_y_rad=-0.01,
                            mount_rotation_rad=(0.01, -0.014, 0.009))


def _values(rig: RigCalibration) -> dict:
    return rig_parameters(rig)["/**"]["ros__parameters"]


def _overrides(values: dict, prefix: str = "") -> list[Parameter]:
    return [Parameter(f"{prefix}{name}", value=value) for name, value in values.items()]


class MockCell:
    """The mock hardware and its camera node in the probe's context, believing ``believed``."""

    def __init__(self, probe: RosProbe, believed: RigCalibration):
        self.probe = probe
        self.hardware = MockHardwareNode(
            context=probe.context, namespace=NAMESPACE, parameter_overrides=[
                Parameter("world", value="wrong"), Parameter("seed", value=5),
                *_overrides(_values(BUILT), f"{WORLD_RIG}.")])
        self.camera = CameraNode(
            self.hardware.camera_source, context=probe.context, namespace=NAMESPACE,
            parameter_overrides=[Parameter("backend", value="mock"),
                                 *_overrides(_values(believed))])
        probe.executor.add_node(self.camera)
        self.images, self.infos = [], []
        probe.node.create_subscription(Image, "image_raw", self.images.append, capture_qos(10))
        probe.node.create_subscription(CameraInfo, "camera_info", self.infos.append,
                                       capture_qos(10))
        self.client = probe.node.create_client(Trigger, SERVICES["capture"])
        self.parameters = AsyncParameterClient(probe.node, f"{NAMESPACE}/camera")

    def capture(self) -> tuple[np.ndarray, CameraInfo]:
        count = len(self.images)
        self.probe.spin_until(self.client.service_is_ready, what="capture service")
        future = self.client.call_async(Trigger.Request())
        self.probe.spin_until(future.done, what="capture answer")
        assert future.result().success, future.result().message
        self.probe.spin_until(lambda: len(self.images) > count and len(self.infos) > count,
                              what="frame and camera_info")
        return msg_to_image(self.images[-1]), self.infos[-1]

    def set(self, **values):
        self.probe.spin_until(self.parameters.services_are_ready, what="parameter services")
        future = self.parameters.set_parameters_atomically(_overrides(values))
        self.probe.spin_until(future.done, what="set answer")
        return future.result().result

    def close(self) -> None:
        self.probe.executor.remove_node(self.camera)
        self.camera.destroy_node()
        self.hardware.destroy_node()


@pytest.fixture()
def probe():
    probe = RosProbe("rig_runtime_probe")
    yield probe
    probe.close()


def test_the_mock_renders_its_own_world_whatever_rig_the_cell_believes(probe):
    frames = {}
    for name, believed in (("nominal", BUILT), ("calibrated", CALIBRATED)):
        cell = MockCell(probe, believed)
        try:
            frames[name], info = cell.capture()
        finally:
            cell.close()
        assert info.k[0] == believed.fx and list(info.d) == list(believed.distortion)
    np.testing.assert_array_equal(frames["nominal"], frames["calibrated"])


def test_the_camera_takes_a_new_rig_between_scans_as_a_whole(probe):
    cell = MockCell(probe, BUILT)
    try:
        frame, _ = cell.capture()
        taken = cell.set(fx=100.8, fy=101.1, distortion=[-0.18, 0.08, 0.0, 0.0, 0.0])
        assert taken.successful, taken.reason
        after, info = cell.capture()
        assert (info.k[0], info.k[4]) == (100.8, 101.1) and info.d[0] == -0.18
        np.testing.assert_array_equal(after.shape, frame.shape)

        # Each value valid alone, not together: refused, the rig kept.
        refused = cell.set(projection="orthographic")
        assert not refused.successful and "pinhole" in refused.reason
        refused = cell.set(width=80)
        assert not refused.successful and "'width'" in refused.reason \
            and "fixed while the node runs" in refused.reason
        assert cell.capture()[1].k[0] == 100.8
    finally:
        cell.close()


def _scan_report(state: str) -> DiagnosticArray:
    return DiagnosticArray(status=[DiagnosticStatus(
        name=f"{NAMESPACE}/scan: scan", values=[KeyValue(key="scan", value="4"),
                                                 KeyValue(key="state", value=state)])])


@pytest.mark.parametrize("state", ["starting", "running", "waiting", "paused"])
def test_the_rig_is_refused_during_a_scan_and_taken_after(probe, state):
    node = probe.node
    declare(node, WRITABLE_RIG_PARAMS)
    rig = RigParameters(node)
    reports = node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)

    def reported(expected: bool):
        def condition() -> bool:
            reports.publish(_scan_report(state if expected else "done"))
            return bool(rig.scanning()) == expected
        return condition

    probe.spin_until(reported(True), what=f"the scan reported {state}")
    before = rig.calibration.fx
    refused = node.set_parameters_atomically([Parameter("fx", value=before + 1.0)])
    assert not refused.successful and f"scan 4 {state}" in refused.reason
    assert rig.calibration.fx == before and node.get_parameter("fx").value == before
    # The same values again change nothing: accepted.
    assert node.set_parameters_atomically([Parameter("fx", value=before)]).successful
    probe.spin_until(reported(False), what="the scan reported done")
    assert node.set_parameters_atomically([Parameter("fx", value=before + 1.0)]).successful
    assert rig.calibration.fx == before + 1.0


@pytest.mark.parametrize("change, words", [
    ({"fx": None}, ["missing fx"]),
    ({"focal": 1.0}, ["unknown focal"]),
    ({"fx": 1400}, ["'fx'", "int", "float"]),
    ({"aim_point_m": [0.0, 0.0]}, ["'aim_point_m'", "3 values"]),
    ({"projection": "orthographic"}, ["pinhole"]),
])
def test_a_bad_rig_file_is_named_with_its_field(tmp_path, change, words):
    values = _values(CALIBRATED)
    for name, value in change.items():
        if value is None:
            del values[name]
        else:
            values[name] = value
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": values}}))
    with pytest.raises(ValueError) as error:
        read_rig_file(path)
    assert str(path) in str(error.value)
    for word in words:
        assert word in str(error.value)


def test_the_file_sfs_calibrate_writes_is_read_back(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(rig_parameters(CALIBRATED)))
    assert read_rig_file(path) == _values(CALIBRATED)
