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

from pathlib import Path

import cv2
import numpy as np
import yaml

from ..geometry.rig import RigCalibration

__all__ = ["rig_parameters", "camera_info", "write_rig_yaml", "write_camera_info"]


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


def _write(path: Path, header: str, data: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    path.write_text("".join(f"# {line}\n" for line in header.splitlines()) + text,
                    encoding="utf-8")
    return path


def write_rig_yaml(rig: RigCalibration, path, *, header: str = "") -> Path:
    """Write ``rig.yaml`` (module docstring) with ``header`` as comment lines; returns the path."""
    return _write(path, header, rig_parameters(rig))


def write_camera_info(rig: RigCalibration, path, *, camera_name: str = "camera",
                      header: str = "") -> Path:
    """Write the ``camera_info`` YAML of the rig's camera; returns the path."""
    return _write(path, header, camera_info(rig, camera_name=camera_name))
