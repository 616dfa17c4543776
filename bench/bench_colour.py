"""Vertex colouring of the reconstructed mug: time and colour error against ground truth.

A simulated scan of the mug (three rings of 16 views and one from above) is
written as a session, reconstructed (marching cubes), and the mesh coloured
from the images by :func:`sfs_ros.core.meshing.colour.vertex_colours`, with the
silhouettes of the segmentation as masks. Two sets of images of the same views:
*albedo* (unshaded, ``ambient=1``, the mug's known colour pattern plus the
camera's noise) and *shaded* (what the mock camera produces: Lambert shading
baked in). Baseline: the same colouring without the z-buffer test
(``occlusion=False``: facing, image and mask tests only), measured in the same
run; ratio = baseline / ours (below 1: the z-buffer costs time).

Error per vertex: mean over R, G, B of ``|colour - truth|`` (0..255), the truth
being the colour pattern at the nearest point of the true surface (a KD-tree on
dense surface samples). Quoted as mean and 95th percentile over all vertices,
over the *seen* ones (blended from at least one view; the others, the underside
on the plate, are filled from their neighbours), over those within one voxel
of the true surface (where the visual hull is the object), and over the
*occluded* ones: hidden by the mesh (the handle, the body) in at least one view
that would otherwise have been blended.

Run: ``python -m bench.bench_colour`` (``--quick`` for the small camera).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.meshing.colour import vertex_colours
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.render import render_image
from sfs_ros.core.segmentation.segment import segment
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan

from .timing import best_of, main

#: The cell's camera (config/rig.yaml) and, for --quick, the tests' smaller one.
RIGS = {"640x480": RigCalibration(width=640, height=480, projection="pinhole", fx=1400.0,
                                  fy=1400.0, camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04)),
        "320x240": RigCalibration(width=320, height=240, projection="pinhole", fx=700.0,
                                  fy=700.0, camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))}
PLAN = ring_plan([15.0, 40.0, 65.0], 16, top_view=True)
#: Surface samples for the nearest-point ground truth: ~0.25 mm apart on the mug,
#: well below a voxel (0.6 to 0.8 mm).
TRUTH_SAMPLES = 400_000


def mug_case(rig: RigCalibration, resolution: int) -> dict:
    """Scan, reconstruct and prepare the colouring inputs of the mug (see the module docstring)."""
    mug = make_object("mug")
    captures = simulate_scan(mug, rig, PLAN, seed=1)
    with tempfile.TemporaryDirectory() as folder:
        write_session(Path(folder) / "session", [(c.name, c.image) for c in captures],
                      [(c.theta_rad, c.phi_rad) for c in captures], rig,
                      bounds_m=carving_box(mug))
        views = load_views(Path(folder) / "session")
        result = reconstruct(views, ReconstructionParams(resolution=resolution))
    by_name = {c.name: c.image for c in captures}
    used = set(result.report["views"]["used"])
    cameras = [v.camera for v in views.views if v.name in used]
    shaded = [by_name[v.name] for v in views.views if v.name in used]
    true_colours = mug.color_at(mug.mesh.vertices)
    albedo = [render_image(mug.mesh.vertices, mug.mesh.faces, camera, vertex_colors=true_colours,
                           ambient=1.0, seed=n) for n, camera in enumerate(cameras)]
    samples = mug.sample_surface(TRUTH_SAMPLES, seed=0)
    distance_m, nearest = cKDTree(samples).query(result.vertices)
    return {"vertices": result.vertices, "faces": result.faces, "cameras": cameras,
            "masks": [segment(image).mask for image in shaded],
            "images": {"albedo": albedo, "shaded": shaded},
            "truth": mug.color_at(samples[nearest]).astype(np.float64),
            "on_surface": distance_m <= result.grid.voxel_size,
            "voxel_size_m": result.grid.voxel_size}


def colour_errors(case: dict, images: str) -> dict:
    """Per-vertex error figures (0..255) of the colouring with and without the z-buffer test."""
    out = {}
    runs = {occlusion: vertex_colours(case["vertices"], case["faces"], case["images"][images],
                                      case["cameras"], masks=case["masks"], occlusion=occlusion)
            for occlusion in (True, False)}
    occluded = runs[True].n_hidden > 0
    for occlusion, run in runs.items():
        error = np.abs(run.colours - case["truth"]).mean(axis=1)
        for subset, selected in (("all", slice(None)), ("seen", run.n_views > 0),
                                 ("on_surface", case["on_surface"] & (run.n_views > 0)),
                                 ("occluded", occluded)):
            key = f"{'zbuffer' if occlusion else 'normal_only'}_{subset}"
            out[key] = (float(error[selected].mean()), float(np.percentile(error[selected], 95)))
    out["fractions"] = {"seen": float(np.mean(runs[True].n_views > 0)),
                        "on_surface": float(case["on_surface"].mean()),
                        "occluded": float(occluded.mean())}
    return out


def run(quick: bool = False) -> list[dict]:
    """Time the colouring of the mug mesh; colour errors go in the notes.

    Returns rows ``{name, seconds, baseline_seconds, ratio, notes}``.
    """
    rig_name, resolution = ("320x240", 128) if quick else ("640x480", 192)
    case = mug_case(RIGS[rig_name], resolution)
    args = (case["vertices"], case["faces"], case["images"]["shaded"], case["cameras"])
    repeats = 2 if quick else 3
    seconds = best_of(lambda: vertex_colours(*args, masks=case["masks"]), repeats)
    baseline = best_of(lambda: vertex_colours(*args, masks=case["masks"], occlusion=False),
                       repeats)
    notes = []
    for images in ("albedo", "shaded"):
        e = colour_errors(case, images)
        f = e["fractions"]
        notes.append(
            f"colour {rig_name} mug, {images} images, |RGB error| per vertex mean/p95 (0..255): "
            + ", ".join(f"{subset} {e[f'zbuffer_{subset}'][0]:.2f}/{e[f'zbuffer_{subset}'][1]:.2f}"
                        for subset in ("all", "seen", "on_surface", "occluded"))
            + f"; normal-only baseline: seen {e['normal_only_seen'][0]:.2f}/"
              f"{e['normal_only_seen'][1]:.2f}, occluded {e['normal_only_occluded'][0]:.2f}/"
              f"{e['normal_only_occluded'][1]:.2f} (vertices: seen {100 * f['seen']:.0f}%, "
              f"on surface {100 * f['on_surface']:.0f}%, occluded {100 * f['occluded']:.1f}%)")
    return [{"name": f"colour mug {len(case['vertices'])} vertices, {len(case['cameras'])} "
                     f"views {rig_name}", "seconds": seconds, "baseline_seconds": baseline,
             "ratio": baseline / seconds, "notes": notes}]


if __name__ == "__main__":
    main(__doc__, run, quick_help="the small camera, fewer repeats")
