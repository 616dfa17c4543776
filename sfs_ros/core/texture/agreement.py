"""How sharp a texture the views agree on: for each face, the blur at which its views
predict one another best.

A blended texel is the weighted mean of the views that see its face (:mod:`.textured`).
Where the mesh is the surface, the views agree to their noise and the sharpest blend is
nearest a view not used; where the mesh departs from the surface (a hull across a
concavity), each view puts the surface's detail somewhere else, and a view not used sees
it somewhere else again: there the mean of views blurred by about the detail's
misplacement is nearer it (a squared error is least at the expected colour, and an
uncertain position spreads the expectation). The views themselves tell which case a face
is in, by leaving one out: each view's colours at the face's sample points (sharp; the
texture takes its centroid alone, its neighbours add the rest) are compared with the
blend of the *other* views (their weights, their gains) at each blur of
:data:`BLUR_LEVELS_PX`, the squared differences summed over the views, weighted as in
the blend, averaged over the face and its neighbours out to :data:`SMOOTHING_RINGS`
edges (a few points a face are a noisy sample; the mesh's error varies smoothly), and the
face takes the blur with the least. A face blended from one view cannot be judged and
stays sharp unless its neighbours are judged.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from scipy import sparse

from ..geometry.camera import Camera
from .levelling import interpolate

__all__ = ["BLUR_LEVELS_PX", "JUDGED_EVERY", "SMOOTHING_RINGS", "blurred_views", "face_blur"]

#: The blurs a face may take: standard deviations of a Gaussian, pixels of its views (0:
#: the views as taken).
BLUR_LEVELS_PX = (0.0, 1.0, 2.0, 4.0)
#: Rings of neighbouring faces (across edges) whose leave-one-out errors are averaged with
#: a face's own before its blur is chosen.
SMOOTHING_RINGS = 16
#: Every so many faces (in the mesh's order) are judged: the rings around a face hold
#: hundreds, half of them judge it as well.
JUDGED_EVERY = 2


def blurred_views(images: Sequence[np.ndarray], levels_px: Sequence[float] = BLUR_LEVELS_PX
                  ) -> list[list[np.ndarray]]:
    """``[level][view]`` (H, W, 3) float32: each of ``images`` (float32) blurred by each
    Gaussian of ``levels_px`` (pixels; 0: the image itself)."""
    return [[image if sigma <= 0 else cv2.GaussianBlur(image, (0, 0), float(sigma))
             for image in images] for sigma in levels_px]


def _smoothed(values: np.ndarray, neighbours: np.ndarray, rings: int) -> np.ndarray:
    """``values`` (m, ...) summed over each face and its neighbours (``neighbours`` (m, 3),
    -1: none), ``rings`` times over."""
    m = len(neighbours)
    f = np.repeat(np.arange(m), 3)
    g = neighbours.ravel()
    keep = g >= 0
    adjacency = sparse.csr_matrix((np.ones(int(keep.sum())), (f[keep], g[keep])), shape=(m, m))
    adjacency = adjacency + sparse.identity(m, format="csr")
    flat = values.reshape(m, -1)
    for _ in range(rings):
        flat = adjacency @ flat
    return flat.reshape(values.shape)


def face_blur(points: np.ndarray, blend: np.ndarray, gains: np.ndarray,
              levels: list[list[np.ndarray]], cameras: Sequence[Camera],
              neighbours: np.ndarray, *, kernel: str = "bilinear",
              rings: int = SMOOTHING_RINGS, every: int = JUDGED_EVERY) -> np.ndarray:
    """(m,) int64 index into ``levels`` of the blur each face's blend takes (module
    docstring).

    ``points`` (m, k, 3) metres, sample points of each face; ``blend`` (m, V) weight of
    each view in each face (0: none); ``gains`` (V, 3) each view's colour gain; ``levels``
    the views' images at each blur (:func:`blurred_views`, the first unblurred), read
    with ``kernel``; ``neighbours`` (m, 3) (:func:`.selection.face_neighbours`); every
    ``every``-th face (in the mesh's order) is judged, the smoothing spreads the errors.
    """
    m, k = points.shape[:2]
    n_levels = len(levels)
    total = np.zeros((m, n_levels, k, 3), np.float32)
    weight_sum = np.zeros(m)
    judged_here = np.zeros(m, bool)
    judged_here[::max(1, int(every))] = True
    used = [np.flatnonzero(judged_here & (blend[:, view] > 0)) for view in range(blend.shape[1])]
    # Each view's colours at its faces' points at every level: (faces, levels, k, 3).
    reads = []
    for view, mine in enumerate(used):
        pixels = np.nan_to_num(cameras[view].project(points[mine].reshape(-1, 3)),
                               nan=-1.0).astype(np.float32)
        reads.append(gains[view].astype(np.float32) * np.stack(
            [interpolate(levels[level][view], pixels[:, 0], pixels[:, 1],
                         kernel=kernel).reshape(-1, k, 3) for level in range(n_levels)],
            axis=1))
        if mine.size:
            total[mine] += blend[mine, view].astype(np.float32)[:, None, None, None] \
                * reads[view]
            weight_sum[mine] += blend[mine, view]
    error = np.zeros((m, n_levels))
    judged = np.zeros(m)
    for view, mine in enumerate(used):
        weight = blend[mine, view]
        others = weight_sum[mine] - weight
        left_out = others > 0
        if not left_out.any():
            continue
        mine, weight, others = mine[left_out], weight[left_out], others[left_out]
        own = reads[view][left_out]
        predicted = (total[mine] - weight[:, None, None, None] * own) \
            / others[:, None, None, None]
        error[mine] += weight[:, None] * np.square(predicted - own[:, :1]).sum(axis=(2, 3))
        judged[mine] += weight
    smoothed = _smoothed(np.column_stack([error, judged]), neighbours, rings)
    error, judged = smoothed[:, :-1], smoothed[:, -1]
    # A face with no judged face (two views or more) within its rings stays unblurred.
    return np.where(judged > 0, np.argmin(error, axis=1), 0).astype(np.int64)
