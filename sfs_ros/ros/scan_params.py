"""The scan node's parameters made into its plan, its progress folder and its sequence's
settings."""

from __future__ import annotations

import math

from sfs_ros.cell_logic.scan_plan import ScanPlan, load_plan
from sfs_ros.cell_logic.scan_progress import ScanProgress
from sfs_ros.cell_logic.scan_sequence import ScanSettings
from sfs_ros.ros.params import ParameterError

__all__ = ["scan_plan", "scan_progress", "scan_settings"]


def scan_plan(values: dict) -> ScanPlan:
    """The plan from the node's parameter values; :class:`ParameterError` naming the cause."""
    if values["plan_file"].strip():
        try:
            return load_plan(values["plan_file"])
        except ValueError as exc:
            raise ParameterError("plan_file", str(exc)) from None
    try:
        return ScanPlan.from_rings(values["rings_phi_deg"], values["per_ring"],
                                   values["top_view"], stagger=values["stagger"],
                                   reorder=values["reorder"])
    except ValueError as exc:
        raise ParameterError("rings_phi_deg", str(exc)) from None


def scan_settings(values: dict, *, board: bool = False) -> ScanSettings:
    """The sequence's settings from the node's parameter values (``board``: a calibration
    scan, which leaves the reconstruction as it is)."""
    steps = [("reset", values["reset_reconstruction"] and not board,
              values["service_timeout_s"]),
             ("home", values["home_before_scan"], values["home_timeout_s"]),
             ("listeners", True, values["listen_timeout_s"])]
    return ScanSettings(
        settle_tolerance_rad=math.radians(values["settle_tolerance_deg"]),
        settle_samples=values["settle_samples"], move_timeout_s=values["move_timeout_s"],
        stall_s=values["stall_s"], move_retries=values["move_retries"],
        capture_timeout_s=values["capture_timeout_s"],
        capture_retries=values["capture_retries"],
        encoder_max_gap_s=values["encoder_max_gap_s"],
        receipt_timeout_s=values["receipt_timeout_s"], max_sends=values["max_sends"],
        prepare=tuple((name, timeout_s) for name, wanted, timeout_s in steps if wanted),
        trigger=values["camera_trigger"], exposure_delay_s=values["exposure_delay_s"],
        rehome_before_retry=values["home_before_retry"])


def scan_progress(values: dict, plan: ScanPlan) -> ScanProgress | None:
    """The folder that keeps the scan's progress (None: ``progress_dir`` empty);
    :class:`ParameterError` for a ``queue_depth`` below the plan's views or a folder that
    cannot be used."""
    if len(plan) > values["queue_depth"]:
        raise ParameterError("queue_depth", f"got {values['queue_depth']}, expected at "
                             f"least the {len(plan)} views of the plan")
    if not values["progress_dir"].strip():
        return None
    try:
        return ScanProgress(values["progress_dir"], plan.views)
    except OSError as exc:
        raise ParameterError("progress_dir", f"cannot use {values['progress_dir']}: "
                             f"{exc}") from None
