"""The camera node: a separate OS process serving real PNG files; in-process with a mock camera."""

import functools
import json

import cv2
import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.render import render_image
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.hardware.cameras import RenderedSource
from sfs_ros.nodes.camera_node import CameraNode
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import msg_to_image
from sfs_ros.ros.names import DIAGNOSTICS, SERVICES

from ros_harness import NAMESPACE, NodeProcess, NodeUnderTest, RosProbe, keep_ours
from tolerances import QUIET_S

MODULE = "sfs_ros.nodes.camera_node"
#: A small rig, as the node reads it from the params file (cx, cy: the image centre).
RIG_PARAMS = {"projection": "pinhole", "width": 64, "height": 48, "fx": 100.0, "fy": 100.0}
RIG = RigCalibration(**RIG_PARAMS)
STREAM_HZ = 10.0


def write_params(path, **camera):
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": {**RIG_PARAMS, **camera}}}))
    return path


def write_frames(folder, sizes) -> list[np.ndarray]:
    """PNG files frame_0.png, ... of random content, one per (width, height); their RGB arrays."""
    folder.mkdir()
    rng = np.random.default_rng(3)
    frames = []
    for k, (width, height) in enumerate(sizes):
        rgb = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        cv2.imwrite(str(folder / f"frame_{k}.png"), rgb[:, :, ::-1])
        frames.append(rgb)
    return frames


def _stamp(msg):
    return msg.header.stamp.sec, msg.header.stamp.nanosec


def _ns(stamp) -> int:
    return stamp[0] * 1_000_000_000 + stamp[1]


class Cell(NodeUnderTest):
    """The node process plus the probe's subscriptions and ``capture`` client."""

    def __init__(self, params_file):
        super().__init__(MODULE, params_file=params_file)
        node = self.probe.node
        self.images, self.infos, self.viewer, self.diagnostics = [], [], [], []
        subs = [node.create_subscription(Image, "image_raw", self.images.append, capture_qos(10)),
                node.create_subscription(CameraInfo, "camera_info", self.infos.append,
                                         capture_qos(10)),
                # a best-effort viewer (REP-2003 sensor data) matches the reliable publisher
                node.create_subscription(Image, "image_raw", self.viewer.append,
                                         qos_profile_sensor_data),
                node.create_subscription(DiagnosticArray, DIAGNOSTICS,
                                         keep_ours(self.diagnostics), 10)]
        self.client = node.create_client(Trigger, SERVICES["capture"])
        self.probe.wait_connected(subscriptions=subs, process=self.process)
        self.probe.spin_until(self.client.service_is_ready, what="capture service",
                              process=self.process)

    def now_ns(self) -> int:
        return self.probe.node.get_clock().now().nanoseconds

    def capture(self) -> Trigger.Response:
        future = self.client.call_async(Trigger.Request())
        self.probe.spin_until(future.done, what="capture answer", process=self.process)
        return future.result()

    def statuses(self):
        return [s for array in self.diagnostics for s in array.status]

    def clear(self) -> None:
        self.images.clear()
        self.infos.clear()
        self.viewer.clear()
        self.diagnostics.clear()


@pytest.fixture()
def start(start_node):
    """``start(params_file)`` -> a running :class:`Cell`, stopped cleanly after the test."""
    return functools.partial(start_node, Cell)


def capture_one(cell: Cell, expected_rgb: np.ndarray, frame: int) -> None:
    """``capture`` answers with a stamp; exactly that frame and its camera_info arrive."""
    cell.clear()
    before = cell.now_ns()
    response = cell.capture()
    after = cell.now_ns()
    assert response.success, response.message
    answer = json.loads(response.message)
    stamp = tuple(answer["stamp"])
    assert answer == {"stamp": list(stamp), "width": 64, "height": 48, "frame": frame}
    # Taken by the node's clock between the call and the answer (same machine, system time).
    assert before <= _ns(stamp) <= after
    cell.probe.spin_until(lambda: cell.images and cell.infos, what="frame and camera_info",
                          process=cell.process)
    cell.probe.spin_for(QUIET_S)
    assert [_stamp(m) for m in cell.images] == [stamp]
    assert [_stamp(m) for m in cell.infos] == [stamp]
    image, info = cell.images[0], cell.infos[0]
    assert image.encoding == "rgb8" and image.header.frame_id == "camera_optical"
    np.testing.assert_array_equal(msg_to_image(image), expected_rgb)       # the file's pixels
    assert info.header.frame_id == "camera_optical"
    assert (info.width, info.height) == (64, 48)
    np.testing.assert_array_equal(np.reshape(info.k, (3, 3)), RIG.K)     # cx, cy = 31.5, 23.5


def test_captures_follow_the_folder_and_bad_frames_are_refused(tmp_path, start):
    frames = write_frames(tmp_path / "frames", [(64, 48), (64, 48), (80, 60), (64, 48)])
    cell = start(write_params(tmp_path / "camera.yaml", backend="folder",
                              folder=str(tmp_path / "frames")))
    capture_one(cell, frames[0], frame=1)
    capture_one(cell, frames[1], frame=2)

    # frame_2.png is 80 x 60: refused, nothing published, an ERROR diagnostic.
    cell.clear()
    response = cell.capture()
    assert not response.success
    assert "80x60" in response.message and "64x48" in response.message, response.message
    cell.probe.spin_until(lambda: any(s.level == DiagnosticStatus.ERROR and "80x60" in s.message
                                      for s in cell.statuses()),
                          what="ERROR diagnostic", process=cell.process)
    cell.probe.spin_for(QUIET_S)
    assert not cell.images and not cell.infos and not cell.viewer
    assert cell.process.alive()

    # The next good frame is published and clears the error.
    capture_one(cell, frames[3], frame=3)
    cell.probe.spin_until(lambda: cell.statuses(), what="diagnostics", process=cell.process)
    last = cell.statuses()[-1]
    values = {kv.key: kv.value for kv in last.values}
    assert last.level == DiagnosticStatus.OK
    assert values["frames"] == "3" and values["failures"] == "1"
    assert "80x60" in values["last_problem"]

    # All four files taken: a clear refusal, and the node carries on.
    response = cell.capture()
    assert not response.success and "all 4 images" in response.message, response.message
    response = cell.capture()
    assert not response.success and "all 4 images" in response.message, response.message
    assert cell.process.alive()
    assert "80x60" in cell.process.output()                      # logged as an error too


def test_rate_streams_frames_without_capture_calls(tmp_path, start):
    frames = write_frames(tmp_path / "frames", [(64, 48), (64, 48)])
    cell = start(write_params(tmp_path / "camera.yaml", backend="folder",
                              folder=str(tmp_path / "frames"), loop=True, rate_hz=STREAM_HZ))
    n = 8
    cell.probe.spin_until(lambda: len(cell.images) >= n and len(cell.infos) >= n
                          and cell.viewer, what=f"{n} streamed frames", process=cell.process)
    stamps = [_stamp(m) for m in cell.images[:n]]
    assert [_stamp(m) for m in cell.infos[:n]] == stamps          # paired, in order
    assert all(_ns(a) < _ns(b) for a, b in zip(stamps, stamps[1:]))
    # The timer never fires early (rcl skips missed periods rather than bursting); a late
    # first frame shortens the mean, so only half the period is asserted.
    mean_interval_s = (_ns(stamps[-1]) - _ns(stamps[0])) / (n - 1) / 1e9
    assert mean_interval_s >= 0.5 / STREAM_HZ
    # The folder loops: the images alternate; which one came first depends on when the
    # probe's subscription matched.
    first = next(k for k, rgb in enumerate(frames)
                 if np.array_equal(msg_to_image(cell.images[0]), rgb))
    for i, msg in enumerate(cell.images[:n]):
        np.testing.assert_array_equal(msg_to_image(msg), frames[(first + i) % 2])


class ClosingRenderedSource(RenderedSource):
    """The mock camera, noting whether the node closed it."""

    closed = False

    def close(self) -> None:
        self.closed = True


def test_an_injected_source_is_used_and_closed_by_the_node():
    # In the test process, as sfs-mock-hardware runs it: the node with its rendered camera.
    mug = make_object("mug")
    angles = (0.4, 0.6)
    source = ClosingRenderedSource(mug, RIG, lambda: angles, seed=5)
    probe = RosProbe()
    overrides = [Parameter(k, value=v) for k, v in {**RIG_PARAMS, "backend": "mock"}.items()]
    node = CameraNode(source, context=probe.context, namespace=NAMESPACE,
                      parameter_overrides=overrides)
    try:
        probe.executor.add_node(node)
        images = []
        probe.node.create_subscription(Image, "image_raw", images.append, capture_qos(10))
        client = probe.node.create_client(Trigger, SERVICES["capture"])
        probe.spin_until(client.service_is_ready, what="capture service")

        def capture():
            future = client.call_async(Trigger.Request())
            probe.spin_until(future.done, what="capture answer")
            return future.result()

        assert capture().success
        probe.spin_until(lambda: images, what="rendered frame")
        expected = render_image(mug.mesh.vertices, mug.mesh.faces, rig_camera(*angles, RIG),
                                vertex_colors=mug.color_at(mug.mesh.vertices),
                                seed=int(np.random.default_rng(5).integers(2**31)))
        np.testing.assert_array_equal(msg_to_image(images[0]), expected)
        source.fail_next(1)
        response = capture()
        assert not response.success and "injected fault" in response.message
        assert capture().success
    finally:
        probe.executor.remove_node(node)
        node.destroy_node()
        probe.close()
    assert source.closed


@pytest.mark.parametrize("camera, name, words", [
    ({"backend": "mock"}, "backend", "sfs-mock-hardware"),
    ({"backend": "folder"}, "folder", "required"),
    ({"backend": "folder", "folder": "no/such/folder"}, "folder", "no/such/folder"),
    ({"backend": "opencv", "device": "no/such/video0"}, "device", "no/such/video0"),
    ({"rate_hz": 500.0}, "rate_hz", "500.0"),
])
def test_invalid_parameters_at_startup_exit_with_one_line(tmp_path, camera, name, words):
    process = NodeProcess(MODULE, params_file=write_params(tmp_path / "camera.yaml", **camera))
    code, lines = process.exit_lines()
    assert code == 2
    assert len(lines) == 1 and f"'{name}'" in lines[0] and words in lines[0], lines
