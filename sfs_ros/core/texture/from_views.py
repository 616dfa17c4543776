"""Texture a mesh from calibrated views: a reconstruction's own
(:func:`texture_reconstruction`, the step a caller runs after the mesh is out, so the
texture never delays the mesh) or any mesh in the views' object frame
(:func:`texture_from_views`), or a carved scan's mesh from the images it carries
(:func:`texture_carved_scan`, the cell's)."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from ..exchange.views import View, ViewSet, read_image
from ..geometry.lens import ideal_camera, undistort_image, undistort_mask
from ..meshing.colour import MAX_COLOUR_VIEWS, spread_views
from ..render import as_mesh_arrays
from .textured import TexturedMesh, texture_mesh

__all__ = ["MIN_SEEN_FRACTION", "check_mesh_in_views", "texture_carved_scan",
           "texture_from_views", "texture_reconstruction"]

#: Share of a mesh's vertices that must lie in front of some view and inside its image.
MIN_SEEN_FRACTION = 0.5
#: About as many vertices, evenly spread in the mesh's order, are checked.
_CHECKED_VERTICES = 5000


def check_mesh_in_views(vertices: np.ndarray, cameras: Sequence) -> float:
    """The share of ``vertices`` (n, 3) metres that some camera sees in front of it and
    inside its image; ValueError naming the mesh's extent when it is below
    :data:`MIN_SEEN_FRACTION` (a mesh in another frame or unit than the views)."""
    vertices = vertices[::max(1, len(vertices) // _CHECKED_VERTICES)]
    inside = np.zeros(len(vertices), bool)
    for camera in cameras:
        in_front = camera.depth(vertices) > 0
        uv = camera.project(vertices)
        inside |= (in_front & np.all(np.isfinite(uv), axis=1)
                   & (uv[:, 0] >= -0.5) & (uv[:, 0] <= camera.width - 0.5)
                   & (uv[:, 1] >= -0.5) & (uv[:, 1] <= camera.height - 0.5))
    seen = float(inside.mean()) if len(inside) else 0.0
    if seen < MIN_SEEN_FRACTION:
        low, high = vertices.min(axis=0), vertices.max(axis=0)
        raise ValueError(
            f"the mesh lies outside the views: {100 * seen:.0f} % of its vertices fall inside "
            f"some view's image (at least {100 * MIN_SEEN_FRACTION:.0f} % expected); it spans "
            f"{np.round(low, 4).tolist()} .. {np.round(high, 4).tolist()} m: is it in the "
            "views' object frame and unit?")
    return seen


def texture_from_views(views: Sequence[View], vertices, faces, *, images: dict | None = None,
                       masks: dict | None = None, closed: bool = False,
                       max_views: int = MAX_COLOUR_VIEWS, **options) -> TexturedMesh:
    """:func:`~.textured.texture_mesh` of a mesh ``vertices`` (n, 3) metres, ``faces``
    (m, 3) in the object frame of ``views``, from at most ``max_views`` of them spread over
    the directions (as the vertex colours).

    Each view's image (``images[name]``, an (H, W, 3) uint8 RGB array as taken or its
    file's path, else the view's own file) and its silhouette (``masks[name]``, (H, W)
    bool as taken, optional: used when every chosen view has one) are undistorted onto
    its ideal camera. ValueError when no view has an image or the mesh lies outside the
    views (:func:`check_mesh_in_views`). ``options`` go to :func:`~.textured.texture_mesh`.
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    if not len(faces):
        raise ValueError("the mesh has no faces: nothing to texture")
    views = [view for view in views if images is None or view.name in images]
    if not views:
        raise ValueError("no view has an image to texture the mesh with")
    cameras = [ideal_camera(view.camera) for view in views]
    check_mesh_in_views(vertices, cameras)
    chosen = [views[k] for k in spread_views(cameras, max_views)]
    texture_images, chosen_masks = [], []
    for view in chosen:
        given = view.image_path if images is None else images[view.name]
        image = read_image(given) if isinstance(given, (str, os.PathLike)) else given
        texture_images.append(undistort_image(image, view.camera))
        mask = None if masks is None else masks.get(view.name)
        chosen_masks.append(None if mask is None else undistort_mask(mask, view.camera))
    return texture_mesh(vertices, faces, texture_images,
                        [ideal_camera(view.camera) for view in chosen],
                        masks=chosen_masks if all(m is not None for m in chosen_masks) else None,
                        closed=closed, **options)


def texture_reconstruction(view_set: ViewSet, result, *, images: dict | None = None,
                           max_views: int = MAX_COLOUR_VIEWS, **options) -> TexturedMesh:
    """:func:`texture_from_views` of ``result`` (a
    :class:`~sfs_ros.core.pipeline.Reconstruction` of ``view_set``) from the views it used
    and their silhouettes (``result.masks``); the mesh counts as closed when its checks
    found it watertight and outward. ``images`` and ``options`` as there."""
    by_name = {view.name: view for view in view_set.views}
    used = [by_name[name] for name in result.report["views"]["used"] if name in by_name
            and (images is None or name in images)]
    if not used:
        raise ValueError("no view the reconstruction used has an image to texture it with")
    mesh = result.report.get("mesh") or {}
    return texture_from_views(used, result.vertices, result.faces, images=images,
                              masks=result.masks, max_views=max_views,
                              closed=bool(mesh.get("watertight") and mesh.get("outward")),
                              **options)


def texture_carved_scan(carved, result, **options) -> TexturedMesh:
    """:func:`~.textured.texture_mesh` of ``result`` (a
    :class:`~sfs_ros.core.mesh_scan.Reconstruction` of the carved scan ``carved``) from
    the images the carved scan carries to colour the mesh (``colour_images`` on the ideal
    cameras of ``colour_views``, with their ``colour_masks``); ValueError when it carries
    none. ``options`` go to :func:`~.textured.texture_mesh`."""
    if not carved.colour_views:
        raise ValueError("the carved scan carries no colour images to texture the mesh with "
                         "(the views' images were not received, or carry no colour)")
    mesh = result.report.get("mesh") or {}
    return texture_mesh(result.vertices, result.faces, carved.colour_images,
                        [carved.views[i].camera for i in carved.colour_views],
                        masks=carved.colour_masks or None,
                        closed=bool(mesh.get("watertight") and mesh.get("outward")), **options)
