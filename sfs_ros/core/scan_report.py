"""The report of a reconstruction, assembled from the pieces its stages return.

:func:`carving_report` is the carving half's (:func:`sfs_ros.core.pipeline.carve_scan`),
:func:`meshing_report` adds the meshing half's (:func:`sfs_ros.core.mesh_scan.mesh_scan`).
The report is JSON-ready; its keys are documented in ``doc/reconstruct.md``.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import TYPE_CHECKING

import numpy as np

from .carving.carve import unpack_bits
from .metrics import silhouette_iou

if TYPE_CHECKING:
    from .carved_scan import CarvedScan
    from .stages import Fused, GridChoice, Hull, Segmented, UsedViews

__all__ = ["SILHOUETTE_IOU_MEANING", "carving_report", "meshing_report", "per_view_ious",
           "silhouette_iou_section"]

#: What the report's silhouette IoU is, written into every report beside it.
SILHOUETTE_IOU_MEANING = (
    "IoU of the mesh's silhouette, drawn into each view, with the mask this reconstruction "
    "made from that view's image. For 'used' views it is agreement with the masks that "
    "carved the mesh (high by construction, not a measure of accuracy); for 'held-out' views "
    "(not carved with) it is a leave-one-out prediction; 'rejected' views show how far off "
    "their masks were. Accuracy needs references the reconstruction did not make.")


def carving_report(*, source: str, n_views: int, params, mesher_options: dict,
                   segmentation, box: GridChoice, segmented: Segmented, used: UsedViews,
                   rejected: list[dict], resegmentation: dict | None, fused: Fused,
                   hull: Hull, timings: dict[str, float]) -> dict:
    """The carving half's report: the input (its ``source`` and ``n_views``), the
    parameters (``params``, a ReconstructionParams, with the mesher's options and the
    ``segmentation`` parameters used), the grid, the views' fates and each stage's piece,
    its stage times under ``timings_s``."""
    return {
        "input": {"source": source, "views": n_views},
        "parameters": {
            **{k: v for k, v in asdict(params).items() if k != "segmentation"},
            "mesher_options": mesher_options,
            "segmentation": asdict(segmentation),
        },
        "grid": box.report,
        "views": {"used": used.names(segmented.views), "held_out": list(params.holdout),
                  "rejected": rejected, "clipped_by_bounds": box.clipped},
        "backdrop": segmented.backdrop,
        "resegmentation": resegmentation,
        "consistency": fused.consistency,
        "fusion": fused.report,
        "refinement": hull.refinement,
        "occupied_voxels": int(hull.occupancy.sum()),
        "specks_removed": hull.specks_removed,
        "timings_s": timings,
    }


def per_view_ious(carved: CarvedScan, evaluated: list[int], evaluated_ious: list,
                  coverage: list | None) -> list[dict]:
    """The report's per-view silhouette IoU: the views ``evaluated`` (indices into
    ``carved.views``) have their IoU in ``evaluated_ious``; the coloured views' silhouettes of
    the mesh came with the colour's z-buffers (``coverage``, packed bits, the same
    pixel-centre rule); both agree with drawing every face, exact ties on the outline
    aside. A view in neither (its drawing left for later) has None."""
    ious: list = [None] * len(carved.views)
    for i, iou in zip(evaluated, evaluated_ious):
        ious[i] = float(iou)
    for i, packed in zip(carved.colour_views, coverage or []):
        mask = carved.masks[i]
        ious[i] = float(silhouette_iou(
            unpack_bits(packed, mask.shape), mask))
    return [{"view": view.name, "role": view.role, "silhouette_iou": iou}
            for view, iou in zip(carved.views, ious)]


def _mean_iou(per_view: list, role: str) -> float | None:
    """The mean IoU of the views of ``role``; None when there are none, or one is not drawn
    yet."""
    values = [p["silhouette_iou"] for p in per_view if p["role"] == role]
    return float(np.mean(values)) if values and None not in values else None


def silhouette_iou_section(per_view: list[dict]) -> dict:
    """The report's ``silhouette_iou``: its meaning, ``per_view`` and the means of the used
    and held-out views."""
    return {"meaning": SILHOUETTE_IOU_MEANING, "per_view": per_view,
            "mean_used": _mean_iou(per_view, "used"),
            "mean_held_out": _mean_iou(per_view, "held-out")}


def meshing_report(carving: dict, *, mesher: str, mesher_stats: dict, mesh_checks: dict,
                   colour_stats: dict | None, per_view: list[dict],
                   timings: dict[str, float]) -> dict:
    """The whole report: the carving half's (``carving``), then the mesher's statistics,
    the mesh checks, the colour's statistics (when coloured) and the silhouette IoU per
    view; the stage times of both halves under ``timings_s``."""
    head = {k: v for k, v in carving.items() if k != "timings_s"}
    return {
        **head,
        "mesher": {"name": mesher, **mesher_stats},
        "mesh": mesh_checks,
        **({"colour": colour_stats} if colour_stats is not None else {}),
        "silhouette_iou": silhouette_iou_section(per_view),
        "timings_s": {**carving.get("timings_s", {}), **timings},
    }
