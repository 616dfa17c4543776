"""The state publisher node: a separate OS process publishing the cell's TF from joint states.

The probe subscribes ``/tf`` and ``/tf_static`` with tf2's QoS and composes the tree from
the received messages itself (no tf2_ros on PyPI): the camera's pose in the turntable
frame must be the rig model's camera, for a prefixed cell attached to a parent frame, and
follow rig parameters set at run time.
"""

import functools
import math

import numpy as np
import pytest
import yaml
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.convert import joint_state

from ros_harness import NAMESPACE, NodeUnderTest
from test_frames import chain, poses, rotation
from test_urdf import NON_IDEAL
from tolerances import QUIET_S

MODULE = "sfs_ros.nodes.tf_node"
NODE = "state_publisher"
#: Frames of this test run only: /tf is global, shared with any run in the same domain.
PREFIX = NAMESPACE.strip("/") + "/"
PARENT = "world"
PARENT_POSE = [0.5, -0.25, 0.8, 0.1, -0.2, 1.3]
#: Pose agreement, metres and rotation-matrix entries: float64 translations and
#: quaternions in the messages (round-off ~1e-15); the bound is far above it.
POSE_TOL = 1e-6


def rig_parameters(rig: RigCalibration) -> dict:
    """The rig as node parameter values (cx, cy below 0 = the image centre)."""
    values = rig.to_dict()
    values["cx"] = -1.0 if rig.cx is None else rig.cx
    values["cy"] = -1.0 if rig.cy is None else rig.cy
    return values


def static_listener_qos() -> QoSProfile:
    """tf2's ``StaticListenerQoS``: reliable, transient-local, keep-last 100.

    The depth matters: each static broadcaster (each cell's state publisher, and any other
    run's in the same ROS domain) keeps its last message for late joiners, and a reader of
    depth 1 keeps only one of the messages that arrive together.
    """
    return QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def matrix(transform) -> np.ndarray:
    """4x4 of a geometry_msgs/Transform (child -> parent), quaternion written out here."""
    q = transform.rotation
    norm = math.sqrt(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2)
    angle = 2 * math.atan2(math.sqrt(q.x ** 2 + q.y ** 2 + q.z ** 2), q.w)
    axis = (q.x, q.y, q.z) if angle else (0.0, 0.0, 1.0)
    T = np.eye(4)
    T[:3, :3] = rotation(axis, angle) if angle else np.eye(3)
    T[:3, 3] = transform.translation.x, transform.translation.y, transform.translation.z
    assert abs(norm - 1) < 1e-12
    return T


def ours(messages: list) -> list:
    """(parent, child, 4x4, stamp) of every transform of this run's cell in ``messages``."""
    return [(t.header.frame_id, t.child_frame_id, matrix(t.transform),
             (t.header.stamp.sec, t.header.stamp.nanosec))
            for msg in messages for t in msg.transforms if t.child_frame_id.startswith(PREFIX)]


def keep_ours(store: list):
    """A TFMessage callback appending to ``store`` the messages of this run's cell: the TF
    topics are global, shared with any other cell in the same domain."""
    def keep(msg) -> None:
        if ours([msg]):
            store.append(msg)
    return keep


class Cell(NodeUnderTest):
    """The node process, the probe's joint state publisher, its TF and URDF subscriptions."""

    def __init__(self, params_file):
        super().__init__(MODULE, params_file=params_file)
        node = self.probe.node
        self.tf, self.static, self.descriptions = [], [], []
        self.joints = node.create_publisher(JointState, "joint_states", 10)
        subs = [node.create_subscription(TFMessage, "/tf", keep_ours(self.tf), capture_qos(100)),
                node.create_subscription(TFMessage, "/tf_static", keep_ours(self.static),
                                         static_listener_qos()),
                node.create_subscription(String, "robot_description", self.descriptions.append,
                                         result_qos())]
        self.probe.wait_connected(publishers=[self.joints], subscriptions=subs,
                                  process=self.process)

    def static_tree(self) -> list:
        """The latest /tf_static of this cell (each message holds all its static transforms)."""
        self.probe.spin_until(lambda: ours(self.static[-1:]), what="/tf_static",
                              process=self.process)
        return [(p, c, T) for p, c, T, _ in ours(self.static[-1:])]

    def moving_tree(self, theta: float, phi: float, stamp: tuple[int, int]) -> list:
        """Publish a joint state; the transforms of /tf stamped with its stamp."""
        self.joints.publish(joint_state(theta, phi, stamp=stamp))
        found = lambda: [(p, c, T) for p, c, T, s in ours(self.tf) if s == stamp]  # noqa: E731
        self.probe.spin_until(lambda: len(found()) == 2, what=f"/tf at {stamp}",
                              process=self.process)
        return found()

    def set_atomically(self, values: dict):
        """SetParametersAtomically on the node, as a user would; its SetParametersResult."""
        client = self.parameter_client(NODE)
        future = client.set_parameters_atomically(
            [Parameter(name, value=value) for name, value in values.items()])
        self.probe.spin_until(future.done, what="the parameters set", process=self.process)
        return future.result().result


@pytest.fixture()
def cell(start_node, tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        **rig_parameters(NON_IDEAL), "frame_prefix": PREFIX, "parent_frame": PARENT,
        "parent_pose": PARENT_POSE}}}))
    return start_node(functools.partial(Cell, params))


def assert_camera_is_the_rig_model(tree: list, rig: RigCalibration, theta: float, phi: float):
    parent_turntable = chain(tree, PARENT, PREFIX + "turntable")
    parent_camera = chain(tree, PARENT, PREFIX + "camera_optical")
    camera_turntable = np.linalg.inv(parent_camera) @ parent_turntable   # object -> camera
    cam = rig_camera(theta, phi, rig)
    assert np.abs(camera_turntable[:3, :3] - cam.R).max() < POSE_TOL, (theta, phi)
    assert np.abs(camera_turntable[:3, 3] - cam.t).max() < POSE_TOL, (theta, phi)


def test_tf_of_a_prefixed_cell_in_a_parent_frame_is_the_rig_model(cell):
    static = cell.static_tree()
    assert {(p, c) for p, c, _ in static} == {(PARENT, PREFIX + "base_link"),
                                              (PREFIX + "carriage", PREFIX + "camera_optical")}
    base = next(T for p, c, T in static if p == PARENT)
    assert np.abs(base[:3, 3] - PARENT_POSE[:3]).max() < POSE_TOL
    for k, (theta, phi) in enumerate(poses()):
        moving = cell.moving_tree(theta, phi, (100 + k, 250))
        assert {(p, c) for p, c, _ in moving} == {(PREFIX + "base_link", PREFIX + "turntable"),
                                                  (PREFIX + "base_link", PREFIX + "carriage")}
        assert_camera_is_the_rig_model(static + moving, NON_IDEAL, theta, phi)

    # Another machine's joint state is ignored; the cell's next one is published.
    cell.joints.publish(JointState(name=["shoulder"], position=[0.3]))
    cell.moving_tree(0.2, 0.1, (200, 0))
    assert all(s in {(100 + k, 250) for k in range(len(poses()))} | {(200, 0)}
               for *_, s in ours(cell.tf))

    # RViz's robot model: the URDF in the same frames.
    cell.probe.spin_until(lambda: cell.descriptions, what="robot_description",
                          process=cell.process)
    assert f'<link name="{PREFIX}camera_optical"/>' in cell.descriptions[-1].data
    assert "ERROR" not in cell.process.output() and "Traceback" not in cell.process.output()


def test_rig_parameters_set_at_run_time_move_the_static_transforms(cell):
    cell.static_tree()
    moved = RigCalibration(**{**NON_IDEAL.to_dict(), "camera_distance_m": 0.9,
                              "mount_rotation_rad": (0.1, -0.05, 0.2)})
    result = cell.set_atomically({"camera_distance_m": 0.9,
                                  "mount_rotation_rad": [0.1, -0.05, 0.2]})
    assert result.successful, result.reason
    cell.probe.spin_until(lambda: any(abs(T[1, 3] + 0.9) < POSE_TOL
                                      for *_, T, _ in ours(cell.static[-1:])),
                          what="/tf_static of the new rig", process=cell.process)
    static = cell.static_tree()
    for k, (theta, phi) in enumerate(poses()[:4]):
        assert_camera_is_the_rig_model(static + cell.moving_tree(theta, phi, (300 + k, 0)),
                                       moved, theta, phi)

    # A set that makes no rig is refused with the reason; the rig and its TF stay.
    published = len(cell.static)
    refused = cell.set_atomically({"convention": "paper", "camera_distance_m": 0.5})
    assert not refused.successful
    assert "physical" in refused.reason, refused.reason
    refused = cell.set_atomically({"aim_point_m": [0.0, 0.1]})
    assert not refused.successful and "aim_point_m" in refused.reason, refused.reason
    cell.probe.spin_for(QUIET_S)
    assert len(cell.static) == published
    assert_camera_is_the_rig_model(static + cell.moving_tree(0.7, 0.4, (400, 0)), moved, 0.7, 0.4)


def test_the_cell_moves_in_its_parent_at_run_time_but_keeps_its_frame_names(cell):
    moved = [1.5, 0.25, 0.0, 0.0, 0.0, -0.4]
    result = cell.set_atomically({"parent_pose": moved})
    assert result.successful, result.reason

    def base():
        found = [T for p, c, T in ours_static(cell) if p == PARENT]
        return found[0] if found else None
    cell.probe.spin_until(lambda: base() is not None
                          and np.abs(base()[:3, 3] - moved[:3]).max() < POSE_TOL,
                          what="/tf_static of the moved cell", process=cell.process)
    # Every node that stamps a frame read its name at start: a new name would part them.
    refused = cell.set_atomically({"frame_prefix": "elsewhere/"})
    assert not refused.successful and "frame_prefix" in refused.reason, refused.reason


def ours_static(cell) -> list:
    return [(p, c, T) for p, c, T, _ in ours(cell.static[-1:])]


def test_tf_message_type_is_upstreams(cell):
    """The TFMessage built into the environment has tf2_msgs' Kilted type hash, so our /tf
    meets other machines' tf2 listeners and recorders."""
    def infos():
        return [i for i in cell.probe.node.get_publishers_info_by_topic("/tf")
                if i.node_name == NODE and i.node_namespace == NAMESPACE]

    cell.probe.spin_until(infos, what="the node's /tf publisher", process=cell.process)
    expected = get_typestore(Stores.ROS2_KILTED).hash_rihs01("tf2_msgs/msg/TFMessage")
    assert all(str(i.topic_type_hash) == expected for i in infos())
