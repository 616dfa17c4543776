"""The meshing half of the cell: a carved scan in, the mesh, its report and pictures written.

Used by the meshing node on a carved scan it received from the carving node, and
by :meth:`sfs_ros.cell_logic.live_reconstruction.LiveReconstruction.reconstruct` on one it carved
itself: the same files either way. Output names (inside the output folder)::

    <name>.ply            # the mesh (.ply, .obj, .stl or .glb), default <scan name>.ply
    <stem>.report.json    # the report
    <stem>.png            # a picture of the mesh,
    <stem>.html           # a page that shows it in a browser (no network needed),
    <stem>.views.png      # and a contact sheet of the views (mask outline, angles, IoU)
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from ..core.carved_scan import CarvedScan
from ..core.exchange.export import SUPPORTED_SUFFIXES
from ..core.mesh_scan import Reconstruction, mesh_scan
from ..core.result_files import SheetViews, add_pictures, write_result
from .paths import confined_path

__all__ = ["THUMBNAIL_PX", "HandOver", "MeshFiles", "mask_to_rgb", "mesh_paths", "thumbnail",
           "write_mesh"]


#: Widest thumbnail of a view's image for the contact sheet (its tiles are 200 pixels).
THUMBNAIL_PX = 256


@dataclass(frozen=True)
class HandOver:
    """What comes with a carved scan besides the carving: the scan's ``scan_name`` (its
    session folder's), that ``session_dir`` (on the carving side's host), the
    ``views_received``, the ``frame_id`` of the grid and cameras, and ``thumbnails``:
    {view name: (h, w, 3) uint8 RGB}, the views' captured images scaled down
    (:func:`thumbnail`) for the contact sheet."""

    scan_name: str
    session_dir: str
    views_received: int
    frame_id: str = ""
    thumbnails: dict = field(default_factory=dict)


def thumbnail(rgb: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8: ``rgb`` scaled down to at most :data:`THUMBNAIL_PX` wide."""
    height, width = rgb.shape[:2]
    if width <= THUMBNAIL_PX:
        return rgb
    size = (THUMBNAIL_PX, max(1, round(height * THUMBNAIL_PX / width)))
    return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)


@dataclass(frozen=True)
class MeshFiles:
    """What :func:`write_mesh` made: ``summary`` (JSON-ready, see :func:`write_mesh`),
    the ``result``, and ``pictures_due``: a callable that, when they were deferred, draws
    the views the evaluation left, writes the pictures, then the report again, naming them
    with the views' silhouette IoU complete (OSError if they cannot be written), else
    None."""

    summary: dict
    result: Reconstruction
    pictures_due: object = None


def mask_to_rgb(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool -> (H, W, 3) uint8 image: object 255, background 0."""
    return np.repeat(np.where(mask, np.uint8(255), np.uint8(0))[:, :, None], 3, axis=2)


def mesh_paths(output_dir, name: str) -> dict[str, Path]:
    """The files of a mesh called ``name`` in ``output_dir`` (:func:`.paths.confined_path`
    says what is refused): ``mesh``, ``report``, ``preview``, ``html``, ``contact_sheet``."""
    root = Path(output_dir).resolve()
    path = confined_path(root, name, suffixes=SUPPORTED_SUFFIXES)
    report_name = path.relative_to(root).with_name(path.stem + ".report.json").as_posix()
    stem = report_name[:-len(".report.json")]
    return {"mesh": path,
            "report": confined_path(root, report_name, suffixes=(".json",)),
            "preview": confined_path(root, stem + ".png", suffixes=(".png",)),
            "html": confined_path(root, stem + ".html", suffixes=(".html",)),
            "contact_sheet": confined_path(root, stem + ".views.png", suffixes=(".png",))}


def _sheet_views(carved: CarvedScan, thumbnails: dict) -> SheetViews:
    """Every segmented view: its thumbnail, else its image where the carved scan has one
    (the views that colour the mesh), else its mask; its mask and angles."""
    images = dict(zip(carved.colour_views, carved.colour_images))

    def image(i: int, name: str, mask: np.ndarray) -> np.ndarray:
        if name in thumbnails:
            return thumbnails[name]
        return images[i] if i in images else mask_to_rgb(mask)

    return SheetViews(names=[v.name for v in carved.views],
                      images=[image(i, v.name, m)
                              for i, (v, m) in enumerate(zip(carved.views, carved.masks))],
                      masks=list(carved.masks), angles_rad=[v.angles_rad for v in carved.views])


def _finite(value) -> float | None:
    return None if value is None or math.isnan(value) else float(value)


def write_mesh(carved: CarvedScan, hand_over: HandOver, output_dir, name: str | None = None,
               *, pictures: bool = True, sheet_views: SheetViews | None = None) -> MeshFiles:
    """Mesh ``carved`` (:func:`sfs_ros.core.mesh_scan.mesh_scan`) and write the files.

    Parameters
    ----------
    name : str or None
        Mesh file name inside ``output_dir``; None: ``<scan name>.ply``. Existing files
        are replaced.
    pictures : bool, keyword-only
        Write the picture, viewer and contact sheet now; False: only the mesh and its
        report, the pictures when ``pictures_due`` is called, which first draws the mesh
        into the views the colour did not draw and that were not held out (their
        silhouette IoU in the report, and the summary's ``silhouette_iou_mean``, are None
        until then: :func:`sfs_ros.core.mesh_scan.mesh_scan`'s ``defer_evaluation``).
    sheet_views : SheetViews or None, keyword-only
        The contact sheet's views; None: those of ``carved`` with ``hand_over``'s
        thumbnails (else the images it carries, else the masks).

    Returns
    -------
    MeshFiles
        Its ``summary``: ``path``, ``report_path``, ``preview_path``, ``html_path``,
        ``contact_sheet_path``, ``session``, ``views_received``, ``views_used``,
        ``views_rejected`` (list of ``{view, reason}``), ``n_vertices``, ``n_faces``,
        ``watertight``, ``volume_m3``, ``area_m2``, ``silhouette_iou_mean``,
        ``holdout_iou`` (None: no views held out), ``voxel_size_m``,
        ``coloured_from_views``, ``seconds``.

    Raises ValueError (a refused name, a mesh that cannot be made) or OSError.
    """
    start = time.perf_counter()
    paths = mesh_paths(output_dir, name or f"{hand_over.scan_name}.ply")
    root = Path(output_dir).resolve()
    result = mesh_scan(carved, defer_evaluation=not pictures)
    colours = result.vertex_colors
    picture_files = dict(preview=paths["preview"], html=paths["html"],
                         contact_sheet=paths["contact_sheet"])

    def views_shown() -> SheetViews:   # made when the pictures are (after the answer)
        return sheet_views or _sheet_views(carved, hand_over.thumbnails)

    written = write_result(result, paths["mesh"], vertex_colors=colours, report=paths["report"],
                           extra={"session": hand_over.session_dir}, within=root,
                           **(dict(picture_files, sheet_views=views_shown()) if pictures
                              else {}))

    def pictures_due() -> None:   # after the answer: the evaluation left, then the pictures
        if result.evaluation_due is not None:
            result.evaluation_due()
        add_pictures(replace(written, document={**written.document, **result.report}), result,
                     vertex_colors=colours, within=root, sheet_views=views_shown(),
                     **picture_files)

    due = None if pictures else pictures_due
    report = result.report
    mesh, views = report["mesh"], report["views"]
    summary = {"path": str(paths["mesh"]), "report_path": str(paths["report"]),
               "preview_path": str(paths["preview"]), "html_path": str(paths["html"]),
               "contact_sheet_path": str(paths["contact_sheet"]),
               "session": hand_over.session_dir, "views_received": hand_over.views_received,
               "views_used": len(views["used"]), "views_rejected": views["rejected"],
               "n_vertices": mesh["n_vertices"], "n_faces": mesh["n_faces"],
               "watertight": mesh["watertight"], "volume_m3": mesh["volume_m3"],
               "area_m2": mesh["area_m2"],
               "silhouette_iou_mean": _finite(report["silhouette_iou"]["mean_used"]),
               "holdout_iou": _finite(report["silhouette_iou"]["mean_held_out"]),
               "voxel_size_m": result.grid.voxel_size,
               "coloured_from_views": report["colour"]["views"] if "colour" in report else 0,
               "seconds": time.perf_counter() - start}
    return MeshFiles(summary=summary, result=result, pictures_due=due)
