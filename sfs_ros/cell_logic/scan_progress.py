"""The scan node's progress on disk, so that a restarted scan node resumes the same scan.

A folder (``OUTPUT_DIR/scan_progress/`` in the cell) holds:

* ``progress.json``: the plan (its viewpoints, radians, to recognise it), the
  scan number, its state, whether the preparation steps ran, and every
  capture of the scan: plan index ``view``, ``stamp`` ``[sec, nanosec]``,
  encoder angles ``theta_rad`` / ``phi_rad`` at the shutter, ``receipted``;
* ``captures/view_<NNN>_<sec>_<nanosec>.bin``: each capture's bytes (the
  messages to send again), written before the capture is sent.

Every file is written atomically (a temporary file, flushed to the disk, then
renamed), so a process killed at any moment leaves the previous version or
the new one, never a torn file. A capture's bytes are written before the
``progress.json`` that lists it. A write that fails (a full disk) raises
``OSError`` and leaves what was there untouched.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.exchange.files import write_atomic

__all__ = ["SavedCapture", "SavedScan", "ScanProgress", "PROGRESS_FILE"]

PROGRESS_FILE = "progress.json"
_CAPTURES = "captures"
_FORMAT = "sfs_ros-scan-progress"
_VERSION = 1
#: Plans are the same when every viewpoint agrees to this, radians (JSON keeps 17 digits).
_PLAN_TOLERANCE_RAD = 1e-12
#: A capture's file, or the temporary file of a write cut short (a process killed then).
_BLOB = re.compile(r"(view_\d{3,}_\d+_\d{9}\.bin|\.view_\d{3,}_\d+_\d{9}\.bin\.[0-9a-f]{8}\.tmp)")
_PROGRESS_TEMPORARY = re.compile(r"\.progress\.json\.[0-9a-f]{8}\.tmp")


@dataclass(frozen=True)
class SavedCapture:
    """One capture as saved: plan index, stamp ``(sec, nanosec)``, encoder angles (rad)."""

    view: int
    stamp: tuple[int, int]
    theta_rad: float
    phi_rad: float
    receipted: bool


@dataclass(frozen=True)
class SavedScan:
    """A scan as saved: its number, state, whether prepared, and its captures."""

    scan: int
    state: str
    prepared: bool
    captures: tuple[SavedCapture, ...]


class ScanProgress:
    """Reads and writes the progress of scans of one plan in ``folder`` (created if needed).

    plan_rad : (n, 2) float, the plan's ``(theta, phi)`` viewpoints, radians.
    """

    def __init__(self, folder, plan_rad):
        self.folder = Path(folder)
        self.plan_rad = np.asarray(plan_rad, dtype=np.float64)
        (self.folder / _CAPTURES).mkdir(parents=True, exist_ok=True)

    def _blob(self, view: int, stamp) -> Path:
        return self.folder / _CAPTURES / f"view_{view:03d}_{stamp[0]}_{stamp[1]:09d}.bin"

    def save_capture(self, view: int, stamp, data: bytes) -> Path:
        """Write one capture's bytes (atomically); OSError when it cannot be written."""
        return write_atomic(self._blob(view, stamp), bytes(data))

    def load_capture(self, capture: SavedCapture) -> bytes:
        """The bytes of a saved capture; OSError if its file is gone."""
        return self._blob(capture.view, capture.stamp).read_bytes()

    def save(self, scan: SavedScan) -> None:
        """Write ``progress.json`` (atomically); OSError when it cannot be written."""
        document = {"format": _FORMAT, "version": _VERSION, "plan_rad": self.plan_rad.tolist(),
                    "scan": scan.scan, "state": scan.state, "prepared": scan.prepared,
                    "captures": [{"view": c.view, "stamp": list(c.stamp),
                                  "theta_rad": c.theta_rad, "phi_rad": c.phi_rad,
                                  "receipted": c.receipted} for c in scan.captures]}
        write_atomic(self.folder / PROGRESS_FILE, json.dumps(document, indent=1).encode())

    def clear_captures(self) -> None:
        """Delete the capture files of the last scan (a new one starts), and temporary files
        left by a process killed while writing."""
        for path in (self.folder / _CAPTURES).iterdir():
            if _BLOB.fullmatch(path.name):
                path.unlink(missing_ok=True)
        for path in self.folder.iterdir():
            if _PROGRESS_TEMPORARY.fullmatch(path.name):
                path.unlink(missing_ok=True)

    def load(self) -> SavedScan | None:
        """The saved scan; None when there is none.

        Raises ValueError naming the file and the problem when it is damaged or
        belongs to another plan (the caller starts afresh and says why).
        """
        path = self.folder / PROGRESS_FILE
        if not path.is_file():
            return None
        try:
            document = json.loads(path.read_bytes()[:10_000_000])
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path} cannot be read ({exc})") from None
        try:
            if document["format"] != _FORMAT or document["version"] != _VERSION:
                raise ValueError(f"format {document['format']!r} version "
                                 f"{document['version']!r}, expected {_FORMAT!r} {_VERSION}")
            plan = np.asarray(document["plan_rad"], dtype=np.float64)
            if plan.shape != self.plan_rad.shape \
                    or not np.allclose(plan, self.plan_rad, rtol=0, atol=_PLAN_TOLERANCE_RAD):
                raise ValueError(f"it is the progress of another plan ({len(plan)} views, this "
                                 f"one has {len(self.plan_rad)} or other viewpoints)")
            captures = tuple(_capture(c, len(self.plan_rad)) for c in document["captures"])
            scan = int(document["scan"])
            state, prepared = str(document["state"]), bool(document["prepared"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path} is not usable: {exc}") from None
        if len({c.view for c in captures}) != len(captures):
            raise ValueError(f"{path} is not usable: a view is listed twice")
        return SavedScan(scan=scan, state=state, prepared=prepared, captures=captures)


def _capture(entry: dict, n_views: int) -> SavedCapture:
    view = entry["view"]
    if isinstance(view, bool) or not isinstance(view, int) or not 0 <= view < n_views:
        raise ValueError(f"view {view!r} is not an index of the plan's {n_views} views")
    sec, nanosec = (int(v) for v in entry["stamp"])
    theta, phi = float(entry["theta_rad"]), float(entry["phi_rad"])
    if not (math.isfinite(theta) and math.isfinite(phi)):
        raise ValueError(f"view {view}: angles {theta}, {phi} are not finite")
    return SavedCapture(view, (sec, nanosec), theta, phi, bool(entry["receipted"]))
