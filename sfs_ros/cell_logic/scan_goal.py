"""What a scan request asks for, checked before the scan starts (no ROS).

A scan goal (``sfs_ros_interfaces/action/Scan``) names its views in one of three ways:
a plan file (the format of :mod:`sfs_ros.cell_logic.scan_plan`), explicit views as two
equal-length lists of encoder targets in radians (visited in the order given), or
neither (the node's configured plan); optionally the scan's name; and what stands on the
plate (:func:`goal_object`: the object to scan, or a calibration board). :func:`goal_plan`
turns that into the plan to scan or a :class:`ValueError` naming what was wrong and what
was expected, so that a bad goal never reaches the axes.
"""

from __future__ import annotations

import math

import numpy as np

from .paths import check_scan_name_format
from .scan_plan import ScanPlan, load_plan

__all__ = ["OBJECTS", "PHI_LIMIT_RAD", "goal_object", "goal_plan", "scan_outcome"]

#: What a scan is of: ``object`` (scanned for its shape; the default) or ``board`` (a
#: calibration board: its captures go to the calibration, not the reconstruction).
OBJECTS = ("object", "board")

#: The carriage's range, |phi| at most this, radians (a plan file's [-90, 90] degrees).
PHI_LIMIT_RAD = math.pi / 2
#: States in which a scan's run has ended.
ENDED = ("done", "paused", "cancelled")
#: Rounding allowed beyond the carriage's range (a value written as pi / 2), radians.
_EDGE_RAD = 1e-9


def _explicit_plan(theta_rad, phi_rad) -> ScanPlan:
    """The plan of explicit views, in the order given; ValueError naming the bad view."""
    theta = np.asarray(list(theta_rad), dtype=np.float64)
    phi = np.asarray(list(phi_rad), dtype=np.float64)
    if len(theta) != len(phi):
        raise ValueError(f"theta_rad has {len(theta)} values and phi_rad {len(phi)}; expected "
                         "equal lengths, one (theta, phi) pair per view")
    bad = np.flatnonzero(~(np.isfinite(theta) & np.isfinite(phi)))
    if len(bad):
        i = int(bad[0])
        raise ValueError(f"view {i} (theta {theta[i]}, phi {phi[i]} rad) is not finite; "
                         "expected finite angles in radians")
    bad = np.flatnonzero(np.abs(phi) > PHI_LIMIT_RAD + _EDGE_RAD)
    if len(bad):
        i = int(bad[0])
        raise ValueError(f"view {i} has phi {phi[i]:.6g} rad, outside the carriage's range "
                         f"[-{PHI_LIMIT_RAD:.6f}, {PHI_LIMIT_RAD:.6f}] rad")
    degrees = np.column_stack([np.degrees(theta), np.clip(np.degrees(phi), -90.0, 90.0)])
    return ScanPlan.from_views(degrees, reorder=False)


def goal_object(value: str) -> str:
    """The scan's object of a goal's ``object`` field ("" = ``object``); ValueError naming
    the value and the choices."""
    value = value.strip() or OBJECTS[0]
    if value not in OBJECTS:
        raise ValueError(f"object {value!r} is not one of {list(OBJECTS)} (\"\" = "
                         f"{OBJECTS[0]!r})")
    return value


def goal_plan(plan_file: str, theta_rad, phi_rad, scan_name: str, *,
              max_views: int) -> ScanPlan | None:
    """The plan a scan goal asks for; None for the configured plan.

    Parameters
    ----------
    plan_file : str
        A YAML plan file, or "" (then ``theta_rad`` / ``phi_rad``, or neither).
    theta_rad, phi_rad : sequences of float, equal lengths
        Explicit views' encoder targets, radians: theta any finite angle (taken
        modulo 2 pi), phi within the carriage's range [-pi/2, pi/2]; empty for none.
    scan_name : str
        "" or a scan folder name (:func:`sfs_ros.cell_logic.paths.check_scan_name_format`).
    max_views : int
        Most views a scan may have (the capture topics' depth).

    Raises
    ------
    ValueError
        Naming what was wrong with the goal and what was expected.
    """
    theta, phi = list(theta_rad), list(phi_rad)
    if scan_name:
        check_scan_name_format(scan_name)
    if plan_file.strip() and (theta or phi):
        raise ValueError("the goal gives both plan_file and theta_rad/phi_rad; expected one "
                         "of them (or neither, for the configured plan)")
    if plan_file.strip():
        plan = load_plan(plan_file)
    elif theta or phi:
        plan = _explicit_plan(theta, phi)
    else:
        return None
    if len(plan) > max_views:
        raise ValueError(f"the goal's plan has {len(plan)} views, more than the {max_views} "
                         "the capture topics hold (the scan node's queue_depth)")
    return plan


def scan_outcome(values: dict, scan: int) -> bool | None:
    """Whether scan number ``scan`` succeeded, from the scan's status ``values``
    (:attr:`sfs_ros.cell_logic.scan_sequence.ScanStatus.values`): None while its run goes on or,
    done, receipts are still to come; True once done with every capture receipted; False
    once paused, cancelled, or done with captures lost in transport."""
    if values["scan"] != scan or values["state"] not in ENDED:
        return None
    if values["state"] == "done" and values["receipted"] + \
            values["lost_in_transport"] < values["total"]:
        return None                                 # receipts still to come
    return values["state"] == "done" and values["lost_in_transport"] == 0
