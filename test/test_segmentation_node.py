"""The segmentation node as a separate OS process, driven over ROS topics from the test."""

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import Image, JointState

from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.metrics import silhouette_iou
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.segmentation.segment import SegmentationParams, segment
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import simulate_scan
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import image_to_msg, joint_state, msg_to_image
from sfs_ros.ros.names import DIAGNOSTICS

from ros_harness import NodeProcess, NodeUnderTest, keep_ours
from tolerances import QUIET_S

MODULE = "sfs_ros.nodes.segmentation_node"
RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=700.0, fy=700.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
# What the params file sets (the rig's image size, as rig.yaml gives it, and segmentation
# parameters the same as these core ones, for the expected masks).
NODE_PARAMS = {"method": "threshold", "background": "white", "close_px": 3, "queue_depth": 30,
               "width": RIG.width, "height": RIG.height}
CORE_PARAMS = SegmentationParams(method="threshold", background="white", close_px=3)
PLAN = ring_plan([20.0, 60.0], 4)          # 8 views
# The rendered mug covers 8 000-10 000 px with an outline of ~400 px; noise
# (sigma 2 grey levels) is far below the contrast, so only rim pixels may be
# wrong: at most half the outline gives IoU >= 1 - 200 / 8 000 = 0.975
# against the true silhouette (measured: 0.998-1.0).
IOU_MIN = 0.975


@pytest.fixture(scope="module")
def params_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("params") / "segmentation.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": NODE_PARAMS}}))
    return path


@pytest.fixture(scope="module")
def mug_scan():
    mug = make_object("mug")
    captures = simulate_scan(mug, RIG, PLAN, seed=4)
    truths = [rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces,
                                   rig_camera(c.theta_rad, c.phi_rad, RIG)) for c in captures]
    return captures, truths


class Cell(NodeUnderTest):
    """The node process plus the probe's publishers and recorders."""

    def __init__(self, params_file):
        super().__init__(MODULE, params_file=params_file)
        node, qos = self.probe.node, capture_qos(100)
        self.image_pub = node.create_publisher(Image, "capture/image", qos)
        self.joints_pub = node.create_publisher(JointState, "capture/joint_state", qos)
        self.masks, self.mask_joints, self.diagnostics = [], [], []
        subs = [node.create_subscription(Image, "capture/mask", self.masks.append, qos),
                node.create_subscription(JointState, "capture/mask_joint_state",
                                         self.mask_joints.append, qos),
                node.create_subscription(DiagnosticArray, DIAGNOSTICS,
                                         keep_ours(self.diagnostics), 10)]
        self.probe.wait_connected([self.image_pub, self.joints_pub], subs, process=self.process)

    def receive(self, n: int) -> None:
        """Spin until ``n`` masks and ``n`` joint states have arrived, then ``QUIET_S`` more."""
        self.probe.spin_until(lambda: len(self.masks) >= n and len(self.mask_joints) >= n,
                              what=f"{n} masks", process=self.process)
        self.probe.spin_for(QUIET_S)

    def clear(self) -> None:
        self.masks.clear()
        self.mask_joints.clear()
        self.diagnostics.clear()


@pytest.fixture(scope="module")
def cell(start_node_for_module, params_file):
    return start_node_for_module(Cell, params_file)


def _stamp(msg):
    return msg.header.stamp.sec, msg.header.stamp.nanosec


def test_every_capture_gives_one_mask_with_its_stamp_and_angles(cell, mug_scan):
    captures, truths = mug_scan
    cell.clear()
    stamps = [(100 + i, 500_000 * i) for i in range(len(captures))]
    order = np.random.default_rng(0).permutation(len(captures))
    for k, i in enumerate(order):          # shuffled; joint state first for every other one
        image = image_to_msg(captures[i].image, stamp=stamps[i], frame_id="camera_optical")
        joints = joint_state(captures[i].theta_rad, captures[i].phi_rad, stamp=stamps[i])
        if k % 2:
            cell.image_pub.publish(image)
            cell.joints_pub.publish(joints)
        else:
            cell.joints_pub.publish(joints)
            cell.image_pub.publish(image)
    cell.receive(len(captures))

    assert sorted(_stamp(m) for m in cell.masks) == sorted(stamps)          # each exactly once
    assert sorted(_stamp(j) for j in cell.mask_joints) == sorted(stamps)
    by_stamp = {_stamp(j): j for j in cell.mask_joints}
    for mask_msg in cell.masks:
        i = stamps.index(_stamp(mask_msg))
        assert mask_msg.encoding == "mono8" and mask_msg.header.frame_id == "camera_optical"
        joints = by_stamp[_stamp(mask_msg)]
        assert list(joints.name) == ["turntable", "carriage"]
        assert list(joints.position) == [captures[i].theta_rad, captures[i].phi_rad]
        mask = msg_to_image(mask_msg) > 0
        # The node applies the params file: the same mask as the core with those parameters.
        np.testing.assert_array_equal(mask, segment(captures[i].image, CORE_PARAMS).mask)
        assert silhouette_iou(mask, truths[i]) >= IOU_MIN
    # ... which is a real check: the core defaults give other masks on some of these views.
    assert any((segment(c.image).mask != segment(c.image, CORE_PARAMS).mask).any()
               for c in captures)


def test_a_capture_sent_again_is_segmented_again(cell, mug_scan):
    captures, _ = mug_scan
    cell.clear()
    for n in (1, 2):          # then a resend: the reconstruction had not receipted the first
        cell.image_pub.publish(image_to_msg(captures[1].image, stamp=(160, 0), frame_id="c"))
        cell.joints_pub.publish(joint_state(captures[1].theta_rad, captures[1].phi_rad,
                                            stamp=(160, 0)))
        cell.receive(n)
    assert [_stamp(m) for m in cell.masks] == [(160, 0), (160, 0)]
    np.testing.assert_array_equal(msg_to_image(cell.masks[0]), msg_to_image(cell.masks[1]))
    last = cell.diagnostics[-1].status[0]
    assert last.level == DiagnosticStatus.OK
    assert {kv.key: kv.value for kv in last.values}["repeats"] == "1"


def test_empty_view_gives_an_all_zero_mask_and_a_warning(cell):
    cell.clear()
    blank = np.full((RIG.height, RIG.width, 3), 250, np.uint8)      # backdrop only
    cell.image_pub.publish(image_to_msg(blank, stamp=(150, 0), frame_id="c"))
    cell.joints_pub.publish(joint_state(0.0, 0.5, stamp=(150, 0)))
    cell.receive(1)
    assert [_stamp(m) for m in cell.masks] == [(150, 0)]
    assert not msg_to_image(cell.masks[0]).any()
    statuses = [s for array in cell.diagnostics for s in array.status]
    assert any(s.level == DiagnosticStatus.WARN and "empty silhouette" in s.message
               for s in statuses)


def test_malformed_inputs_are_reported_and_the_node_carries_on(cell, mug_scan):
    captures, truths = mug_scan
    cell.clear()
    good = captures[0]

    def send(stamp, *, image=None, joints=None):
        cell.image_pub.publish(image or image_to_msg(good.image, stamp=stamp, frame_id="c"))
        cell.joints_pub.publish(joints or joint_state(good.theta_rad, good.phi_rad, stamp=stamp))

    wrong_encoding = image_to_msg(good.image, stamp=(200, 0), frame_id="c")
    wrong_encoding.encoding = "yuv422"
    send((200, 0), image=wrong_encoding)
    short_data = image_to_msg(good.image, stamp=(201, 0), frame_id="c")
    short_data.data = short_data.data[:-7]
    send((201, 0), image=short_data)
    one_joint = JointState(name=["turntable"], position=[0.3])
    one_joint.header.stamp.sec = 202
    send((202, 0), joints=one_joint)
    send((203, 0))                                   # a good capture after the bad ones
    cell.receive(1)

    assert [_stamp(m) for m in cell.masks] == [(203, 0)]
    assert [_stamp(j) for j in cell.mask_joints] == [(203, 0)]
    assert silhouette_iou(msg_to_image(cell.masks[0]) > 0, truths[0]) >= IOU_MIN
    assert cell.process.alive()
    statuses = [s for array in cell.diagnostics for s in array.status]
    errors = [s.message for s in statuses if s.level == DiagnosticStatus.ERROR]
    assert any("yuv422" in e for e in errors)
    assert any("carriage" in e for e in errors)
    last = {kv.key: kv.value for kv in statuses[-1].values}
    assert statuses[-1].level == DiagnosticStatus.OK            # the good capture clears it
    assert last["malformed"] == "3" and last["waiting_images"] == "0"
    assert "malformed image at stamp 200.000000000" in cell.process.output()


def test_runtime_parameter_changes_are_validated(cell):
    def set_one(name, value):
        return cell.set_parameter("segmentation", name, value)

    out_of_range = set_one("threshold", 1.5)
    assert not out_of_range.successful and "threshold" in out_of_range.reason
    inverted = set_one("threshold_range", [0.3, 0.2])
    assert not inverted.successful and "threshold_range" in inverted.reason
    assert not set_one("preset", "white-background").successful      # read-only
    assert set_one("dilate_px", 0).successful


def test_invalid_parameter_at_startup_exits_with_one_line(params_file):
    process = NodeProcess(MODULE, params_file=params_file, parameters={"threshold": 7.0})
    code, lines = process.exit_lines()
    assert code != 0
    assert len(lines) == 1 and "'threshold'" in lines[0] and "7.0" in lines[0], lines
