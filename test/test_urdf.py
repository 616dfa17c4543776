"""The cell's URDF has the rig model's kinematics (no ROS: parsed with xml.etree).

Forward kinematics is composed here from the URDF's joints as robot_state_publisher
does (``T_parent_child = T(origin) T(joint motion)``), with our own rpy and axis-angle
code, and compared with ``rig_camera``: the camera pose relative to ``turntable``
must be the inverse of the rig model's object -> camera ``R``, ``t``.
"""

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from sfs_ros.cell_logic.message_fields import JOINT_NAMES
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.geometry.urdf import (
    CAMERA_FRAME,
    OBJECT_FRAME,
    cell_urdf,
    main,
    rig_from_parameters,
    rpy_from_matrix,
)

REPO = Path(__file__).resolve().parents[1]
#: Pose agreement, metres and rotation-matrix entries: rounding of a few matrix
#: products and of rpy angles written with 17 digits (errors ~1e-15 x lengths ~1 m).
POSE_TOL = 1e-9

NON_IDEAL = RigCalibration(
    projection="pinhole", width=640, height=480, fx=1400.0, fy=1390.0, cx=321.5, cy=238.0,
    camera_distance_m=0.55, aim_point_m=(0.012, -0.008, 0.045), theta_zero_rad=0.31,
    phi_zero_rad=-0.07, distortion=(-0.12, 0.03, 0.001, -0.002, 0.0),
    axis_point_m=(0.004, -0.003), axis_tilt_x_rad=0.02, axis_tilt_y_rad=-0.035,
    mount_rotation_rad=(0.015, -0.02, 0.04))


def rotation(axis, angle):
    """Rodrigues, written again here so the test does not reuse the code it checks."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rpy_matrix(roll, pitch, yaw):
    """URDF rpy: fixed-axis roll about X, pitch about Y, yaw about Z."""
    return rotation((0, 0, 1), yaw) @ rotation((0, 1, 0), pitch) @ rotation((1, 0, 0), roll)


def transform(R, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def floats(text):
    return [float(v) for v in text.split()]


class Urdf:
    def __init__(self, text: str):
        self.root = ET.fromstring(text)
        self.links = [link.get("name") for link in self.root.findall("link")]
        self.joints = {j.get("name"): j for j in self.root.findall("joint")}
        self.parent = {j.find("child").get("link"): j for j in self.joints.values()}

    def joint_transform(self, joint, position: float) -> np.ndarray:
        origin = joint.find("origin")
        T = transform(rpy_matrix(*floats(origin.get("rpy"))), floats(origin.get("xyz")))
        kind = joint.get("type")
        if kind == "fixed":
            return T
        assert kind in ("revolute", "continuous"), kind
        return T @ transform(rotation(floats(joint.find("axis").get("xyz")), position), np.zeros(3))

    def pose(self, link: str, positions: dict) -> np.ndarray:
        """4x4 pose of ``link`` in the root link (maps link coordinates to root)."""
        T = np.eye(4)
        while link in self.parent:
            joint = self.parent[link]
            T = self.joint_transform(joint, positions.get(joint.get("name"), 0.0)) @ T
            link = joint.find("parent").get("link")
        return T


def angles():
    rng = np.random.default_rng(7)
    thetas = np.concatenate([[0.0, math.pi / 2, math.pi, -2.5, 7.0], rng.uniform(-7, 7, 40)])
    phis = np.concatenate([[0.0, math.pi / 2 - 0.1, -math.pi / 2 + 0.2, 1.0, 0.3],
                           rng.uniform(-1.4, 1.4, 40)])
    return list(zip(thetas, phis))


@pytest.mark.parametrize("rig", [RigCalibration(), NON_IDEAL,
                                 RigCalibration(projection="pinhole", camera_distance_m=0.6,
                                                aim_point_m=(0.0, 0.0, 0.04))],
                         ids=["default", "non-ideal", "config"])
def test_forward_kinematics_is_the_rig_camera(rig):
    urdf = Urdf(cell_urdf(rig))
    for theta, phi in angles():
        positions = {"turntable": theta, "carriage": phi}
        base_turntable = urdf.pose(OBJECT_FRAME, positions)
        base_camera = urdf.pose(CAMERA_FRAME, positions)
        camera_turntable = np.linalg.inv(base_camera) @ base_turntable   # object -> camera
        cam = rig_camera(theta, phi, rig)
        assert np.abs(camera_turntable[:3, :3] - cam.R).max() < POSE_TOL, (theta, phi)
        assert np.abs(camera_turntable[:3, 3] - cam.t).max() < POSE_TOL, (theta, phi)


def test_non_ideal_rig_moves_the_frames():
    """The comparison above is not vacuous: the non-ideal rig's poses differ from the
    default's by far more than the tolerance, and both joints change the camera pose."""
    urdf, ideal = Urdf(cell_urdf(NON_IDEAL)), Urdf(cell_urdf(RigCalibration()))
    for theta, phi in angles()[:5]:
        positions = {"turntable": theta, "carriage": phi}
        a = np.linalg.inv(urdf.pose(CAMERA_FRAME, positions)) @ urdf.pose(OBJECT_FRAME, positions)
        b = np.linalg.inv(ideal.pose(CAMERA_FRAME, positions)) @ ideal.pose(OBJECT_FRAME, positions)
        assert np.abs(a - b).max() > 1e-3
    zero = urdf.pose(CAMERA_FRAME, {})
    assert np.abs(urdf.pose(CAMERA_FRAME, {"carriage": 0.2}) - zero).max() > 0.05
    assert np.abs(urdf.pose(OBJECT_FRAME, {"turntable": 0.2}) - urdf.pose(OBJECT_FRAME, {})).max() > 0.1


def test_tree_links_and_joint_names():
    urdf = Urdf(cell_urdf(NON_IDEAL))
    assert urdf.root.tag == "robot"
    assert set(urdf.links) == {"base_link", "turntable", "carriage", "camera_optical"}
    roots = [link for link in urdf.links if link not in urdf.parent]
    assert roots == ["base_link"]                        # one tree, one root
    moving = {name for name, j in urdf.joints.items() if j.get("type") != "fixed"}
    assert moving == set(JOINT_NAMES)                    # what the motor node publishes
    limit = urdf.joints["carriage"].find("limit")        # phi in [-90, 90] deg after the zero
    assert float(limit.get("lower")) == pytest.approx(NON_IDEAL.phi_zero_rad - math.pi / 2)
    assert float(limit.get("upper")) == pytest.approx(NON_IDEAL.phi_zero_rad + math.pi / 2)
    # The carving and meshing nodes publish in the object frame, the camera in its optical frame.
    for node in ("carving_node.py", "meshing_node.py"):
        text = (REPO / "sfs_ros" / "nodes" / node).read_text()
        assert "frame_names(declare(self, FRAME_PARAMS)).turntable_frame" in text
    text = (REPO / "sfs_ros" / "nodes" / "camera_node.py").read_text()
    assert "frame_names(values).camera_frame" in text
    from sfs_ros.ros.frames import FRAME_PARAMS  # ROS: only here (the rest needs none)

    defaults = {p.name: p.default for p in FRAME_PARAMS}
    assert (defaults["turntable_frame"], defaults["camera_frame"]) == (OBJECT_FRAME, CAMERA_FRAME)


def test_installed_urdf_is_made_from_config_rig_yaml():
    """urdf/sfs_cell.urdf is what ``python -m sfs_ros.core.geometry.urdf config/rig.yaml``
    prints: the file cannot drift from the rig the nodes are started with."""
    parameters = yaml.safe_load((REPO / "config" / "rig.yaml").read_text())["/**"]["ros__parameters"]
    expected = cell_urdf(rig_from_parameters(parameters))
    assert (REPO / "urdf" / "sfs_cell.urdf").read_text() == expected, (
        "regenerate: python -m sfs_ros.core.geometry.urdf config/rig.yaml > urdf/sfs_cell.urdf")


def test_main_prints_the_urdf_and_reports_bad_files(tmp_path, capsys):
    assert main([str(REPO / "config" / "rig.yaml")]) == 0
    assert capsys.readouterr().out == (REPO / "urdf" / "sfs_cell.urdf").read_text()
    bad = tmp_path / "rig.yaml"
    bad.write_text("/**:\n  ros__parameters:\n    fx: -3.0\n")
    assert main([str(bad)]) == 1
    assert "fx" in capsys.readouterr().err
    assert main([]) == 2


def test_paper_convention_and_wrong_input_refused():
    with pytest.raises(ValueError, match="physical"):
        cell_urdf(RigCalibration(convention="paper"))
    with pytest.raises(ValueError, match="RigCalibration"):
        cell_urdf({"fx": 1.0})


def test_rpy_round_trip_including_gimbal_lock():
    rng = np.random.default_rng(3)
    for _ in range(500):
        R = rotation(rng.normal(size=3), rng.uniform(-math.pi, math.pi))
        assert np.abs(rpy_matrix(*rpy_from_matrix(R)) - R).max() < 1e-14
    for pitch in (math.pi / 2, -math.pi / 2):
        for roll, yaw in ((0.3, 0.0), (0.3, -1.1), (-2.0, 2.5)):
            R = rpy_matrix(roll, pitch, yaw)
            assert np.abs(rpy_matrix(*rpy_from_matrix(R)) - R).max() < 1e-14
    with pytest.raises(ValueError):
        rpy_from_matrix(np.eye(4))
