"""A reconstruction's files: the mesh, its report, and on request pictures of it.

:func:`write_result` writes, for a :class:`~sfs_ros.core.pipeline.Reconstruction`:

* the mesh (format from the suffix: .ply, .obj, .stl, .glb; vertex colours
  when given; with a texture, a textured .glb, or .obj with its .mtl and .png), and
  beside it ``<stem>.report.json``: ``output`` (the mesh's
  path), ``units``, the caller's extra entries, the pipeline's report, and
  ``preview`` / ``html`` / ``contact_sheet`` (paths of those written);
* on request a PNG picture of the mesh, a self-contained HTML viewer, and a
  contact sheet of the views (mask outlines, angles, silhouette IoU, reasons
  for rejection); or later, by :func:`add_pictures`, for a caller that wants
  the mesh out first (in the cell the pictures take a good part of a reconstruction).

Every file is written atomically, all in one batch
(:func:`sfs_ros.core.exchange.files.write_atomic_all`): all are staged on disk
first (a failure or an interruption then changes nothing), then the old report
is removed, the mesh renamed into place, the pictures, and the report last. A
report therefore never describes a mesh that is not there: if the mesh cannot
be renamed into place (its name is a folder, say) the old report is gone and
nothing new is written; and the report names only pictures that exist. (A
reader that finds the new mesh may find no report yet.)
With ``within``, no symbolic link below that folder is followed while writing.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

from .exchange.export import mesh_bytes, textured_mesh_files
from .exchange.files import write_atomic_all
from .pictures.contact_sheet import contact_sheet
from .pictures.html_viewer import html_viewer
from .pictures.preview import png_bytes, preview_image

__all__ = ["SheetViews", "WrittenResult", "add_pictures", "report_path_for", "write_result"]

REPORT_SUFFIX = ".report.json"


@dataclass(frozen=True)
class SheetViews:
    """The views a contact sheet shows, in order (k views).

    names : k str, the views' names as in the report; images : k of (H, W, 3)
    uint8 RGB or None (a grey tile); masks : k of (H, W) bool or None;
    angles_rad : k of (theta, phi) or None; reasons : {name: str}, rejection
    reasons that replace the report's (e.g. shortened), optional.
    """

    names: list
    images: list
    masks: list
    angles_rad: list
    reasons: dict = field(default_factory=dict)

    def __post_init__(self):
        k = len(self.names)
        if not len(self.images) == len(self.masks) == len(self.angles_rad) == k:
            raise ValueError(f"contact sheet views need as many images, masks and angles as "
                             f"names ({k}), got {len(self.images)}, {len(self.masks)}, "
                             f"{len(self.angles_rad)}")


@dataclass(frozen=True)
class WrittenResult:
    """What :func:`write_result` wrote: the paths (None for a file not asked for) and the
    report document (the JSON written, as a dict)."""

    mesh: Path
    report: Path
    preview: Path | None
    html: Path | None
    contact_sheet: Path | None
    document: dict


def report_path_for(mesh_path) -> Path:
    """``<stem>.report.json`` beside the mesh ``mesh_path``."""
    mesh_path = Path(mesh_path)
    return mesh_path.with_name(mesh_path.stem + REPORT_SUFFIX)


def write_result(result, mesh_path, *, units: str = "m", vertex_colors=None,
                 report=None, extra: dict | None = None, preview=None, html=None,
                 contact_sheet=None, sheet_views: SheetViews | None = None,
                 within=None, textured=None) -> WrittenResult:
    """Write a reconstruction's mesh, its report and the pictures asked for.

    Parameters
    ----------
    result : sfs_ros.core.pipeline.Reconstruction
        Its ``vertices`` (n, 3) float64 metres, ``faces`` (m, 3) int and ``report``.
    mesh_path : path-like
        The mesh file, a suffix of :data:`.exchange.export.MESH_FORMATS`; missing folders are created
        (for every file written).
    units : {"m", "mm"}, keyword-only
        Length unit of the mesh file.
    vertex_colors : (n, 3|4) uint8 or None
        Colours of the mesh's vertices, also used by the preview and the viewer.
    report : path-like or None
        The report; None: :func:`report_path_for` of ``mesh_path``.
    extra : dict or None
        Entries of the report placed after ``output`` and ``units`` (JSON-ready).
    preview, html, contact_sheet : path-like or None
        PNG picture of the mesh, HTML viewer, contact sheet PNG; None: not written.
    sheet_views : SheetViews or None
        The views on the contact sheet; required with ``contact_sheet``.
    within : path-like or None
        A folder every file must lie in, written without following links below
        it (:func:`~sfs_ros.core.exchange.files.write_atomic_all`).
    textured : sfs_ros.core.texture.TexturedMesh or None
        The mesh with its texture: written instead of ``result``'s mesh (.glb or .obj,
        :func:`~sfs_ros.core.exchange.export.textured_mesh_files`); the viewer shows the
        texture, the preview the texture's colour at each vertex; the report gains
        ``texture`` (its figures) and ``texture_files``.

    Returns
    -------
    WrittenResult

    Raises
    ------
    ValueError
        A mesh path or units the mesh cannot be written with, colours an .stl
        cannot hold, or a contact sheet without its views; nothing is written.
    OSError
        A file could not be written: staged, the mesh and report stay as they were;
        the mesh not renamed into place, no report is left beside it.
    """
    if contact_sheet is not None and sheet_views is None:
        raise ValueError("a contact sheet needs sheet_views: the images and masks it shows")
    mesh_path = Path(mesh_path)
    report_path = report_path_for(mesh_path) if report is None else Path(report)
    if textured is None:
        meshes = [(mesh_path, mesh_bytes(result.vertices, result.faces, mesh_path,
                                         vertex_colors=vertex_colors, units=units))]
    else:
        meshes = textured_mesh_files(textured, mesh_path, units=units)
    document = {"output": str(mesh_path), "units": units, **(extra or {}), **result.report}
    if textured is not None:
        document.update(texture=textured.stats, texture_files=[str(p) for p, _ in meshes])
    pictures = _pictures(result, mesh_path, vertex_colors, preview, html, contact_sheet,
                         sheet_views, textured)
    document.update({key: str(path) for key, (path, _) in pictures.items()})
    files = [(report_path, None), *meshes, *pictures.values(),
             (report_path, json.dumps(document, indent=2).encode("utf-8"))]
    _write(files, within)
    return WrittenResult(mesh=mesh_path, report=report_path,
                         preview=pictures.get("preview", (None,))[0],
                         html=pictures.get("html", (None,))[0],
                         contact_sheet=pictures.get("contact_sheet", (None,))[0],
                         document=document)


def add_pictures(written: WrittenResult, result, *, vertex_colors=None, preview=None,
                 html=None, contact_sheet=None, sheet_views: SheetViews | None = None,
                 within=None) -> WrittenResult:
    """Write the pictures of a result :func:`write_result` wrote without them, then its
    report again, naming them (the mesh is not touched).

    ``written`` is what :func:`write_result` returned for ``result``; the other
    arguments are as there (``vertex_colors`` those of the mesh). The pictures
    are renamed into place before the report, so the report names only pictures
    that exist. Returns the new :class:`WrittenResult`; ValueError and OSError
    as :func:`write_result` (the report then stays as it was).
    """
    if contact_sheet is not None and sheet_views is None:
        raise ValueError("a contact sheet needs sheet_views: the images and masks it shows")
    pictures = _pictures(result, written.mesh, vertex_colors, preview, html, contact_sheet,
                         sheet_views)
    document = {**written.document, **{key: str(path) for key, (path, _) in pictures.items()}}
    _write([*pictures.values(),
            (written.report, json.dumps(document, indent=2).encode("utf-8"))], within)
    return replace(written, document=document,
                   **{key: path for key, (path, _) in pictures.items()})


def _pictures(result, mesh_path: Path, vertex_colors, preview, html, contact_sheet,
              sheet_views, textured=None) -> dict:
    """{"preview" | "html" | "contact_sheet": (path, bytes)} of the pictures asked for (of
    the ``textured`` mesh when given)."""
    pictures = {}
    shown = (result.vertices, result.faces, vertex_colors, {})
    if textured is not None:
        shown = (textured.vertices, textured.faces, textured.vertex_colours(),
                 {"uv": textured.uv, "texture": textured.texture})
    vertices, faces, colours, texture = shown
    if preview is not None:
        pictures["preview"] = (Path(preview), png_bytes(preview_image(
            vertices, faces, vertex_colors=colours)))
    if html is not None:
        pictures["html"] = (Path(html), html_viewer(
            vertices, faces, vertex_colors=colours, title=mesh_path.name,
            **texture).encode("utf-8"))
    if contact_sheet is not None:
        pictures["contact_sheet"] = (Path(contact_sheet),
                                     png_bytes(_sheet(result.report, sheet_views)))
    return pictures


def _write(files: list, within) -> None:
    """Write ``files`` ([(path, bytes or None: removed)]) atomically, in one batch, in this
    order."""
    if within is None:
        for path, _ in files:
            path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic_all(files, within=within)


def _sheet(report: dict, views: SheetViews):
    """The contact sheet of ``views`` with the report's silhouette IoU and rejections."""
    iou = {p["view"]: p["silhouette_iou"] for p in report["silhouette_iou"]["per_view"]}
    reasons = {r["view"]: r["reason"] for r in report["views"]["rejected"]} | views.reasons
    return contact_sheet(views.images, views.masks, views.names, views.angles_rad,
                         [iou.get(n) for n in views.names],
                         rejected=[reasons.get(n) for n in views.names])
