"""Levelling the views' colours where their charts meet, so a texture shows no patchwork.

Two views of one surface differ in exposure and white balance (the camera's automatic
exposure, the light's angle to each view). Two steps, as in Waechter, Moehrle and
Goesele (2014), simplified:

* **global**: one gain per view and channel, ``g_l``, fitted by least squares in the log
  domain along every seam edge (neighbouring faces from views ``a`` and ``b``): the
  mean colour of the edge's ends and midpoint in either view, ``c_a`` and ``c_b``, should
  agree, ``log g_a + log c_a = log g_b + log c_b``; the gains' logarithms are held
  towards 0 by a weak term (1 % of a view's seam count), which also fixes the common
  scale. Samples darker than :data:`DARK` grey levels or whose views disagree by more
  than a factor :data:`MISMATCH` (a seam on a misregistered edge) are left out;
* **local**: at every vertex where faces of several views meet, each view's colour
  (after its gain) is moved to the mean of them all, the move fading linearly to zero
  across the faces around the vertex, so the colour is continuous across the seam.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import sparse
from scipy.sparse.linalg import lsqr

from ..geometry.camera import Camera

__all__ = ["DARK", "MISMATCH", "bilinear", "corner_colours", "sample_image", "seam_edges", "view_gains"]

#: Seam samples darker than this (grey levels, any channel) are not fitted: their ratio is
#: mostly noise.
DARK = 8.0
#: Seam samples whose two views' colours differ by more than this factor are not fitted.
MISMATCH = 2.0
#: Width of the maps OpenCV samples points with.
_REMAP_WIDTH = 4096
#: Weight of the term holding each view's log gain to 0, per seam edge of that view.
_PRIOR = 0.01


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(k, 3) float32 ``image`` (H, W, 3) float32 at the points ``x, y`` (k,) pixels (pixel
    ``(r, c)``'s centre at ``(c, r)``), bilinear, the border repeated beyond it."""
    k = len(x)
    rows = max(1, -(-k // _REMAP_WIDTH))            # OpenCV's maps are below 32767 a side
    maps = np.full((2, rows * _REMAP_WIDTH), -1.0, np.float32)
    maps[0, :k], maps[1, :k] = x, y
    out = cv2.remap(image, maps[0].reshape(rows, -1), maps[1].reshape(rows, -1),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:k]


def sample_image(image: np.ndarray, camera: Camera, points: np.ndarray) -> np.ndarray:
    """(k, 3) float32 colour of ``image`` (H, W, 3) float32 at the projections of ``points``
    (k, 3) metres, bilinear (the border repeated for points projecting outside)."""
    uv = np.nan_to_num(camera.project(points), nan=-1.0) if len(points) else np.zeros((0, 2))
    return bilinear(image, uv[:, 0], uv[:, 1])


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


def view_gains(images: list, cameras: list[Camera], vertices: np.ndarray, labels: np.ndarray,
               seams: np.ndarray) -> np.ndarray:
    """(V, 3) float64 gain of each view and channel (module docstring) from the seam edges
    ``seams`` (:func:`seam_edges`) of faces with ``labels``; ``images`` float32."""
    n_views = len(cameras)
    ends = vertices[seams[:, 2:]]                                     # (e, 2, 3)
    points = np.concatenate([ends, ends.mean(axis=1, keepdims=True)], axis=1)
    sides = []
    for face in (seams[:, 0], seams[:, 1]):
        colour = np.zeros((len(seams), 3, 3), np.float32)
        for label in np.unique(labels[face]):
            mine = labels[face] == label
            colour[mine] = sample_image(images[label], cameras[label],
                                        points[mine].reshape(-1, 3)).reshape(-1, 3, 3)
        sides.append(colour.mean(axis=1).astype(np.float64))
    a, b = labels[seams[:, 0]], labels[seams[:, 1]]
    per_view = np.bincount(np.concatenate([a, b]), minlength=n_views).astype(np.float64)
    gains = np.ones((n_views, 3))
    for channel in range(3):
        ca, cb = sides[0][:, channel], sides[1][:, channel]
        keep = (ca > DARK) & (cb > DARK)
        keep[keep] &= np.abs(np.log(ca[keep] / cb[keep])) < np.log(MISMATCH)
        gains[:, channel] = np.exp(_log_gains(a[keep], b[keep],
                                              np.log(cb[keep] / ca[keep]), per_view))
    return gains


def _log_gains(a: np.ndarray, b: np.ndarray, target: np.ndarray, per_view: np.ndarray):
    """Least-squares ``x`` (V,) with ``x[a] - x[b] = target`` per seam sample and the weak
    prior ``sqrt(_PRIOR * per_view) * x = 0`` (at least a small weight)."""
    n_views, e = len(per_view), len(a)
    rows = np.concatenate([np.arange(e), np.arange(e), e + np.arange(n_views)])
    cols = np.concatenate([a, b, np.arange(n_views)])
    values = np.concatenate([np.ones(e), -np.ones(e), np.sqrt(_PRIOR * np.maximum(per_view, 1))])
    matrix = sparse.csr_matrix((values, (rows, cols)), shape=(e + n_views, n_views))
    return lsqr(matrix, np.concatenate([target, np.zeros(n_views)]), atol=1e-10, btol=1e-10)[0]


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
