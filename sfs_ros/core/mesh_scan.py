"""The meshing half of a reconstruction: a carved scan in, a checked mesh and a report out.

Stages (each timed in the report): meshing (the mesher's second half), mesh
checks, colour (when the carving chose views to colour from), reprojection of
the mesh into every view (the evaluation; of the views used and rejected, it may be left
for after the mesh is answered: :func:`mesh_scan`'s ``defer_evaluation``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from .carved_scan import CarvedScan
from .geometry.grid import VoxelGrid
from .meshing.colour import vertex_colours
from .meshing.mesh_checks import check_mesh
from .meshing.meshers import mesher
from .metrics import reprojection_ious
from .outline import edge_faces
from .scan_report import meshing_report, per_view_ious, silhouette_iou_section

__all__ = ["Reconstruction", "mesh_scan", "timed"]


@dataclass
class Reconstruction:
    """What :func:`mesh_scan` (and :func:`sfs_ros.core.pipeline.reconstruct`) return.

    vertices : (n, 3) float64, metres, object frame; faces : (m, 3) int64,
    outward; occupancy : (nx, ny, nz) bool on ``grid``; report : JSON-ready dict;
    vertex_colors : (n, 3) uint8 RGB when coloured, else None;
    masks : {view name: (H, W) bool} silhouette of every view read and segmented, as taken
        (through the lens; carving used it undistorted, :mod:`.geometry.lens`).
    evaluation_due : with :func:`mesh_scan`'s ``defer_evaluation``, the drawing of the views
        left out of the evaluation (called once, no arguments: it completes ``report``'s
        ``silhouette_iou`` and its ``evaluation`` time in place); else None.
    """

    vertices: np.ndarray
    faces: np.ndarray
    occupancy: np.ndarray
    grid: VoxelGrid
    report: dict = field(default_factory=dict)
    vertex_colors: np.ndarray | None = None
    masks: dict = field(default_factory=dict)
    evaluation_due: Callable[[], None] | None = None


@contextmanager
def timed(seconds: dict[str, float], stage: str):
    """Add the wall time of the ``with`` block to ``seconds[stage]``."""
    start = time.perf_counter()
    try:
        yield
    finally:
        seconds[stage] = seconds.get(stage, 0.0) + time.perf_counter() - start


class _Finish:
    """Colour, checks and evaluation of one mesh, overlapped: the colour blends its views
    (both cores), then fills the vertices no view sees (one core) beside the checks and
    then the evaluation (both cores), which wait for the views to be blended; with no
    colour, the checks run beside the evaluation. A mesh closed by construction has its
    edges paired once (:func:`.outline.edge_faces`, :attr:`edges`), for the checks and the
    evaluation both. With
    ``defer``, the evaluation draws only the held-out views (:attr:`deferred`: the others
    it does not draw)."""

    def __init__(self, carved: CarvedScan, vertices, faces, timings: dict, progress,
                 defer: bool = False):
        self.carved, self.vertices, self.faces = carved, vertices, faces
        self.timings, self.progress = timings, progress
        coloured = set(carved.colour_views)
        # The colour draws its views' silhouettes of the mesh with its z-buffers; the
        # others are drawn for the evaluation.
        drawn = [i for i in range(len(carved.views)) if i not in coloured]
        self.evaluated = [i for i in drawn if not defer or carved.views[i].role == "held-out"]
        self.deferred = sorted(set(drawn) - set(self.evaluated))
        self.colour_views_blended = threading.Event()
        self.edges = None

    def colour(self, closed: bool):
        carved = self.carved
        with timed(self.timings, "colour"):
            self.progress("colour", 0.0)
            try:
                found = vertex_colours(
                    self.vertices, self.faces, carved.colour_images,
                    [carved.views[i].camera for i in carved.colour_views],
                    masks=carved.colour_masks, coverage=True, closed=closed,
                    on_blended=self.colour_views_blended.set) if carved.colour_views else None
            finally:
                self.colour_views_blended.set()
            self.progress("colour", 1.0)
        return found

    def evaluate(self, closed: bool, views: list[int] | None = None) -> list:
        """The silhouette IoU of ``views`` (indices; None: :attr:`evaluated`), once the
        colour's views are blended."""
        self.colour_views_blended.wait()
        carved, views = self.carved, self.evaluated if views is None else views
        with timed(self.timings, "evaluation"):
            return reprojection_ious(self.vertices, self.faces,
                                     [carved.views[i].camera for i in views],
                                     [carved.masks[i] for i in views], closed=closed,
                                     edges=self.edges if closed else None) if views else []

    def checks(self) -> dict:
        with timed(self.timings, "mesh_checks"):
            return check_mesh(self.vertices, self.faces, edges=self.edges).as_dict()

    def run(self, closed_by_construction: bool) -> tuple[dict, object, list]:
        """``(mesh report, colours or None, silhouette IoU of the evaluated views)``.

        A mesh closed by construction has its checks run beside the colour and the
        evaluation, which count on a closed mesh for half their drawing (should the
        checks find it otherwise, both are done again, the same as one after the
        other): on the evaluation's thread before it while the colour fills its unseen
        vertices, or with no colour on this thread while the evaluation runs. Another
        mesher's mesh is checked first."""
        if closed_by_construction:
            with timed(self.timings, "mesh_checks"):
                self.edges = edge_faces(self.faces, len(self.vertices))
        given = None if closed_by_construction else self.checks()
        expect_closed = True if given is None else bool(given["watertight"]
                                                        and given["outward"])
        checks_here = given is None and not self.carved.colour_views

        def checks_then_evaluate(closed: bool):
            self.colour_views_blended.wait()
            checked = None if given is not None or checks_here else self.checks()
            return checked, self.evaluate(closed)

        with ThreadPoolExecutor(max_workers=1) as side:
            checks_and_evaluation = side.submit(checks_then_evaluate, expect_closed)
            try:
                colours, failure = self.colour(expect_closed), None
            except ValueError as exc:   # an error of a wrong guess is no error: see below
                colours, failure = None, exc
            checked_here = self.checks() if checks_here else None
            checked_there, ious = checks_and_evaluation.result()
        report = given or checked_here or checked_there
        closed = bool(report["watertight"] and report["outward"])
        if closed != expect_closed:
            colours = self.colour(closed)
            ious = self.evaluate(closed)
        elif failure is not None:
            raise failure
        return report, colours, ious


def mesh_scan(carved: CarvedScan, *, progress=None,
              defer_evaluation: bool = False) -> Reconstruction:
    """Mesh, check, colour and evaluate a carved scan; the report joins the carving's.

    ``progress``: (stage name, fraction done) callback. ``defer_evaluation``: the silhouette
    IoU of the views used and rejected (those the colour does not draw are drawn then) is
    made by the result's ``evaluation_due``, not now (it, and the mean of the used views,
    are None in the report until then); the held-out views are drawn now. Raises
    ``ValueError`` with a one-line reason when the mesher cannot mesh the input.
    """
    progress = progress or (lambda stage, fraction: None)
    timings: dict[str, float] = {}
    chosen = mesher(carved.mesher)
    with timed(timings, "meshing"):
        progress("meshing", 0.0)
        vertices, faces, mesher_stats = chosen.mesh(carved.occupancy, carved.grid,
                                                    carved.mesher_input)
        progress("meshing", 1.0)
    finish = _Finish(carved, vertices, faces, timings, progress, defer=defer_evaluation)
    mesh_report, colours, evaluated_ious = finish.run(chosen.closed)
    coverage = None if colours is None else colours.coverage
    deferred = defer_evaluation and bool(finish.deferred or coverage)
    with timed(timings, "evaluation"):
        progress("evaluation", 0.0)
        per_view = per_view_ious(carved, finish.evaluated, evaluated_ious,
                                 None if deferred else coverage)
        progress("evaluation", 1.0)
    report = meshing_report(carved.report, mesher=carved.mesher, mesher_stats=mesher_stats,
                            mesh_checks=mesh_report,
                            colour_stats=None if colours is None else colours.stats,
                            per_view=per_view, timings=timings)
    result = Reconstruction(vertices=vertices, faces=faces, occupancy=carved.occupancy,
                            grid=carved.grid, report=report,
                            vertex_colors=None if colours is None else colours.colours,
                            masks=carved.taken)
    if deferred:
        closed = bool(mesh_report["watertight"] and mesh_report["outward"])

        def evaluate_deferred() -> None:
            result.evaluation_due = None
            views = finish.evaluated + finish.deferred
            ious = [*evaluated_ious, *finish.evaluate(closed, finish.deferred)]
            with timed(timings, "evaluation"):
                per_view_all = per_view_ious(carved, views, ious, coverage)
            report["silhouette_iou"] = silhouette_iou_section(per_view_all)
            report["timings_s"]["evaluation"] = timings["evaluation"]

        result.evaluation_due = evaluate_deferred
    return result
