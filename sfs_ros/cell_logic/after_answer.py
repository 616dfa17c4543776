"""Products of a reconstruction made after its answer: named in the answer, made later.

A reconstruction answers as soon as the mesh and its report are written. A product
that takes longer (the textured model, the mesh refined below the hull) is a
:class:`Product`: its path is fixed before
the answer, which names it; :func:`make_product` is run after the answer, writes it and
then the report again, naming it under the product's key (so a reader that finds the key
in the report finds the file). A caller polls the report for the key
(:func:`sfs_ros.ros.cell_client.wait_for_product`). Output names, beside the mesh::

    <stem>.textured.glb   # the mesh with its texture atlas (binary glTF)
    <stem>.refined<suffix>   # the mesh refined below the hull, in the mesh's format
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from ..core.exchange.export import mesh_bytes, textured_mesh_files
from ..core.exchange.files import write_atomic_all
from ..core.mesh_scan import mesh_scan
from ..core.refinement import refine_carved_scan
from ..core.texture.from_views import texture_carved_scan
from .paths import confined_path

__all__ = ["REFINED_STEM", "TEXTURED_SUFFIX", "Product", "make_product", "product_path",
           "products_after", "refined_model", "textured_model", "without_colour"]

#: What the textured model's name adds to the mesh's stem.
TEXTURED_SUFFIX = ".textured.glb"
#: What the refined mesh's name adds to the mesh's stem (before the mesh's own suffix).
REFINED_STEM = ".refined"


@dataclass(frozen=True)
class Product:
    """A file made after the answer: ``key`` (the answer's field and the report's entry
    naming it, e.g. ``"textured_path"``), its ``path``, and ``make``, which writes it and
    returns the report's further entries about it (a JSON-ready dict)."""

    key: str
    path: Path
    make: Callable[[], dict]


def product_path(output_dir, report_path, suffix: str) -> Path:
    """The path of a product beside the mesh whose report is ``report_path``: its stem
    plus ``suffix`` (e.g. :data:`TEXTURED_SUFFIX`), confined to ``output_dir``."""
    root = Path(output_dir).resolve()
    report = Path(report_path).resolve().relative_to(root).as_posix()
    stem = report[:-len(".report.json")]
    return confined_path(root, stem + suffix, suffixes=(Path(suffix).suffix,))


def textured_model(carved, result, output_dir, report_path) -> Product:
    """The textured model of ``result`` (the mesh of the carved scan ``carved``) as a
    product: a .glb beside the mesh, textured from the images the carved scan carries
    (:func:`sfs_ros.core.texture.from_views.texture_carved_scan`); ValueError at once
    when it carries none."""
    if not carved.colour_views:
        raise ValueError("no texture: the carved scan carries no colour images (the views' "
                         "captured images were not received)")
    path = product_path(output_dir, report_path, TEXTURED_SUFFIX)
    root = Path(output_dir).resolve()

    def make() -> dict:
        textured = texture_carved_scan(carved, result)
        write_atomic_all(textured_mesh_files(textured, path), within=root)
        return {"texture": textured.stats}

    return Product(key="textured_path", path=path, make=make)


def refined_model(carved, images: dict, output_dir, report_path, mesh_path,
                  on_mesh: Callable | None = None) -> Product:
    """The mesh of ``carved`` refined below its hull from the views' colours
    (:func:`sfs_ros.core.refinement.refine_carved_scan`, then meshed, coloured when
    ``carved`` colours its mesh) as a product: ``<stem>.refined<suffix>`` beside the mesh
    ``mesh_path``, in its format; ``on_mesh(vertices, faces, vertex colours or None)`` is
    called once it is written (to publish it).

    images : {view name: (H, W, 3) uint8 RGB on the view's ideal camera}, of every view
        the hull was carved with (the carving node's ``view_image`` of each view, or the
        images the carved scan carries); ValueError at once when one is missing, naming
        how many.
    """
    used = [view.name for view in carved.views if view.role == "used"]
    missing = [name for name in used if name not in images]
    if missing:
        raise ValueError(_missing_images(missing, used))
    suffix = Path(mesh_path).suffix.lower()
    path = product_path(output_dir, report_path, REFINED_STEM + suffix)
    root = Path(output_dir).resolve()

    def make() -> dict:
        refined = mesh_scan(refine_carved_scan(carved, images))
        write_atomic_all([(path, mesh_bytes(refined.vertices, refined.faces, path,
                                            vertex_colors=refined.vertex_colors))], within=root)
        if on_mesh is not None:
            on_mesh(refined.vertices, refined.faces, refined.vertex_colors)
        report = refined.report
        return {"refinement": report["refinement"],
                "refined_mesh": {**{k: report["mesh"][k] for k in ("n_vertices", "n_faces",
                                                                   "watertight", "volume_m3")},
                                 "seconds": report["timings_s"]["refinement"]}}

    return Product(key="refined_mesh_path", path=path, make=make)


def _missing_images(missing: list, used: list) -> str:
    """Why no refined mesh: the images of ``missing`` of the views ``used`` are not here."""
    return (f"no refined mesh: the images of {len(missing)} of the {len(used)} views used did "
            f"not come (first {missing[0]}): the carving node keeps no captured image of them "
            "(none received, or its colour parameter false)")


def products_after(carved, meshed, made, output_dir, images: dict, *, texture: bool,
                   refine: bool, on_mesh: Callable | None = None
                   ) -> tuple[list[Product], list[tuple[str, str]]]:
    """The products to make after the answer to the mesh ``made``
    (:class:`sfs_ros.cell_logic.mesh_files.MeshFiles`) of the carved scan ``carved``:
    ``(products, notes)``, a product that cannot be made left out with a note
    ``(level, text)`` (``"error"`` for the texture, ``"warning"`` for the refined mesh:
    the hull's mesh is out). ``meshed``: the carved scan as the mesh was made of it
    (without its images when not coloured); ``images``: {view name: (H, W, 3) uint8} of
    this scan's views, held by the caller or carried by the carved scan; ``on_mesh`` as
    :func:`refined_model`'s."""
    summary, products, notes = made.summary, [], []
    if texture:
        try:
            products.append(textured_model(carved, made.result, output_dir,
                                           summary["report_path"]))
        except ValueError as exc:
            notes.append(("error", f"{exc}; the mesh {summary['path']} is written"))
    if refine:
        try:
            products.append(refined_model(meshed, images, output_dir,
                                          summary["report_path"], summary["path"],
                                          on_mesh=on_mesh))
        except ValueError as exc:
            notes.append(("warning", f"{exc}; the hull's mesh {summary['path']} is written"))
    return products, notes


def without_colour(carved):
    """``carved`` (a :class:`~sfs_ros.core.carved_scan.CarvedScan`) without the images
    that colour its mesh: the mesh of a scan whose images came for the texture alone."""
    return replace(carved, colour_views=[], colour_masks=[], colour_images=[])


def make_product(product: Product, report_path, output_dir) -> None:
    """Make ``product``, then write the report (``report_path``) again with the product's
    key naming its path and its entries; the report is read as it is now (the pictures
    may have named themselves since the answer). ValueError or OSError when it cannot be
    made; the report then stays as it was."""
    entries = product.make()
    report = Path(report_path)
    document = json.loads(report.read_text(encoding="utf-8"))
    document.update({product.key: str(product.path), **entries})
    write_atomic_all([(report, json.dumps(document, indent=2).encode("utf-8"))],
                     within=Path(output_dir).resolve())
