"""Writing a calibration: the cell's ``rig.yaml`` and a ROS ``camera_info`` YAML.

``rig.yaml`` is a ROS parameters file (``/**: ros__parameters:``) holding
every :class:`RigCalibration` field under its own name, as ``config/rig.yaml``
(a principal point of ``-1.0`` there means the image centre).

The ``camera_info`` file is the format of ``camera_calibration_parsers``
(``image_width``, ``image_height``, ``camera_name``, ``camera_matrix``,
``distortion_model: plumb_bob``, ``distortion_coefficients``,
``rectification_matrix``, ``projection_matrix``), as written by the ROS
``camera_calibration`` tool for a monocular camera: ``P = [K' | 0]`` with
``K'`` the new camera matrix of the undistorted image (``alpha = 0``: only
valid pixels).
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import yaml

from ..exchange.files import write_atomic
from ..exchange.limits import brief, printable
from ..geometry.rig import RigCalibration

__all__ = ["rig_parameters", "camera_info", "yaml_document", "rig_yaml", "camera_info_yaml",
           "write_rig_yaml", "write_camera_info"]


def rig_parameters(rig: RigCalibration) -> dict:
    """``{"/**": {"ros__parameters": {...}}}`` of every rig field (plain Python values)."""
    values = rig.to_dict()
    for name in ("cx", "cy"):
        values[name] = -1.0 if values[name] is None else float(values[name])
    plain = {k: ([float(x) for x in v] if isinstance(v, list) else
                 float(v) if isinstance(v, float) else v) for k, v in values.items()}
    return {"/**": {"ros__parameters": plain}}


def _matrix(a: np.ndarray) -> dict:
    return {"rows": int(a.shape[0]), "cols": int(a.shape[1]),
            "data": [float(v) for v in a.ravel()]}


def camera_info(rig: RigCalibration, *, camera_name: str = "camera") -> dict:
    """The ``camera_info`` mapping of the rig's camera (module docstring)."""
    if rig.projection != "pinhole":
        raise ValueError(f"camera_info needs a pinhole rig, got {rig.projection!r}")
    D = np.array(rig.distortion)
    size = (rig.width, rig.height)
    new_K, _ = cv2.getOptimalNewCameraMatrix(rig.K, D, size, 0.0, size)
    return {"image_width": int(rig.width), "image_height": int(rig.height),
            "camera_name": str(camera_name),
            "camera_matrix": _matrix(rig.K),
            "distortion_model": "plumb_bob",
            "distortion_coefficients": _matrix(D[None, :]),
            "rectification_matrix": _matrix(np.eye(3)),
            "projection_matrix": _matrix(np.hstack([new_K, np.zeros((3, 1))]))}


def yaml_document(data: dict, *, header: str = "", what: str = "document") -> bytes:
    """``data`` as UTF-8 YAML under ``header`` as comment lines, checked to read back.

    Control characters in ``header`` (a folder's name, say) are written escaped
    (``\\x01``), so the comment stays a comment that YAML and rcl accept. The text
    is parsed again and must give ``data``: ValueError naming ``what`` if not.
    """
    comments = "".join(f"# {printable(line, limit=sys.maxsize)}\n"
                       for line in header.splitlines())
    text = comments + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    try:
        back = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{what} would not be valid YAML ({brief(str(exc))}); "
                         "nothing written") from None
    if back != data:
        raise ValueError(f"{what} would not read back as written; nothing written")
    return text.encode("utf-8")


def rig_yaml(rig: RigCalibration, *, header: str = "") -> bytes:
    """The text of ``rig.yaml`` (module docstring) with ``header`` as comment lines."""
    return yaml_document(rig_parameters(rig), header=header, what="rig.yaml")


def camera_info_yaml(rig: RigCalibration, *, camera_name: str = "camera",
                     header: str = "") -> bytes:
    """The text of the rig camera's ``camera_info`` YAML with ``header`` as comment lines."""
    return yaml_document(camera_info(rig, camera_name=camera_name), header=header,
                         what="camera_info")


def write_rig_yaml(rig: RigCalibration, path, *, header: str = "") -> Path:
    """Write ``rig.yaml`` (:func:`rig_yaml`) atomically (a link at ``path`` is replaced,
    not followed); returns the path."""
    return _write(path, rig_yaml(rig, header=header))


def write_camera_info(rig: RigCalibration, path, *, camera_name: str = "camera",
                      header: str = "") -> Path:
    """Write the ``camera_info`` YAML of the rig's camera (:func:`camera_info_yaml`)
    atomically; returns the path."""
    return _write(path, camera_info_yaml(rig, camera_name=camera_name, header=header))


def _write(path, data: bytes) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_atomic(path, data)
