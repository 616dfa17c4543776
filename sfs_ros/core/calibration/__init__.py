"""Calibrating the cell from photographs of a ChArUco board on the turntable.

:func:`detect_board` finds the board's corners in each image,
:func:`calibrate_rig` fits the rig's kinematic chain to them (a
:class:`RigFit`), :func:`write_rig_yaml` and :func:`write_camera_info` write
the result for the nodes and for other ROS tools; :func:`calibrate_views` does
the first two for a scan session of board photographs.
"""

from .board import BoardSpec, Detection, detect_board
from .from_views import calibrate_views
from .model import BoardPose, canonical
from .outputs import (
    camera_info,
    camera_info_yaml,
    rig_parameters,
    rig_yaml,
    write_camera_info,
    write_rig_yaml,
    yaml_document,
)
from .solver import FIXED, PARAMETERS, RigFit, calibrate_rig

__all__ = ["FIXED", "PARAMETERS", "BoardPose", "BoardSpec", "Detection", "RigFit",
           "calibrate_rig", "calibrate_views", "camera_info", "canonical", "detect_board",
           "rig_parameters", "write_camera_info", "write_rig_yaml", "rig_yaml",
           "camera_info_yaml", "yaml_document"]
