"""How well a coloured mesh reproduces views it was not made from: PSNR in held-out views.

:func:`held_out_psnr` draws a mesh, unshaded, into a view's camera (its texture, its
vertex colours, or any per-pixel colouring) and compares the drawing with the view's
image over a given region: the true silhouette for a synthetic scan, the view's own mask
for a real one, eroded by ``erode_px`` pixels (outline pixels mix object and backdrop in
a real image). Pixels of the region the mesh misses are drawn as the backdrop, so a
wrong shape costs too. :func:`nearest_view_texture` is the baseline a texture is judged
against: every face projected from the view it faces most squarely, with no visibility
test, no seam smoothing and no levelling, each view read bilinearly as a renderer's
projective texture reads it. :func:`held_out_colour_psnr` measures a
reconstruction's texture and vertex colours in the views it held out.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import cv2
import numpy as np

from ..exchange.views import read_image
from ..geometry.camera import Camera
from ..geometry.lens import ideal_camera, undistort_image, undistort_mask
from ..render import as_mesh_arrays, render_image
from .selection import face_neighbours, towards_camera
from .textured import TexturedMesh, textured_from_labels

__all__ = ["HELD_OUT_ERODE_PX", "held_out_colour_psnr", "held_out_psnr", "nearest_view_labels",
           "nearest_view_texture", "psnr"]

#: Peak of 8-bit colours.
PEAK = 255.0
#: Pixels a held-out view's own silhouette is eroded by: a real image's outline pixels mix
#: object and backdrop, and a segmented outline is off by a pixel or so.
HELD_OUT_ERODE_PX = 2


def psnr(drawn: np.ndarray, image: np.ndarray, region: np.ndarray) -> float:
    """PSNR (dB, peak 255) of ``drawn`` against ``image`` (H, W, 3) over ``region`` (H, W)
    bool; ValueError for an empty region; inf where they agree exactly."""
    region = np.asarray(region, bool)
    if not region.any():
        raise ValueError("the region to compare is empty: the object is not in this view")
    diff = drawn[region].astype(np.float64) - image[region].astype(np.float64)
    mse = float(np.mean(diff * diff))
    return math.inf if mse == 0 else 10.0 * math.log10(PEAK * PEAK / mse)


def held_out_psnr(vertices, faces, camera: Camera, image: np.ndarray, region: np.ndarray, *,
                  vertex_colors=None, pixel_colors=None, erode_px: int = 0) -> float:
    """PSNR (dB) of the mesh drawn unshaded into ``camera`` against ``image`` (H, W, 3) uint8,
    over ``region`` (H, W) bool eroded by ``erode_px`` pixels (module docstring).

    ``vertices`` (n, 3) metres and ``faces`` (m, 3) in the camera's object frame (an ideal
    camera: ``image`` and ``region`` undistorted onto it); the colours as
    :func:`~sfs_ros.core.render.render_image` takes them: ``vertex_colors`` (n, 3) or
    ``pixel_colors`` (a :class:`TexturedMesh`'s ``colour_at``). The backdrop is drawn
    black, so pixels the mesh misses count as far off as they can.
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    image = np.asarray(image)
    region = np.asarray(region, bool)
    if image.shape != (camera.height, camera.width, 3) or region.shape != image.shape[:2]:
        raise ValueError(f"image {image.shape} and region {region.shape} must be the camera's "
                         f"({camera.height}, {camera.width}, 3) and ({camera.height}, "
                         f"{camera.width})")
    if int(erode_px) < 0:
        raise ValueError(f"erode_px must be >= 0, got {erode_px}")
    if erode_px:
        size = 2 * int(erode_px) + 1
        region = cv2.erode(region.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)
    colours = None if vertex_colors is None else np.asarray(vertex_colors)[:, :3]
    drawn = render_image(vertices, faces, camera, vertex_colors=colours,
                         pixel_colors=pixel_colors, ambient=1.0, noise_sigma=0.0,
                         background_rgb=(0, 0, 0))
    return psnr(drawn, image, region)


def nearest_view_labels(vertices: np.ndarray, faces: np.ndarray,
                        cameras: Sequence[Camera]) -> np.ndarray:
    """(m,) int64: for each face the camera whose direction to its centroid is nearest its
    normal (the largest cosine), -1 where every camera sees its back."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    centroid = tri.mean(axis=1)
    cosines = np.empty((len(faces), len(cameras)))
    for k, camera in enumerate(cameras):
        cosines[:, k] = np.einsum("md,md->m", normal, towards_camera(camera, centroid))
    return np.where(cosines.max(axis=1) > 0, cosines.argmax(axis=1), -1).astype(np.int64)


def nearest_view_texture(vertices, faces, images: Sequence, cameras: Sequence[Camera], *,
                         max_size: int = 4096) -> TexturedMesh:
    """The baseline texture (module docstring): each face projected from
    :func:`nearest_view_labels`'s view, read bilinearly, in the same atlas as
    :func:`~.textured.texture_mesh`'s (``images`` (H, W, 3) uint8 on ideal ``cameras``)."""
    vertices, faces = as_mesh_arrays(vertices, faces)
    labels = nearest_view_labels(vertices, faces, list(cameras))
    return textured_from_labels(vertices, faces, labels, face_neighbours(faces), images,
                                list(cameras), level=False, max_size=max_size,
                                kernel="bilinear")


def held_out_colour_psnr(view_set, result, textured: TexturedMesh | None = None, *,
                         images: dict | None = None, erode_px: int = HELD_OUT_ERODE_PX
                         ) -> dict | None:
    """PSNR of a reconstruction's colours in its held-out views (those it was not carved
    with), inside each view's own silhouette (``result.masks``, the best a real capture
    has) eroded by ``erode_px``: of ``textured`` and of ``result.vertex_colors``, each when
    given. Images as :func:`~.from_views.texture_from_views` takes them (``images`` {name:
    array or path}, else each view's file), undistorted with its mask onto the ideal camera.

    Returns None without held-out views or colours, else ``{"views": [names],
    "erode_px", "texture_db": mean or None, "vertex_colours_db": mean or None,
    "per_view": [{"view", "texture_db", "vertex_colours_db"}]}`` (JSON-ready).
    """
    names = [n for n in result.report["views"]["held_out"] if n in result.masks
             and (images is None or n in images)]
    if not names or (textured is None and result.vertex_colors is None):
        return None
    by_name = {view.name: view for view in view_set.views}
    per_view = []
    for name in names:
        view = by_name[name]
        given = view.image_path if images is None else images[name]
        image = read_image(given) if isinstance(given, (str, os.PathLike)) else given
        camera = ideal_camera(view.camera)
        image = undistort_image(image, view.camera)
        region = undistort_mask(result.masks[name], view.camera)
        entry = {"view": name, "texture_db": None, "vertex_colours_db": None}
        if textured is not None:
            entry["texture_db"] = held_out_psnr(textured.vertices, textured.faces, camera,
                                                image, region, pixel_colors=textured.colour_at,
                                                erode_px=erode_px)
        if result.vertex_colors is not None:
            entry["vertex_colours_db"] = held_out_psnr(
                result.vertices, result.faces, camera, image, region,
                vertex_colors=result.vertex_colors, erode_px=erode_px)
        per_view.append(entry)

    def mean(key):
        values = [e[key] for e in per_view if e[key] is not None]
        return float(np.mean(values)) if values else None

    return {"views": names, "erode_px": int(erode_px), "texture_db": mean("texture_db"),
            "vertex_colours_db": mean("vertex_colours_db"), "per_view": per_view}
