"""The whole ``sfs-reconstruct`` against decoding its images alone.

Objects rendered once by the project's renderer on white from 4 rings of views (at 10,
30, 50 and 70 degrees), each written as a session folder with no carving box: the mug
and the chair (a detailed object: thin legs, an antenna, a back with a hole, a ring and
an open cup) from 100 views of 800 x 800 (pinhole, 0.375 mm a pixel), and the mug with
the cell's camera (640 x 480, 0.43 mm a pixel) from 16, 48 and 144 views. Timed:
``sfs-reconstruct`` with default options but the refinement below the hull
(``--no-refine``; its own figures in ``bench_refine``), from reading the images to the
mesh and its report written. Baseline: ``cv2.imread`` of every image of the set,
measured in the same run. Ratio = baseline / ours. A note gives ours / decode, the run's
CPU time (every thread's) and the cores it kept busy, and the mesh's silhouette IoU
against the renderer's exact silhouettes of the true mesh (mean and worst view).

Where the Middlebury rings are beside the repository (``../shared/datasets/middlebury``;
not with ``--quick``), the same for dinoSparseRing and templeSparseRing (16 photographs
of 640 x 480 each, decoding their images the baseline), the mesh scored against masks
made by the data sets' own recipe (:func:`~sfs_ros.core.exchange.middlebury.readme_mask`).

Run: ``python -m bench.bench_reconstruct`` (``--quick``: the mug alone, 40 views of
400 x 400).
"""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np
import trimesh

from sfs_ros.cli.reconstruct import main as reconstruct_main
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.middlebury import read_middlebury, readme_mask
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.exchange.views import read_image
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.metrics import reprojection_ious
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import exact_silhouettes, simulate_scan

from .timing import best_of, best_of_with_cpu, main

MIDDLEBURY = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "middlebury"
#: The rings: (par file, the README recipe's threshold).
RINGS = (("dinoSparseRing/dinoSR_par.txt", 0.19), ("templeSparseRing/templeSR_par.txt", 0.3))


#: The rings' elevations, degrees.
RINGS_DEG = (10.0, 30.0, 50.0, 70.0)


def square_rig(size_px: int) -> RigCalibration:
    """A square pinhole camera 0.6 m from the object, ``size_px`` wide (0.375 mm a pixel
    at 800)."""
    return RigCalibration(width=size_px, height=size_px, projection="pinhole",
                          fx=2.0 * size_px, fy=2.0 * size_px, camera_distance_m=0.6,
                          aim_point_m=(0.0, 0.0, 0.04))


#: The cell's camera: 640 x 480 at fx 1400 px (0.43 mm a pixel at 0.6 m).
CELL_RIG = RigCalibration(width=640, height=480, projection="pinhole", fx=1400.0, fy=1400.0,
                          camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))


def write_scan(folder: Path, name: str, rig: RigCalibration,
               per_ring: int) -> tuple[Path, object]:
    """Render object ``name`` from 4 rings of ``per_ring`` views; returns the session folder
    and the object."""
    obj = make_object(name)
    captures = simulate_scan(obj, rig, ring_plan(RINGS_DEG, per_ring), seed=3)
    session = write_session(folder / "session", [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], rig)
    return session, obj


def exact_silhouette_iou(session: Path, obj, mesh_path: Path) -> np.ndarray:
    """Per view, IoU of the mesh's silhouette with the true mesh's exact silhouette."""
    mesh = trimesh.load(mesh_path, force="mesh", process=False)
    cameras = [view.camera for view in load_views(session).views]
    return reprojection_ious(mesh.vertices, mesh.faces, cameras, exact_silhouettes(obj, cameras))


def _reconstruct(argv: list[str]) -> None:
    """``sfs-reconstruct argv``, its printing swallowed; RuntimeError when it fails."""
    with contextlib.redirect_stdout(io.StringIO()):
        if reconstruct_main(argv) != 0:
            raise RuntimeError(f"sfs-reconstruct failed on {argv[0]}")


def _cores(seconds: float, cpu: float) -> str:
    """A run's ``cpu`` seconds of CPU time and the cores they kept busy over its wall time
    of ``seconds``."""
    return f"CPU {cpu:.2f} s ({cpu / seconds:.2f} cores)"


def _stages(report: dict) -> str:
    return ", ".join(f"{k} {v:.2f}" for k, v in report["timings_s"].items())


def middlebury_rows() -> list[dict]:
    """The whole ``sfs-reconstruct --no-refine`` of each ring against ``cv2.imread`` of its
    photographs; none when the data sets are not there."""
    rows = []
    for par, threshold in RINGS:
        if not (MIDDLEBURY / par).is_file():
            continue
        views = read_middlebury(MIDDLEBURY / par).views
        decode = best_of(lambda: [cv2.imread(str(v.image_path)) for v in views], 3)
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "mesh.ply"
            seconds, cpu = best_of_with_cpu(
                lambda: _reconstruct([str(MIDDLEBURY / par), "-o", str(out), "-q", "--no-refine"]),
                2)
            report = json.loads(out.with_name("mesh.report.json").read_text())
            mesh = trimesh.load(out, force="mesh", process=False)
        ious = reprojection_ious(mesh.vertices, mesh.faces, [v.camera for v in views],
                                 [readme_mask(read_image(v.image_path), threshold) for v in views])
        name = Path(par).parent.name
        again = (report.get("resegmentation") or {}).get("resegmented")
        rows.append({"name": f"sfs-reconstruct {name} vs imread", "seconds": seconds,
                     "baseline_seconds": decode, "ratio": decode / seconds,
                     "notes": [f"{name}: {seconds / decode:.1f}x the decoding; "
                               f"{_cores(seconds, cpu)}; grid "
                               f"{report['grid']['shape']}; IoU against the README masks "
                               f"{np.mean(ious):.4f} (worst {np.min(ious):.4f}); views cut "
                               f"again {again}; stages (s): "
                               f"{_stages(report)}"]})
    return rows


def synthetic_row(name: str, rig: RigCalibration, per_ring: int) -> dict:
    """The whole ``sfs-reconstruct --no-refine`` of object ``name`` seen by ``rig`` from
    ``4 * per_ring`` views against ``cv2.imread`` of its images."""
    with tempfile.TemporaryDirectory() as tmp:
        session, obj = write_scan(Path(tmp), name, rig, per_ring)
        images = sorted((session / "images").glob("*.png"))
        decode = best_of(lambda: [cv2.imread(str(p)) for p in images], 3)
        out = Path(tmp) / "mesh.ply"
        seconds, cpu = best_of_with_cpu(
            lambda: _reconstruct([str(session), "-o", str(out), "-q", "--no-refine"]), 2)
        report = json.loads(out.with_name("mesh.report.json").read_text())
        ious = exact_silhouette_iou(session, obj, out)
    size = f"{rig.width}x{rig.height}"
    again = (report.get("resegmentation") or {}).get("resegmented")
    return {"name": f"sfs-reconstruct {name} {len(images)} views {size} vs imread",
            "seconds": seconds, "baseline_seconds": decode, "ratio": decode / seconds,
            "notes": [f"{name} {len(images)} x {size}: {seconds / decode:.1f}x the decoding; "
                      f"{_cores(seconds, cpu)}; silhouette IoU against the exact "
                      f"silhouettes: mean "
                      f"{np.mean(ious):.4f}, worst {np.min(ious):.4f}; grid "
                      f"{report['grid']['shape']}, voxel "
                      f"{report['grid']['voxel_size_m'] * 1e3:.3f} mm "
                      f"({report['grid']['resolution_source']}); views cut again {again}; "
                      f"stages (s): {_stages(report)}"]}


def run(quick: bool = False) -> list[dict]:
    if quick:
        return [synthetic_row("mug", square_rig(400), 10)]
    rows = [synthetic_row("mug", square_rig(800), 25), synthetic_row("chair", square_rig(800), 25)]
    rows += [synthetic_row("mug", CELL_RIG, per_ring) for per_ring in (4, 12, 36)]
    return rows + middlebury_rows()


if __name__ == "__main__":
    main(__doc__, run, quick_help="40 views of 400 x 400")
