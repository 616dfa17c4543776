"""The cell's TF tree (sfs_ros.core.geometry.frames) is the rig model, in the configured frames.

The transforms are composed here as tf2 does (``T_parent_child`` matrices multiplied
along the tree) and the camera's pose in the turntable frame compared with
``rig_camera``: it must be the inverse of the rig model's object -> camera ``R``, ``t``.
Also: the xacro macro expands (with PyPI's xacro) to the URDF's kinematics with every
name prefixed, and ``config/frames.yaml`` holds exactly the frame parameters.
"""

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from sfs_ros.core.geometry.frames import (
    FrameNames,
    moving_transforms,
    pose_rotation,
    quaternion_from_matrix,
    static_transforms,
)
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.geometry.urdf import cell_urdf, cell_xacro, main, rig_from_parameters

from test_urdf import NON_IDEAL, Urdf, rotation, rpy_matrix

REPO = Path(__file__).resolve().parents[1]
#: Pose agreement, metres and rotation-matrix entries: a few 4x4 products of entries ~1
#: and lengths ~1 m, each rounding ~1e-16.
POSE_TOL = 1e-9

#: Tilted, off-centre, zeroed and mount-rotated, with the axis tilts larger than NON_IDEAL's.
TILTED = RigCalibration(projection="pinhole", width=640, height=480, fx=1400.0, fy=1400.0,
                        camera_distance_m=0.8, aim_point_m=(-0.03, 0.02, 0.11),
                        theta_zero_rad=-1.2, phi_zero_rad=0.25, axis_point_m=(0.05, -0.04),
                        axis_tilt_x_rad=0.0, axis_tilt_y_rad=0.2,
                        mount_rotation_rad=(-0.1, 0.05, 0.3))
RIGS = {"default": RigCalibration(), "non-ideal": NON_IDEAL, "tilted": TILTED}


def poses():
    """A dozen encoder readings (theta, phi), radians: the corners of the C-arm and random."""
    rng = np.random.default_rng(11)
    fixed = [(0.0, 0.0), (math.pi, 1.2), (-2.5, -1.2), (7.0, 0.3)]
    return fixed + list(zip(rng.uniform(-7, 7, 8), rng.uniform(-1.2, 1.2, 8)))


def chain(transforms, root: str, frame: str) -> np.ndarray:
    """4x4 pose of ``frame`` in ``root`` (``X_root = T X_frame``) from a list of transforms,
    each a (parent, child, 4x4) tuple, by walking up the tree as tf2 does."""
    up = {child: (parent, T) for parent, child, T in transforms}
    T = np.eye(4)
    while frame != root:
        parent, step = up[frame]
        T, frame = step @ T, parent
    return T


def as_tuples(transforms):
    return [(t.parent, t.child, t.matrix()) for t in transforms]


@pytest.mark.parametrize("rig", RIGS.values(), ids=RIGS.keys())
def test_camera_in_turntable_is_the_rig_camera(rig):
    names = FrameNames()
    for theta, phi in poses():
        tree = as_tuples(static_transforms(rig, names) + moving_transforms(rig, names, theta, phi))
        base_turntable = chain(tree, "base_link", "turntable")
        base_camera = chain(tree, "base_link", "camera_optical")
        camera_turntable = np.linalg.inv(base_camera) @ base_turntable   # object -> camera
        cam = rig_camera(theta, phi, rig)
        assert np.abs(camera_turntable[:3, :3] - cam.R).max() < POSE_TOL, (theta, phi)
        assert np.abs(camera_turntable[:3, 3] - cam.t).max() < POSE_TOL, (theta, phi)


@pytest.mark.parametrize("rig", RIGS.values(), ids=RIGS.keys())
def test_the_transforms_are_the_urdfs_joints(rig):
    """One kinematics: the TF of a reading is the URDF's forward kinematics at it."""
    urdf = Urdf(cell_urdf(rig))
    names = FrameNames()
    for theta, phi in poses()[:4]:
        tree = as_tuples(static_transforms(rig, names) + moving_transforms(rig, names, theta, phi))
        for link in ("turntable", "carriage", "camera_optical"):
            expected = urdf.pose(link, {"turntable": theta, "carriage": phi})
            assert np.abs(chain(tree, "base_link", link) - expected).max() < POSE_TOL


def test_static_and_moving_split():
    names = FrameNames()
    static = static_transforms(TILTED, names)
    assert [(t.parent, t.child) for t in static] == [("carriage", "camera_optical")]
    moving = moving_transforms(TILTED, names, 0.4, -0.2)
    assert [(t.parent, t.child) for t in moving] == [("base_link", "turntable"),
                                                    ("base_link", "carriage")]
    # The joints move what they should: the turntable with theta, the carriage with phi.
    other = moving_transforms(TILTED, names, 0.9, 0.3)
    assert all(np.abs(a.rotation - b.rotation).max() > 0.1 for a, b in zip(moving, other))
    assert all(np.array_equal(a.translation, b.translation) for a, b in zip(moving, other))
    with pytest.raises(ValueError, match="finite"):
        moving_transforms(TILTED, names, math.nan, 0.0)
    with pytest.raises(ValueError, match="physical"):
        static_transforms(RigCalibration(convention="paper"), names)


def test_prefix_and_names_apply_to_every_frame():
    names = FrameNames(prefix="cell1/", base="lab", camera="cam_optical", parent="world")
    transforms = static_transforms(TILTED, names) + moving_transforms(TILTED, names, 0.1, 0.2)
    frames = {f for t in transforms for f in (t.parent, t.child)}
    assert frames == {"world", "cell1/lab", "cell1/turntable", "cell1/carriage",
                      "cell1/cam_optical"}
    assert names.turntable_frame == "cell1/turntable" and names.camera_frame == "cell1/cam_optical"
    # The URDF made for the same names has the same links (what RViz's model shows).
    links = {link.get("name") for link in ET.fromstring(
        cell_urdf(TILTED, links=names.links())).findall("link")}
    assert links == frames - {"world"}


@pytest.mark.parametrize("pose", [[0.4, -1.0, 0.75, 0.1, -0.3, 2.0],
                                  [0.4, -1.0, 0.75, *(0.2 * np.array([0.1, -0.5, 0.3, 0.8]))]],
                         ids=["rpy", "quaternion"])
def test_parent_attach(pose):
    """parent -> base is the given pose (URDF rpy, or an unnormalised quaternion x, y, z, w);
    the camera in the turntable frame does not change with it."""
    names = FrameNames(prefix="c/", parent="world", parent_pose=tuple(pose))
    static = static_transforms(TILTED, names)
    assert (static[0].parent, static[0].child) == ("world", "c/base_link")
    if len(pose) == 6:
        expected = rpy_matrix(*pose[3:])
    else:   # rotation about the quaternion's axis by twice the angle of its w
        q = np.array(pose[3:]) / np.linalg.norm(pose[3:])
        expected = rotation(q[:3], 2 * math.acos(q[3]))
    assert np.abs(static[0].rotation - expected).max() < 1e-12
    assert np.array_equal(static[0].translation, pose[:3])
    tree = as_tuples(static + moving_transforms(TILTED, names, 1.0, 0.5))
    world_camera = chain(tree, "world", "c/camera_optical")
    world_turntable = chain(tree, "world", "c/turntable")
    cam = rig_camera(1.0, 0.5, TILTED)
    camera_turntable = np.linalg.inv(world_camera) @ world_turntable
    assert np.abs(camera_turntable[:3, :3] - cam.R).max() < POSE_TOL
    assert np.abs(camera_turntable[:3, 3] - cam.t).max() < POSE_TOL


def test_quaternion_round_trip():
    """Every branch of the quaternion (trace or one diagonal entry the largest) gives the
    rotation back, with w >= 0."""
    rng = np.random.default_rng(5)
    angles = [(axis, angle) for axis in np.eye(3) for angle in (0.0, 1.0, math.pi - 1e-3, math.pi)]
    angles += [(rng.normal(size=3), rng.uniform(0, math.pi)) for _ in range(300)]
    for axis, angle in angles:
        R = rotation(axis, angle)
        q = quaternion_from_matrix(R)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-15
        back, _ = pose_rotation([0, 0, 0, *q])
        assert np.abs(back - R).max() < 1e-14


@pytest.mark.parametrize("kwargs, error", [
    ({"prefix": "/cell1/"}, "prefix"), ({"prefix": "cell 1/"}, "prefix"),
    ({"base": ""}, "base"), ({"camera": "/camera"}, "camera"),
    ({"carriage": "turntable"}, "different"), ({"parent": "/world"}, "parent"),
    ({"parent": "base_link"}, "one of the cell's own"),
    ({"parent_pose": (0.0, 0.0, 0.0)}, "six finite numbers"),
    ({"parent_pose": (0.0, 0.0, math.inf, 0.0, 0.0, 0.0)}, "six finite numbers"),
    ({"parent_pose": (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)}, "no direction")])
def test_bad_frame_names_refused(kwargs, error):
    with pytest.raises(ValueError, match=error):
        FrameNames(**kwargs)


def _rig_yaml() -> RigCalibration:
    parameters = yaml.safe_load((REPO / "config" / "rig.yaml").read_text())["/**"]["ros__parameters"]
    return rig_from_parameters(parameters)


def test_installed_xacro_is_made_from_config_rig_yaml(capsys):
    expected = cell_xacro(_rig_yaml())
    assert (REPO / "urdf" / "sfs_cell.urdf.xacro").read_text() == expected, (
        "regenerate: python -m sfs_ros.core.geometry.urdf --xacro config/rig.yaml "
        "> urdf/sfs_cell.urdf.xacro")
    assert main(["--xacro", str(REPO / "config" / "rig.yaml")]) == 0
    assert capsys.readouterr().out == expected


def test_xacro_macro_names_everything_with_the_prefix():
    root = ET.fromstring(cell_xacro(NON_IDEAL))
    namespace = "{http://www.ros.org/wiki/xacro}"
    (macro,) = root.findall(f"{namespace}macro")
    assert macro.get("name") == "sfs_cell"
    assert macro.get("params").split() == ["prefix:=''", "parent", "*origin"]
    names = [e.get("name") for e in macro if e.tag in ("link", "joint")]
    assert len(names) == 4 + 4 and all(n.startswith("${prefix}") for n in names)
    for joint in macro.findall("joint"):
        links = [joint.find("parent").get("link"), joint.find("child").get("link")]
        assert all(link.startswith("${prefix}") or link == "${parent}" for link in links)


def test_xacro_expands_to_the_rig_model_in_a_robots_description(tmp_path):
    """The macro, included twice in a robot's description (two cells, one with a prefix),
    expands with xacro to links and joints whose kinematics is the rig model's."""
    import xacro

    macro = tmp_path / "sfs_cell.urdf.xacro"
    macro.write_text(cell_xacro(NON_IDEAL))
    robot = tmp_path / "robot.urdf.xacro"
    robot.write_text(f"""<?xml version="1.0"?>
<robot name="workshop" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <link name="world"/>
  <xacro:include filename="{macro}"/>
  <xacro:sfs_cell prefix="cell1/" parent="world"><origin xyz="1 2 0.5" rpy="0 0 0.7"/></xacro:sfs_cell>
  <xacro:sfs_cell parent="world"><origin xyz="0 0 0" rpy="0 0 0"/></xacro:sfs_cell>
</robot>""")
    urdf = Urdf(xacro.process_file(str(robot)).toxml())
    assert set(urdf.links) == {"world"} | {p + n for p in ("", "cell1/") for n in (
        "base_link", "turntable", "carriage", "camera_optical")}
    base = urdf.pose("cell1/base_link", {})
    assert np.abs(base[:3, :3] - rpy_matrix(0, 0, 0.7)).max() < 1e-12
    assert np.abs(base[:3, 3] - [1, 2, 0.5]).max() < 1e-12
    for theta, phi in poses():
        for prefix in ("", "cell1/"):
            positions = {prefix + "turntable": theta, prefix + "carriage": phi}
            camera_turntable = (np.linalg.inv(urdf.pose(prefix + "camera_optical", positions))
                                @ urdf.pose(prefix + "turntable", positions))
            cam = rig_camera(theta, phi, NON_IDEAL)
            assert np.abs(camera_turntable[:3, :3] - cam.R).max() < POSE_TOL
            assert np.abs(camera_turntable[:3, 3] - cam.t).max() < POSE_TOL


def test_frames_file_holds_exactly_the_frame_parameters_with_their_defaults():
    from sfs_ros.ros.frames import FRAME_PARAMS

    values = yaml.safe_load((REPO / "config" / "frames.yaml").read_text())["/**"]["ros__parameters"]
    assert values == {p.name: p.default for p in FRAME_PARAMS}
