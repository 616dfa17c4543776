"""GrabCut's graph cut with frozen colour models, on the undecided pixels only.

``cv2.grabCut(image, labels, None, bgd, fgd, 1, cv2.GC_EVAL_FREEZE_MODEL)`` builds a
graph over every pixel of the image, also the sure ones, whose labels it never
changes. When the undecided pixels are a narrow band (an outline to re-decide at full
resolution), nearly all that work is spent on fixed pixels. :func:`band_cut` builds the
same energy (GrabCut's: the data term of the colour models, smoothness ``gamma = 50``
weighted by the colour contrast with GrabCut's ``beta`` over the whole image, 8
neighbours) over the undecided pixels alone: a sure neighbour is folded into the
pixel's terminal weights, where it pulls the same way it would as a node of the full
graph. The minimum cut is then the full graph's (up to ties between equal cuts).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit
from scipy.sparse import csr_array
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

from .grabcut import grabcut
from .kmeans import OpenCVRandom

__all__ = ["band_cut", "coarse_to_fine_grabcut", "grabcut_beta", "gmm_likelihood"]

#: GrabCut's smoothness weight (grabcut.cpp: gamma = 50); diagonal neighbours get
#: gamma / sqrt(2).
_GAMMA = 50.0
#: Neighbour offsets (rows, columns) of GrabCut's graph: left, up-left, up, up-right
#: (each pair once; the edges are symmetric).
_OFFSETS = ((0, -1), (-1, -1), (-1, 0), (-1, 1))
#: All 8 neighbours (rows, columns) of a pixel, and their smoothness weights' factors.
_NEIGHBOURS = np.array([(0, -1), (-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1)],
                       np.int64)
_NEIGHBOUR_GAMMA = np.array([_GAMMA if dy == 0 or dx == 0 else _GAMMA / np.sqrt(2.0)
                             for dy, dx in _NEIGHBOURS])
#: A data term past any finite weight (a colour a model gives no probability: infinite
#: in GrabCut); such a pixel is fixed before the flow (:func:`_settle`).
_HUGE = 1e300
#: Capacities are integers (``scipy.sparse.csgraph.maximum_flow``): weights are scaled
#: by at most this before rounding, less when the total would not fit 31 bits.
_MAX_SCALE = 1000.0
_CAPACITY_BUDGET = 2.0e9


def gmm_likelihood(model: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """GrabCut's mixture density (without its constant ``(2 pi)^-3/2``) at ``colours``.

    model : (1, 65) float64 as ``cv2.grabCut`` fills it (5 weights, 5 x 3 means,
        5 x 3 x 3 covariances); colours : (n, 3) float64. Returns (n,) float64.
    """
    model = np.asarray(model, np.float64).ravel()
    weights, means, covs = model[:5], model[5:20].reshape(5, 3), model[20:65].reshape(5, 3, 3)
    out = np.zeros(len(colours))
    for k in range(5):
        if weights[k] <= 0:
            continue
        diff = colours - means[k]
        mahalanobis = ((diff @ np.linalg.inv(covs[k])) * diff).sum(axis=1)
        out += weights[k] / np.sqrt(np.linalg.det(covs[k])) * np.exp(-0.5 * mahalanobis)
    return out


def grabcut_beta(image: np.ndarray) -> float:
    """GrabCut's contrast scale of (h, w, 3) uint8 ``image``: 1 / (2 x the mean squared
    colour difference of neighbouring pixels), 0 for a flat image."""
    h, w = image.shape[:2]
    total = 0.0
    for dy, dx in _OFFSETS:
        x0, x1 = max(0, -dx), w - max(0, dx)
        total += cv2.norm(image[-dy:, x0:x1], image[:h + dy, x0 + dx:x1 + dx], cv2.NORM_L2SQR)
    if total <= np.finfo(np.float64).eps:
        return 0.0
    return 1.0 / (2.0 * total / (4 * w * h - 3 * w - 3 * h + 2))


def band_cut(image: np.ndarray, labels: np.ndarray, models: tuple[np.ndarray, np.ndarray],
             beta: float | None = None) -> None:
    """Decide the undecided pixels of ``labels`` in place, as ``cv2.grabCut`` with
    ``GC_EVAL_FREEZE_MODEL`` and one iteration would.

    image : (h, w, 3) uint8; labels : (h, w) uint8 ``cv2.GC_*`` values (probable object
    and probable backdrop are decided, sure labels stay); models : the backdrop's and the
    object's (1, 65) float64 GrabCut models; beta : the contrast scale
    (:func:`grabcut_beta` of ``image`` when None, as GrabCut takes it).
    """
    free = (labels == cv2.GC_PR_FGD) | (labels == cv2.GC_PR_BGD)
    n = int(np.count_nonzero(free))
    if n == 0:
        return
    beta = grabcut_beta(image) if beta is None else beta
    h, w = labels.shape
    index = np.full((h, w), -1, np.int32)
    index[free] = np.arange(n)
    rows, cols = np.nonzero(free)
    colours = image[rows, cols].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):   # no probability either way: 0
        # source = object: cutting a pixel from it costs -log P(colour | backdrop)
        terminal = -np.log(gmm_likelihood(models[0], colours)) \
            + np.log(gmm_likelihood(models[1], colours))
    terminal = np.nan_to_num(terminal, nan=0.0, posinf=_HUGE, neginf=-_HUGE)
    neighbours, weights = _link(image, labels, index, rows, cols, terminal, float(beta))
    forced = _settle(neighbours, weights, terminal)
    chosen = forced > 0
    left = forced == 0
    if left.any():
        # The links among the nodes left, renumbered; their terminal weights are at
        # most the sum of their links now (finite).
        tails, slots = np.nonzero(left[:, None] & (neighbours >= 0))
        heads = neighbours[tails, slots]
        keep = left[heads]
        tails, heads, caps = tails[keep], heads[keep], weights[tails[keep], slots[keep]]
        number = np.cumsum(left) - 1
        chosen[left] = _min_cut(int(left.sum()), number[tails], number[heads], caps,
                                terminal[left])
    labels[free] = np.where(chosen, cv2.GC_PR_FGD, cv2.GC_PR_BGD)


def coarse_to_fine_grabcut(features: np.ndarray, labels: np.ndarray, *, work_pixels: int,
                           iterations: int) -> np.ndarray:
    """GrabCut of ``features`` ((h, w, 3) uint8) from ``labels`` ((h, w) uint8 GC_*):
    (h, w) uint8, 1 = object.

    Up to ``work_pixels`` pixels it runs at full size (``iterations`` of GrabCut's
    learning and cutting from ``cv2.GC_INIT_WITH_MASK``). A larger image is cut on a
    reduced copy first, where the colour models are learnt; then the boundary band, as
    wide as a working pixel on each side, is cut again at full size with those models
    frozen (:func:`band_cut`, over the band's pixels alone), so the outline has
    full-resolution precision at a fraction of the cost. Nothing is cut when the labels
    leave no backdrop or nothing but backdrop."""
    h, w = labels.shape
    scale = min(1.0, float(np.sqrt(work_pixels / (h * w))))
    if scale == 1.0:
        work, work_labels = features, labels.copy()
    else:
        small = (max(8, round(w * scale)), max(8, round(h * scale)))
        work = cv2.resize(features, small, interpolation=cv2.INTER_AREA)
        work_labels = cv2.resize(labels, small, interpolation=cv2.INTER_NEAREST)
    background = (work_labels == cv2.GC_BGD) | (work_labels == cv2.GC_PR_BGD)
    if not background.any() or background.all():  # nothing to decide
        return ((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)).astype(np.uint8)
    # GrabCut seeds its colour models by k-means: from a fixed seed, the same result every run.
    models = grabcut(work, work_labels, iterations, OpenCVRandom(0))
    chosen = ((work_labels == cv2.GC_FGD) | (work_labels == cv2.GC_PR_FGD)).astype(np.uint8)
    if scale == 1.0:
        return chosen
    chosen = (cv2.resize(chosen.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
              > 0.5).astype(np.uint8)
    reach = int(np.ceil(1.0 / scale)) + 1
    square = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    band = (cv2.dilate(chosen, square) > 0) & (cv2.erode(chosen, square) == 0)
    rows, cols = np.flatnonzero(band.any(axis=1)), np.flatnonzero(band.any(axis=0))
    if len(rows) == 0:
        return chosen
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    # Outside the band the reduced cut stands (as sure labels); inside, the prior's.
    fine = np.where(chosen[box] > 0, cv2.GC_FGD, cv2.GC_BGD).astype(np.uint8)
    fine[band[box]] = labels[box][band[box]]
    band_cut(np.ascontiguousarray(features[box]), fine, models)
    chosen[box] = (fine == cv2.GC_FGD) | (fine == cv2.GC_PR_FGD)
    return chosen


@njit(cache=True)
def _link(image, labels, index, rows, cols, terminal, beta):
    """The links of each undecided pixel to its 8 neighbours: (n, 8) int32 neighbour node
    (-1: outside the image or sure) and (n, 8) float64 weights, GrabCut's
    ``gamma exp(-beta |colour difference|^2)`` (gamma / sqrt 2 diagonally). A sure
    neighbour's weight is added to ``terminal`` ((n,) float64, > 0 towards the object)
    in place, towards its side."""
    h, w = labels.shape
    n = rows.shape[0]
    neighbours = np.full((n, 8), -1, np.int32)
    weights = np.zeros((n, 8))
    for i in range(n):
        y, x = rows[i], cols[i]
        for k in range(8):
            yy, xx = y + _NEIGHBOURS[k, 0], x + _NEIGHBOURS[k, 1]
            if yy < 0 or yy >= h or xx < 0 or xx >= w:
                continue
            d2 = 0.0
            for c in range(3):
                d = float(image[y, x, c]) - float(image[yy, xx, c])
                d2 += d * d
            weight = _NEIGHBOUR_GAMMA[k] * np.exp(-beta * d2)
            j = index[yy, xx]
            if j >= 0:
                neighbours[i, k] = j
                weights[i, k] = weight
            elif labels[yy, xx] == 1:    # cv2.GC_FGD
                terminal[i] += weight
            else:
                terminal[i] -= weight
    return neighbours, weights


@njit(cache=True)
def _settle(neighbours, weights, terminal):
    """Fix the nodes whose terminal weight outweighs all their links to nodes not fixed:
    such a node is on its terminal's side in every minimum cut, and then pulls its
    neighbours as a sure pixel does (its weight moves to their terminals, in place).
    Repeated until none is left to fix. Returns (n,) int8: 1 object, -1 backdrop, 0 left
    to cut."""
    n = neighbours.shape[0]
    forced = np.zeros(n, np.int8)
    linked = np.zeros(n)
    for i in range(n):
        for k in range(8):
            if neighbours[i, k] >= 0:
                linked[i] += weights[i, k]
    queue = np.empty(n + 8 * n, np.int64)   # each node once, then once per fixed neighbour
    queue[:n] = np.arange(n)
    head, tail = 0, n
    while head < tail:
        i = queue[head]
        head += 1
        if forced[i] != 0 or abs(terminal[i]) <= linked[i]:
            continue
        side = 1 if terminal[i] > 0 else -1
        forced[i] = side
        for k in range(8):
            j = neighbours[i, k]
            if j >= 0 and forced[j] == 0:
                terminal[j] += side * weights[i, k]
                linked[j] -= weights[i, k]
                queue[tail] = j
                tail += 1
    return forced


def _min_cut(n: int, tails: np.ndarray, heads: np.ndarray, caps: np.ndarray,
             terminal: np.ndarray) -> np.ndarray:
    """(n,) bool, the object side of the minimum cut of n nodes with links
    (tails -> heads, caps) and terminal weights (> 0 towards the object): the nodes the
    source still reaches in the residual graph of a maximum flow."""
    scale = min(_MAX_SCALE, _CAPACITY_BUDGET / max(1.0, float(np.abs(terminal).sum())
                                                   + float(caps.sum())))
    source, sink = n, n + 1
    to_object, to_backdrop = np.flatnonzero(terminal > 0), np.flatnonzero(terminal < 0)
    rows = np.concatenate([tails, np.full(len(to_object), source), to_backdrop])
    cols = np.concatenate([heads, to_object, np.full(len(to_backdrop), sink)])
    data = np.rint(np.concatenate([caps, terminal[to_object], -terminal[to_backdrop]])
                   * scale).astype(np.int32)
    capacity = csr_array((data, (rows.astype(np.int32), cols.astype(np.int32))),
                         shape=(n + 2, n + 2))
    capacity.sum_duplicates()
    flow = maximum_flow(capacity, source, sink, method="dinic").flow
    residual = csr_array(capacity - flow)
    residual.data[residual.data < 0] = 0
    residual.eliminate_zeros()
    reached = breadth_first_order(residual, source, directed=True, return_predecessors=False)
    chosen = np.zeros(n + 2, bool)
    chosen[reached] = True
    return chosen[:n]
