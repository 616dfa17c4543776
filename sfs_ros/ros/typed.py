"""The cell's typed interfaces (``sfs_ros_interfaces``) filled from the nodes' own state.

The scan node's :class:`~sfs_ros.cell_logic.scan_sequence.ScanStatus` becomes a
``CellStatus`` message and a ``Scan`` action feedback; a
:meth:`~sfs_ros.cell_logic.live_reconstruction.LiveReconstruction.reconstruct` summary becomes a
``Reconstruct`` response. Angles are radians, counts plain integers; a figure that does
not exist (no held-out views) is NaN.
"""

from __future__ import annotations

import math

from sfs_ros.cell_logic.scan_sequence import ScanStatus
from sfs_ros_interfaces.action import Scan
from sfs_ros_interfaces.msg import CellStatus, ReconstructionStatus

__all__ = ["cell_status", "scan_feedback", "scan_result", "fill_reconstruct_response",
           "status_line"]


def status_line(status: ScanStatus) -> str:
    """One line: the problem, else the warning, else the summary."""
    return status.problem or status.warning or status.summary


def cell_status(status: ScanStatus, reading: tuple[float, float], connected: bool, *,
                stamp, scan_object: str = "object") -> CellStatus:
    """The ``CellStatus`` of the scan now; ``reading``: the last encoder ``(theta, phi)``,
    rad (NaN before one); ``connected``: readings arrive; ``scan_object``: what the scan
    is of ("object" or "board")."""
    v = status.values
    msg = CellStatus(scan=v["scan"], state=v["state"], object=scan_object,
                     view=v["view"] if v["state"] != "idle" else 0, total=v["total"],
                     captured=v["captured"],
                     receipted=v["receipted"], theta_rad=float(reading[0]),
                     phi_rad=float(reading[1]), axes_connected=bool(connected),
                     message=status_line(status))
    msg.header.stamp = stamp
    return msg


def scan_feedback(status: CellStatus) -> Scan.Feedback:
    """The action's feedback of a ``CellStatus``."""
    return Scan.Feedback(scan=status.scan, state=status.state, view=status.view,
                         views_total=status.total, views_captured=status.captured,
                         views_receipted=status.receipted, theta_rad=status.theta_rad,
                         phi_rad=status.phi_rad, message=status.message)


def fill_reconstruct_response(response, summary: dict, *, frame_id: str):
    """``response`` (``Reconstruct.Response``) filled from a reconstruct ``summary``."""
    response.mesh_path = summary["path"]
    response.report_path = summary["report_path"]
    response.preview_path = summary["preview_path"]
    response.html_path = summary["html_path"]
    response.contact_sheet_path = summary["contact_sheet_path"]
    response.textured_path = summary.get("textured_path", "")
    response.refined_mesh_path = summary.get("refined_mesh_path", "")
    response.frame_id = frame_id
    response.session_dir = summary["session"]
    response.views_used = summary["views_used"]
    response.views_rejected = len(summary["views_rejected"])
    response.coloured_from_views = summary["coloured_from_views"]
    response.n_vertices = summary["n_vertices"]
    response.n_faces = summary["n_faces"]
    response.watertight = bool(summary["watertight"])
    response.voxel_size_m = float(summary["voxel_size_m"])
    response.volume_m3 = float(summary["volume_m3"] if summary["volume_m3"] is not None
                               else math.nan)
    held_out = summary.get("holdout_iou")
    response.holdout_iou = math.nan if held_out is None else float(held_out)
    response.seconds = float(summary["seconds"])
    return response


def scan_result(success: bool, message: str, values: dict | None = None,
                reconstruction: ReconstructionStatus | None = None, *,
                board: bool = False) -> Scan.Result:
    """The ``Scan`` action's result: ``success`` and ``message``; with the scan's status
    ``values``, its number and counts, the views stored counted by the receipts (a
    ``board`` scan's: the calibration node's) or by the carving node's ``reconstruction``
    status, with its session folder and the views it rejected."""
    result = Scan.Result(success=success, message=message)
    if values is None:
        return result
    result.scan, result.views_total = values["scan"], values["total"]
    result.views_captured = values["captured"]
    if board:
        result.views_stored = values["receipted"]      # by the calibration node
    else:
        result.session_dir = reconstruction.session_dir
        result.views_stored = reconstruction.views_stored
        result.views_rejected = list(reconstruction.views_rejected)
    return result
