"""A calibration in the running cell, without ROS: board captures stored, the fit, its files.

The calibration node receives the captures of a board scan (the scan node sends a scan of
object ``board`` on ``calibration/image`` + ``calibration/joint_state``) and hands each to
a :class:`BoardCaptures`, which stores it in a session folder (the
:mod:`sfs_ros.core.exchange.session` format, so ``sfs-calibrate FOLDER`` reads it too) and
says whether the board is in it. :func:`fit_and_write` then fits the rig with
:func:`sfs_ros.core.calibration.calibrate_views` (the fit of ``sfs-calibrate``) and writes
``rig.yaml``, ``camera_info.yaml`` and ``calibration_report.yaml`` beside the session
(the texts of :mod:`sfs_ros.core.calibration.outputs`), each atomically, ``rig.yaml``
last, inside the node's output folder.

A calibration's folder: ``OUTPUT_DIR/calibration_<UTC time>/`` holding ``session/``
(``session.yaml``, ``views.csv``, ``images/view_<sec>_<nanosec>.png``) and the three files.
Angles are radians, images (H, W, 3) uint8 RGB of the rig's size.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.calibration import (
    BoardSpec,
    RigFit,
    calibrate_views,
    camera_info_yaml,
    detect_board,
    rig_yaml,
    yaml_document,
)
from ..core.exchange.files import write_atomic_all
from ..core.exchange.session import append_view, read_session, write_session
from ..core.geometry.rig import RigCalibration

__all__ = ["BoardCaptures", "CalibrationFiles", "calibration_folder", "calibration_report",
           "fit_and_write", "SESSION", "RIG_FILE", "CAMERA_INFO_FILE", "REPORT_FILE"]

SESSION = "session"
RIG_FILE, CAMERA_INFO_FILE, REPORT_FILE = ("rig.yaml", "camera_info.yaml",
                                           "calibration_report.yaml")


def calibration_folder(output_dir) -> Path:
    """A new folder ``calibration_<UTC time>[_N]`` in ``output_dir`` (which must exist)."""
    output = Path(output_dir)
    base = "calibration_" + time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    for n in range(1000):
        folder = output / (base if n == 0 else f"{base}_{n}")
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            continue
    raise OSError(f"no free calibration folder name {base}_N in {output}")


class BoardCaptures:
    """The captures of one board scan, stored as they come (any thread).

    folder : path-like
        The calibration's folder; captures go to ``folder/session``.
    rig : RigCalibration
        The cell's rig when the scan started (the fit's start; the images' size).
    board : BoardSpec or None
        Looked for in each capture (counted in :attr:`detected`); None: not looked for.
    """

    def __init__(self, folder, rig: RigCalibration, board: BoardSpec | None):
        self.folder = Path(folder)
        self.session = self.folder / SESSION
        self.rig, self.board = rig, board
        self.detected = 0                   # captures in which the board was found
        self.planned = 0                    # views of the board scan's plan (the caller's)
        self._stored: set[tuple[int, int]] = set()
        self._lock = threading.Lock()

    @property
    def stored(self) -> int:
        """Captures stored."""
        with self._lock:
            return len(self._stored)

    def add(self, stamp: tuple[int, int], rgb: np.ndarray, theta_rad: float,
            phi_rad: float) -> bool:
        """Store the capture at ``stamp`` (once: a capture sent again is known by its
        stamp); whether the board is in it. ValueError for an image of another size,
        OSError when it cannot be written (nothing stored: it may come again)."""
        name = f"view_{stamp[0]}_{stamp[1]:09d}.png"
        with self._lock:
            if tuple(stamp) in self._stored:
                return False
            if not self._stored:
                write_session(self.session, [(name, rgb)], [(theta_rad, phi_rad)], self.rig)
            else:
                append_view(self.session, name, rgb, theta_rad, phi_rad)
            self._stored.add(tuple(stamp))
        found = self.board is not None and detect_board(rgb, self.board)[0] is not None
        if found:
            with self._lock:
                self.detected += 1
        return found


@dataclass(frozen=True)
class CalibrationFiles:
    """What :func:`fit_and_write` made: the fit and the files written."""

    fit: RigFit
    rig_file: Path
    camera_info_file: Path
    report_file: Path


def calibration_report(fit: RigFit) -> dict:
    """The ``calibration_report.yaml`` mapping: RMS and per-view residuals (px), rejected
    views with their reasons, each fitted parameter's standard uncertainty, what is held
    fixed, and the board's pose (rad, m)."""
    return {"rms_px": fit.rms_px, "corners": fit.corners, "view_rms_px": fit.view_rms_px,
            "rejected": {name: reason for name, reason in fit.rejected},
            "uncertainty": fit.uncertainty, "fixed": fit.fixed,
            "board_pose": {"tilt_x_rad": float(fit.board.tilt_x_rad),
                           "tilt_y_rad": float(fit.board.tilt_y_rad),
                           "offset_m": [float(v) for v in fit.board.offset_m]}}


def fit_and_write(captures: BoardCaptures, *, within, radial_terms: int = 2,
                  max_view_rms_px: float = 1.0, camera_name: str = "camera") -> CalibrationFiles:
    """Fit the rig to the stored captures and write the three files beside the session.

    ``within``: the folder nothing may be written outside of (the node's output folder).
    Raises ValueError naming the cause: no capture stored, the board found in none, too
    few usable views (:func:`calibrate_views`); OSError when a file cannot be written.
    """
    if captures.board is None:
        raise ValueError("no board to fit: expected a BoardSpec")
    if captures.stored == 0:
        raise ValueError(f"no board capture was stored in {captures.session}: expected the "
                         "captures of a board scan on calibration/image")
    fit = calibrate_views(read_session(captures.session), captures.board,
                          radial_terms=radial_terms, max_view_rms_px=max_view_rms_px)
    header = (f"Calibrated by the calibration node from {captures.session}: "
              f"{len(fit.view_rms_px)} views, {fit.corners} corners, RMS {fit.rms_px:.3f} px")
    paths = [captures.folder / n for n in (RIG_FILE, CAMERA_INFO_FILE, REPORT_FILE)]
    write_atomic_all([(paths[1], camera_info_yaml(fit.rig, camera_name=camera_name,
                                                  header=header)),
                      (paths[2], yaml_document(calibration_report(fit), header=header,
                                               what=REPORT_FILE)),
                      (paths[0], rig_yaml(fit.rig, header=header))], within=within)
    return CalibrationFiles(fit, *paths)
