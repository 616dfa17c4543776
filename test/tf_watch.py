"""What a TF listener of a running cell receives, composed here (no tf2_ros on PyPI).

:class:`TfWatch` subscribes ``/tf`` and ``/tf_static`` (tf2's QoS) and a cell's
``joint_states`` on a node spun elsewhere (a :class:`CellClient`'s, in its own
thread), keeps the transforms of the frames it is told are this test run's (the TF
topics are global: any run in the same ROS domain publishes there too), and finds
the tree at the latest joint state the state publisher turned into ``/tf``. The
transforms are composed as tf2 does (:func:`test_frames.chain`), each quaternion
written out by :func:`test_tf_node.matrix`.
"""

from __future__ import annotations

import threading

import numpy as np
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

from sfs_ros.ros import capture_qos

from test_tf_node import matrix, static_listener_qos


def transform_matrix(R, t) -> np.ndarray:
    """4x4 of a rotation and a translation (``X_parent = R X_child + t``)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def camera_pose(camera) -> np.ndarray:
    """4x4 pose of a rig model camera (object -> camera ``R``, ``t``) in the object frame."""
    return np.linalg.inv(transform_matrix(camera.R, camera.t))


class TfWatch:
    """``/tf``, ``/tf_static`` and ``joint_states`` as received by ``node``.

    prefixes : the frame prefixes of this run's cells; a transform is kept when its
        child frame starts with one of them.
    joint_topics : ``{prefix: joint_states topic}`` of each cell (absolute names).
    """

    def __init__(self, node, prefixes, joint_topics: dict[str, str]):
        self._node = node
        self._prefixes = tuple(prefixes)
        self._lock = threading.Lock()
        self.moving: list[tuple] = []     # (parent, child, 4x4, stamp) of /tf
        self.static: list[tuple] = []     # (parent, child, 4x4) of /tf_static
        self.mixed: list[list[str]] = []  # child frames of messages holding two cells' frames
        self.joints: dict[str, dict] = {p: {} for p in joint_topics}   # stamp -> (theta, phi)
        self.subscriptions = [
            node.create_subscription(TFMessage, "/tf", self._on_tf, capture_qos(100)),
            node.create_subscription(TFMessage, "/tf_static", self._on_static,
                                     static_listener_qos())]
        self.subscriptions += [
            node.create_subscription(JointState, topic,
                                     lambda msg, p=prefix: self._on_joints(p, msg), 10)
            for prefix, topic in joint_topics.items()]

    def _ours(self, msg) -> list:
        kept = [t for t in msg.transforms if t.child_frame_id.startswith(self._prefixes)]
        cells = {p for t in kept for p in self._prefixes if t.child_frame_id.startswith(p)}
        if len(cells) > 1:
            self.mixed.append([t.child_frame_id for t in kept])
        return kept

    def _on_tf(self, msg) -> None:
        with self._lock:
            self.moving += [(t.header.frame_id, t.child_frame_id, matrix(t.transform),
                             (t.header.stamp.sec, t.header.stamp.nanosec))
                            for t in self._ours(msg)]

    def _on_static(self, msg) -> None:
        with self._lock:
            self.static += [(t.header.frame_id, t.child_frame_id, matrix(t.transform))
                            for t in self._ours(msg)]

    def _on_joints(self, prefix: str, msg) -> None:
        if {"turntable", "carriage"} <= set(msg.name):
            angles = {n: p for n, p in zip(msg.name, msg.position)}
            with self._lock:
                self.joints[prefix][(msg.header.stamp.sec, msg.header.stamp.nanosec)] = \
                    (angles["turntable"], angles["carriage"])

    def tree_at_last_joint_state(self, prefix: str):
        """``(theta, phi, transforms)`` at the latest joint state of the cell with frames
        ``prefix`` whose two moving transforms have arrived, ``transforms`` being the
        (parent, child, 4x4) of both and of every static one received; None before."""
        with self._lock:
            moving = [m for m in self.moving if m[1].startswith(prefix)]
            joints = dict(self.joints[prefix])
            static = list(self.static)
        stamps = sorted({s for *_, s in moving} & set(joints), reverse=True)
        for stamp in stamps:
            at = [(p, c, T) for p, c, T, s in moving if s == stamp]
            if len(at) == 2:
                return (*joints[stamp], at + static)
        return None

    def frames(self) -> tuple[set, set]:
        """The (parent, child) pairs received on ``/tf`` and on ``/tf_static``."""
        with self._lock:
            return ({(p, c) for p, c, *_ in self.moving}, {(p, c) for p, c, _ in self.static})

    def close(self) -> None:
        for sub in self.subscriptions:
            self._node.destroy_subscription(sub)
