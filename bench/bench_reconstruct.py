"""The whole ``sfs-reconstruct`` against decoding its images alone.

A mug on white, rendered once by the project's renderer from 100 views on a
hemisphere (4 rings of 25, 800 x 800 pinhole), written as a session folder
with no carving box. Timed: ``sfs-reconstruct`` with default options but the
refinement below the hull (``--no-refine``; its own figures in ``bench_refine``), from
reading the images to the mesh and its report written. Baseline: ``cv2.imread``
of every image of the set, measured in the same run. Ratio = baseline / ours
(the goal: above 0.25, i.e. the whole reconstruction within 4x the decoding).
A note gives the mesh's silhouette IoU against the renderer's exact
silhouettes of the true mesh (mean and worst view).

Run: ``python -m bench.bench_reconstruct`` (``--quick``: 40 views of 400 x 400).
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
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.metrics import reprojection_ious
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import exact_silhouettes, simulate_scan

from .timing import best_of, main


def write_scan(folder: Path, *, size_px: int, per_ring: int) -> tuple[Path, object]:
    """Render the mug from 4 rings of ``per_ring`` views at ``size_px`` square; returns
    the session folder and the object."""
    obj = make_object("mug")
    rig = RigCalibration(width=size_px, height=size_px, projection="pinhole",
                         fx=2.0 * size_px, fy=2.0 * size_px, camera_distance_m=0.6,
                         aim_point_m=(0.0, 0.0, 0.04))
    captures = simulate_scan(obj, rig, ring_plan([10.0, 30.0, 50.0, 70.0], per_ring), seed=3)
    session = write_session(folder / "session", [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], rig)
    return session, obj


def exact_silhouette_iou(session: Path, obj, mesh_path: Path) -> np.ndarray:
    """Per view, IoU of the mesh's silhouette with the true mesh's exact silhouette."""
    mesh = trimesh.load(mesh_path, force="mesh", process=False)
    cameras = [view.camera for view in load_views(session).views]
    return reprojection_ious(mesh.vertices, mesh.faces, cameras, exact_silhouettes(obj, cameras))


def run(quick: bool = False) -> list[dict]:
    size_px, per_ring = (400, 10) if quick else (800, 25)
    with tempfile.TemporaryDirectory() as tmp:
        session, obj = write_scan(Path(tmp), size_px=size_px, per_ring=per_ring)
        images = sorted((session / "images").glob("*.png"))
        decode = best_of(lambda: [cv2.imread(str(p)) for p in images], 3)
        out = Path(tmp) / "mesh.ply"
        argv = [str(session), "-o", str(out), "-q", "--no-refine"]

        def reconstruct_quietly():
            with contextlib.redirect_stdout(io.StringIO()):
                if reconstruct_main(argv) != 0:
                    raise RuntimeError(f"sfs-reconstruct failed on {session}")

        seconds = best_of(reconstruct_quietly, 2)
        report = json.loads(out.with_name("mesh.report.json").read_text())
        ious = exact_silhouette_iou(session, obj, out)
    stages = ", ".join(f"{k} {v:.2f}" for k, v in report["timings_s"].items())
    return [{"name": f"sfs-reconstruct {len(images)} views {size_px}x{size_px} vs imread",
             "seconds": seconds, "baseline_seconds": decode, "ratio": decode / seconds,
             "notes": [f"grid {report['grid']['shape']}, voxel "
                       f"{report['grid']['voxel_size_m'] * 1e3:.3f} mm "
                       f"({report['grid']['resolution_source']}); silhouette IoU against the "
                       f"exact silhouettes: mean {np.mean(ious):.4f}, worst {np.min(ious):.4f}; "
                       f"stages (s): {stages}"]}]


if __name__ == "__main__":
    main(__doc__, run, quick_help="40 views of 400 x 400")
