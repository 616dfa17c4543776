"""numpy / core objects <-> ROS messages: round trips and closed-form checks."""

import array

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image, JointState, PointCloud2, PointField
from shape_msgs.msg import Mesh
from visualization_msgs.msg import Marker

from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.ros.convert import (
    angles_from_joint_state,
    camera_info,
    camera_poses,
    cloud_to_points,
    image_to_msg,
    joint_state,
    mesh_to_marker,
    mesh_to_shape,
    msg_to_image,
    points_to_cloud,
    shape_to_mesh,
)

from tolerances import PIXEL_ROUND_OFF_PX, ROUND_OFF

STAMP = (1712345678, 123456789)
RNG = np.random.default_rng(7)


def _wire(msg):
    """The message after serialisation, as a subscriber in another process receives it."""
    return deserialize_message(serialize_message(msg), type(msg))


def test_rgb_image_round_trip_through_the_wire():
    image = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    msg = image_to_msg(image, stamp=STAMP, frame_id="camera")
    assert (msg.encoding, msg.height, msg.width, msg.step) == ("rgb8", 5, 7, 21)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == STAMP
    assert msg.header.frame_id == "camera"
    np.testing.assert_array_equal(msg_to_image(_wire(msg)), image)


def test_read_back_is_a_view_of_the_message_buffer():
    msg = image_to_msg(np.zeros((4, 4), np.uint8), stamp=STAMP, frame_id="c")
    image = msg_to_image(msg)
    image[1, 2] = 9
    assert msg.data[1 * 4 + 2] == 9


def test_bgr8_is_returned_as_rgb():
    rgb = RNG.integers(0, 256, (3, 4, 3), dtype=np.uint8)
    msg = image_to_msg(np.ascontiguousarray(rgb[:, :, ::-1]), stamp=STAMP, frame_id="c",
                       encoding="bgr8")
    np.testing.assert_array_equal(msg_to_image(msg), rgb)


def test_mask_is_mono8_0_or_255():
    mask = RNG.random((6, 5)) > 0.5
    msg = image_to_msg(mask, stamp=STAMP, frame_id="c")
    assert msg.encoding == "mono8"
    np.testing.assert_array_equal(msg_to_image(msg), np.where(mask, 255, 0))


def test_row_padding_is_skipped():
    image = RNG.integers(0, 256, (3, 5, 3), dtype=np.uint8)
    padded = np.zeros((3, 18), np.uint8)        # 15 bytes of pixels + 3 of padding per row
    padded[:, :15] = image.reshape(3, 15)
    padded[:, 15:] = 77
    msg = Image(height=3, width=5, encoding="rgb8", step=18)
    msg.data = array.array("B", padded.tobytes())
    np.testing.assert_array_equal(msg_to_image(msg), image)


@pytest.mark.parametrize("bigendian", [0, 1])
def test_mono16_respects_byte_order(bigendian):
    values = np.array([[1, 258], [65535, 4096]], np.uint16)   # 258 = 0x0102
    raw = values.astype(">u2" if bigendian else "<u2").tobytes()
    msg = Image(height=2, width=2, encoding="mono16", step=4, is_bigendian=bigendian)
    msg.data = array.array("B", raw)
    np.testing.assert_array_equal(msg_to_image(msg), values)


def test_malformed_images_are_refused_with_a_reason():
    msg = image_to_msg(np.zeros((4, 4, 3), np.uint8), stamp=STAMP, frame_id="c")
    msg.encoding = "yuv422"
    with pytest.raises(ValueError, match="yuv422"):
        msg_to_image(msg)
    msg = image_to_msg(np.zeros((4, 4, 3), np.uint8), stamp=STAMP, frame_id="c")
    msg.data = msg.data[:-1]
    with pytest.raises(ValueError, match="47 bytes"):
        msg_to_image(msg)
    msg = image_to_msg(np.zeros((4, 4, 3), np.uint8), stamp=STAMP, frame_id="c")
    msg.step = 10
    with pytest.raises(ValueError, match="step"):
        msg_to_image(msg)
    with pytest.raises(ValueError, match="does not fit"):
        image_to_msg(np.zeros((4, 4), np.uint8), stamp=STAMP, frame_id="c", encoding="rgb8")
    with pytest.raises(ValueError, match="float"):
        image_to_msg(np.zeros((4, 4), np.float32), stamp=STAMP, frame_id="c")


def test_joint_state_round_trip_and_lookup_by_name():
    msg = _wire(joint_state(0.25, -1.0, stamp=Time(sec=3, nanosec=4)))
    assert list(msg.name) == ["turntable", "carriage"]
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 4)
    assert angles_from_joint_state(msg) == (0.25, -1.0)
    swapped = JointState(name=["carriage", "gripper", "turntable"], position=[0.5, 9.0, 1.5])
    assert angles_from_joint_state(swapped) == (1.5, 0.5)


@pytest.mark.parametrize("names, positions, match", [
    (["turntable"], [0.1], "carriage"),
    (["turntable", "carriage"], [0.1], "no position"),
    (["turntable", "carriage"], [0.1, float("nan")], "finite"),
])
def test_bad_joint_states_are_refused(names, positions, match):
    with pytest.raises(ValueError, match=match):
        angles_from_joint_state(JointState(name=names, position=positions))


def test_pinhole_camera_info_projects_like_the_camera():
    K = np.array([[700.0, 0.0, 160.0], [0.0, 710.0, 120.0], [0.0, 0.0, 1.0]])
    camera = Camera(K=K, R=np.eye(3), t=np.zeros(3), width=320, height=240)
    info = _wire(camera_info(camera, stamp=STAMP, frame_id="camera_optical"))
    assert (info.width, info.height, info.header.frame_id) == (320, 240, "camera_optical")
    np.testing.assert_array_equal(np.reshape(info.k, (3, 3)), K)
    P = np.reshape(info.p, (3, 4))
    points = np.array([[0.01, -0.02, 0.5], [-0.05, 0.03, 0.8]])   # camera frame = world here
    h = np.c_[points, np.ones(2)] @ P.T
    np.testing.assert_allclose(h[:, :2] / h[:, 2:], camera.project(points), atol=PIXEL_ROUND_OFF_PX)
    assert list(info.d) == [0.0] * 5


def test_camera_info_carries_the_lens_distortion():
    D = (-0.2, 0.05, 0.001, -0.002, 0.0)
    camera = Camera(K=np.diag([700.0, 700.0, 1.0]), R=np.eye(3), t=np.zeros(3), width=320,
                    height=240, distortion=D)
    info = _wire(camera_info(camera, stamp=STAMP, frame_id="c"))
    assert info.distortion_model == "plumb_bob" and list(info.d) == list(D)


def test_orthographic_camera_info_is_affine():
    K = np.array([[2000.0, 0.0, 100.0], [0.0, 2000.0, 80.0], [0.0, 0.0, 1.0]])   # px per metre
    camera = Camera(K=K, R=np.eye(3), t=np.zeros(3), width=200, height=160, orthographic=True)
    P = np.reshape(camera_info(camera, stamp=STAMP, frame_id="c").p, (3, 4))
    np.testing.assert_array_equal(P[2], [0, 0, 0, 1])
    points = RNG.normal(0, 0.05, (4, 3))
    h = np.c_[points, np.ones(4)] @ P.T
    np.testing.assert_allclose(h[:, :2], camera.project(points), atol=PIXEL_ROUND_OFF_PX)


def test_cloud_round_trip_in_float32():
    points = RNG.normal(0.0, 0.1, (1000, 3))
    msg = _wire(points_to_cloud(points, stamp=STAMP, frame_id="turntable"))
    assert (msg.width, msg.height, msg.point_step, msg.is_dense) == (1000, 1, 12, True)
    # float32 keeps 24 bits of mantissa: relative error <= 2**-24 of each coordinate.
    np.testing.assert_allclose(cloud_to_points(msg), points, rtol=2 ** -24, atol=0)


def test_cloud_with_other_layout_is_read():
    # Organised 2 x 3, fields z, x, y as big-endian float64 after a 4-byte intensity, padded rows.
    points = RNG.normal(size=(2, 3, 3))
    record = np.dtype({"names": ["i", "z", "x", "y"], "formats": ["<f4", ">f8", ">f8", ">f8"],
                       "offsets": [0, 4, 12, 20], "itemsize": 32})
    rows = np.zeros((2, 3 * 32 + 8), np.uint8)
    for r in range(2):
        rec = np.zeros(3, record)
        rec["x"], rec["y"], rec["z"] = points[r].T
        rows[r, :96] = rec.view(np.uint8)
    fields = [PointField(name=n, offset=o, datatype=PointField.FLOAT64, count=1)
              for n, o in (("z", 4), ("x", 12), ("y", 20))]
    msg = PointCloud2(height=2, width=3, fields=fields, is_bigendian=True, point_step=32,
                      row_step=104)
    msg.data = array.array("B", rows.tobytes())
    np.testing.assert_array_equal(cloud_to_points(msg), points.reshape(-1, 3))


def _tetrahedron():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return vertices, faces


def test_marker_lists_three_corners_per_face():
    vertices, faces = _tetrahedron()
    marker = _wire(mesh_to_marker(vertices, faces, stamp=STAMP, frame_id="turntable",
                                  color=(1.0, 0.5, 0.0, 1.0)))
    assert marker.type == Marker.TRIANGLE_LIST and marker.action == Marker.ADD
    corners = np.array([(p.x, p.y, p.z) for p in marker.points])
    np.testing.assert_array_equal(corners, vertices[faces.ravel()])
    assert marker.pose.orientation.w == 1.0 and marker.scale.x == 1.0 and marker.color.g == 0.5


def test_marker_colours_each_corner_with_its_vertex_colour():
    vertices, faces = _tetrahedron()
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]], np.uint8)
    marker = _wire(mesh_to_marker(vertices, faces, stamp=STAMP, frame_id="turntable",
                                  vertex_colors=rgb))
    colours = np.array([(c.r, c.g, c.b, c.a) for c in marker.colors])
    assert len(colours) == len(marker.points) == 3 * len(faces)
    np.testing.assert_allclose(colours[:, :3], rgb[faces.ravel()] / 255.0, atol=1e-6)  # float32
    with pytest.raises(ValueError, match="vertex_colors"):
        mesh_to_marker(vertices, faces, stamp=STAMP, frame_id="t", vertex_colors=rgb[:2])


def _rotate(q, v):
    """Vector ``v`` rotated by the unit quaternion message ``q`` (closed form)."""
    u, w = np.array([q.x, q.y, q.z]), q.w
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


def test_camera_pose_arrows_point_where_the_cameras_look():
    rig = RigCalibration(width=320, height=240, projection="pinhole", fx=700.0, fy=700.0,
                         camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
    cameras = [rig_camera(t, p, rig) for t, p in ((0.0, 0.0), (1.0, 0.5), (2.5, 1.2))]
    msg = _wire(camera_poses(cameras, stamp=STAMP, frame_id="turntable"))
    assert msg.header.frame_id == "turntable" and len(msg.poses) == 3
    for pose, camera in zip(msg.poses, cameras):
        p = pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], camera.center, atol=ROUND_OFF)
        # Body axes: x forward, z towards the top of the image (optical -y).
        np.testing.assert_allclose(_rotate(pose.orientation, [1, 0, 0]), camera.forward,
                                   atol=1e-9)
        np.testing.assert_allclose(_rotate(pose.orientation, [0, 0, 1]), -camera.R[1],
                                   atol=1e-9)


def test_shape_mesh_round_trip():
    vertices, faces = _tetrahedron()
    back = shape_to_mesh(_wire(mesh_to_shape(vertices, faces)))
    np.testing.assert_array_equal(back[0], vertices)
    np.testing.assert_array_equal(back[1], faces)
    assert isinstance(mesh_to_shape(vertices, faces[:0]), Mesh)


def test_bad_meshes_are_refused():
    vertices, faces = _tetrahedron()
    with pytest.raises(ValueError, match="indices"):
        mesh_to_shape(vertices, faces + 1)
    with pytest.raises(ValueError, match="color"):
        mesh_to_marker(vertices, faces, stamp=STAMP, frame_id="c", color=(2, 0, 0, 1))


def test_empty_cloud_round_trips():
    # An empty hull (after a reset) is a valid cloud with no points.
    msg = points_to_cloud(np.zeros((0, 3)), stamp=(1, 2), frame_id="turntable")
    assert (msg.width, msg.row_step, len(msg.data)) == (0, 0, 0)
    assert cloud_to_points(msg).shape == (0, 3)


def test_health_is_the_worst_of_problem_and_warning():
    from diagnostic_msgs.msg import DiagnosticStatus

    from sfs_ros.ros.convert import health
    assert health("broken", "odd", "fine") == (DiagnosticStatus.ERROR, "broken")
    assert health("", "odd", "fine") == (DiagnosticStatus.WARN, "odd")
    assert health("", "", "fine") == (DiagnosticStatus.OK, "fine")
