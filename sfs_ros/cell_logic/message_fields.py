"""The fields of the cell's messages as numpy arrays and numbers, without ROS.

Decoders for messages however they were deserialized: rclpy's classes, or the
``rosbags`` package's when a bag is read without ROS. They read fields only
(``msg.encoding``, ``msg.name``, ...), so :mod:`sfs_ros.ros.convert` and the bag
reader (:mod:`sfs_ros.cell_logic.bag`) share them.

Stamps: a ``builtin_interfaces/Time`` (anything with ``sec`` and ``nanosec``)
or a ``(sec, nanosec)`` pair. Angles in radians.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["JOINT_NAMES", "IMAGE_ENCODINGS", "check_image_size", "image_rows", "stamp_key",
           "format_stamp", "view_key", "msg_to_image", "mask_from_msg", "colour_image_from_msg",
           "angles_from_joint_state", "ForeignJointState", "scan_report", "status_namespace"]

#: Joint names of the cell: turntable = theta, carriage = phi.
JOINT_NAMES = ("turntable", "carriage")

#: Image encoding -> (channels, dtype of one channel).
IMAGE_ENCODINGS = {"rgb8": (3, np.uint8), "bgr8": (3, np.uint8), "mono8": (1, np.uint8),
                   "mono16": (1, np.uint16)}

Stamp = tuple[int, int]


def stamp_key(stamp) -> Stamp:
    """``(sec, nanosec)`` ints from a ``builtin_interfaces/Time`` (or anything with
    ``sec`` and ``nanosec``) or from a ``(sec, nanosec)`` pair; ``ValueError`` otherwise."""
    if hasattr(stamp, "sec") and hasattr(stamp, "nanosec"):
        sec, nanosec = stamp.sec, stamp.nanosec
    else:
        try:
            sec, nanosec = stamp
        except (TypeError, ValueError):
            raise ValueError(f"stamp must be a Time message or a (sec, nanosec) pair, "
                             f"got {stamp!r}") from None
    if not (float(sec).is_integer() and float(nanosec).is_integer()
            and 0 <= nanosec < 1_000_000_000):
        raise ValueError(f"stamp must have integer sec and nanosec in [0, 1e9), got {stamp!r}")
    return int(sec), int(nanosec)


def format_stamp(stamp: Stamp) -> str:
    """``sec.nanosec`` of a ``(sec, nanosec)`` stamp, for messages."""
    return f"{stamp[0]}.{stamp[1]:09d}"


def view_key(stamp: Stamp) -> str:
    """The key a capture's view goes by (in the reconstruction and its session files):
    ``sec_nanosec`` of its stamp."""
    return f"{stamp[0]}_{stamp[1]:09d}"


def check_image_size(msg, size: tuple[int, int], what: str) -> None:
    """ValueError unless the image message ``msg`` is ``size`` (width, height) pixels, the
    rig's: checked from its header, before its pixels are looked at or kept."""
    if (msg.width, msg.height) != tuple(size):
        raise ValueError(f"{what} is {msg.width}x{msg.height} pixels, expected the rig's "
                         f"{size[0]}x{size[1]} (width x height)")


def image_rows(msg, bytes_per_pixel: int) -> np.ndarray:
    """(H, W * bytes_per_pixel) uint8 view of an image message's pixel bytes, row padding
    (``step`` > row size) skipped; ValueError when the sizes do not add up."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = w * bytes_per_pixel
    if h == 0 or w == 0:
        raise ValueError(f"image is empty ({w}x{h})")
    if step < row_bytes:
        raise ValueError(f"image step {step} is smaller than a row of {w} {msg.encoding} "
                         f"pixels ({row_bytes} bytes)")
    if len(msg.data) != h * step:
        raise ValueError(f"image data has {len(msg.data)} bytes, expected height * step = "
                         f"{h} * {step} = {h * step}")
    return np.frombuffer(msg.data, np.uint8).reshape(h, step)[:, :row_bytes]


def msg_to_image(msg) -> np.ndarray:
    """Array of a ``sensor_msgs/Image``: (H, W, 3) uint8 RGB for ``rgb8`` / ``bgr8``,
    (H, W) uint8 for ``mono8``, (H, W) uint16 for ``mono16``.

    A view of ``msg.data`` (no copy) except for 16-bit data in non-native
    byte order; row padding (``step`` > row size) is skipped and ``bgr8`` is
    returned as a channel-reversed view. Raises ``ValueError`` for other
    encodings and for sizes that do not add up.
    """
    if msg.encoding not in IMAGE_ENCODINGS:
        raise ValueError(f"unsupported image encoding {msg.encoding!r}; "
                         f"expected one of {sorted(IMAGE_ENCODINGS)}")
    channels, dtype = IMAGE_ENCODINGS[msg.encoding]
    h, w = int(msg.height), int(msg.width)
    rows = image_rows(msg, channels * np.dtype(dtype).itemsize)
    if np.dtype(dtype).itemsize > 1:
        order = ">" if msg.is_bigendian else "<"
        rows = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order))
        rows = rows.astype(dtype, copy=False)
    image = rows.reshape(h, w, channels) if channels > 1 else rows.reshape(h, w)
    return image[:, :, ::-1] if msg.encoding == "bgr8" else image


def mask_from_msg(msg, size: tuple[int, int]) -> tuple[np.ndarray, str]:
    """A mono8 mask, (H, W) uint8 (a copy), and its frame id; ValueError for another size
    than ``size`` (the rig's width, height), another encoding or a bad layout."""
    check_image_size(msg, size, "mask")
    if msg.encoding != "mono8":
        raise ValueError(f"mask encoding is {msg.encoding!r}, expected 'mono8'")
    return msg_to_image(msg).copy(), msg.header.frame_id


def colour_image_from_msg(msg, size: tuple[int, int]) -> np.ndarray:
    """A captured colour image, (H, W, 3) uint8 RGB (a copy); ValueError for another size
    than ``size`` (the rig's width, height), an encoding other than rgb8 or bgr8 or a bad
    layout."""
    check_image_size(msg, size, "captured image")
    image = msg_to_image(msg)
    if image.ndim != 3 or image.dtype != np.uint8:
        raise ValueError(f"encoding {msg.encoding!r}, expected rgb8 or bgr8")
    return image.copy()


class ForeignJointState(ValueError):
    """A joint state with none of the cell's joints: another machine's (a robot arm's
    ``joint_state_broadcaster`` on the same topic), not a malformed one of the cell."""


def angles_from_joint_state(msg) -> tuple[float, float]:
    """``(theta_rad, phi_rad)`` of the joints named "turntable" and "carriage" (any order)
    of a ``sensor_msgs/JointState``.

    Raises ``ValueError`` when a joint is missing, has no position, or is not finite.
    """
    names = list(msg.name)
    positions = list(msg.position)
    if not set(JOINT_NAMES) & set(names):
        raise ForeignJointState(f"joint state has none of the cell's joints (names {names}); "
                                f"expected {list(JOINT_NAMES)}")
    angles = []
    for joint in JOINT_NAMES:
        if joint not in names:
            raise ValueError(f"joint state has no joint {joint!r} (names {names}); "
                             f"expected {list(JOINT_NAMES)}")
        index = names.index(joint)
        if index >= len(positions):
            raise ValueError(f"joint state has {len(positions)} positions for {len(names)} "
                             f"names: no position for {joint!r}")
        value = float(positions[index])
        if not math.isfinite(value):
            raise ValueError(f"joint {joint!r} position is {value}, expected a finite angle")
        angles.append(value)
    return angles[0], angles[1]


def status_namespace(name: str) -> str | None:
    """The namespace of the node that named a diagnostic status ``<full node name>: <kind>``
    (``"/sfs/scan: scan"`` -> ``"/sfs"``, ``"/scan: scan"`` -> ``"/"``); None for a name
    without a full node name."""
    node = name.rsplit(": ", 1)[0]
    if not node.startswith("/"):
        return None
    return node.rsplit("/", 1)[0] or "/"


def scan_report(array, namespace: str | None = None) -> tuple[int, str] | None:
    """``(scan number, state)`` the scan node reports in a ``diagnostic_msgs/DiagnosticArray``
    (its status named ``<node>: scan`` with the values ``scan`` and ``state``); None when
    the array holds no such status or its scan is not a number. ``namespace``: only the
    scan node of that namespace (``"/sfs"``, ``"/"``) counts (the diagnostics topic is
    shared by every cell)."""
    for status in array.status:
        if not status.name.endswith(": scan"):
            continue
        if namespace is not None and status_namespace(status.name) != namespace:
            continue
        values = {kv.key: kv.value for kv in status.values}
        scan = values.get("scan", "")
        if scan.isdigit():
            return int(scan), values.get("state", "")
    return None
