"""The refinement below the visual hull against the hull pipeline, and both against the truth.

Each object is rendered once by the project's renderer with its solid colour texture under
a light fixed in the lab (``simulate_scan(..., textured=True)``): 48 views of 640 x 480
(pinhole, fx 1400 px, 0.6 m away) on rings at 20, 45 and 70 degrees, written as a session
folder. Then ``sfs-reconstruct`` runs on it twice in this process (segmentation,
consensus, fusion, carving, meshing, the reprojection check, at the grid it chooses):
with ``--no-refine`` (the hull pipeline) and with its defaults (the refinement on).
Timed: the refinement stage of the second run (``timings_s["refinement"]`` of its
report); baseline: the whole first run (reading the images to the mesh and its report
written). Ratio = baseline / ours: the goal is above 0.1 (the refinement within 10x the
hull pipeline).

A note per object gives both meshes' volume IoU against the true shape (0.5 mm grid over
the carving box), their accuracy (mesh to truth) and completeness (truth to mesh), mean
and 90th percentile in mm, and what the refinement removed. The objects: a cup, a bowl
and a block with a blind pocket (concavities no silhouette shows) and the hull-exact
controls (sphere, torus, solid mug, a barrel: a solid of revolution), all textured.

Run: ``python -m bench.bench_refine [--quick] [--objects cup sphere ...]`` (``--quick``:
320 x 240 views, fx 700, the cup and the sphere unless objects are named).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import trimesh

from sfs_ros.cli.reconstruct import main as reconstruct_main
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.metrics import mesh_occupancy, occupancy_from_contains, volume_iou
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan, surface_errors

from .timing import print_table

CONCAVE = ("cup", "bowl", "pocket_block")
CONTROLS = ("sphere", "torus", "mug", "barrel")
OBJECTS = CONCAVE + CONTROLS
QUICK_OBJECTS = ("cup", "sphere")
#: Volume IoU is scored on this grid, metres.
SCORE_VOXEL_M = 0.0005


def rig(quick: bool) -> RigCalibration:
    """The bench's camera: 640 x 480 at fx 1400 px (0.43 mm a pixel at 0.6 m), or half."""
    scale = 0.5 if quick else 1.0
    return RigCalibration(width=int(640 * scale), height=int(480 * scale),
                          projection="pinhole", fx=1400.0 * scale, fy=1400.0 * scale,
                          camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))


def write_scan(folder: Path, name: str, quick: bool) -> tuple[Path, object]:
    """Render ``name`` textured from 48 views on three rings; the session folder and the
    object."""
    obj = make_object(name)
    calibration = rig(quick)
    captures = simulate_scan(obj, calibration, ring_plan([20.0, 45.0, 70.0], 16),
                             textured=True, seed=1)
    session = write_session(folder / name, [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], calibration)
    return session, obj


def reconstruct_timed(session: Path, out: Path, *options: str) -> tuple[float, dict]:
    """Wall time of one ``sfs-reconstruct`` run, seconds, and its report."""
    argv = [str(session), "-o", str(out), "-q", *options]
    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        if reconstruct_main(argv) != 0:
            raise RuntimeError(f"sfs-reconstruct {' '.join(options)} failed on {session}")
    seconds = time.perf_counter() - start
    return seconds, json.loads(out.with_name(out.stem + ".report.json").read_text())


def score(obj, mesh_path: Path) -> dict:
    """Volume IoU, accuracy and completeness (mm) of the mesh against the true shape."""
    mesh = trimesh.load(mesh_path, force="mesh", process=False)
    box = carving_box(obj)
    grid = VoxelGrid(box[0], box[1], SCORE_VOXEL_M)
    iou = volume_iou(mesh_occupancy(mesh.vertices, mesh.faces, grid),
                     occupancy_from_contains(obj.contains, grid))
    errors = surface_errors(obj, mesh.vertices, mesh.faces, n_samples=20000)
    return {"iou": iou, **{k: 1e3 * v for k, v in errors.items()}}


def _describe(s: dict) -> str:
    return (f"IoU {s['iou']:.3f}, acc {s['accuracy_mean_m']:.2f}/{s['accuracy_p90_m']:.2f}, "
            f"compl {s['completeness_mean_m']:.2f}/{s['completeness_p90_m']:.2f} mm")


def run_object(name: str, quick: bool) -> dict:
    """One object's row: the refinement stage against the hull pipeline, and the scores."""
    with tempfile.TemporaryDirectory() as tmp:
        session, obj = write_scan(Path(tmp), name, quick)
        hull_s, hull_report = reconstruct_timed(session, Path(tmp) / "hull.ply", "--no-refine")
        refined_s, refined_report = reconstruct_timed(session, Path(tmp) / "refined.ply")
        hull, refined = score(obj, Path(tmp) / "hull.ply"), score(obj, Path(tmp) / "refined.ply")
    stage = refined_report["timings_s"]["refinement"]
    removal = refined_report["refinement"] or {}
    grid = hull_report["grid"]
    removed = (f"removed {100 * removal['removed_fraction_of_hull']:.1f} % of the hull"
               if removal.get("applied") else f"not applied: {removal.get('reason')}")
    return {"name": f"refinement {name} ({grid['voxel_size_m'] * 1e3:.2f} mm grid)",
            "seconds": stage, "baseline_seconds": hull_s, "ratio": hull_s / stage,
            "notes": [f"{name}: refinement {stage / hull_s:.1f}x the hull pipeline; hull "
                      f"{_describe(hull)}; refined {_describe(refined)}; "
                      f"IoU change {refined['iou'] - hull['iou']:+.4f}; {removed}; "
                      f"grid {grid['shape']}; the whole run with the refinement "
                      f"{refined_s:.1f} s"]}


def warm_up() -> None:
    """One run with the refinement on a tiny scan, so that every compiled kernel of both runs
    is loaded (or compiled) before the timing."""
    calibration = RigCalibration(width=160, height=120, projection="pinhole", fx=350.0,
                                 fy=350.0, camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))
    captures = simulate_scan(make_object("sphere"), calibration,
                             ring_plan([20.0, 45.0, 70.0], 4), textured=True, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        session = write_session(Path(tmp) / "warm", [(c.name, c.image) for c in captures],
                                [(c.theta_rad, c.phi_rad) for c in captures], calibration)
        reconstruct_timed(session, Path(tmp) / "warm.ply")


def run(quick: bool = False, objects=None) -> list[dict]:
    """The rows of ``objects`` (default: all, or the cup and the sphere when quick)."""
    warm_up()
    names = objects or (QUICK_OBJECTS if quick else OBJECTS)
    return [run_object(name, quick) for name in names]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="320 x 240 views; the cup and the sphere unless objects are named")
    parser.add_argument("--objects", nargs="+", choices=OBJECTS, metavar="NAME",
                        help=f"only these objects (of {', '.join(OBJECTS)})")
    args = parser.parse_args(argv)
    print_table(run(quick=args.quick, objects=args.objects))


if __name__ == "__main__":
    main()
