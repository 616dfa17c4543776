"""Which of the views the consensus cuts again change the mesh.

For each input, ``reconstruct`` with its defaults but the refinement below the hull; then,
for each view the consensus cut again, the same reconstruction with that one view's
re-cut undone (the consensus stage's masks, that view's first mask put back; every other
stage runs as it does), and once with every re-cut undone. A row's note says how many
re-cuts left the mesh the same (vertices and faces equal), how many changed the hull
(voxels) and the mesh's score with each and with none.

Beside it, a test a view could be spared its cut by, judged against what the cuts did:
a view's re-cut can grow the hull only where the hull of the views that keep their masks
(the settled ones) reaches beyond its mask. A view is called spared when that hull's
projection reaches beyond its first mask by no more than the consensus's own tolerance
(:func:`~sfs_ros.core.segmentation.consensus.settled`, told about the mask near the
projection only: what the re-cut could take away is not counted, so it spares at least
as many views as a test that counted it would). The note gives the views it spares, whether
any of them changed the mesh, and what the test costs.

The inputs: the Middlebury rings when they lie beside the repository (scored against the
README recipe's masks), the chair of ``bench_reconstruct`` (100 views of 800 x 800) and
its mug from the cell's camera (48 views of 640 x 480), and the hostile hemisphere of
``test/test_hostile_hemisphere.py`` on black and white (both scored against the exact
silhouettes). ``--quick``: the 48-view mug alone.

Run: ``python -m bench.bench_consensus``.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path
from unittest import mock

import cv2
import numpy as np

from sfs_ros.core import pipeline
from sfs_ros.core.carving.carve import carve
from sfs_ros.core.carving.consistency import hull_silhouettes
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.middlebury import read_middlebury, readme_mask
from sfs_ros.core.exchange.views import View, ViewSet, read_image
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.metrics import reprojection_ious
from sfs_ros.core.pipeline import ReconstructionParams
from sfs_ros.core.segmentation.consensus import settled
from sfs_ros.core.simulation.hostile import simulate_hostile_scan
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import exact_silhouettes
from sfs_ros.core.stages import Resegmented, UsedViews, fusion_grid, resegment_views

from .bench_reconstruct import CELL_RIG, MIDDLEBURY, RINGS, square_rig, write_scan
from .timing import main

#: The hostile hemisphere's camera and plan (as test/test_hostile_hemisphere.py's).
HOSTILE_RIG = RigCalibration(width=640, height=480, projection="pinhole", fx=1300.0, fy=1300.0,
                             camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))
HOSTILE_PLAN = ring_plan([15.0, 35.0, 55.0, 75.0], 12)


class _Consensus:
    """Stands in for ``pipeline.resegment_views``: the first call runs it and keeps what it
    gave (and the views' first masks); every call returns that, with the views in
    ``undone`` (indices into the used views) given back their first masks."""

    def __init__(self):
        self.kept = None
        self.undone: tuple[int, ...] = ()

    def __call__(self, segmented, used, grid, params):
        if self.kept is None:
            start = time.perf_counter()
            again = resegment_views(segmented, used, grid, params)
            self.kept = (segmented, used, grid, again, time.perf_counter() - start)
        first_segmented, first, _, again, _ = self.kept
        if not self.undone:
            return again
        views = again.segmented.views
        masks, used_masks = list(again.segmented.masks), list(again.used.masks)
        taken = dict(again.segmented.taken)
        for n in self.undone:
            i = first.indices[n]
            masks[i] = used_masks[n] = first.masks[n]
            taken[views[i].name] = first_segmented.taken[views[i].name]
        return Resegmented(replace(again.segmented, masks=masks, taken=taken),
                           UsedViews.of(views, first.indices, used_masks), again.report)


def spared_by_the_settled_hull(used: UsedViews, grid, cut: list[int]) -> list[int]:
    """The views of ``cut`` whose first mask, where it lies within a pixel of the projection
    of the hull the other views (those not cut) carve on the consensus's grid (the
    fusion's: :func:`~sfs_ros.core.stages.fusion_grid`), is :func:`settled` on it."""
    keep = [n for n in range(len(used.cameras)) if n not in cut]
    if not keep or not cut:
        return []
    coarse = fusion_grid(np.array([grid.bounds_min, grid.bounds_max]), grid)
    hull = carve(coarse, [used.cameras[n] for n in keep], [used.masks[n] for n in keep])
    projections, footprint = hull_silhouettes(coarse, hull, [used.cameras[n] for n in cut])
    near = np.ones((3, 3), np.uint8)
    return [n for n, p, f in zip(cut, projections, footprint)
            if settled(p, used.masks[n] & (cv2.dilate(p.view(np.uint8), near) > 0), f)]


def study(name: str, view_set: ViewSet, score) -> dict:
    """The row of one input: ``score(vertices, faces)`` -> (n,) IoU per view."""
    consensus = _Consensus()
    params = ReconstructionParams(refine=False)
    with mock.patch.object(pipeline, "resegment_views", consensus):
        result = pipeline.reconstruct(view_set, params)
        _, used, grid, again, consensus_s = consensus.kept
        cut = [n for n, view in enumerate(again.report["per_view"]) if view["resegmented"]]
        same, voxels, scores = [], [], []
        for n in cut:
            consensus.undone = (n,)
            other = pipeline.reconstruct(view_set, params)
            same.append(np.array_equal(other.vertices, result.vertices)
                        and np.array_equal(other.faces, result.faces))
            voxels.append(int(np.count_nonzero(other.occupancy != result.occupancy)))
            scores.append(float(np.mean(score(other.vertices, other.faces))))
        consensus.undone = tuple(cut)
        none = pipeline.reconstruct(view_set, params)
    start = time.perf_counter()
    spared = spared_by_the_settled_hull(used, grid, cut)
    test_s = time.perf_counter() - start
    ious = score(result.vertices, result.faces)
    changed = [n for n, s in zip(cut, same) if not s]
    moved = sorted(abs(s - float(np.mean(ious))) for s, kept in zip(scores, same) if not kept)
    voxels = sorted(v for v, kept in zip(voxels, same) if not kept)
    return {"name": f"consensus of {name}: {len(cut)} of {len(used.cameras)} views cut again",
            "seconds": consensus_s, "baseline_seconds": None, "ratio": None,
            "notes": [f"{name}: {len(cut) - len(changed)} of {len(cut)} re-cuts left the mesh "
                      f"the same; undone one at a time, the others changed the hull by "
                      f"{voxels[0] if voxels else 0}-{voxels[-1] if voxels else 0} voxels and the "
                      f"score by {moved[0] if moved else 0:.1e}-{moved[-1] if moved else 0:.1e}; "
                      f"score {np.mean(ious):.4f} (worst {np.min(ious):.4f}), every re-cut undone "
                      f"{np.mean(score(none.vertices, none.faces)):.4f}; the settled hull of "
                      f"the views not cut spares {len(spared)} "
                      f"({len(set(spared) & set(changed))} of them changed the mesh) in "
                      f"{test_s:.2f} s"]}


def middlebury_rows() -> list[dict]:
    rows = []
    for par, threshold in RINGS:
        if (MIDDLEBURY / par).is_file():
            view_set = read_middlebury(MIDDLEBURY / par)
            cameras = [v.camera for v in view_set.views]
            references = [readme_mask(read_image(v.image_path), threshold)
                          for v in view_set.views]
            rows.append(study(Path(par).parent.name, view_set,
                              lambda v, f, c=cameras, r=references: reprojection_ious(v, f, c, r)))
    return rows


def rendered_row(name: str, rig: RigCalibration, per_ring: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        session, obj = write_scan(Path(tmp), name, rig, per_ring)
        view_set = load_views(session)
        cameras = [v.camera for v in view_set.views]
        references = exact_silhouettes(obj, cameras)
        return study(f"{name} {len(cameras)} x {rig.width}x{rig.height}", view_set,
                     lambda v, f: reprojection_ious(v, f, cameras, references))


def hostile_row(backdrop: str) -> dict:
    captures = simulate_hostile_scan(make_object("mug"), HOSTILE_RIG, HOSTILE_PLAN,
                                     backdrop=backdrop, seed=3)
    cameras = [c.camera for c in captures]
    with tempfile.TemporaryDirectory() as tmp:
        views = []
        for c in captures:
            cv2.imwrite(str(Path(tmp) / c.name), cv2.cvtColor(c.image, cv2.COLOR_RGB2BGR))
            views.append(View(c.name, Path(tmp) / c.name, c.camera))
        return study(f"hostile hemisphere on {backdrop}", ViewSet(views=views, source="session"),
                     lambda v, f: reprojection_ious(v, f, cameras,
                                                    [c.object_mask for c in captures]))


def run(quick: bool = False) -> list[dict]:
    if quick:
        return [rendered_row("mug", CELL_RIG, 12)]
    return middlebury_rows() + [rendered_row("chair", square_rig(800), 25),
                                rendered_row("mug", CELL_RIG, 12),
                                hostile_row("black"), hostile_row("white")]


if __name__ == "__main__":
    main(__doc__, run, quick_help="the 48-view mug alone")
