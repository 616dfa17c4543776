"""What a scanning session's bag holds: its topics, their types and QoS, and the records
the recorder writes itself.

Recorded topics (:data:`TOPICS`, names relative to the cell's namespace):

| topic | type | QoS kind |
|---|---|---|
| ``capture/image``, ``capture/mask`` | sensor_msgs/Image | capture |
| ``capture/joint_state``, ``capture/mask_joint_state`` | sensor_msgs/JointState | capture |
| ``calibration/image`` | sensor_msgs/Image | capture |
| ``calibration/joint_state`` | sensor_msgs/JointState | capture |
| ``capture/stored`` | std_msgs/Header | capture |
| ``joint_states`` | sensor_msgs/JointState | default |
| ``diagnostics`` | diagnostic_msgs/DiagnosticArray (from the absolute ``/diagnostics``) | default |
| ``camera_info`` | sensor_msgs/CameraInfo | default |
| ``hull`` | sensor_msgs/PointCloud2 | result |
| ``camera_poses`` | geometry_msgs/PoseArray | result |
| ``mesh``, ``mesh_shape`` | visualization_msgs/Marker, shape_msgs/Mesh | result |
| ``sfs/parameters`` | std_msgs/String | result |
| ``sfs/scan`` | std_msgs/UInt32 | default |

QoS kinds: *capture* = reliable, volatile, keep-last ``depth``; *result* =
reliable, transient-local, depth 1; *default* = reliable, volatile, depth 10.

The recorder writes the two ``sfs/`` topics itself (:data:`RECORDER_TOPICS`):

* ``sfs/parameters`` holds one JSON document per bag (:func:`parameters_message`),
  written when the recorder has fetched them at the start: format
  ``sfs_ros-parameters`` version 1, ``namespace`` (the recorder's), ``nodes``
  (every parameter of each node asked, ``{node: {name: value}}``),
  ``unavailable`` (``{node: reason}`` for those that did not answer) and, from
  the reconstruction and segmentation nodes' values, ``session`` (the
  ``session.yaml`` fields ``rig``, ``bounds_m``, ``segmentation``) and
  ``reconstruction`` (``resolution``, ``mesher``). A message rather than the
  metadata's ``custom_data``: ``metadata.yaml`` is only written when the bag is
  closed, and a killed recorder's bag must still say how it was made.
* ``sfs/scan`` holds the number of the scan the scan node reports
  (:func:`scan_message`): written the first time the bag hears of a scan and
  each time the number changes, just before the diagnostics message that
  reported it. A change means a new scan started (and, unless the scan node's
  ``reset_reconstruction`` is off, that the reconstruction was reset).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from rosbags.typesys import Stores, get_typestore

from ..bag_input import BAG_SUFFIXES
from ..paths import confined_path

__all__ = ["CAPTURE", "RESULT", "DEFAULT", "TOPICS", "PARAMETERS_TOPIC", "PARAMETERS_FORMAT",
           "SCAN_TOPIC", "RECORDER_TOPICS", "STORAGES", "BAG_SUFFIXES", "STORE", "bag_folder",
           "new_bag_folder", "parameters_message", "scan_message"]

CAPTURE, RESULT, DEFAULT = "capture", "result", "default"
PARAMETERS_TOPIC = "sfs/parameters"
PARAMETERS_FORMAT = "sfs_ros-parameters"
SCAN_TOPIC = "sfs/scan"
#: Topics the recorder writes itself rather than records.
RECORDER_TOPICS = (PARAMETERS_TOPIC, SCAN_TOPIC)

#: Relative topic name -> (message type, QoS kind).
TOPICS: dict[str, tuple[str, str]] = {
    "capture/image": ("sensor_msgs/msg/Image", CAPTURE),
    "capture/joint_state": ("sensor_msgs/msg/JointState", CAPTURE),
    "capture/mask": ("sensor_msgs/msg/Image", CAPTURE),
    "capture/mask_joint_state": ("sensor_msgs/msg/JointState", CAPTURE),
    "calibration/image": ("sensor_msgs/msg/Image", CAPTURE),
    "calibration/joint_state": ("sensor_msgs/msg/JointState", CAPTURE),
    "capture/stored": ("std_msgs/msg/Header", CAPTURE),
    "joint_states": ("sensor_msgs/msg/JointState", DEFAULT),
    "diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", DEFAULT),
    "camera_info": ("sensor_msgs/msg/CameraInfo", DEFAULT),
    "hull": ("sensor_msgs/msg/PointCloud2", RESULT),
    "camera_poses": ("geometry_msgs/msg/PoseArray", RESULT),
    "mesh": ("visualization_msgs/msg/Marker", RESULT),
    "mesh_shape": ("shape_msgs/msg/Mesh", RESULT),
    PARAMETERS_TOPIC: ("std_msgs/msg/String", RESULT),
    SCAN_TOPIC: ("std_msgs/msg/UInt32", DEFAULT),
}
STORAGES = ("mcap", "sqlite3")
#: The message types rosbags (de)serializes, as ROS 2 has them.
STORE = get_typestore(Stores.ROS2_KILTED)

_BAG_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")


def bag_folder(output_dir, name: str) -> Path:
    """``<output_dir>/bags/<name>``, confined to ``output_dir`` (which must exist);
    ValueError for a name that is not 1-100 letters, digits, ``_``, ``-`` or ``.``."""
    if not isinstance(name, str) or not _BAG_NAME.fullmatch(name):
        raise ValueError(f"bag name {name!r} must be 1-100 letters, digits, '_', '-' or '.', "
                         "not starting with '.', '_' or '-'")
    return confined_path(output_dir, f"bags/{name}/{name}.mcap", suffixes=(".mcap",)).parent


def new_bag_folder(output_dir, name: str, *, scan: int | None, rolling: bool,
                   stamp: str) -> Path:
    """The folder of a new bag in ``output_dir``: ``name`` when given (one that exists is
    refused when the bag is written); else ``scan_NNN_<stamp>`` for scan NNN, ``scan_<stamp>``
    for a scan not yet reported (``rolling``: a bag opened with a scan) or ``bag_<stamp>``
    (on request), with ``_2``, ``_3``, ... until it is new. ValueError for a bad name."""
    if name:
        return bag_folder(output_dir, name)
    prefix = "bag" if not rolling else "scan" if scan is None else f"scan_{scan:03d}"
    base = f"{prefix}_{stamp}"
    folder, n = bag_folder(output_dir, base), 1
    while folder.exists():
        n += 1
        folder = bag_folder(output_dir, f"{base}_{n}")
    return folder


def parameters_message(document: dict) -> bytes:
    """The CDR bytes of the ``std_msgs/String`` holding ``document`` (JSON) for
    :data:`PARAMETERS_TOPIC`; ``format`` and ``version`` are filled in."""
    text = json.dumps({"format": PARAMETERS_FORMAT, "version": 1, **document})
    return _cdr(STORE.types["std_msgs/msg/String"](data=text), "std_msgs/msg/String")


def scan_message(scan: int) -> bytes:
    """The CDR bytes of the ``std_msgs/UInt32`` holding scan number ``scan`` for
    :data:`SCAN_TOPIC`; ValueError unless 0 <= scan < 2**32."""
    if isinstance(scan, bool) or not isinstance(scan, int) or not 0 <= scan < 2 ** 32:
        raise ValueError(f"scan number must be an integer in [0, 2**32), got {scan!r}")
    return _cdr(STORE.types["std_msgs/msg/UInt32"](data=scan), "std_msgs/msg/UInt32")


def _cdr(msg, msgtype: str) -> bytes:
    return bytes(STORE.serialize_cdr(msg, msgtype))
