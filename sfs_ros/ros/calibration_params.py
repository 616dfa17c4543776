"""The calibration node's parameters (:data:`PARAMS`), as ``doc/reference.md`` lists them."""

from __future__ import annotations

from sfs_ros.ros.params import Param

__all__ = ["PARAMS"]

#: The calibration node's parameters: its output folder and plan, the board, the fit, the
#: capture queues and the deadlines.
PARAMS: list[Param] = [
    Param("output_dir", "", "Folder that receives each calibration's folder "
          "(calibration_<UTC time>/: session/, rig.yaml, camera_info.yaml, "
          "calibration_report.yaml); nothing is written outside it.", read_only=True,
          constraints="required, non-empty"),
    Param("plan_file", "", "The calibration plan (format of config/calibration_plan.yaml) of "
          "a goal without one.", read_only=True, constraints="required unless every goal "
          "gives plan_file"),
    Param("columns", 7, "Chessboard squares of the board along x.", bounds=(3, 1000),
          read_only=True),
    Param("rows", 5, "Chessboard squares of the board along y.", bounds=(3, 1000),
          read_only=True),
    Param("square_m", 0.03, "Side of a chessboard square, metres.", bounds=(1e-6, 10.0),
          read_only=True),
    Param("marker_m", 0.022, "Side of an ArUco marker, metres.", bounds=(1e-6, 10.0),
          read_only=True, constraints="less than square_m"),
    Param("dictionary", "DICT_5X5_100", "ArUco dictionary of the board (an OpenCV name).",
          read_only=True),
    Param("radial_terms", 2, "Radial distortion terms fitted: 2 holds k3 at 0, 3 fits it.",
          bounds=(2, 3), read_only=True),
    Param("max_view_rms_px", 1.0, "A view whose corners miss by more than this RMS after "
          "the fit is rejected, pixels.", bounds=(0.01, 100.0), read_only=True),
    Param("camera_name", "camera", "camera_name in camera_info.yaml.", read_only=True),
    Param("queue_depth", 100, "Depth of the capture topics; at least the views of a plan.",
          bounds=(1, 100000), read_only=True),
    Param("scan_timeout_s", 3600.0, "Longest board scan, s.", bounds=(1.0, 86400.0),
          read_only=True),
    Param("apply_timeout_s", 60.0, "Deadline of reading the cell's rig and of applying the "
          "new one, s.", bounds=(1.0, 3600.0), read_only=True),
]
