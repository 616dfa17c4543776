"""The carving node's parameters (:data:`PARAMS`) made into its scan: the box, the
reconstruction, the checks.

Each function takes the node's parameter values (``{name: value}``, as
:func:`sfs_ros.ros.params.read` gives them) and raises :class:`ParameterError` naming
the parameter that cannot be used.
"""

from __future__ import annotations

import numpy as np

from sfs_ros.cell_logic.carving_scan import CarvingScan, grid_refusal, memory_budget
from sfs_ros.cell_logic.live_reconstruction import LiveReconstruction, check_scan_name
from sfs_ros.cell_logic.mesh_options import MeshOptions, mesh_options
from sfs_ros.core.exchange.views import as_bounds
from sfs_ros.core.meshing.meshers import MESHER
from sfs_ros.core.settings import BOUNDS_M, COLOUR, MAX_MEMORY, RESOLUTION
from sfs_ros.ros.params import Param, ParameterError
from sfs_ros.ros.rig_params import WRITABLE_RIG_PARAMS, rig_calibration

__all__ = ["PARAMS", "carve_options", "check_scan_settings", "live_reconstruction", "open_scan",
           "request_refusal", "scan_bounds", "scan_settings"]


#: The carving node's parameters: the rig calibration, then the scan's own (the per-scan
#: settings settable at run time, between scans).
PARAMS: list[Param] = [
    *WRITABLE_RIG_PARAMS,
    Param.of(BOUNDS_M, constraints="six values, min < max on each axis; from the next reset"),
    Param.of(RESOLUTION, constraints="the live hull's and the final reconstruction's; from "
             "the next reset"),
    Param.of(MESHER, constraints="from the next reset"),
    Param("scan_name", "", "Name of the next scan's folder in output_dir and of its mesh "
          "(<name>.ply); empty = scan_NNN, the next free number.",
          constraints="from the next reset; 1-100 letters, digits, '_', '-', '.', a folder "
          "not yet in output_dir"),
    Param("output_dir", "", "Folder for scan session folders, meshes and reports (created if "
          "needed); every file the node writes stays inside it.", read_only=True,
          constraints="required, non-empty"),
    Param("hull_rate_hz", 2.0, "Most hull clouds per second; the latest is always published "
          "once the views received so far are carved.", bounds=(0.0, 1000.0), read_only=True,
          constraints="0 = after every view"),
    Param("max_hull_points", 100000, "Most points of a hull cloud (an evenly spaced subset "
          "of the surface voxels beyond that).", bounds=(1, 100_000_000), read_only=True),
    Param("queue_depth", 100, "Depth of the reliable mask topics and of the buffer of unpaired "
          "halves per topic; at least the number of views of a scan.", bounds=(1, 100000),
          read_only=True),
    Param.of(COLOUR, read_only=True, constraints="the captured images on capture/image"),
    Param.of(MAX_MEMORY, read_only=True, constraints=f"empty = {MAX_MEMORY.default_text}"),
    Param("rehearse", True, "At start, receive and reconstruct a small simulated scan (in a "
          "folder in output_dir, removed after) so that the first real reconstruction finds "
          "its code loaded (about 0.2 s less from the last view to the mesh).", read_only=True),
]


def scan_settings(values: dict) -> tuple:
    """The settings that need a new :class:`LiveReconstruction` when they change (the
    rig among them)."""
    return (tuple(values["bounds_m"]), values["resolution"], values["mesher"],
            rig_calibration(values))


def scan_bounds(values: dict) -> np.ndarray:
    """``bounds_m`` as a (2, 3) box, metres."""
    box = values["bounds_m"]
    try:
        if len(box) != 6:
            raise ValueError(f"got {len(box)} values")
        return as_bounds(np.reshape(box, (2, 3)), what="bounds_m")
    except ValueError:
        raise ParameterError("bounds_m", f"got {box!r}, expected [xmin, ymin, zmin, xmax, ymax, "
                             "zmax] with finite min < max") from None


def live_reconstruction(values: dict, scan_name: str | None = None) -> LiveReconstruction:
    """The live reconstruction of the per-scan settings and rig in ``values``, its first
    scan named ``scan_name`` (None: the next free number)."""
    return LiveReconstruction(rig_calibration(values), scan_bounds(values),
                              output_dir=values["output_dir"], resolution=values["resolution"],
                              mesher=values["mesher"], scan_name=scan_name)


def open_scan(values: dict) -> CarvingScan:
    """The scan at start-up. A grid the memory budget cannot hold gives a scan without a
    reconstruction, with the refusal (the node stays up; a reset with a resolution that
    fits ends it)."""
    if not values["output_dir"].strip():
        raise ParameterError("output_dir", "is required: the folder for the scans")
    rig_calibration(values)
    bounds = scan_bounds(values)
    try:
        budget = memory_budget(values["max_memory"])
    except ValueError as exc:
        raise ParameterError("max_memory", str(exc)) from None
    refusal = grid_refusal(bounds, values["resolution"], budget)
    if refusal:
        return CarvingScan(None, budget, refusal, scan_settings(values))
    try:
        # scan_name is for the next reset: a respawned node must not be refused
        # because the scan it was named for is on disk already.
        return CarvingScan(live_reconstruction(values), budget,
                           settings=scan_settings(values))
    except (ValueError, OSError) as exc:
        raise ParameterError("output_dir" if isinstance(exc, OSError)
                             else "resolution", str(exc)) from None


def check_scan_settings(values: dict, budget: int) -> None:
    """ParameterError for per-scan settings that cannot make a scan within ``budget``
    bytes."""
    refusal = grid_refusal(scan_bounds(values), values["resolution"], budget)
    if refusal:
        raise ParameterError("resolution", refusal)
    if values["scan_name"]:
        try:
            check_scan_name(values["output_dir"], values["scan_name"])
        except ValueError as exc:
            raise ParameterError("scan_name", str(exc)) from None


def request_refusal(values: dict, options: MeshOptions, budget: int) -> str:
    """Why a carving request's grid (its ``options`` over ``values``) cannot be held within
    ``budget`` bytes, or "" (also when it asks for the node's own grid)."""
    grid = dict(values)
    if options.resolution is not None:
        grid["resolution"] = options.resolution
    if options.bounds_m is not None:
        grid["bounds_m"] = options.bounds_m.ravel().tolist()
    if grid == values:
        return ""
    return grid_refusal(scan_bounds(grid), grid["resolution"], budget)


def carve_options(request, values: dict, budget: int) -> MeshOptions:
    """The options of a ``CarveScan`` ``request`` (each left empty: the node's parameter in
    ``values``); ValueError ``request refused: <reason>`` for a bad one or a grid that does
    not fit ``budget`` bytes."""
    try:
        options = mesh_options(values["output_dir"], resolution=request.resolution,
                               bounds_m=list(request.bounds_m), mesher=request.mesher,
                               colour=request.colour)
    except ValueError as exc:
        raise ValueError(f"request refused: {exc}") from None
    refusal = request_refusal(values, options, budget)
    if refusal:
        raise ValueError(f"request {refusal}")
    return options
