"""A texture for a mesh from calibrated views: :func:`texture_mesh`.

Each face is given one view (:mod:`.selection`: seen unhidden, frontal, near and sharp,
neighbours from the same view where quality allows), the faces of a view make charts laid
out as the view sees them (:mod:`.atlas`), the views' colours are levelled along the
seams (:mod:`.levelling`), and every texel takes the colour at the texel's point of the
face in the views that see the face fully (those that glimpse it, where none sees it
fully), read bicubically (:data:`VIEW_KERNEL`), blended, each weighted by its quality
relative to the face's best view to the power :data:`BLEND_POWER` (from
:data:`BLEND_MIN` of it) and times its gain, and blurred as far as the views, left out
one by one, predict one another best (:mod:`.agreement`); with ``blend_power`` None:
the face's one view, plus the levelling's seam offsets. One view per face puts the
detail of that view alone, sharp, but wherever the mesh departs from the surface by a
fraction of a millimetre that detail lands off in other directions; the blend keeps what
the views agree on and averages their noise: unblurred on a true mesh, where the views
agree, blurred where the mesh departs from the surface (doc/benchmarks.md, the atlas).
Texels around each chart repeat its border's colours (``padding`` of them) so that
filtering does not bleed across a seam; the rest of the atlas is the texture's mean
colour. Faces no view sees (the underside on the plate) take the colour of their lowest
corner (:mod:`.atlas`: one texel for the unseen faces around a vertex), each corner's
colour the mean of its seen faces' or, for corners no view sees, near the harmonic
interpolation along the edges the vertex colours use, solved on patches of a few edges
and smoothed (:class:`~sfs_ros.core.meshing.colour.SmoothedFill`: no view sees them,
their colour need only be smooth and meet the seen ones without a seam).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ..carving.carve import validate_masks
from ..geometry.camera import Camera
from ..meshing.colour import SmoothedFill, check_image
from ..render import as_mesh_arrays
from ..workers import map_in_threads
from .agreement import BLUR_LEVELS_PX, blurred_views, face_blur
from .atlas import Atlas, build_atlas
from .levelling import (
    KERNELS,
    corner_colours,
    interpolate,
    sample_image,
    seam_edges,
    seam_offsets,
    view_gains,
)
from .selection import (
    SMOOTHNESS,
    face_neighbours,
    face_qualities,
    label_faces,
    sharpness,
)

__all__ = ["BLEND_MIN", "BLEND_POWER", "LEVELLING_BLUR_PX", "TEXELS_PER_PIXEL", "VIEW_KERNEL",
           "TexturedMesh", "texture_mesh", "textured_from_labels"]

#: Texels per pixel of a face's view along each side, by default: at 1 the texture is
#: the views' pixels themselves, but a renderer's bilinear look-ups at a chart's border
#: then mix in the texels of its padding; at 2 these are a quarter of the chart's area
#: and the texture of a fine pattern comes 1.3-2.2 dB nearer held-out views
#: (doc/reconstruct.md, the atlas).
TEXELS_PER_PIXEL = 2.0
#: Each texel is the blend of the views that see its face fully, each weighted by its
#: quality relative to the face's best, to this power (None: the face's one view).
BLEND_POWER = 1.0
#: Views below this share of a face's best quality are not blended into it (they would
#: add little for a sample each).
BLEND_MIN = 0.1
#: How a texel's colour is read from a view's pixels, by default (:data:`.levelling.KERNELS`):
#: bicubic, since a pattern a few pixels a period lies between the pixels' samples on a
#: curve that straight lines from pixel to pixel cut short (doc/benchmarks.md, the atlas).
VIEW_KERNEL = "bicubic"
#: Standard deviation (pixels) of the Gaussian blur of the images the levelling compares.
LEVELLING_BLUR_PX = 2.0


@dataclass(frozen=True)
class TexturedMesh:
    """A mesh with a texture (:func:`texture_mesh`).

    Attributes
    ----------
    vertices : (k, 3) float64
        Metres, object frame: the input's vertices, one copy per chart a vertex lies in.
    faces : (m, 3) int64
        The input's faces in its order, indexing ``vertices``.
    uv : (k, 2) float64
        Texture coordinates in [0, 1], v up from the texture's bottom row.
    texture : (H, W, 3) uint8
        RGB atlas.
    source_vertex : (k,) int64
        The input vertex each vertex copies.
    face_view : (m,) int64
        The view (index into the cameras given) each face's colour comes from; -1 for
        faces no view sees.
    stats : dict
        JSON-ready figures: faces, views, charts, seam edges, atlas size and use,
        gains, seconds per step (the atlas and the fill's factors made beside the
        levelling and the agreement test).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    source_vertex: np.ndarray
    face_view: np.ndarray
    stats: dict

    def colour_at(self, face_index: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(k, 3) float32 texture colour (bilinear) at points of faces ``face_index`` (k,)
        with ``barycentric`` (k, 3) coordinates: what a renderer draws there."""
        uv = np.einsum("kc,kcd->kd", barycentric, self.uv[self.faces[face_index]])
        height, width = self.texture.shape[:2]
        return interpolate(self.texture.astype(np.float32), uv[:, 0] * width - 0.5,
                           (1.0 - uv[:, 1]) * height - 0.5)

    def vertex_colours(self) -> np.ndarray:
        """(k, 3) uint8 the texture at each vertex (for drawings without textures)."""
        corner = np.zeros((len(self.vertices), 3), np.float32)
        face = np.repeat(np.arange(len(self.faces)), 3)
        corner[self.faces.ravel()] = self.colour_at(face, np.tile(np.eye(3), (len(self.faces), 1)))
        return np.clip(np.rint(corner), 0, 255).astype(np.uint8)


def _dilate(image: np.ndarray, filled: np.ndarray, steps: int) -> None:
    """Grow the filled texels of ``image`` (H, W, 3) float32 by ``steps`` texels in place,
    each new texel the mean of its filled 8-neighbours; then the rest the mean colour."""
    _grow(image, filled.astype(np.int32), int(steps))


@njit(cache=True, nogil=True)
def _grow(image, filled, steps):
    """:func:`_dilate`'s loops; ``filled`` (H, W) int32 (1: filled) is marked with the step
    that filled each texel (2, 3, ...), so that a step reads the texels filled before it
    alone."""
    height, width = filled.shape
    for step in range(steps):
        stamp, grown = step + 2, 0
        for r in range(height):
            for c in range(width):
                if filled[r, c]:
                    continue
                total0 = total1 = total2 = 0.0
                count = 0
                for rr in range(max(r - 1, 0), min(r + 2, height)):
                    for cc in range(max(c - 1, 0), min(c + 2, width)):
                        if filled[rr, cc] and filled[rr, cc] < stamp:
                            total0 += image[rr, cc, 0]
                            total1 += image[rr, cc, 1]
                            total2 += image[rr, cc, 2]
                            count += 1
                if count:
                    image[r, c, 0] = total0 / count
                    image[r, c, 1] = total1 / count
                    image[r, c, 2] = total2 / count
                    filled[r, c] = stamp
                    grown += 1
        if grown == 0:
            break
    mean0 = mean1 = mean2 = 0.0
    count = 0
    for r in range(height):
        for c in range(width):
            if filled[r, c]:
                mean0 += image[r, c, 0]
                mean1 += image[r, c, 1]
                mean2 += image[r, c, 2]
                count += 1
    count = max(count, 1)
    for r in range(height):
        for c in range(width):
            if not filled[r, c]:
                image[r, c, 0] = mean0 / count
                image[r, c, 1] = mean1 / count
                image[r, c, 2] = mean2 / count


def _texels(atlas: Atlas, vertices, faces, labels, images, cameras, gains, offsets,
            vertex_colour, kernel: str, blend=None, blur=None) -> np.ndarray:
    """(H, W, 3) float32 atlas: each texel of a face its view's colour at the texel's point
    (interpolated with ``kernel``), times the view's gain plus the interpolated seam offsets
    (``offsets`` (m, 3, 3)), or the blend of its views (:func:`_blend_views`); of an unseen
    face, ``vertex_colour`` (n, 3) interpolated."""
    image = np.zeros((*atlas.shape, 3), np.float32)
    rows, cols = np.nonzero(atlas.face_index >= 0)
    face = atlas.face_index[rows, cols]
    bary = atlas.barycentric[rows, cols]
    colour = np.empty((len(face), 3), np.result_type(bary, vertex_colour))
    label = labels[face]
    blended = np.zeros(len(face), bool) if blend is None else \
        _blend_views(colour, face, bary, vertices, faces, blend, blur, images, cameras, gains,
                     kernel)
    single = (label >= 0) & ~blended
    unseen = np.flatnonzero((label < 0) & ~blended)
    colour[unseen] = np.einsum("kc,kcd->kd", bary[unseen], vertex_colour[faces[face[unseen]]])
    for view in np.unique(label[single]):
        mine = np.flatnonzero(single & (label == view))
        points = np.einsum("kc,kcd->kd", bary[mine], vertices[faces[face[mine]]])
        colour[mine] = (gains[view] * sample_image(images[0][view], cameras[view], points,
                                                   kernel=kernel)
                        + np.einsum("kc,kcd->kd", bary[mine], offsets[face[mine]]))
    image[rows, cols] = colour
    return image


def _blend_views(colour, face, bary, vertices, faces, blend, blur, images, cameras, gains,
                 kernel: str) -> np.ndarray:
    """Set ``colour`` (k, 3) of texels (of faces ``face`` (k,), at ``bary`` (k, 3)) to the
    blend of every view with a weight for their face (``blend`` (m, V), 0: not blended),
    each view's colour (``images[blur[face]][view]``, ``blur`` (m,) the face's level of
    :func:`.agreement.blurred_views`) times its gain; returns (k,) bool the texels set."""
    blended = np.flatnonzero(blend.any(axis=1)[face])
    points = np.einsum("kc,kcd->kd", bary[blended], vertices[faces[face[blended]]])
    n_levels = len(images)
    texel, weight, bounds = _blend_pairs(face[blended], blend, blur, n_levels)
    colour_here = np.empty((len(texel), 3), np.float32)
    for group in range(blend.shape[1] * n_levels):
        mine = slice(bounds[group], bounds[group + 1])
        if bounds[group + 1] > bounds[group]:
            at_view, blurred = divmod(group, n_levels)
            pixels = np.nan_to_num(cameras[at_view].project(points[texel[mine]]), nan=-1.0)
            colour_here[mine] = gains[at_view] * interpolate(
                images[blurred][at_view], pixels[:, 0], pixels[:, 1], kernel=kernel)
    total = np.stack([np.bincount(texel, weights=weight * colour_here[:, c],
                                  minlength=len(blended)) for c in range(3)], axis=1)
    weight_sum = np.bincount(texel, weights=weight, minlength=len(blended))
    colour[blended] = total / weight_sum[:, None]
    out = np.zeros(len(face), bool)
    out[blended] = True
    return out


@njit(cache=True, nogil=True)
def _blend_pairs(face, blend, blur, n_levels):
    """Every (texel, view) with a weight, for texels of faces ``face`` (k,) weighed by
    ``blend`` (m, V) and blurred at level ``blur`` (m,) of ``n_levels``: the texels (p,)
    int64 and their weights (p,), grouped by ``view * n_levels + blur`` (a counting sort,
    texels ascending within a group) so that each view is read once at each blur, and
    the groups' bounds (V * n_levels + 1,) int64."""
    n_views = blend.shape[1]
    counts = np.zeros(n_views * n_levels + 1, np.int64)
    for t in range(face.shape[0]):
        f = face[t]
        for v in range(n_views):
            if blend[f, v] > 0:
                counts[v * n_levels + blur[f] + 1] += 1
    bounds = np.cumsum(counts)
    at = bounds[:-1].copy()
    texel = np.empty(bounds[-1], np.int64)
    weight = np.empty(bounds[-1], blend.dtype)
    for t in range(face.shape[0]):
        f = face[t]
        for v in range(n_views):
            if blend[f, v] > 0:
                group = v * n_levels + blur[f]
                texel[at[group]] = t
                weight[at[group]] = blend[f, v]
                at[group] += 1
    return texel, weight, bounds


def _views_colours(vertices, faces, labels, neighbours, images, cameras, seen, level: bool,
                   blend, kernel: str, blur_levels_px: tuple) -> tuple:
    """What :func:`textured_from_labels` reads the views with: ``(floats, seams, gains,
    offsets, vertex colours, blur)`` (the images as float32 at each blur of
    ``blur_levels_px``, the seam edges, :func:`_levelled`'s (the vertex colours not yet
    filled), and each face's blur of
    :func:`.agreement.face_blur`, None without a ``blend``), and the seconds of the
    levelling and the agreement test."""
    seconds, start = {}, time.perf_counter()
    floats = [image.astype(np.float32) for image in images]
    seams = seam_edges(faces, labels, neighbours)
    gains, offsets, vertex = _levelled(floats, cameras, vertices, faces, labels, seams, seen,
                                       level, offsets=blend is None)
    seconds["levelling"] = time.perf_counter() - start
    blur = None
    if blend is not None:
        floats = blurred_views(floats, blur_levels_px)
        # Judged at each face's centroid (its first sample point).
        blur = face_blur(vertices[faces].mean(axis=1, keepdims=True), blend, gains, floats,
                         cameras, neighbours, kernel=kernel)
    else:
        floats = [floats]
    seconds["agreement"] = time.perf_counter() - start - seconds["levelling"]
    return (floats, seams, gains, offsets, vertex, blur), seconds


def _split_by_chart(faces: np.ndarray, atlas: Atlas, n_vertices: int) -> tuple:
    """One vertex per (chart, vertex): (source vertex (k,), faces (m, 3), uv (k, 2)), the
    vertices chart by chart."""
    source = np.empty(faces.size, np.int64)
    corner = np.empty(faces.size, np.int64)
    new_faces = np.empty_like(faces, np.int64)
    k = _copies_by_chart(np.ascontiguousarray(faces, np.int64), atlas.chart, n_vertices,
                         source, corner, new_faces)
    return source[:k], new_faces, atlas.uv.reshape(-1, 2)[corner[:k]]


@njit(cache=True, nogil=True)
def _copies_by_chart(faces, chart, n_vertices, source, corner, new_faces):
    """:func:`_split_by_chart`'s loop over the faces chart by chart (``chart`` (m,) int >= 0,
    counting sort): each vertex's copy in a chart made at its first corner there
    (``source``, ``corner`` (3m,) the vertex and that corner, flat), ``new_faces`` (m, 3)
    indexing the copies; returns the copies made."""
    start = np.zeros(chart.max() + 2, np.int64)
    for f in range(chart.shape[0]):
        start[chart[f] + 1] += 1
    start = np.cumsum(start)
    order = np.empty(chart.shape[0], np.int64)
    for f in range(chart.shape[0]):
        order[start[chart[f]]] = f
        start[chart[f]] += 1
    seen_in = np.full(n_vertices, -1, np.int64)
    copy_of = np.empty(n_vertices, np.int64)
    k = 0
    for i in range(order.shape[0]):
        f = order[i]
        for j in range(3):
            v = faces[f, j]
            if seen_in[v] != chart[f]:
                seen_in[v] = chart[f]
                copy_of[v] = k
                source[k] = v
                corner[k] = 3 * f + j
                k += 1
            new_faces[f, j] = copy_of[v]
    return k


def _compared(labels: np.ndarray, seen: np.ndarray | None, level: bool) -> np.ndarray:
    """(m,) the labels (m,) of the faces whose corners set the vertex colours (and, when
    ``level``, the seams' colours: those fully seen, ``seen`` (m, V) bool, by their view),
    -1 for the others: glimpsed faces neither move the colours where views meet nor are
    moved."""
    if not level:
        return labels
    return np.where(seen[np.arange(len(labels)), np.maximum(labels, 0)], labels, -1)


def _vertex_fill(faces: np.ndarray, compared: np.ndarray, n_vertices: int) -> SmoothedFill | None:
    """The smoothed fill of the vertices of no face with a view in ``compared`` (m,)
    (:func:`_compared`), None when there are none; it needs no colour, so it is factored
    beside the levelling."""
    seen = np.zeros(n_vertices, bool)
    seen[faces[compared >= 0]] = True
    return None if seen.all() else SmoothedFill.of(seen, faces)


def _levelled(images, cameras, vertices, faces, labels, seams, seen, level: bool,
              offsets: bool = True) -> tuple:
    """The gains (V, 3), seam offsets (m, 3, 3) and vertex colours (n, 3) (of the
    vertices of faces with a view in :func:`_compared`; zero at the others, which
    :func:`_vertex_fill` fills) of :func:`texture_mesh`; ``seen`` (m, V) bool the faces
    each view sees fully; without ``offsets`` (a blended texture) the seam offsets are
    zero."""
    # Exposure is what the views disagree on at a scale of pixels; finer detail that a
    # fraction of a pixel of misregistration changes is blurred away before comparing.
    smooth = [cv2.GaussianBlur(image, (0, 0), LEVELLING_BLUR_PX) for image in images]
    gains = (view_gains(images, cameras, vertices, faces, seen, labels, seams)
             if level and len(seams) else np.ones((len(cameras), 3)))
    compared = _compared(labels, seen, level)
    corner, vertex, views = corner_colours(smooth, cameras, gains, vertices, faces, compared)
    offsets = (seam_offsets(views, vertex, corner, faces, compared, len(cameras))
               if level and offsets else np.zeros_like(corner))
    return gains, offsets, vertex


def _qualities(vertices, faces, images, cameras, masks, closed: bool) -> tuple:
    """(m, V) quality of each view for each face (:mod:`.selection`), sharpness included,
    and (m, V) bool where the view sees the face fully (not a glimpse)."""
    quality, full = face_qualities(vertices, faces, cameras, masks, closed=closed)
    sharp = np.array(list(map_in_threads(lambda view: sharpness(*view), zip(images, masks))))
    quality *= sharp / sharp.max() if sharp.max() > 0 else np.ones_like(sharp)
    return quality, full


@njit(cache=True, nogil=True)
def _blend_weights(quality, full, labels, least, power, blend):
    """The weight of each view in each face's texels into ``blend`` (m, V) (zeros): of a
    face with a view (``labels`` (m,) >= 0), its quality (``quality`` (m, V)) relative to
    its best view's, to the ``power``, where that is at least ``least`` and the view sees
    the face fully (``full`` (m, V)) or, for a face no view sees fully, glimpses it."""
    for f in range(quality.shape[0]):
        if labels[f] < 0:
            continue
        best, any_full = quality[f, 0], False
        for j in range(quality.shape[1]):
            best = max(best, quality[f, j])
            any_full |= full[f, j]
        best = max(best, 1e-300)
        for j in range(quality.shape[1]):
            relative = quality[f, j] / best
            supported = full[f, j] if any_full else quality[f, j] > 0.0
            if supported and relative >= least:
                blend[f, j] = relative ** power


def texture_mesh(vertices, faces, images: Sequence, cameras: Sequence[Camera], *,
                 masks: Sequence | None = None, closed: bool = False, level: bool = True,
                 smoothness: float = SMOOTHNESS, texels_per_pixel: float = TEXELS_PER_PIXEL,
                 max_size: int = 4096, padding: int = 2,
                 blend_power: float | None = BLEND_POWER,
                 kernel: str = VIEW_KERNEL,
                 blur_levels_px: Sequence[float] = BLUR_LEVELS_PX) -> TexturedMesh:
    """Texture a closed mesh from the views that see it (module docstring).

    Parameters
    ----------
    vertices : (n, 3) float64, metres; faces : (m, 3) int, outward
    images : sequence of (H, W, 3) uint8 RGB, each its camera's size (no lens: undistorted)
    cameras : sequence of Camera
    masks : sequence of (H, W) bool, optional
        The silhouettes; a view does not colour a face outside its silhouette.
    closed : bool
        The mesh is closed and outward (its z-buffers draw the front faces only).
    level : bool
        Level the views' colours along the seams (:mod:`.levelling`).
    smoothness : float >= 0
        Cost of a seam against a face's quality (:func:`.selection.label_faces`).
    texels_per_pixel : float > 0
        Texels per pixel of a face's view (1: the views' pixels per metre on the object;
        default :data:`TEXELS_PER_PIXEL`).
    max_size, padding : int
        Largest side of the atlas and texels between charts, each side.
    blend_power : float or None
        Weights of the views blended into each texel (module docstring); None: one view.
    kernel : str
        How the views are read at the texels' points (:data:`.levelling.KERNELS`; default
        :data:`VIEW_KERNEL`).
    blur_levels_px : sequence of float >= 0
        The blurs a blended face may take where its views disagree (:mod:`.agreement`),
        the first 0.

    Returns
    -------
    TexturedMesh
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    cameras = list(cameras)
    if not cameras or len(images) != len(cameras):
        raise ValueError(f"need one image per camera and at least one, got {len(images)} "
                         f"images and {len(cameras)} cameras")
    masks = [None] * len(cameras) if masks is None else validate_masks(cameras, masks)
    images = [check_image(i, image, c) for i, (image, c) in enumerate(zip(images, cameras))]
    start = time.perf_counter()
    quality, full = _qualities(vertices, faces, images, cameras, masks, closed)
    neighbours = face_neighbours(faces)
    labels, sweeps = label_faces(quality, neighbours, smoothness=smoothness)
    if (labels < 0).all():
        raise ValueError("no face is seen by any view: check the cameras and the mesh")
    selection_s = time.perf_counter() - start
    blend = None
    if blend_power is not None:
        blend = np.zeros(quality.shape)
        _blend_weights(quality, full, labels, BLEND_MIN, float(blend_power), blend)
    textured = textured_from_labels(vertices, faces, labels, neighbours, images, cameras,
                                    seen=full, level=level, blend=blend, texels_per_pixel=texels_per_pixel,
                                    max_size=max_size, padding=padding, kernel=kernel,
                                    blur_levels_px=blur_levels_px)
    textured.stats.update(labelling_sweeps=int(sweeps), smoothness=float(smoothness))
    textured.stats["seconds"] = {"selection": selection_s, **textured.stats["seconds"]}
    return textured


def textured_from_labels(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
                         neighbours: np.ndarray, images: Sequence, cameras: Sequence[Camera], *,
                         seen: np.ndarray | None = None, level: bool = True,
                         blend: np.ndarray | None = None,
                         texels_per_pixel: float = TEXELS_PER_PIXEL,
                         max_size: int = 4096, padding: int = 2,
                         kernel: str = VIEW_KERNEL,
                         blur_levels_px: Sequence[float] = BLUR_LEVELS_PX) -> TexturedMesh:
    """The atlas, levelling and texels of :func:`texture_mesh` for faces whose views are
    chosen: ``labels`` (m,) int64 (-1: none), ``neighbours`` (m, 3)
    (:func:`.selection.face_neighbours`); ``vertices`` (n, 3) float64, ``faces`` (m, 3)
    int64 checked, ``images`` (H, W, 3) uint8 each its camera's size; ``seen`` (m, V)
    bool the faces each view sees fully (:func:`.selection.face_qualities`; needed to
    ``level``: the views are compared on those faces only); ``blend`` (m, V) the weight of
    each view in each face's texels (0: none; None: the face's one view, with the seam
    offsets); the other arguments as there."""
    if level and seen is None:
        raise ValueError("levelling needs the faces each view sees (seen)")
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
    blur_levels_px = tuple(float(sigma) for sigma in blur_levels_px)
    if (not blur_levels_px or blur_levels_px[0] != 0.0
            or not all(math.isfinite(sigma) and sigma >= 0 for sigma in blur_levels_px)):
        raise ValueError(f"blur_levels_px must be blurs >= 0 px, the first 0, got "
                         f"{blur_levels_px}")

    def atlas_step():
        start = time.perf_counter()
        atlas = build_atlas(vertices, faces, labels, neighbours, cameras,
                            texels_per_pixel=texels_per_pixel, max_size=max_size,
                            padding=padding)
        atlas_s = time.perf_counter() - start
        fill = _vertex_fill(faces, _compared(labels, seen, level), len(vertices))
        return (atlas, fill), {"atlas": atlas_s, "fill": time.perf_counter() - start - atlas_s}

    def colour_step():
        return _views_colours(vertices, faces, labels, neighbours, images, cameras, seen,
                              level, blend, kernel, blur_levels_px)

    # The atlas, the fill's factors and the views' colours meet only in the texels: made
    # side by side.
    ((atlas, fill), seconds), ((floats, seams, gains, offsets, vertex, blur), colour_seconds) = \
        map_in_threads(lambda step: step(), (atlas_step, colour_step))
    seconds.update(colour_seconds)
    start = time.perf_counter()
    if fill is not None:
        vertex = fill(vertex)
    image = _texels(atlas, vertices, faces, labels, floats, cameras, gains, offsets, vertex,
                    kernel, blend, blur)
    claimed = atlas.face_index >= 0
    _dilate(image, claimed.copy(), int(padding))
    source, new_faces, uv = _split_by_chart(faces, atlas, len(vertices))
    seconds["texels"] = time.perf_counter() - start
    stats = {"faces": int(len(faces)), "views": len(cameras), "unseen_faces": int((labels < 0).sum()),
             "charts": int(atlas.chart.max()) + 1, "seam_edges": int(len(seams)),
             "atlas_size": [int(atlas.shape[1]), int(atlas.shape[0])],
             "atlas_use": float(claimed.mean()), "texels_per_pixel": atlas.texels_per_pixel,
             "levelled": bool(level), "gains": np.round(gains, 4).tolist(),
             "blur_px": ({} if blur is None else
                         {str(sigma): float(np.mean(blur[labels >= 0] == i))
                          for i, sigma in enumerate(blur_levels_px)}),
             "seconds": seconds}
    return TexturedMesh(vertices=vertices[source], faces=new_faces, uv=uv,
                        texture=np.clip(np.rint(image), 0, 255).astype(np.uint8),
                        source_vertex=source, face_view=labels, stats=stats)
