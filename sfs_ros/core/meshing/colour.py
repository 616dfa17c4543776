"""Per-vertex colour of a mesh from the images it was reconstructed from.

A view takes part in the colour of a vertex when it *sees* the vertex:

* the vertex projects into the image (in front of a pinhole camera);
* it faces the camera: ``cos = n . d > min_cos``, with ``n`` the vertex normal
  (area-weighted mean of the face normals) and ``d`` the unit direction from
  the vertex to the camera centre (orthographic: against the viewing direction);
* the mesh itself does not hide it: the mesh's depth is rendered from the camera
  with :func:`.render.rasterize_depth` and the vertex must lie no deeper than
  the z-buffer, interpolated bilinearly at its projection, plus a tolerance
  (see :func:`vertex_colours`), so what the handle of a mug hides from a view
  takes no colour from that view;
* when masks are given, it lies inside the silhouette.

The views that see a vertex are blended, each image sampled bilinearly at the
vertex's projection, with the weight

    ``w = ((cos - min_cos) / (1 - min_cos)) ** angle_power * ramp``,
    ``ramp = clip((d_edge - 1.5) / edge_ramp_px, 0, 1)``

which falls smoothly to zero at grazing angles and near edges, where an image
mixes the object with what lies behind it and where a view entering or leaving
the blend would show as a seam. ``d_edge`` (pixels) is the distance to the
nearest *edge pixel*: background of the rendered mesh, a step of the z-buffer
(a depth discontinuity), or outside the mask. The 1.5 px margin keeps the
2 x 2 pixels read by bilinear sampling off edge pixels: a block holding an edge
pixel interpolates to at most sqrt(2) px.

Vertices that no view sees (the underside resting on the turntable, deep
concavities) are filled from their neighbours along mesh edges: harmonic
interpolation, each such vertex the mean of its neighbours, the seen ones fixed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit
from scipy import sparse
from scipy.sparse import csgraph
from scipy.sparse.linalg import splu

from ..carving.carve import validate_masks
from ..geometry.camera import Camera
from ..render import as_mesh_arrays, depth_of_checked
from ..settings import MAX_COLOUR_VIEWS
from ..workers import map_in_threads

__all__ = ["ANGLE_POWER", "DEPTH_TOLERANCE_PX", "EDGE_RAMP_PX", "MAX_COLOUR_VIEWS", "MIN_COS",
           "HarmonicFill", "SmoothedFill", "VertexColours", "ViewSight",
           "check_image", "fill_from_neighbours", "sight_maps", "sight_weight", "spread_views",
           "vertex_colours", "vertex_normals", "view_point", "view_sight"]

#: A z-buffer step between neighbouring pixels of more than this many pixel
#: footprints is a depth discontinuity (a smooth surface only steps that much
#: when steeper than atan(4) = 76 degrees, where ``min_cos`` drops it anyway).
DEPTH_STEP_FOOTPRINTS = 4.0
#: Distance (pixels) to an edge pixel below which the edge ramp is zero.
EDGE_MARGIN_PX = 1.5
#: The sight test's defaults (:func:`view_sight`, :func:`vertex_colours`): the least
#: cosine between a normal and the direction to the camera, the power of the angle's
#: weight, the pixels of ramp off the edges and of depth tolerance.
MIN_COS, ANGLE_POWER, EDGE_RAMP_PX, DEPTH_TOLERANCE_PX = 0.2, 2.0, 3.0, 1.0


@dataclass(frozen=True)
class VertexColours:
    """What :func:`vertex_colours` returns.

    Attributes
    ----------
    colours : (n, 3) uint8
        RGB per vertex.
    n_views : (n,) int64
        Views blended into each vertex; 0 where the colour was filled in from
        the neighbours.
    n_hidden : (n,) int64
        Views that would have been blended into each vertex but in which the
        mesh hides it (always 0 with ``occlusion=False``).
    stats : dict
        JSON-ready: ``vertices``, ``views``, ``seen`` and ``filled`` vertex
        counts, ``mean_views_per_seen_vertex``, ``occlusion`` (whether the
        z-buffer test was on) and ``occluded_pairs`` (the sum of ``n_hidden``).
    coverage : list or None
        With ``coverage=True``: per view, the pixel centres the mesh covers (its
        z-buffer's finite pixels), ``np.packbits`` of the (H, W) bool image (unpack
        with ``count=H * W``); else None.
    """

    colours: np.ndarray
    n_views: np.ndarray
    n_hidden: np.ndarray
    stats: dict
    coverage: list | None = None


def spread_views(cameras: Sequence[Camera], limit: int) -> list[int]:
    """Indices (ascending) of at most ``limit`` of ``cameras`` whose viewing directions
    spread evenly: farthest-point order from the first, each next view the one whose
    direction lies farthest (in angle) from those taken; all of them when there are no
    more than ``limit``."""
    if limit < 1:
        raise ValueError(f"limit must be at least 1 view, got {limit}")
    if len(cameras) <= limit:
        return list(range(len(cameras)))
    directions = np.array([c.R[2] for c in cameras])   # optical axes, object frame
    nearest = directions @ directions[0]               # cosine to the nearest taken view
    nearest[0] = np.inf                                # (taken: never picked again)
    taken = [0]
    for _ in range(limit - 1):
        pick = int(np.argmin(nearest))
        taken.append(pick)
        nearest = np.maximum(nearest, directions @ directions[pick])
        nearest[pick] = np.inf
    return sorted(taken)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) float64 unit area-weighted vertex normals; zero where a vertex has no face.

    ``vertices`` (n, 3) float64, ``faces`` (m, 3) int64 counter-clockwise seen
    from outside, so the normals point outwards.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    normals = np.zeros_like(vertices)
    _add_face_normals(vertices, np.ascontiguousarray(faces, dtype=np.int64), normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


@njit(cache=True, nogil=True)
def _add_face_normals(vertices, faces, normals):
    """Add each face's normal, of length twice its area, to ``normals`` (n, 3) at its
    three corners."""
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        e1x, e1y, e1z = (vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1],
                         vertices[b, 2] - vertices[a, 2])
        e2x, e2y, e2z = (vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1],
                         vertices[c, 2] - vertices[a, 2])
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        for corner in range(3):
            v = faces[t, corner]
            normals[v, 0] += nx
            normals[v, 1] += ny
            normals[v, 2] += nz


def _footprint_terms(camera: Camera) -> tuple[float, float]:
    """The size of one pixel on a fronto-parallel surface at depth ``z`` (metres) is
    ``constant + z * per_metre``, metres: returns ``(constant, per_metre)``."""
    f = min(camera.K[0, 0], camera.K[1, 1])
    return (1.0 / f, 0.0) if camera.orthographic else (0.0, 1.0 / f)


@njit(cache=True, nogil=True, inline="always")
def _bilinear_at(image, u, v, channel):
    """``image[..., channel]`` (H, W, C) sampled bilinearly at ``(u, v)`` in
    [0, W-1] x [0, H-1], pixels."""
    c0 = min(int(u), image.shape[1] - 2)
    r0 = min(int(v), image.shape[0] - 2)
    fu = u - c0
    fv = v - r0
    top = (1.0 - fu) * image[r0, c0, channel] + fu * image[r0, c0 + 1, channel]
    bottom = (1.0 - fu) * image[r0 + 1, c0, channel] + fu * image[r0 + 1, c0 + 1, channel]
    return (1.0 - fv) * top + fv * bottom


@njit(cache=True, nogil=True, inline="always")
def sight_weight(u, v, z, cos, edge_px, zbuf, min_cos, angle_power, edge_ramp_px,
                  depth_tolerance_px, footprint_per_m, footprint_constant):
    """How well one view sees a point: ``(weight, hidden)``, its weight in a blend (module
    docstring; 0: not seen) and whether the mesh hides it.

    u, v, z, cos : float, the projection (pixels, within the image), depth (metres) and
    view cosine; edge_px (H, W, 1) float32 distance to an edge pixel, or (0, 0, 1) for
    none; zbuf (H, W, 1) float64 z-buffer, or (0, 0, 1). A pixel's footprint at depth z
    is ``footprint_constant + z * footprint_per_m``, metres (:func:`_footprint_terms`).
    """
    ramp = 1.0
    if edge_px.shape[0]:
        ramp = min(1.0, max(0.0, (_bilinear_at(edge_px, u, v, 0) - EDGE_MARGIN_PX)
                            / edge_ramp_px))
        if ramp == 0.0:   # (the weight below, times 0: no power computed)
            return 0.0, False
    w = ramp * (((cos - min_cos) / (1.0 - min_cos)) ** angle_power if cos > min_cos else 0.0)
    if w > 0.0 and zbuf.shape[0]:
        # w > 0 only off the edges: the 2 x 2 pixels read see one surface, all finite.
        tan = np.sqrt(1.0 - cos ** 2) / cos
        tol = (footprint_constant + z * footprint_per_m) * (depth_tolerance_px + tan)
        if z > _bilinear_at(zbuf, u, v, 0) + tol:
            return 0.0, True
    return w, False


@njit(cache=True, nogil=True)
def _sight_weights(u, v, z, cos, edge_px, zbuf, min_cos, angle_power, edge_ramp_px,
                   depth_tolerance_px, footprint_per_m, footprint_constant, weights, hidden):
    """:func:`sight_weight` of k points, ``u, v, z, cos`` (k,) float64: fills ``weights``
    (k,) and ``hidden`` (k,) bool."""
    for i in range(u.size):
        weights[i], hidden[i] = sight_weight(u[i], v[i], z[i], cos[i], edge_px, zbuf, min_cos,
                                              angle_power, edge_ramp_px, depth_tolerance_px,
                                              footprint_per_m, footprint_constant)


@njit(cache=True, nogil=True)
def _weigh_view(R, t, K, orthographic, vertices, normals, image, edge_px, zbuf, min_cos,
                angle_power, edge_ramp_px, depth_tolerance_px, footprint_per_m,
                footprint_constant, idx, weights, colours, hidden):
    """One view's part in the blend, in one pass over the n vertices: each vertex that
    faces the camera (``cos > min_cos``) and projects into ``image`` (H, W, 3) uint8
    (:func:`_view_of`, :func:`_in_image`) is weighed (:func:`sight_weight`). Fills, in
    vertex order, ``idx[:k]`` (n,) int64 the k vertices it blends into (weight > 0), their
    ``weights[:k]`` (n,) and ``colours[:k]`` (n, 3), the weighted colour of the image
    there, and ``hidden[:h]`` (n,) int64 the h vertices the mesh hides; returns
    ``(k, h)``."""
    height, width = image.shape[0], image.shape[1]
    k = 0
    h = 0
    for i in range(vertices.shape[0]):
        x, y, z, cos = _in_camera(R, t, orthographic, vertices[i, 0], vertices[i, 1],
                                   vertices[i, 2], normals[i, 0], normals[i, 1], normals[i, 2])
        if not cos > min_cos:
            continue
        u, v = _pixel(K, orthographic, x, y, z)
        if not (u >= 0 and u <= width - 1 and v >= 0 and v <= height - 1):
            continue
        w, is_hidden = sight_weight(u, v, z, cos, edge_px, zbuf, min_cos, angle_power,
                                     edge_ramp_px, depth_tolerance_px, footprint_per_m,
                                     footprint_constant)
        if is_hidden:
            hidden[h] = i
            h += 1
        if w > 0.0:
            idx[k] = i
            weights[k] = w
            for c in range(3):
                colours[k, c] = w * _bilinear_at(image, u, v, c)
            k += 1
    return k, h


@njit(cache=True, nogil=True)
def _add_view(idx, weights, weighted, hidden, total, weight_sum, n_views, n_hidden):
    """Add one view's part (from :func:`_weigh_view`, the vertices ``idx`` it blends into,
    each once, and ``hidden`` those it would but the mesh hides) to the running sums: the
    same additions as ``total[idx] += weighted`` and so on, in one pass."""
    for k in range(idx.size):
        i = idx[k]
        for c in range(3):
            total[i, c] += weighted[k, c]
        weight_sum[i] += weights[k]
        n_views[i] += 1
    for k in range(hidden.size):
        n_hidden[hidden[k]] += 1


def _edge_distance_px(zbuf: np.ndarray | None, mask: np.ndarray | None,
                      camera: Camera) -> np.ndarray | None:
    """(H, W) float32 distance (pixels) of each pixel to the nearest edge pixel.

    Edge pixels: background of the z-buffer ``zbuf`` (inf), either side of a
    z-buffer step of more than :data:`DEPTH_STEP_FOOTPRINTS` footprints between
    4-neighbours, outside ``mask``. None when there is neither.
    """
    if zbuf is None and mask is None:
        return None
    out = np.zeros((camera.height, camera.width), np.float32)
    if zbuf is None:
        out[...] = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2,
                                         cv2.DIST_MASK_PRECISE)
        return out
    # Every pixel off the mesh is an edge pixel: outside the mesh's box grown by one
    # pixel the distance is 0, and inside it the nearest edge pixel is in that box.
    first_row, last_row, first_col, last_col = _finite_box(zbuf)
    if last_row < 0:
        return out
    r0, c0 = max(0, first_row - 1), max(0, first_col - 1)
    off_edges = np.empty((min(camera.height, last_row + 2) - r0,
                          min(camera.width, last_col + 2) - c0), np.uint8)
    constant, per_metre = _footprint_terms(camera)
    _off_edges(zbuf, np.zeros((0, 0), bool) if mask is None else mask, r0, c0, constant,
               per_metre, off_edges)
    out[r0:r0 + off_edges.shape[0], c0:c0 + off_edges.shape[1]] = cv2.distanceTransform(
        off_edges, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return out


@njit(cache=True, nogil=True)
def _finite_box(zbuf):
    """``(first row, last row, first column, last column)`` of the finite pixels of
    ``zbuf`` (H, W); last row -1 when there is none."""
    first_row, last_row, first_col, last_col = zbuf.shape[0], -1, zbuf.shape[1], -1
    for r in range(zbuf.shape[0]):
        for c in range(zbuf.shape[1]):
            if math.isfinite(zbuf[r, c]):
                first_row, last_row = min(first_row, r), r
                first_col, last_col = min(first_col, c), max(last_col, c)
    return first_row, last_row, first_col, last_col


@njit(cache=True, nogil=True)
def _off_edges(zbuf, mask, r0, c0, footprint_constant, footprint_per_m, out):
    """``out`` (h, w) uint8: 1 at the pixels of the z-buffer ``zbuf`` (H, W) from row
    ``r0`` and column ``c0`` on that are no edge pixel (:func:`_edge_distance_px`), else 0;
    ``mask`` (H, W) bool or (0, 0) for none. A pixel's footprint at depth z is
    ``footprint_constant + z * footprint_per_m``, metres."""
    h, w = out.shape
    for r in range(h):
        for c in range(w):
            inside = mask.shape[0] == 0 or mask[r0 + r, c0 + c]
            out[r, c] = 1 if inside and math.isfinite(zbuf[r0 + r, c0 + c]) else 0
    for r in range(h):
        for c in range(w):
            a = zbuf[r0 + r, c0 + c]
            for dr, dc in ((1, 0), (0, 1)):   # 4-neighbours (inf - inf: no step)
                if r + dr < h and c + dc < w:
                    b = zbuf[r0 + r + dr, c0 + c + dc]
                    limit = DEPTH_STEP_FOOTPRINTS * (footprint_constant
                                                     + min(a, b) * footprint_per_m)
                    if abs(a - b) > limit:
                        out[r, c] = 0
                        out[r + dr, c + dc] = 0


def _planes(image: np.ndarray | None, dtype) -> np.ndarray:
    """``image`` (H, W) as an (H, W, 1) array of ``dtype`` for :func:`_weigh_view`; None
    as an empty (0, 0, 1) one."""
    if image is None:
        return np.zeros((0, 0, 1), dtype)
    return np.ascontiguousarray(image, dtype)[:, :, None]


@njit(cache=True, nogil=True, inline="always")
def _in_camera(R, t, orthographic, px, py, pz, nx, ny, nz):
    """The point ``(px, py, pz)`` (metres) in the camera ``R, t``'s frame: ``(x, y, z,
    cos)``, metres, and the cosine of the angle between its unit normal ``(nx, ny, nz)``
    and the direction to the camera."""
    x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
    y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
    z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
    cx = R[0, 0] * nx + R[0, 1] * ny + R[0, 2] * nz
    cy = R[1, 0] * nx + R[1, 1] * ny + R[1, 2] * nz
    cz = R[2, 0] * nx + R[2, 1] * ny + R[2, 2] * nz
    if orthographic:
        return x, y, z, -cz
    return x, y, z, -(cx * x + cy * y + cz * z) / max(math.sqrt(x * x + y * y + z * z), 1e-300)


@njit(cache=True, nogil=True, inline="always")
def view_point(R, t, K, orthographic, px, py, pz, nx, ny, nz):
    """How the camera ``R, t, K`` sees the point ``(px, py, pz)`` (metres) with the unit
    normal ``(nx, ny, nz)``: ``(u, v, depth, cos)`` (:func:`_view_of`'s, of one point)."""
    x, y, z, cos = _in_camera(R, t, orthographic, px, py, pz, nx, ny, nz)
    u, v = _pixel(K, orthographic, x, y, z)
    return u, v, z, cos


@njit(cache=True, nogil=True, inline="always")
def _pixel(K, orthographic, x, y, z):
    """``(u, v)``, pixels, of the point ``(x, y, z)`` in the camera's frame (NaN behind a
    pinhole camera)."""
    if orthographic:
        qx, qy, qw = x, y, 1.0
    else:
        qx, qy, qw = x, y, z if z > 0.0 else np.nan
    return ((K[0, 0] * qx + K[0, 1] * qy + K[0, 2] * qw) / qw,
            (K[1, 0] * qx + K[1, 1] * qy + K[1, 2] * qw) / qw)


@njit(cache=True, nogil=True)
def _view_kernel(R, t, K, orthographic, vertices, normals, u, v, depth, cos):
    """Fills ``u, v`` (pixels; NaN behind a pinhole camera), ``depth`` (metres) and
    ``cos`` for each vertex (see :func:`_view_of`)."""
    for i in range(vertices.shape[0]):
        x, y, depth[i], cos[i] = _in_camera(R, t, orthographic, vertices[i, 0],
                                            vertices[i, 1], vertices[i, 2], normals[i, 0],
                                            normals[i, 1], normals[i, 2])
        u[i], v[i] = _pixel(K, orthographic, x, y, depth[i])


def _view_of(camera: Camera, vertices: np.ndarray, normals: np.ndarray) -> tuple:
    """How ``camera`` sees each vertex: ``u, v`` (n,) pixels (NaN behind a pinhole
    camera), depth (n,) metres and ``cos`` (n,) of the angle between the normal
    and the direction to the camera."""
    u, v, depth, cos = (np.empty(len(vertices)) for _ in range(4))
    _view_kernel(camera.R, camera.t, camera.K, bool(camera.orthographic), vertices, normals,
                 u, v, depth, cos)
    return u, v, depth, cos


def _in_image(u: np.ndarray, v: np.ndarray, camera: Camera) -> np.ndarray:
    """(k,) bool: the projections ``u, v`` (pixels) lie where bilinear sampling reads the
    image, [0, W-1] x [0, H-1] (NaN, behind a pinhole camera, does not)."""
    return (u >= 0) & (u <= camera.width - 1) & (v >= 0) & (v <= camera.height - 1)


@dataclass(frozen=True)
class ViewSight:
    """How one view sees k points (:func:`view_sight`): ``u, v`` (k,) float64 pixels, NaN
    outside the image; ``weight`` (k,) float64 the colour blend's weight, 0 where the
    view does not see the point (grazing, near an edge, outside the mask, hidden); and
    ``hidden`` (k,) bool where the mesh hides it."""

    u: np.ndarray
    v: np.ndarray
    weight: np.ndarray
    hidden: np.ndarray


def view_sight(camera: Camera, points: np.ndarray, normals: np.ndarray, zbuf: np.ndarray | None,
               mask: np.ndarray | None, *, angle_power: float = ANGLE_POWER,
               min_cos: float = MIN_COS, edge_ramp_px: float = EDGE_RAMP_PX,
               depth_tolerance_px: float = DEPTH_TOLERANCE_PX,
               depth_zbuf: np.ndarray | None = None) -> ViewSight:
    """Which of ``points`` (k, 3) metres, with unit ``normals`` (k, 3), ``camera`` sees and
    how well: the test and weight :func:`vertex_colours` blends with, against the mesh's
    z-buffer ``zbuf`` (H, W) metres (:func:`~sfs_ros.core.render.rasterize_depth`; None:
    no occlusion test) and the silhouette ``mask`` (H, W) bool (optional). The options
    are :func:`vertex_colours`'s; ``depth_zbuf`` (H, W) metres, when given, is the
    z-buffer the depth test reads instead of ``zbuf`` (whose outline and depth steps
    still make the edges)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    u, v, z, cos = _view_of(camera, points, np.ascontiguousarray(normals, dtype=np.float64))
    inside = _in_image(u, v, camera)
    u, v = np.where(inside, u, np.nan), np.where(inside, v, np.nan)
    idx = np.flatnonzero(inside & (cos > min_cos))
    edge_px, depth, per_metre, constant = sight_maps(camera, zbuf, mask, depth_zbuf)
    weights, hidden = np.zeros(len(points)), np.zeros(len(points), bool)
    w, h = np.empty(len(idx)), np.empty(len(idx), bool)
    _sight_weights(u[idx], v[idx], z[idx], cos[idx], edge_px, depth, min_cos, angle_power,
                   edge_ramp_px, depth_tolerance_px, per_metre, constant, w, h)
    weights[idx], hidden[idx] = w, h
    return ViewSight(u=u, v=v, weight=weights, hidden=hidden)


def sight_maps(camera: Camera, zbuf: np.ndarray | None, mask: np.ndarray | None,
               depth_zbuf: np.ndarray | None = None) -> tuple:
    """What :func:`sight_weight` reads of one view (arguments as :func:`view_sight`'s):
    ``(edge_px (H, W, 1) float32, depth (H, W, 1) float64, footprint_per_m,
    footprint_constant)``, the maps (0, 0, 1) where there is none."""
    constant, per_metre = _footprint_terms(camera)
    return (_planes(_edge_distance_px(zbuf, mask, camera), np.float32),
            _planes(zbuf if depth_zbuf is None else depth_zbuf, np.float64), per_metre, constant)


def check_image(index: int, image, camera: Camera) -> np.ndarray:
    """``image`` as an array; ValueError unless (H, W, 3) uint8 for a camera of >= 2 x 2 px."""
    if not isinstance(camera, Camera):
        raise ValueError(f"camera of view {index} must be a Camera, got {type(camera).__name__}")
    image = np.asarray(image)
    expected = (camera.height, camera.width, 3)
    if image.shape != expected or image.dtype != np.uint8:
        raise ValueError(f"image of view {index} must be {expected} uint8 RGB (the camera's "
                         f"size), got {image.dtype} {image.shape}")
    if camera.width < 2 or camera.height < 2:
        raise ValueError(f"view {index} is {camera.width}x{camera.height} px; bilinear "
                         "sampling needs at least 2x2")
    return image


def fill_from_neighbours(colours: np.ndarray, seen: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Colours (n, 3) float64 of the unseen vertices by harmonic interpolation along edges
    (:class:`HarmonicFill`; ``seen`` (n,) bool, ``faces`` (m, 3))."""
    return HarmonicFill.of(seen, faces)(colours)


@njit(cache=True, nogil=True)
def _unseen_neighbours(seen, faces, index, n_unknown):
    """The neighbours along the edges of ``faces`` (m, 3) of each vertex not ``seen`` (n,)
    bool, ``index`` (n,) int64 its row among the u unseen ones (-1 for the others):
    ``(start (u + 1,), neighbours)`` int64, row ``r``'s neighbours
    ``neighbours[start[r]:start[r + 1]]``, ascending, each once."""
    start = np.zeros(n_unknown + 1, np.int64)
    for t in range(faces.shape[0]):
        for k in range(3):
            a, b = faces[t, k], faces[t, (k + 1) % 3]
            if not seen[a]:
                start[index[a] + 1] += 1
            if not seen[b]:
                start[index[b] + 1] += 1
    for r in range(n_unknown):
        start[r + 1] += start[r]
    listed = np.empty(start[n_unknown], np.int64)
    filled = start[:-1].copy()
    for t in range(faces.shape[0]):
        for k in range(3):
            a, b = faces[t, k], faces[t, (k + 1) % 3]
            if not seen[a]:
                listed[filled[index[a]]] = b
                filled[index[a]] += 1
            if not seen[b]:
                listed[filled[index[b]]] = a
                filled[index[b]] += 1
    # Each row sorted (a few entries: insertion sort) and its repeats dropped, in place.
    kept = 0
    for r in range(n_unknown):
        first = kept
        for e in range(start[r], start[r + 1]):
            value = listed[e]
            at = kept
            while at > first and listed[at - 1] > value:
                at -= 1
            if at > first and listed[at - 1] == value:
                continue
            for move in range(kept, at, -1):
                listed[move] = listed[move - 1]
            listed[at] = value
            kept += 1
        start[r] = first
    start[n_unknown] = kept
    return start, listed[:kept].copy()


@dataclass(frozen=True)
class HarmonicFill:
    """The harmonic interpolation of the unseen vertices' colours along edges, factored
    for one mesh and its seen vertices before any colour is known (:meth:`of`), then
    applied to colours (:meth:`__call__`).

    Solves ``deg(i) c_i = sum of c_j over the neighbours j`` for every unseen
    vertex ``i``, the seen ones fixed. A connected component with no seen vertex
    takes the mean colour of all seen vertices. Only the unseen vertices' rows
    of the adjacency are built: the unknowns are a small part of a mesh.

    Attributes
    ----------
    seen : (n,) bool
        The vertices whose colours are kept.
    unknown : (u,) int64
        The unseen vertices.
    orphan : (u,) bool
        Those in a component with no seen vertex.
    boundary_row, boundary_vertex : (b,) int64
        Each edge from an unseen vertex (its row among ``unknown``) to a seen vertex.
    factor : SuperLU or None
        The factored Laplacian of the unseen vertices not orphaned (None: none).
    """

    seen: np.ndarray
    unknown: np.ndarray
    orphan: np.ndarray
    boundary_row: np.ndarray
    boundary_vertex: np.ndarray
    factor: object

    @classmethod
    def of(cls, seen: np.ndarray, faces: np.ndarray) -> HarmonicFill:
        """The fill of the vertices not ``seen`` (n,) bool of a mesh of ``faces`` (m, 3)."""
        n = len(seen)
        unknown = np.flatnonzero(~seen)
        index = np.full(n, -1, np.int64)
        index[unknown] = np.arange(len(unknown))
        # Each edge once per unseen end, by unseen end then other end.
        start, ends_j = _unseen_neighbours(seen, np.ascontiguousarray(faces, np.int64), index,
                                           len(unknown))
        ends_i = np.repeat(unknown, np.diff(start))
        row, inner = index[ends_i], ~seen[ends_j]
        adjacency = sparse.csr_matrix((np.ones(int(inner.sum())),
                                       (row[inner], index[ends_j[inner]])),
                                      shape=(len(unknown), len(unknown)))
        degree = np.bincount(row, minlength=len(unknown)).astype(np.float64)
        # A component of the unseen vertices that touches no seen one lies in a component
        # of the mesh with no seen vertex.
        n_components, label = csgraph.connected_components(adjacency, directed=False)
        orphan = (np.bincount(label[row[~inner]], minlength=n_components) == 0)[label]
        solve = np.flatnonzero(~orphan)
        factor = None
        if solve.size:
            laplacian = sparse.diags(degree[solve]) - adjacency[solve][:, solve]
            # Symmetric positive definite: a symmetric ordering and no pivoting (SuperLU's
            # symmetric mode) factor it in about two thirds of the time of the default.
            factor = splu(laplacian.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                          options={"SymmetricMode": True})
        return cls(seen=seen, unknown=unknown, orphan=orphan, boundary_row=row[~inner],
                   boundary_vertex=ends_j[~inner], factor=factor)

    def __call__(self, colours: np.ndarray) -> np.ndarray:
        """(n, 3) float64 ``colours`` (n, 3) with the unseen vertices' interpolated."""
        out = np.array(colours, np.float64)
        out[self.unknown[self.orphan]] = out[self.seen].mean(axis=0)
        if self.factor is not None:
            known_sum = np.stack([np.bincount(self.boundary_row,
                                              weights=out[self.boundary_vertex, c],
                                              minlength=len(self.unknown)) for c in range(3)],
                                 axis=1)
            out[self.unknown[~self.orphan]] = self.factor.solve(known_sum[~self.orphan])
        return out


@dataclass(frozen=True)
class SmoothedFill:
    """Colours for the unseen vertices, smooth and meeting the seen ones without a seam,
    near :class:`HarmonicFill`'s at a fraction of its cost: the harmonic interpolation
    solved on patches of the unseen vertices (each vertex within ``radius`` edges of its
    patch's first; one unknown a patch, the patches' Laplacian the vertices' summed), each
    vertex its patch's colour, then ``sweeps`` symmetric Gauss-Seidel passes (each unseen
    vertex the mean of its neighbours, forwards then backwards, the seen ones fixed) that
    smooth the patches' steps away. Every colour is a weighted mean of the seen ones
    (within their range; a constant stays constant); as ``sweeps`` grows it tends to
    :class:`HarmonicFill`'s. A connected component with no seen vertex takes the mean
    colour of all seen vertices. Made for one mesh and its seen vertices before any colour
    is known (:meth:`of`), then applied to colours (:meth:`__call__`).

    Attributes
    ----------
    seen : (n,) bool
        The vertices whose colours are kept.
    order : (r,) int64
        The unseen vertices that a path of edges joins to a seen one, nearest first.
    start, neighbours : (r + 1,), int64
        The neighbours of ``order[i]``: ``neighbours[start[i]:start[i + 1]]``.
    patch : (r,) int64
        The patch of each of ``order``.
    boundary_row, boundary_vertex : (b,) int64
        Each edge from one of ``order`` (its row) to a seen vertex.
    factor : SuperLU or None
        The factored Laplacian of the patches (None: no unseen vertex joined to a seen one).
    orphans : (o,) int64
        The unseen vertices in a component with no seen vertex.
    sweeps : int
        The smoothing passes after the patches.
    """

    seen: np.ndarray
    order: np.ndarray
    start: np.ndarray
    neighbours: np.ndarray
    patch: np.ndarray
    boundary_row: np.ndarray
    boundary_vertex: np.ndarray
    factor: object
    orphans: np.ndarray
    sweeps: int

    @classmethod
    def of(cls, seen: np.ndarray, faces: np.ndarray, sweeps: int = 8,
           radius: int = 4) -> SmoothedFill:
        """The fill of the vertices not ``seen`` (n,) bool of a mesh of ``faces`` (m, 3):
        patches of ``radius`` >= 0 edges, ``sweeps`` >= 0 smoothing passes."""
        if sweeps < 0 or radius < 0:
            raise ValueError(f"sweeps and radius must be >= 0, got {sweeps} and {radius}")
        seen = np.asarray(seen, bool)
        unknown = np.flatnonzero(~seen)
        index = np.full(len(seen), -1, np.int64)
        index[unknown] = np.arange(len(unknown))
        start, neighbours = _unseen_neighbours(seen, np.ascontiguousarray(faces, np.int64),
                                               index, len(unknown))
        reached, order = _nearest_first(seen, unknown, index, start, neighbours)
        start, neighbours = _rows_in_order(index[order], start, neighbours)
        row = np.full(len(seen), -1, np.int64)
        row[order] = np.arange(len(order))
        patch = _patches(row, start, neighbours, int(radius))
        ends_i = np.repeat(np.arange(len(order)), np.diff(start))
        ends_j = row[neighbours]
        inner = ends_j >= 0
        factor = None
        if order.size:
            n_patches = int(patch.max()) + 1
            # The patches' Laplacian: P^T L P for P (r, patches) each vertex's patch.
            diagonal = np.bincount(patch, weights=np.diff(start).astype(np.float64),
                                   minlength=n_patches)
            laplacian = sparse.csc_matrix(
                (np.concatenate([diagonal, -np.ones(int(inner.sum()))]),
                 (np.concatenate([np.arange(n_patches), patch[ends_i[inner]]]),
                  np.concatenate([np.arange(n_patches), patch[ends_j[inner]]]))),
                shape=(n_patches, n_patches))
            factor = splu(laplacian, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                          options={"SymmetricMode": True})
        return cls(seen=seen, order=order, start=start, neighbours=neighbours, patch=patch,
                   boundary_row=ends_i[~inner], boundary_vertex=neighbours[~inner],
                   factor=factor, orphans=unknown[~reached[unknown]], sweeps=int(sweeps))

    def __call__(self, colours: np.ndarray) -> np.ndarray:
        """(n, 3) float64 ``colours`` (n, 3) with the unseen vertices' filled."""
        out = np.array(colours, np.float64)
        if self.orphans.size:
            out[self.orphans] = out[self.seen].mean(axis=0) if self.seen.any() else 0.0
        if self.factor is not None:
            n_patches = self.factor.shape[0]
            known_sum = np.stack([np.bincount(self.patch[self.boundary_row],
                                              weights=out[self.boundary_vertex, c],
                                              minlength=n_patches) for c in range(3)], axis=1)
            out[self.order] = self.factor.solve(known_sum)[self.patch]
            _sweep(out, self.order, self.start, self.neighbours, self.sweeps)
        return out


@njit(cache=True, nogil=True)
def _nearest_first(seen, unknown, index, start, neighbours):
    """Breadth-first from the seen vertices over the unseen ones' neighbours (rows of
    :func:`_unseen_neighbours`, ``index`` (n,) each vertex's row, -1 for the seen):
    ``(reached (n,) bool, order (r,) int64)``, the unseen vertices reached, nearest
    first."""
    reached = seen.copy()
    order = np.empty(len(unknown), np.int64)
    count = 0
    for v in unknown:  # those with a seen neighbour first
        r = index[v]
        for e in range(start[r], start[r + 1]):
            if seen[neighbours[e]]:
                reached[v] = True
                order[count] = v
                count += 1
                break
    head = 0
    while head < count:
        r = index[order[head]]
        head += 1
        for e in range(start[r], start[r + 1]):
            w = neighbours[e]
            if not reached[w]:
                reached[w] = True
                order[count] = w
                count += 1
    return reached, order[:count].copy()


@njit(cache=True, nogil=True)
def _rows_in_order(rows, start, neighbours):
    """The neighbour lists of ``rows`` (r,) of (``start``, ``neighbours``), one after
    the other: ``(start (r + 1,), neighbours)`` int64."""
    new_start = np.zeros(len(rows) + 1, np.int64)
    for i in range(len(rows)):
        new_start[i + 1] = new_start[i] + start[rows[i] + 1] - start[rows[i]]
    new = np.empty(new_start[-1], np.int64)
    for i in range(len(rows)):
        new[new_start[i]:new_start[i + 1]] = neighbours[start[rows[i]]:start[rows[i] + 1]]
    return new_start, new


@njit(cache=True, nogil=True)
def _patches(row, start, neighbours, radius):
    """(r,) int64 each row's patch: rows taken in turn, each not yet in a patch starting
    one, breadth-first out to ``radius`` edges over the rows in none (``row`` (n,) each
    vertex's row, -1 for those not among them)."""
    n_rows = len(start) - 1
    patch = np.full(n_rows, -1, np.int64)
    queue = np.empty(n_rows, np.int64)
    depth = np.empty(n_rows, np.int64)
    n_patches = 0
    for first in range(n_rows):
        if patch[first] >= 0:
            continue
        patch[first] = n_patches
        queue[0], depth[0] = first, 0
        head, tail = 0, 1
        while head < tail:
            i, d = queue[head], depth[head]
            head += 1
            if d == radius:
                continue
            for e in range(start[i], start[i + 1]):
                j = row[neighbours[e]]
                if j >= 0 and patch[j] < 0:
                    patch[j] = n_patches
                    queue[tail], depth[tail] = j, d + 1
                    tail += 1
        n_patches += 1
    return patch


@njit(cache=True, nogil=True)
def _sweep(out, order, start, neighbours, sweeps):
    """``sweeps`` symmetric Gauss-Seidel passes on ``out`` (n, 3) float64 in place: each
    of ``order`` the mean of its neighbours (:class:`SmoothedFill`'s rows)."""
    for sweep in range(2 * sweeps):
        for step in range(len(order)):
            i = step if sweep % 2 == 0 else len(order) - 1 - step
            r = g = b = 0.0
            for e in range(start[i], start[i + 1]):
                w = neighbours[e]
                r += out[w, 0]
                g += out[w, 1]
                b += out[w, 2]
            count = start[i + 1] - start[i]
            v = order[i]
            out[v, 0], out[v, 1], out[v, 2] = r / count, g / count, b / count

def _check_colour_inputs(images: Sequence, cameras: list[Camera], masks: Sequence | None, *,
                         angle_power: float, min_cos: float, edge_ramp_px: float,
                         depth_tolerance_px: float, coverage: bool,
                         occlusion: bool) -> list:
    """ValueError naming the first of :func:`vertex_colours`' arguments out of its range;
    else the masks, validated (one None per view when none are given)."""
    if not cameras:
        raise ValueError("need at least one view (image and camera) to colour a mesh")
    if len(images) != len(cameras):
        raise ValueError(f"got {len(cameras)} cameras but {len(images)} images; expected one "
                         "image per camera")
    masks = [None] * len(cameras) if masks is None else validate_masks(cameras, masks)
    if not (math.isfinite(angle_power) and angle_power >= 0):
        raise ValueError(f"angle_power must be a finite number >= 0, got {angle_power}")
    if not 0.0 <= min_cos < 1.0:
        raise ValueError(f"min_cos must be in [0, 1), got {min_cos}")
    if not (math.isfinite(edge_ramp_px) and edge_ramp_px > 0):
        raise ValueError(f"edge_ramp_px must be a finite number of pixels > 0, got {edge_ramp_px}")
    if not (math.isfinite(depth_tolerance_px) and depth_tolerance_px >= 0):
        raise ValueError(f"depth_tolerance_px must be a finite number of pixels >= 0, "
                         f"got {depth_tolerance_px}")
    if coverage and not occlusion:
        raise ValueError("coverage comes from the occlusion test's z-buffers: it needs "
                         "occlusion=True")
    return masks


@dataclass(frozen=True)
class _Weighing:
    """One mesh (as :func:`~sfs_ros.core.render.as_mesh_arrays` returns it) and
    :func:`vertex_colours`' options, to weigh each view's colours with."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    occlusion: bool
    closed: bool
    coverage: bool
    min_cos: float
    angle_power: float
    edge_ramp_px: float
    depth_tolerance_px: float

    def one_view(self, view: tuple) -> tuple:
        """What one view ``(image, camera, mask)`` adds: the vertices it sees, their
        weights and colours, and the vertices it would see but the mesh hides (and its
        coverage by the mesh, packed bits, when asked for)."""
        image, camera, mask = view
        vertices, n = self.vertices, len(self.vertices)
        zbuf = (depth_of_checked(vertices, self.faces, camera, closed=self.closed)
                if self.occlusion else None)
        edge_px = _edge_distance_px(zbuf, mask, camera)
        constant, per_metre = _footprint_terms(camera)
        idx, weights, weighted = np.empty(n, np.int64), np.empty(n), np.empty((n, 3))
        hidden = np.empty(n, np.int64)
        k, h = _weigh_view(camera.R, camera.t, camera.K, bool(camera.orthographic), vertices,
                           self.normals, image, _planes(edge_px, np.float32),
                           _planes(zbuf, np.float64), self.min_cos, self.angle_power,
                           self.edge_ramp_px, self.depth_tolerance_px, per_metre, constant,
                           idx, weights, weighted, hidden)
        covered = np.packbits(np.isfinite(zbuf), axis=None) if self.coverage else None
        # (copied out: the vertex-sized buffers are not kept while the result waits)
        return idx[:k].copy(), weights[:k].copy(), weighted[:k].copy(), hidden[:h].copy(), \
            covered


def vertex_colours(vertices, faces, images: Sequence, cameras: Sequence[Camera], *,
                   masks: Sequence | None = None, occlusion: bool = True,
                   angle_power: float = ANGLE_POWER, min_cos: float = MIN_COS,
                   edge_ramp_px: float = EDGE_RAMP_PX,
                   depth_tolerance_px: float = DEPTH_TOLERANCE_PX, coverage: bool = False,
                   closed: bool = False, on_blended: Callable[[], None] | None = None
                   ) -> VertexColours:
    """Colour every vertex of a closed mesh from the views that see it.

    Parameters
    ----------
    vertices : (n, 3) float64
        Metres, object frame.
    faces : (m, 3) int
        Vertex indices, counter-clockwise seen from outside (outward normals).
    images : sequence of (H, W, 3) uint8
        RGB image of each view, the size of its camera.
    cameras : sequence of Camera
        Object frame -> pixels of each image.
    masks : sequence of (H, W) bool, optional
        Silhouette of the object in each view (True = object); a vertex takes
        no colour from a view where it falls outside the silhouette.
    occlusion : bool
        Test visibility against the mesh's z-buffer (the default). False keeps
        only the normal, image and mask tests: a baseline in which what the
        mesh hides from a view is coloured with whatever the view shows there.
    angle_power : float >= 0
        Exponent ``k`` of the view-angle weight ``((cos - min_cos) / (1 - min_cos)) ** k``.
    min_cos : float in [0, 1)
        Views seeing the surface at ``cos <= min_cos`` (default 0.2: beyond 78
        degrees from the normal) do not contribute.
    edge_ramp_px : float > 0
        Width of the ramp of the weight from 0 to 1 near edges, pixels.
    depth_tolerance_px : float >= 0
        A vertex at depth ``z`` (metres), seen at ``angle`` from its normal, is
        visible when ``z <= z_buffer(u, v) + footprint * (depth_tolerance_px +
        tan(angle))``: the z-buffer interpolated bilinearly at the projection
        ``(u, v)`` (exact on a plane; off the edges its 2 x 2 pixels see one
        surface), ``footprint`` the size of a pixel at depth ``z``. A faceted
        surface bends within the pixel by up to ``tan(angle)`` footprints (its
        depth step across one pixel); what hides the vertex lies further in front.
    coverage : bool
        Also return each view's coverage by the mesh, from the z-buffers drawn for
        the occlusion test (the same pixel-centre rule as
        :func:`sfs_ros.core.metrics.reprojection_ious`): the silhouettes of the
        mesh, for free. Needs ``occlusion``.
    closed : bool
        The mesh is closed and outward-oriented (the pipeline's checks found it
        watertight with a positive volume): the z-buffers draw only the faces
        turned towards the camera, the same depths for about half the work (see
        :func:`~sfs_ros.core.render.rasterize_depth`).
    on_blended : callable or None
        Called (no arguments) once every view is blended, before the vertices no view
        sees are filled in, which takes one core: another thread may then use the rest.

    Returns
    -------
    VertexColours
        ``colours`` (n, 3) uint8, ``n_views`` and ``n_hidden`` (n,) int64, ``stats``.

    Raises
    ------
    ValueError
        Bad mesh, image, mask or option; no view; or no vertex seen by any view.
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    cameras = list(cameras)
    masks = _check_colour_inputs(images, cameras, masks, angle_power=angle_power,
                                 min_cos=min_cos, edge_ramp_px=edge_ramp_px,
                                 depth_tolerance_px=depth_tolerance_px, coverage=coverage,
                                 occlusion=occlusion)
    images = [check_image(i, image, c) for i, (image, c) in enumerate(zip(images, cameras))]
    normals = vertex_normals(vertices, faces)
    total = np.zeros((len(vertices), 3))
    weight_sum = np.zeros(len(vertices))
    n_views = np.zeros(len(vertices), dtype=np.int64)
    n_hidden = np.zeros(len(vertices), dtype=np.int64)
    weighing = _Weighing(vertices, faces, normals, occlusion=occlusion, closed=closed,
                         coverage=coverage, min_cos=min_cos, angle_power=angle_power,
                         edge_ramp_px=edge_ramp_px, depth_tolerance_px=depth_tolerance_px)

    # Views in threads (numpy and the rasteriser release the GIL), summed in view order:
    # the same sums as one view after the other.
    covers = []
    for idx, w, weighted, hidden, covered in map_in_threads(weighing.one_view,
                                                           zip(images, cameras, masks)):
        covers.append(covered)
        _add_view(idx, w, weighted, hidden, total, weight_sum, n_views, n_hidden)

    if on_blended is not None:
        on_blended()
    return _blended(total, weight_sum, n_views, n_hidden, faces, len(cameras), occlusion,
                    covers if coverage else None)


def _blended(total, weight_sum, n_views, n_hidden, faces, n_cameras: int, occlusion: bool,
             coverage: list | None) -> VertexColours:
    """The vertices' colours from the views' sums: ``total`` (n, 3) weighted colours and
    ``weight_sum`` (n,) their weights; the vertices no view sees filled from their
    neighbours."""
    seen = weight_sum > 0
    if not seen.any():
        raise ValueError("no vertex is seen by any view: check that the cameras look at the "
                         "mesh (calibration, frame) and that faces are outward")
    colours = np.zeros((len(total), 3))
    colours[seen] = total[seen] / weight_sum[seen, None]
    if not seen.all():
        colours = fill_from_neighbours(colours, seen, faces)
    stats = {"vertices": int(len(total)), "views": n_cameras, "seen": int(seen.sum()),
             "filled": int((~seen).sum()),
             "mean_views_per_seen_vertex": float(n_views[seen].mean()),
             "occlusion": bool(occlusion), "occluded_pairs": int(n_hidden.sum())}
    return VertexColours(colours=np.clip(np.rint(colours), 0, 255).astype(np.uint8),
                         n_views=n_views, n_hidden=n_hidden, stats=stats, coverage=coverage)
