"""Products of a reconstruction made after its answer: named in the answer, made later.

A reconstruction answers as soon as the mesh and its report are written. A product
that takes longer (the textured model) is a :class:`Product`: its path is fixed before
the answer, which names it; :func:`make_product` is run after the answer, writes it and
then the report again, naming it under the product's key (so a reader that finds the key
in the report finds the file). A caller polls the report for the key
(:func:`sfs_ros.ros.cell_client.wait_for_product`). Output names, beside the mesh::

    <stem>.textured.glb   # the mesh with its texture atlas (binary glTF)
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from ..core.exchange.export import textured_mesh_files
from ..core.exchange.files import write_atomic_all
from ..core.texture.from_views import texture_carved_scan
from .paths import confined_path

__all__ = ["TEXTURED_SUFFIX", "Product", "make_product", "product_path", "textured_model",
           "without_colour"]

#: What the textured model's name adds to the mesh's stem.
TEXTURED_SUFFIX = ".textured.glb"


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
