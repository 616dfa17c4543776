"""The carving node's scan without ROS: which views go into the live reconstruction.

:class:`CarvingScan` holds the :class:`~sfs_ros.cell_logic.live_reconstruction.LiveReconstruction` (or why
none can be held: a grid the memory budget cannot hold), the views a full disk refused
(kept in memory and offered again), the keys of earlier scans' views (a late copy of one
is not stored in the next scan) and :class:`CarvingHealth`, the counts and the problem
the node's diagnostics and status report. The node receives, publishes and logs; every
decision about a view is made here.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sfs_ros.cell_logic.live_reconstruction import DuplicateViewError, LiveReconstruction
from sfs_ros.cell_logic.message_fields import format_stamp, view_key
from sfs_ros.core.carving.resolution import (
    default_memory_budget,
    grid_shape,
    parse_memory,
    refuse_unfit_grid,
)
from sfs_ros.core.geometry.rig import rig_camera

__all__ = ["EARLIER_VIEWS_KEPT", "CarvingHealth", "CarvingScan", "EarlierViews",
           "HullSchedule", "ViewOutcome", "grid_refusal", "memory_budget", "reset_refusal",
           "store_problem"]

#: Views of earlier scans remembered by their keys, so that a late copy of one (a resend
#: that crossed its receipt) is not stored into the next scan; the most recent are kept.
EARLIER_VIEWS_KEPT = 10_000
#: The counters of :class:`CarvingHealth`, all zero at start.
COUNTERS = ("views_received", "carved", "empty", "rejected", "malformed", "repeats", "stale",
            "unpaired_dropped", "carvings", "carving_failures", "scan_views")


def memory_budget(text: str) -> int:
    """The working memory a grid may take, bytes: ``text`` parsed (``"2G"``), or the
    default budget for an empty one; ValueError for a size that is not one."""
    return parse_memory(text) if text.strip() else default_memory_budget()


def grid_refusal(bounds_m: np.ndarray, resolution: int, budget: int) -> str:
    """Why the voxel grid of ``resolution`` voxels along the longest side of ``bounds_m``
    (2, 3) metres cannot be held within ``budget`` bytes ("" if it can), with the memory
    it would need; nothing is allocated."""
    voxel_m = float(np.max(bounds_m[1] - bounds_m[0])) / resolution
    try:
        refuse_unfit_grid(grid_shape(bounds_m, voxel_m), budget, f"resolution {resolution}")
    except ValueError as exc:
        return f"refused: {exc}"
    return ""


def reset_refusal(capturing: tuple[int, str] | None, bounds_m: np.ndarray, resolution: int,
                  budget: int) -> str:
    """Why a reset cannot start a new scan now ("" if it can): the scan node is taking
    views (``capturing``: the scan number and state it reports, None when it is not; a new
    scan would split them over two session folders), or the grid of ``resolution`` over
    ``bounds_m`` (2, 3) metres does not fit ``budget`` bytes (:func:`grid_refusal`)."""
    if capturing is not None:
        return (f"reset refused: the scan node reports scan {capturing[0]} {capturing[1]}; "
                "its views go to the scan open now (cancel it first: scan/cancel, then "
                "reset)")
    return grid_refusal(bounds_m, resolution, budget)


def store_problem(stamp, live: LiveReconstruction, exc: OSError, waiting: int) -> str:
    """The ERROR of a view the disk refused: where, why, the free space, what happens next."""
    folder = live.session_dir or live.output_dir
    try:
        stat = os.statvfs(live.output_dir)
        free = f"{stat.f_bavail * stat.f_frsize / 1e6:.1f} MB free"
    except OSError:
        free = "free space unknown"
    return (f"view at stamp {format_stamp(stamp)} not stored in {folder}: "
            f"{exc.strerror or exc} ({free}; a view's image takes at most "
            f"{live.calibration.width * live.calibration.height * 3 / 1e6:.2f} MB); {waiting} "
            f"view(s) kept in memory without a receipt, stored as soon as a write succeeds")


class EarlierViews:
    """The keys of views stored in earlier scans, the ``kept`` most recent."""

    def __init__(self, kept: int = EARLIER_VIEWS_KEPT):
        self._kept = kept
        self._keys: dict[str, None] = {}    # insertion ordered: the oldest first

    def remember(self, keys) -> None:
        """Remember the keys of a finished scan's views (the oldest beyond ``kept`` go)."""
        self._keys.update(dict.fromkeys(keys))
        for key in list(self._keys)[:max(0, len(self._keys) - self._kept)]:
            del self._keys[key]

    def __contains__(self, key: str) -> bool:
        return key in self._keys

    def __len__(self) -> int:
        return len(self._keys)


@dataclass
class CarvingHealth:
    """The node's counts, this scan's problem (ERROR until the next good view), warning and
    rejected views, and the time spent storing and carving its views; safe from any
    thread (every change and read under one lock)."""

    problem: str = ""
    warning: str = ""
    rejected: list[str] = field(default_factory=list)   # this scan's rejected views, named
    carve_s: float = 0.0
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(COUNTERS, 0))
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def count(self, name: str) -> None:
        with self.lock:
            self.counts[name] += 1

    def report(self, problem: str) -> None:
        with self.lock:
            self.problem = problem

    def new_scan(self) -> None:
        """A new scan: no views, no problem, nothing rejected."""
        with self.lock:
            self.counts["scan_views"] = 0
            self.carve_s = 0.0
            self.problem = self.warning = ""
            self.rejected = []

    def snapshot(self) -> tuple[dict, str, str, list[str]]:
        """``(counts with carve_s, problem, warning, rejected views)`` as they are now."""
        with self.lock:
            return (dict(self.counts, carve_s=round(self.carve_s, 4)), self.problem,
                    self.warning, list(self.rejected))


@dataclass(frozen=True)
class ViewOutcome:
    """What became of a view offered to :meth:`CarvingScan.add_view`.

    kind : str
        ``"carved"``, ``"empty"`` (stored, carves nothing), ``"stale"`` (of an earlier
        scan), ``"repeat"`` (stored already), ``"rejected"`` (unusable), ``"unstored"``
        (the disk refused it: kept, offered again) or ``"refused"`` (no reconstruction held).
    text : str
        What to tell: the problem, the warning or the note (empty for ``"carved"``).
    """

    kind: str
    text: str = ""

    @property
    def receipted(self) -> bool:
        """Whether the view gets its receipt: resending it cannot change what happened."""
        return self.kind not in ("unstored", "refused")

    @property
    def stored(self) -> bool:
        """Whether the view joined this scan."""
        return self.kind in ("carved", "empty")


class HullSchedule:
    """When the live hull is published: after a change, once no job waits or ``period_s``
    seconds after the last publication."""

    def __init__(self, period_s: float):
        self.period_s = period_s
        self.changed = False
        self._last = -float("inf")

    def due(self, pending: int, now: float) -> bool:
        """Whether to publish now, with ``pending`` jobs waiting, at ``now`` (monotonic s)."""
        return self.changed and (pending == 0 or now - self._last >= self.period_s)

    def published(self, now: float) -> None:
        self._last, self.changed = now, False


class CarvingScan:
    """The scan the carving node receives: the live reconstruction and what it is given.

    live : LiveReconstruction or None
        None while ``refusal`` says why none can be held.
    budget : int
        The working memory a grid may take, bytes.
    cameras : list of Camera
        This scan's views' cameras, in arrival order.
    settings : tuple
        The per-scan settings ``live`` was made with (compared only: a new scan with
        others needs a new reconstruction).
    """

    def __init__(self, live: LiveReconstruction | None, budget: int, refusal: str = "",
                 settings: tuple = ()):
        self.live = live
        self.budget = budget
        self.refusal = refusal
        self.settings = settings
        self.health = CarvingHealth(problem=refusal)
        self.unstored: dict[str, tuple] = {}   # view key -> add_view's arguments
        self.earlier = EarlierViews()
        self.cameras: list = []

    def reopen(self) -> str:
        """Take up the scan that was open when the node last stopped (a restart); what was
        found."""
        text = self.live.reopen()
        self.cameras = [rig_camera(theta, phi, self.live.calibration)
                        for _, _, theta, phi in self.live.views()]
        with self.health.lock:
            self.health.counts["scan_views"] = self.live.n_views
        return text

    def working_memory_reserve(self) -> int:
        """The heap a reconstruction of this scan needs, bytes, within the budget (0 without
        a reconstruction)."""
        return 0 if self.live is None else min(self.live.working_memory_bytes, self.budget)

    def add_colour_image(self, stamp, image: np.ndarray) -> str:
        """Keep the captured image (H, W, 3) uint8 RGB of the view at ``stamp`` (``(sec,
        nanosec)``) to colour the mesh: "" or why it was not kept. Requires ``live``."""
        try:
            self.live.add_colour_image(view_key(stamp), image)
        except ValueError as exc:
            return f"captured image at stamp {format_stamp(stamp)} not kept for colour: {exc}"
        return ""

    def carving_failed(self, exc: ValueError) -> str:
        """Count a carving that failed with ``exc``; its ERROR."""
        self.health.count("carving_failures")
        reason = str(exc)
        if self.live.n_views == 0:
            reason += ": publish masks with their joint states first"
        return f"carving failed: {reason}"

    def carved(self, carved, seconds: float) -> str:
        """Count a carving (a :class:`~sfs_ros.core.carved_scan.CarvedScan` made in
        ``seconds``); its summary."""
        self.health.count("carvings")
        return (f"carved {sum(v.role == 'used' for v in carved.views)} of "
                f"{self.live.n_views} views on a grid of {list(carved.grid.shape)} voxels "
                f"({carved.mesher}, {len(carved.colour_views)} views to colour from) in "
                f"{seconds:.2f} s")

    def add_view(self, stamp, frame_id: str, mask: np.ndarray, theta: float,
                 phi: float) -> ViewOutcome:
        """Give one view (stamp ``(sec, nanosec)``, its mask's frame, the (H, W) mask, the
        angles in rad) to the live reconstruction, counting what became of it."""
        if self.live is None:
            return ViewOutcome("refused", f"view at stamp {format_stamp(stamp)} not received: "
                                          f"{self.refusal}")
        start = time.perf_counter()
        key = view_key(stamp)
        if key in self.earlier:
            self.health.count("stale")
            return ViewOutcome("stale", f"view at stamp {format_stamp(stamp)} came again after "
                                        "its scan ended: not stored in this scan, receipt sent "
                                        "again")
        self.unstored.pop(key, None)
        try:
            added = self.live.add_view(key, mask, theta, phi)
        except OSError as exc:
            self.unstored[key] = (stamp, frame_id, mask, theta, phi)
            return ViewOutcome("unstored", store_problem(stamp, self.live, exc,
                                                         len(self.unstored)))
        except DuplicateViewError:
            self.health.count("repeats")
            return ViewOutcome("repeat", f"view at stamp {format_stamp(stamp)} came again: "
                                         "already stored, receipt sent again")
        except ValueError as exc:
            self.health.count("rejected")
            with self.health.lock:
                self.health.rejected.append(f"view at stamp {format_stamp(stamp)} (theta "
                                            f"{theta:.6g} rad, phi {phi:.6g} rad): {exc}")
            return ViewOutcome("rejected", f"view at stamp {format_stamp(stamp)} rejected: {exc}")
        self.cameras.append(rig_camera(theta, phi, self.live.calibration))
        kind = "carved" if added.carved else "empty"
        warning = "" if added.carved else f"view at stamp {format_stamp(stamp)}: {added.reason}"
        with self.health.lock:
            self.health.carve_s += time.perf_counter() - start
            self.health.counts["scan_views"] = added.n_views
            self.health.counts[kind] += 1
            self.health.problem = ""
            self.health.warning = warning
        return ViewOutcome(kind, warning)

    def store_unstored(self, add: Callable[..., None]) -> None:
        """Call ``add(*arguments)`` for the views the disk refused, oldest first, until one is
        refused again (the rest waits too)."""
        for key, args in list(self.unstored.items()):
            add(*args)
            if key in self.unstored:
                return

    def new_scan(self, name: str | None, settings: tuple,
                 make_live: Callable[[], LiveReconstruction]) -> bool:
        """Start a new scan named ``name`` (None: the next free number) with the per-scan
        ``settings``: a new reconstruction from ``make_live()`` when none is held or the
        settings changed, else the same one reset. Whether a new reconstruction was made;
        ValueError (the scan name is taken, the settings cannot make a scan): no new scan."""
        earlier = [] if self.live is None else self.live.view_keys()
        changed = self.live is None or settings != self.settings
        if changed:
            if self.live is not None:
                self.live.close()
            self.live = make_live()
            self.refusal = ""
            self.settings = settings
        else:
            self.live.reset(name)
        self.unstored.clear()
        self.earlier.remember(earlier)
        self.cameras = []
        self.health.new_scan()
        return changed
