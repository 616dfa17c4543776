"""Texture a reconstruction from the views it was carved with: the step a caller runs after
the mesh is out (:func:`texture_reconstruction`), so the texture never delays the mesh."""

from __future__ import annotations

import os

from ..exchange.views import ViewSet, read_image
from ..geometry.lens import ideal_camera, undistort_image, undistort_mask
from ..meshing.colour import MAX_COLOUR_VIEWS, spread_views
from .textured import TexturedMesh, texture_mesh

__all__ = ["texture_reconstruction"]


def texture_reconstruction(view_set: ViewSet, result, *, images: dict | None = None,
                           max_views: int = MAX_COLOUR_VIEWS, **options) -> TexturedMesh:
    """:func:`~.textured.texture_mesh` of ``result`` (a
    :class:`~sfs_ros.core.pipeline.Reconstruction` of ``view_set``) from the views it
    used, at most ``max_views`` of them spread over the directions (as the vertex colours).

    Each view's image (``images[name]``, an (H, W, 3) uint8 RGB array as taken or its
    file's path, else the view's own file) and its silhouette (``result.masks``) are
    undistorted onto its ideal camera; the mesh counts as closed when its checks found it
    watertight and outward. ``options`` go to :func:`~.textured.texture_mesh`.
    """
    by_name = {view.name: view for view in view_set.views}
    used = [by_name[name] for name in result.report["views"]["used"] if name in by_name
            and (images is None or name in images)]
    if not used:
        raise ValueError("no view the reconstruction used has an image to texture it with")
    cameras = [ideal_camera(view.camera) for view in used]
    chosen = [used[k] for k in spread_views(cameras, max_views)]
    texture_images, masks = [], []
    for view in chosen:
        given = view.image_path if images is None else images[view.name]
        image = read_image(given) if isinstance(given, (str, os.PathLike)) else given
        texture_images.append(undistort_image(image, view.camera))
        mask = result.masks.get(view.name)
        masks.append(None if mask is None else undistort_mask(mask, view.camera))
    mesh = result.report.get("mesh") or {}
    return texture_mesh(result.vertices, result.faces, texture_images,
                        [ideal_camera(view.camera) for view in chosen],
                        masks=masks if all(m is not None for m in masks) else None,
                        closed=bool(mesh.get("watertight") and mesh.get("outward")), **options)
