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
from numba import njit

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


def _smoothed(values: np.ndarray, neighbours: np.ndarray, rings: int,
              wanted: np.ndarray) -> np.ndarray:
    """``values`` (m, c) float64 summed over each face and its neighbours (``neighbours``
    (m, 3), -1: none), ``rings`` times over, at the ``wanted`` (m,) bool faces (the others
    zero); ``values`` are zero but at wanted faces."""
    out = np.zeros_like(values)
    _ring_sums(np.ascontiguousarray(values), neighbours, int(rings), wanted, out)
    return out


@njit(cache=True, nogil=True)
def _ring_sums(values, neighbours, rings, wanted, out):
    """:func:`_smoothed` into ``out`` (m, c) (zeros). A sum over ``rings`` rings at a wanted
    face gathers the walks of as many steps from a wanted face (where the values are not
    zero): every face they pass lies within half as many steps of one or the other, so
    the sums are made on those faces alone, the others left zero."""
    m, c = values.shape
    # The faces within (rings + 1) // 2 steps of a wanted face, breadth first.
    steps = np.full(m, -1, np.int64)
    region = np.empty(m, np.int64)
    n = 0
    for f in range(m):
        if wanted[f]:
            steps[f] = 0
            region[n] = f
            n += 1
    half, head = (rings + 1) // 2, 0
    while head < n:
        f = region[head]
        head += 1
        if steps[f] == half:
            continue
        for k in range(3):
            g = neighbours[f, k]
            if g >= 0 and steps[g] < 0:
                steps[g] = steps[f] + 1
                region[n] = g
                n += 1
    # Those faces in the mesh's order (which keeps neighbours near in memory), numbered
    # apart with their neighbours among them (n where there is none, or it lies
    # outside: a row of zeros throughout, whose addition changes no sum), each column's
    # values in a row of their own.
    region = np.sort(region[:n])
    local = np.full(m, n, np.int64)
    for i in range(n):
        local[region[i]] = i
    around = np.full((n, 3), n, np.int64)
    now = np.zeros((c, n + 1))
    for i in range(n):
        f = region[i]
        for k in range(3):
            if neighbours[f, k] >= 0:
                around[i, k] = local[neighbours[f, k]]
        for j in range(c):
            now[j, i] = values[f, j]
    after = np.zeros_like(now)
    for _ in range(rings):
        for j in range(c):
            plane, summed = now[j], after[j]
            for i in range(n):
                summed[i] = ((plane[i] + plane[around[i, 0]]) + plane[around[i, 1]]) \
                    + plane[around[i, 2]]
        now, after = after, now
    for i in range(n):
        f = region[i]
        if wanted[f]:
            for j in range(c):
                out[f, j] = now[j, i]


def face_blur(points: np.ndarray, blend: np.ndarray, gains: np.ndarray,
              levels: list[list[np.ndarray]], cameras: Sequence[Camera],
              neighbours: np.ndarray, *, kernel: str = "bilinear",
              rings: int = SMOOTHING_RINGS, every: int = JUDGED_EVERY) -> np.ndarray:
    """(m,) int64 index into ``levels`` of the blur each face's blend takes (module
    docstring; 0 for a face no view is blended into).

    ``points`` (m, k, 3) metres, sample points of each face; ``blend`` (m, V) weight of
    each view in each face (0: none); ``gains`` (V, 3) each view's colour gain; ``levels``
    the views' images at each blur (:func:`blurred_views`, the first unblurred), read
    with ``kernel``; ``neighbours`` (m, 3) (:func:`.selection.face_neighbours`); every
    ``every``-th face (in the mesh's order) is judged, the smoothing spreads the errors.
    """
    m, k = points.shape[:2]
    n_levels = len(levels)
    every = max(1, int(every))
    blended = (blend > 0).any(axis=1)
    # The faces judged (each ``every``-th, with a view), and their weights: (j,), (j, V).
    judged_faces = every * np.flatnonzero(blended[::every])
    weights = blend[judged_faces]
    total = np.zeros((len(judged_faces), n_levels, k, 3), np.float32)
    weight_sum = np.zeros(len(judged_faces))
    used = [np.flatnonzero(weights[:, view] > 0) for view in range(blend.shape[1])]
    # Each view's colours at its faces' points at every level: (faces, levels, k, 3).
    reads = []
    for view, mine in enumerate(used):
        pixels = np.nan_to_num(cameras[view].project(
            points[judged_faces[mine]].reshape(-1, 3)), nan=-1.0).astype(np.float32)
        reads.append(gains[view].astype(np.float32) * np.stack(
            [interpolate(levels[level][view], pixels[:, 0], pixels[:, 1],
                         kernel=kernel).reshape(-1, k, 3) for level in range(n_levels)],
            axis=1))
        if mine.size:
            total[mine] += weights[mine, view].astype(np.float32)[:, None, None, None] \
                * reads[view]
            weight_sum[mine] += weights[mine, view]
    # Each judged face's leave-one-out errors at every level, then its weight: (m, levels + 1).
    errors = np.zeros((m, n_levels + 1))
    for view, mine in enumerate(used):
        weight = weights[mine, view]
        others = weight_sum[mine] - weight
        left_out = others > 0
        if not left_out.any():
            continue
        mine, weight, others = mine[left_out], weight[left_out], others[left_out]
        own = reads[view][left_out]
        predicted = (total[mine] - weight[:, None, None, None] * own) \
            / others[:, None, None, None]
        face = judged_faces[mine]
        errors[face, :-1] += weight[:, None] * np.square(predicted - own[:, :1]).sum(axis=(2, 3))
        errors[face, -1] += weight
    smoothed = _smoothed(errors, neighbours, rings, blended)
    error, judged = smoothed[:, :-1], smoothed[:, -1]
    # A face with no judged face (two views or more) within its rings stays unblurred.
    return np.where(judged > 0, np.argmin(error, axis=1), 0).astype(np.int64)
