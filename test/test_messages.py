"""Message fields decoded without ROS: the same answers from rosbags' messages as rclpy's."""

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from sfs_ros.cell_logic.message_fields import (
    ForeignJointState,
    angles_from_joint_state,
    colour_image_from_msg,
    mask_from_msg,
    msg_to_image,
    scan_report,
    status_namespace,
)

STORE = get_typestore(Stores.ROS2_KILTED)
T = STORE.types


def _round_trip(msg, msgtype: str):
    """``msg`` as a bag reader gets it: serialized to CDR, then deserialized by rosbags."""
    return STORE.deserialize_cdr(bytes(STORE.serialize_cdr(msg, msgtype)), msgtype)


def _header():
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=2),
                                    frame_id="")


def test_a_padded_bgr8_image_from_rosbags_is_rgb_without_its_padding():
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    rows = np.zeros((2, 12), np.uint8)                      # 9 bytes of pixels + 3 of padding
    rows[:, :9] = rgb[:, :, ::-1].reshape(2, 9)
    msg = _round_trip(T["sensor_msgs/msg/Image"](header=_header(), height=2, width=3,
                                                 encoding="bgr8", is_bigendian=0, step=12,
                                                 data=rows.reshape(-1)), "sensor_msgs/msg/Image")
    np.testing.assert_array_equal(msg_to_image(msg), rgb)


def _image(rows: np.ndarray, encoding: str, frame_id: str = ""):
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=2),
                                      frame_id=frame_id)
    return T["sensor_msgs/msg/Image"](header=header, height=rows.shape[0],
                                      width=rows.shape[1],
                                      encoding=encoding, is_bigendian=0,
                                      step=rows[0].size, data=rows.reshape(-1))


def test_a_mask_of_the_rigs_size_is_a_copy_with_its_frame_and_others_are_refused():
    rows = np.array([[0, 255, 0], [255, 255, 0]], np.uint8)
    msg = _image(rows, "mono8", "camera_optical")
    mask, frame_id = mask_from_msg(msg, (3, 2))
    np.testing.assert_array_equal(mask, rows)
    assert frame_id == "camera_optical" and not np.shares_memory(mask, msg.data)
    with pytest.raises(ValueError, match="mask is 3x2 pixels, expected the rig's 4x2"):
        mask_from_msg(msg, (4, 2))
    with pytest.raises(ValueError, match="mask encoding is 'rgb8', expected 'mono8'"):
        mask_from_msg(_image(np.zeros((2, 3, 3), np.uint8), "rgb8"), (3, 2))


def test_a_captured_image_is_rgb_of_the_rigs_size_and_a_mask_is_no_colour_image():
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    msg = _image(rgb[:, :, ::-1].copy(), "bgr8")
    image = colour_image_from_msg(msg, (3, 2))
    np.testing.assert_array_equal(image, rgb)
    assert not np.shares_memory(image, msg.data)
    with pytest.raises(ValueError, match="captured image is 3x2 pixels, expected the rig's"):
        colour_image_from_msg(msg, (2, 3))
    with pytest.raises(ValueError, match="encoding 'mono8', expected rgb8 or bgr8"):
        colour_image_from_msg(_image(np.zeros((2, 3), np.uint8), "mono8"), (3, 2))


def test_a_big_endian_mono16_image_from_rosbags_reads_its_values():
    values = np.array([[1, 256], [65535, 4660]], dtype=">u2")
    msg = _round_trip(T["sensor_msgs/msg/Image"](header=_header(), height=2, width=2,
                                                 encoding="mono16", is_bigendian=1, step=4,
                                                 data=values.view(np.uint8).reshape(-1)),
                      "sensor_msgs/msg/Image")
    np.testing.assert_array_equal(msg_to_image(msg), values.astype(np.uint16))


def test_joint_angles_from_rosbags_are_found_by_name():
    msg = _round_trip(T["sensor_msgs/msg/JointState"](
        header=_header(), name=["carriage", "turntable"], position=np.array([0.5, -1.25]),
        velocity=np.zeros(0), effort=np.zeros(0)), "sensor_msgs/msg/JointState")
    assert angles_from_joint_state(msg) == (-1.25, 0.5)


def _diagnostics(*statuses):
    return _round_trip(T["diagnostic_msgs/msg/DiagnosticArray"](header=_header(), status=[
        T["diagnostic_msgs/msg/DiagnosticStatus"](
            level=0, name=name, message="", hardware_id="",
            values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in values])
        for name, values in statuses]), "diagnostic_msgs/msg/DiagnosticArray")


@pytest.mark.parametrize("statuses, expected", [
    ([("/cell/scan: scan", [("state", "running"), ("scan", "12")])], (12, "running")),
    ([("/cell/motor: motor", [("scan", "3")]), ("/cell/scan: scan", [("scan", "4")])], (4, "")),
    ([("/cell/motor: motor", [("scan", "3")])], None),          # not the scan node's status
    ([("/cell/scan: scan", [("scan", "")])], None),             # no number
    ([("/cell/scan: scan", [("state", "idle")])], None),
    ([], None),
])
def test_the_scan_nodes_report_is_found_in_a_diagnostics_array(statuses, expected):
    assert scan_report(_diagnostics(*statuses)) == expected


def _joints(names, positions):
    return _round_trip(T["sensor_msgs/msg/JointState"](
        header=_header(), name=names, position=np.array(positions, dtype=np.float64),
        velocity=np.zeros(0), effort=np.zeros(0)), "sensor_msgs/msg/JointState")


def test_a_joint_state_of_another_machine_is_foreign_one_missing_a_joint_is_malformed():
    with pytest.raises(ForeignJointState, match="none of the cell's joints"):
        angles_from_joint_state(_joints(["shoulder_pan", "elbow"], [0.1, 0.2]))
    with pytest.raises(ForeignJointState):
        angles_from_joint_state(_joints([], []))
    with pytest.raises(ValueError, match="has no joint 'carriage'") as raised:
        angles_from_joint_state(_joints(["turntable", "elbow"], [0.1, 0.2]))
    assert not isinstance(raised.value, ForeignJointState)


@pytest.mark.parametrize("name, namespace", [
    ("/sfs/scan: scan", "/sfs"), ("/scan: scan", "/"), ("/a/b/motor: motor", "/a/b"),
    ("scan: scan", None),                                 # a node name without namespace
])
def test_the_namespace_of_a_status_is_its_nodes(name, namespace):
    assert status_namespace(name) == namespace


def test_a_scan_report_of_another_namespace_is_passed_over():
    array = _diagnostics(("/other/scan: scan", [("scan", "7"), ("state", "running")]),
                         ("/cell/scan: scan", [("scan", "2"), ("state", "done")]))
    assert scan_report(array, "/cell") == (2, "done")
    assert scan_report(array, "/other") == (7, "running")
    assert scan_report(array, "/") is None
    assert scan_report(array) == (7, "running")           # the first, when not asked
