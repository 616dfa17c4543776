"""Levelling the views' colours where their charts meet, so a texture shows no patchwork.

Two views of one surface differ in exposure and white balance (the camera's automatic
exposure, the light's angle to each view). Two steps, as in Waechter, Moehrle and
Goesele (2014), simplified:

* **global**: one gain per view and channel, ``g_l``, fitted by least squares in the log
  domain over every pair of views ``a`` and ``b`` that meet at a seam: their mean
  colours over the faces both see unhidden, ``c_a`` and ``c_b`` (at the faces'
  centroids; faces either sees at a slant beyond 60 degrees left out), should agree,
  ``log g_a + log c_a = log g_b + log c_b``, each pair weighted by the square root of
  its faces; the gains' logarithms are held towards 0 by a weak
  term (1 % of a view's shared faces), which also fixes the common scale. Means over
  whole regions, not seam by seam: detail finer than a pixel or two differs between two
  views' samples of one point (resampling, misregistration) and averages out only over
  many points. Samples darker than :data:`DARK` grey levels in any channel are left out;
* **local**: at every vertex where faces of several views meet, each view's colour
  (after its gain) is moved to the mean of them all, the move averaged along the seam
  with the view's moves at the neighbouring such vertices (:func:`seam_offsets`) and
  fading linearly to zero across the faces around the vertex, so the colour is
  continuous across the seam. Faces a view only glimpses (:mod:`.selection`) take no
  part.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import sparse
from scipy.sparse.linalg import lsqr

from ..geometry.camera import Camera
from .selection import towards_camera

__all__ = ["COMPARED_FACES", "DARK", "FRONTAL_COS", "KERNELS", "corner_colours", "interpolate",
           "sample_image", "seam_edges", "seam_offsets", "view_gains"]

#: Samples darker than this (grey levels, any channel) are not compared: their ratio is
#: mostly noise.
DARK = 8.0
#: Sweeps of averaging the seam offsets with their neighbours' (:func:`seam_offsets`).
SEAM_SMOOTHING = 10
#: Faces a view sees more obliquely than acos of this are not compared: a pixel there
#: spans much of the surface, and its colour is the mean of detail the other view resolves.
FRONTAL_COS = 0.5
#: The interpolations :func:`interpolate` offers, by name: OpenCV's flags.
KERNELS = {"bilinear": cv2.INTER_LINEAR, "bicubic": cv2.INTER_CUBIC}
#: About as many faces, evenly spread in the mesh's order, are compared for the gains.
COMPARED_FACES = 20000
#: Width of the maps OpenCV samples points with.
_REMAP_WIDTH = 4096
#: Weight of the term holding each view's log gain to 0, per seam edge of that view.
_PRIOR = 0.01


def interpolate(image: np.ndarray, x: np.ndarray, y: np.ndarray, *,
                kernel: str = "bilinear") -> np.ndarray:
    """(k, 3) float32 ``image`` (H, W, 3) float32 at the points ``x, y`` (k,) pixels (pixel
    ``(r, c)``'s centre at ``(c, r)``), interpolated with ``kernel`` (:data:`KERNELS`:
    bilinear, 2 x 2 pixels; bicubic, 4 x 4), the border repeated beyond it."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
    k = len(x)
    rows = max(1, -(-k // _REMAP_WIDTH))            # OpenCV's maps are below 32767 a side
    maps = np.full((2, rows * _REMAP_WIDTH), -1.0, np.float32)
    maps[0, :k], maps[1, :k] = x, y
    out = cv2.remap(image, maps[0].reshape(rows, -1), maps[1].reshape(rows, -1),
                    KERNELS[kernel], borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:k]


def sample_image(image: np.ndarray, camera: Camera, points: np.ndarray, *,
                 kernel: str = "bilinear") -> np.ndarray:
    """(k, 3) float32 colour of ``image`` (H, W, 3) float32 at the projections of ``points``
    (k, 3) metres, interpolated with ``kernel`` (:func:`interpolate`; the border repeated for
    points projecting outside)."""
    uv = np.nan_to_num(camera.project(points), nan=-1.0) if len(points) else np.zeros((0, 2))
    return interpolate(image, uv[:, 0], uv[:, 1], kernel=kernel)


def seam_edges(faces: np.ndarray, labels: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """(e, 4) int64 rows ``(face, neighbour, vertex, vertex)`` of every seam edge once: two
    neighbouring faces seen from different views (both labels >= 0)."""
    m = len(faces)
    f = np.repeat(np.arange(m), 3)
    k = np.tile(np.arange(3), m)
    g = neighbours.ravel()
    seam = (g > f) & (labels[f] >= 0) & (labels[np.maximum(g, 0)] >= 0) \
        & (labels[f] != labels[np.maximum(g, 0)])
    f, k, g = f[seam], k[seam], g[seam]
    return np.column_stack([f, g, faces[f, k], faces[f, (k + 1) % 3]])


def view_gains(images: list, cameras: list[Camera], vertices: np.ndarray, faces: np.ndarray,
               seen: np.ndarray, labels: np.ndarray, seams: np.ndarray) -> np.ndarray:
    """(V, 3) float64 gain of each view and channel (module docstring): for every pair of
    views meeting at a seam edge (``seams``, :func:`seam_edges` of faces with ``labels``),
    the ratio of their mean colours over the faces both see (``seen`` (m, V) bool) within
    acos :data:`FRONTAL_COS` of the face's normal, at the faces' centroids (about
    :data:`COMPARED_FACES` of them); ``images`` float32."""
    n_views = len(cameras)
    a, b = labels[seams[:, 0]], labels[seams[:, 1]]
    pairs = np.unique(np.column_stack([np.minimum(a, b), np.maximum(a, b)]), axis=0)
    # Means over many faces: every so many of a large mesh's hold them as well.
    step = max(1, len(faces) // COMPARED_FACES)
    faces, seen = faces[::step], seen[::step]
    tri = vertices[faces]
    centroid = tri.mean(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    colour = np.zeros((len(faces), n_views, 3), np.float32)
    frontal = np.zeros((len(faces), n_views), np.float32)
    for view in np.unique(pairs):
        cos = np.einsum("md,md->m", normal, towards_camera(cameras[view], centroid))
        mine = np.flatnonzero(seen[:, view] & (cos >= FRONTAL_COS))
        sampled = sample_image(images[view], cameras[view], centroid[mine])
        bright = np.all(sampled > DARK, axis=1)
        colour[mine[bright], view] = sampled[bright]
        frontal[mine[bright], view] = 1.0
    gains = np.ones((n_views, 3))
    pair_a, pair_b = pairs[:, 0], pairs[:, 1]
    # Over the faces both views of a pair see: sums[a, b] the colour in view a, as
    # matrix products (V, m) @ (m, V).
    count = (frontal.T @ frontal)[pair_a, pair_b].astype(np.float64)
    sums = np.stack([(colour[..., c] * frontal).T @ frontal for c in range(3)], axis=-1)
    sums = np.stack([sums[pair_a, pair_b], sums[pair_b, pair_a]]).astype(np.float64)
    fitted = count > 0
    pair_a, pair_b, count = pair_a[fitted], pair_b[fitted], count[fitted]
    per_view = np.bincount(np.concatenate([pair_a, pair_b]),
                           weights=np.concatenate([count, count]), minlength=n_views)
    for channel in range(3):
        ratio = sums[1, fitted, channel] / sums[0, fitted, channel]
        gains[:, channel] = np.exp(_log_gains(pair_a, pair_b, np.log(ratio), per_view,
                                              np.sqrt(count)))
    return gains


def _log_gains(a: np.ndarray, b: np.ndarray, target: np.ndarray, per_view: np.ndarray,
               weight: np.ndarray):
    """Weighted least-squares ``x`` (V,) with ``weight * (x[a] - x[b]) = weight * target``
    per pair and the weak prior ``sqrt(_PRIOR * per_view) * x = 0`` (at least a small
    weight)."""
    n_views, e = len(per_view), len(a)
    rows = np.concatenate([np.arange(e), np.arange(e), e + np.arange(n_views)])
    cols = np.concatenate([a, b, np.arange(n_views)])
    values = np.concatenate([weight, -weight, np.sqrt(_PRIOR * np.maximum(per_view, 1))])
    matrix = sparse.csr_matrix((values, (rows, cols)), shape=(e + n_views, n_views))
    return lsqr(matrix, np.concatenate([weight * target, np.zeros(n_views)]),
                atol=1e-10, btol=1e-10)[0]


def corner_colours(images: list, cameras: list[Camera], gains: np.ndarray,
                   vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each seen face's corners as its view sees them, and where views meet.

    Returns ``(corner (m, 3, 3) float64 colour of each face's corners in its view, times
    the gain; vertex (n, 3) float64 mean colour of each vertex over the views of its
    faces; views (n,) int64 how many views meet at each vertex)``; unseen faces' rows of
    ``corner`` and unseen vertices' of ``vertex`` are 0.
    """
    n, n_views = len(vertices), len(cameras)
    seen = np.flatnonzero(labels >= 0)
    pair = (faces[seen] * n_views + labels[seen, None]).ravel()      # (vertex, view) keys
    keys, inverse = np.unique(pair, return_inverse=True)
    vertex_of, view_of = keys // n_views, keys % n_views
    colour = np.zeros((len(keys), 3))
    for label in np.unique(view_of):
        mine = view_of == label
        colour[mine] = gains[label] * sample_image(images[label], cameras[label],
                                                   vertices[vertex_of[mine]])
    views = np.bincount(vertex_of, minlength=n)
    total = np.stack([np.bincount(vertex_of, weights=colour[:, c], minlength=n)
                      for c in range(3)], axis=1)
    vertex = np.divide(total, views[:, None], out=np.zeros((n, 3)), where=views[:, None] > 0)
    corner = np.zeros((len(faces), 3, 3))
    corner[seen] = colour[inverse.reshape(-1, 3)]
    return corner, vertex, views


def seam_offsets(vertices_views: np.ndarray, vertex: np.ndarray, corner: np.ndarray,
                 faces: np.ndarray, labels: np.ndarray, n_views: int) -> np.ndarray:
    """(m, 3, 3) offsets moving each face's corners (``corner`` (m, 3, 3)) to the mean of
    the views meeting there (``vertex`` (n, 3); ``vertices_views`` (n,) how many meet),
    smoothed along the seams: each view's offset at a vertex is averaged, over
    :data:`SEAM_SMOOTHING` sweeps, with its offsets at the neighbouring vertices where
    views meet too. Exposure and shading differ smoothly along a seam; detail finer than
    the blur that two views sample differently does not, and averages out."""
    seen = np.flatnonzero(labels >= 0)
    meeting = vertices_views[faces[seen]] >= 2                        # (s, 3)
    key = faces[seen] * n_views + labels[seen, None]
    keys, inverse = np.unique(key[meeting], return_inverse=True)
    offset = np.zeros((len(keys), 3))
    offset[inverse] = (vertex[faces[seen]] - corner[seen])[meeting]
    # Edges of each face between two corners where views meet, as (key, key) of one view.
    index = np.full(key.shape, -1)
    index[meeting] = inverse
    ends = np.concatenate([index[:, [0, 1]], index[:, [1, 2]], index[:, [2, 0]]])
    ends = ends[(ends >= 0).all(axis=1)]
    n = len(keys)
    adjacency = sparse.csr_matrix((np.ones(2 * len(ends)), (np.r_[ends[:, 0], ends[:, 1]],
                                                            np.r_[ends[:, 1], ends[:, 0]])),
                                  shape=(n, n))
    adjacency.data[:] = 1.0                                            # duplicates once
    adjacency = adjacency + sparse.identity(n, format="csr")
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    for _ in range(SEAM_SMOOTHING):
        offset = (adjacency @ offset) / degree[:, None]
    out = np.zeros_like(corner)
    moved = np.zeros((len(seen), 3, 3))
    moved[meeting] = offset[inverse]
    out[seen] = moved
    return out
