"""GrabCut as OpenCV computes it, the same labels for less work.

``grabcut(image, labels, iterations, random)`` gives the labels and colour models
``cv2.grabCut(image, labels, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)`` gives:
the same k-means start (:mod:`.kmeans`: OpenCV's k-means on the same samples, drawing
from OpenCV's random generator in the same state), the same colour models learnt from
the same sums, the same graph energy and its minimum cut found by Boykov-Kolmogorov's
max-flow as OpenCV's ``GCGraph`` runs it (its search trees grown, augmented and repaired
step for step). Bit for bit on every image tried (``test/test_grabcut.py``, and the
segmentation's masks of the Middlebury rings, the hostile cell and the bench's
renders); only two minimum cuts of exactly equal cost could part them, should a tie
meet a vertex that OpenCV's full graph and ours order differently.

What it saves: OpenCV evaluates each Gaussian of a colour model at every pixel, five
per pixel to pick its component and ten more for its data term, and builds the graph
over every pixel anew each iteration. Here each distinct colour of the image (a quarter
of the pixels of a photograph's working copy; a few hundred on its backdrop) is
evaluated once an iteration, a component is picked without an exponential where the
choice is clear by far more than the rounding, the links (which depend on the image
alone) are built once, and the graph holds the probable pixels alone: a sure pixel is
on its side in every minimum cut (its terminal weight, 9 gamma, outweighs all its
links), so its link to a probable pixel is that pixel's terminal weight.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numba import njit

from .kmeans import OpenCVRandom, distinct_colours, kmeans_colours

__all__ = ["grabcut"]

#: GrabCut's constants (OpenCV's grabcut.cpp): Gaussians per colour model, smoothness
#: weight, k-means iterations of the start.
_COMPONENTS = 5
_GAMMA = 50.0
_KMEANS_ITERATIONS = 10
#: GrabCut's weight of a sure pixel's terminal link (9 gamma).
_LAMBDA = 9 * _GAMMA
#: GrabCut divides gamma by the square root of 2 taken in single precision.
_GAMMA_DIAGONAL = _GAMMA / float(np.sqrt(np.float32(2.0)))
#: A covariance whose determinant is at most this gets this much added to its diagonal.
_SINGULAR_DETERMINANT = 1e-6
_SINGULAR_FIX = 0.01
#: A determinant at most this after the widening is an error (OpenCV asserts).
_EPSILON = float(np.finfo(np.float64).eps)
_BGD, _FGD, _PR_BGD, _PR_FGD = cv2.GC_BGD, cv2.GC_FGD, cv2.GC_PR_BGD, cv2.GC_PR_FGD
#: BK's special parents: a search tree's root's link, and a vertex cut off its tree.
_TERMINAL, _ORPHAN = -1, -2
_INT_MAX = 2147483647
#: A component is picked by the logarithm of its density when that is above this (the
#: density far from underflow) and leads the next by this margin (relative).
_LOG_NORMAL = -700.0
_LOG_MARGIN = 1e-9
#: A mixture's term whose logarithm is this far below an earlier term's leaves the sum
#: as it is: 54 ln 2 (below 2^-54 of it), and 1 more against the logarithms' rounding.
_NEGLIGIBLE = 54 * math.log(2.0) + 1.0
#: Largest squared colour difference of two uint8 RGB pixels.
_MAX_SQUARED_DIFFERENCE = 3 * 255 ** 2


def grabcut(image: np.ndarray, labels: np.ndarray, iterations: int,
            random: OpenCVRandom) -> tuple[np.ndarray, np.ndarray]:
    """Decide the probable pixels of ``labels`` in place, as ``cv2.grabCut`` with
    ``GC_INIT_WITH_MASK`` and ``iterations`` iterations does.

    image : (h, w, 3) uint8; labels : (h, w) uint8 ``cv2.GC_*`` values, with at least one
    backdrop (sure or probable) and one object pixel; random : the generator the k-means
    start draws from (advanced), where ``cv2.grabCut`` draws from OpenCV's generator of
    the calling thread: in the same state, the labels are the same. Returns the
    backdrop's and the object's colour models, (1, 65) float64 each, as ``cv2.grabCut``
    leaves them (5 weights, 5 x 3 means, 5 x 3 x 3 covariances).
    """
    image = np.ascontiguousarray(image, np.uint8)
    if image.ndim != 3 or image.shape[2] != 3 or labels.shape != image.shape[:2] \
            or labels.dtype != np.uint8:
        raise ValueError(f"expected an (h, w, 3) uint8 image and (h, w) uint8 labels, got "
                         f"{image.shape} {image.dtype} and {labels.shape} {labels.dtype}")
    backdrop = (labels == _BGD) | (labels == _PR_BGD)
    if backdrop.all() or not backdrop.any():
        raise ValueError("the labels must hold both backdrop and object pixels")
    colours, colour_of = distinct_colours(image.reshape(-1, 3))
    models = np.zeros((2, _COMPONENTS, 13))  # per model and component: weight, mean, covariance
    start = np.zeros(labels.size, np.int32)
    for members in (backdrop.ravel(), ~backdrop.ravel()):
        start[members] = kmeans_colours(colours, colour_of[members],
                                        min(_COMPONENTS, int(members.sum())), random,
                                        max_iterations=_KMEANS_ITERATIONS)
    flat = labels.reshape(-1).copy()
    _learn(image.reshape(-1, 3), flat, start, models)
    probable = (flat == _PR_BGD) | (flat == _PR_FGD)
    first, head, after, capacity, fold = _graph(image, _beta(image), probable.reshape(labels.shape),
                                                labels)
    where = np.flatnonzero(probable)
    for _ in range(iterations):
        excess = _relearn(flat, colours, colour_of, where, fold, models)
        source = _max_flow(first, head, after, capacity.copy(), excess)
        flat[probable] = np.where(source, _PR_FGD, _PR_BGD)
    labels[...] = flat.reshape(labels.shape)
    return tuple(np.concatenate([m[:, 0], m[:, 1:4].ravel(), m[:, 4:13].ravel()])[None]
                 for m in models)


@njit(cache=True, nogil=True)
def _beta(image):
    """GrabCut's contrast scale of (h, w, 3) uint8 ``image``: 1 / (2 x the mean squared
    colour difference of neighbouring pixels); 0 for a flat image. OpenCV sums the
    squared differences in double precision, each a whole number below 2^18 and their
    total below 2^53 for any image under 2^33 pixels: exact, so summed here in whole
    numbers, a neighbour direction at a time."""
    h, w = image.shape[:2]
    total = 0
    for y in range(h):
        row = image[y]
        for x in range(1, w):
            total += _squared_difference(row[x], row[x - 1])
        if y == 0:
            continue
        above = image[y - 1]
        for x in range(w):
            total += _squared_difference(row[x], above[x])
        for x in range(1, w):
            total += _squared_difference(row[x], above[x - 1])
        for x in range(w - 1):
            total += _squared_difference(row[x], above[x + 1])
    if total == 0:
        return 0.0
    return 1.0 / (2.0 * np.float64(total) / (4 * w * h - 3 * w - 3 * h + 2))


@njit(cache=True, nogil=True, inline="always")
def _squared_difference(a, b):
    """Squared difference of two (3,) uint8 colours, a whole number."""
    d0 = np.int64(a[0]) - np.int64(b[0])
    d1 = np.int64(a[1]) - np.int64(b[1])
    d2 = np.int64(a[2]) - np.int64(b[2])
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, nogil=True)
def _graph(image, beta, probable, labels):
    """GrabCut's graph over the probable pixels of (h, w, 3) uint8 ``image``, stored as
    OpenCV's ``GCGraph`` stores its graph: (v,) int64 first edge of each vertex (0: none;
    the probable pixels in raster order), and per edge (2 per link, the pair ``2k, 2k + 1``)
    its (m,) int64 head and next edge of its tail, and (m,) float64 capacity; and (v,)
    float64 the links to sure pixels, folded into the terminal weights (+ towards the
    object).

    A sure pixel's terminal weight (9 gamma) outweighs all its links (at most
    4 (1 + 1 / sqrt 2) gamma): it is on its own side in every minimum cut, and its link to
    a probable pixel counts as that pixel's terminal weight towards that side.

    Only the probable pixels are visited (a narrow band is a small part of its box): each
    makes its links to the earlier probable neighbours (left, up-left, up, up-right, as
    OpenCV's raster pass makes them, so the edges come in its order) and folds those to
    sure neighbours, the earlier ones and then the later ones (right, down-left, down,
    down-right) in the order OpenCV's pass meets them, so every sum is the same."""
    h, w = image.shape[:2]
    index = np.full(h * w, -1, np.int64)
    pixels = np.flatnonzero(probable.ravel())
    n = pixels.shape[0]
    for v in range(n):
        index[pixels[v]] = v
    m = 8 * n + 2  # each link made once, by its later pixel, a probable one: 4 per vertex
    first = np.zeros(n, np.int64)
    head = np.zeros(m, np.int64)
    after = np.zeros(m, np.int64)
    capacity = np.zeros(m)
    fold = np.zeros(n)
    contrast = np.full(_MAX_SQUARED_DIFFERENCE + 1, -1.0)  # exp(-beta d^2), on first use
    e = 2  # edge 0 would end its tail's list (and edge 1 make a parent of none): unused
    for i in range(n):
        y, x = pixels[i] // w, pixels[i] % w
        for dy, dx, gamma in ((0, -1, _GAMMA), (-1, -1, _GAMMA_DIAGONAL), (-1, 0, _GAMMA),
                              (-1, 1, _GAMMA_DIAGONAL), (0, 1, _GAMMA),
                              (1, -1, _GAMMA_DIAGONAL), (1, 0, _GAMMA),
                              (1, 1, _GAMMA_DIAGONAL)):
            yy, xx = y + dy, x + dx
            if yy < 0 or yy >= h or xx < 0 or xx >= w:
                continue
            j = index[yy * w + xx]
            later = dy > 0 or (dy == 0 and dx > 0)
            if later and j >= 0:
                continue                       # that link is made by the later pixel
            weight = gamma * _contrast(image, contrast, beta, y, x, yy, xx)
            if j < 0:
                fold[i] += weight if labels[yy, xx] == _FGD else -weight
            else:
                head[e], after[e], capacity[e] = j, first[i], weight
                first[i] = e
                head[e + 1], after[e + 1], capacity[e + 1] = i, first[j], weight
                first[j] = e + 1
                e += 2
    return first, head[:e], after[:e], capacity[:e], fold


@njit(cache=True, nogil=True, inline="always")
def _contrast(image, contrast, beta, y, x, yy, xx):
    """``exp(-beta d^2)`` of the squared colour difference ``d^2`` of pixels (y, x) and
    (yy, xx) of ``image``, kept in ``contrast`` (by ``d^2``, -1 until first used)."""
    d0 = float(image[y, x, 0]) - float(image[yy, xx, 0])
    d1 = float(image[y, x, 1]) - float(image[yy, xx, 1])
    d2 = float(image[y, x, 2]) - float(image[yy, xx, 2])
    squared = d0 * d0 + d1 * d1 + d2 * d2
    k = int(squared)
    if contrast[k] < 0:
        contrast[k] = math.exp(-beta * squared)
    return contrast[k]


@njit(cache=True, nogil=True)
def _learn(pixels, labels, components, models):
    """Fit both colour models ((2, 5, 13) float64: per model, backdrop then object, and
    component its weight, mean (3) and covariance (9), in place) to (n, 3) uint8
    ``pixels`` with (n,) uint8 GC ``labels`` and (n,) int32 ``components``."""
    sums = np.zeros((2, _COMPONENTS, 12))
    counts = np.zeros((2, _COMPONENTS), np.int64)
    for i in range(pixels.shape[0]):
        side = 0 if labels[i] == _BGD or labels[i] == _PR_BGD else 1
        _add(sums[side, components[i]], counts[side], components[i], float(pixels[i, 0]),
             float(pixels[i, 1]), float(pixels[i, 2]), 1)
    _fit(models, sums, counts)


@njit(cache=True, nogil=True, inline="always")
def _add(sums, counts, k, r, g, b, times):
    """Add ``times`` samples of colour (r, g, b) to component k's (12,) ``sums`` (of the
    colour and of its products) and ``counts``. Every sum is a whole number below 2^53,
    exact in float64: the order of the additions does not matter."""
    counts[k] += times
    colour = (r, g, b)
    for a in range(3):
        sums[a] += times * colour[a]
        for c in range(3):
            sums[3 + 3 * a + c] += times * colour[a] * colour[c]


@njit(cache=True, nogil=True)
def _fit(models, sums, counts):
    """Both colour models ((2, 5, 13), in place) from their components' (2, 5, 12) sums
    and (2, 5) counts, as OpenCV's ``GMM`` learns: weights by count, the mean by the
    reciprocal of the count, a nearly singular covariance widened."""
    for side in range(2):
        total = counts[side].sum()
        for k in range(_COMPONENTS):
            model = models[side, k]
            n = counts[side, k]
            if n == 0:
                model[0] = 0.0
                continue
            inv_n = 1.0 / n
            model[0] = n / total
            for a in range(3):
                model[1 + a] = sums[side, k, a] * inv_n
            for a in range(3):
                for b in range(3):
                    model[4 + 3 * a + b] = sums[side, k, 3 + 3 * a + b] * inv_n \
                        - model[1 + a] * model[1 + b]
            if _determinant(model[4:13]) <= _SINGULAR_DETERMINANT:
                for a in range(3):
                    model[4 + 4 * a] += _SINGULAR_FIX


@njit(cache=True, nogil=True)
def _determinant(c):
    """Determinant of a 3 x 3 matrix given row by row ((9,)), in OpenCV's order."""
    return c[0] * (c[4] * c[8] - c[5] * c[7]) - c[1] * (c[3] * c[8] - c[5] * c[6]) \
        + c[2] * (c[3] * c[7] - c[4] * c[6])


@njit(cache=True, nogil=True)
def _gaussians(models):
    """Per model and component, what OpenCV evaluates a Gaussian with: (2, 5, 16)
    float64 weight (0: unused), mean (3), inverse covariance (9, as OpenCV indexes it:
    ``inverse[a][b]`` at ``3 a + b``), ``1 / sqrt(determinant)``, its logarithm, and
    the logarithm of the weight over the square root of the determinant."""
    out = np.zeros((2, _COMPONENTS, 16))
    for side in range(2):
        for k in range(_COMPONENTS):
            model = models[side, k]
            if model[0] <= 0:
                continue
            c = model[4:13]
            determinant = _determinant(c)
            if determinant <= _EPSILON:
                raise ValueError("a colour model's covariance is singular")
            inv = 1.0 / determinant
            g = out[side, k]
            g[0] = model[0]
            g[1:4] = model[1:4]
            g[4] = (c[4] * c[8] - c[5] * c[7]) * inv
            g[7] = -(c[3] * c[8] - c[5] * c[6]) * inv
            g[10] = (c[3] * c[7] - c[4] * c[6]) * inv
            g[5] = -(c[1] * c[8] - c[2] * c[7]) * inv
            g[8] = (c[0] * c[8] - c[2] * c[6]) * inv
            g[11] = -(c[0] * c[7] - c[1] * c[6]) * inv
            g[6] = (c[1] * c[5] - c[2] * c[4]) * inv
            g[9] = -(c[0] * c[5] - c[2] * c[3]) * inv
            g[12] = (c[0] * c[4] - c[1] * c[3]) * inv
            g[13] = 1.0 / math.sqrt(determinant)
            g[14] = math.log(g[13])
            g[15] = math.log(g[0]) + g[14]
    return out


@njit(cache=True, nogil=True)
def _likeliest(g, r, gr, b):
    """The component of a colour model ((5, 16) from :func:`_gaussians`) OpenCV assigns
    colour (r, gr, b) to: the first of the largest densities. Picked by the logarithms of
    the densities, without an exponential, when the largest leads the next by far more
    than their rounding (1e-9 against errors of 1e-15); by the densities as OpenCV
    computes them otherwise (near ties, or densities that underflow)."""
    best, second, k_best = -np.inf, -np.inf, 0
    for k in range(_COMPONENTS):
        if g[k, 0] <= 0:
            continue
        q = g[k, 14] - 0.5 * _mahalanobis(g[k], r, gr, b)
        if q > best:
            best, second, k_best = q, best, k
        elif q > second:
            second = q
    if best > _LOG_NORMAL and best - second > _LOG_MARGIN * (1.0 + abs(best)):
        return k_best
    k_best, top = 0, 0.0
    for k in range(_COMPONENTS):
        p = _density(g[k], r, gr, b)
        if p > top:
            k_best, top = k, p
    return k_best


@njit(cache=True, nogil=True)
def _mahalanobis(g, r, gr, b):
    """Squared Mahalanobis distance of colour (r, gr, b) to a Gaussian ((16,) from
    :func:`_gaussians`), in OpenCV's order of operations."""
    d0, d1, d2 = r - g[1], gr - g[2], b - g[3]
    return d0 * (d0 * g[4] + d1 * g[7] + d2 * g[10]) \
        + d1 * (d0 * g[5] + d1 * g[8] + d2 * g[11]) \
        + d2 * (d0 * g[6] + d1 * g[9] + d2 * g[12])


@njit(cache=True, nogil=True)
def _density(g, r, gr, b):
    """One Gaussian ((16,) from :func:`_gaussians`) at colour (r, gr, b), without its
    weight, in OpenCV's order of operations; 0 for an unused component."""
    if g[0] <= 0:
        return 0.0
    return g[13] * math.exp(-0.5 * _mahalanobis(g, r, gr, b))


@njit(cache=True, nogil=True, inline="always")
def _mixture(g, r, gr, b):
    """A colour model ((5, 16) from :func:`_gaussians`) at colour (r, gr, b): its
    components' densities times their weights, summed in OpenCV's order.

    A term below 2^-54 of an earlier one is below half the last bit of the sum it is
    added to (the sum of positive terms is at least each of them), so the sum rounds
    back to itself: its exponential is skipped. Which terms those are is read off the
    logarithms of the terms, without an exponential, with a margin (``_NEGLIGIBLE``)
    far beyond their rounding."""
    total = 0.0
    largest = -np.inf                          # the logarithm of the largest term added
    for k in range(_COMPONENTS):
        if g[k, 0] <= 0:
            continue                           # an unused component adds 0
        m = _mahalanobis(g[k], r, gr, b)
        log_term = g[k, 15] - 0.5 * m
        if log_term < largest - _NEGLIGIBLE:
            continue
        total += g[k, 0] * (g[k, 13] * math.exp(-0.5 * m))
        largest = max(largest, log_term)
    return total


@njit(cache=True, nogil=True)
def _relearn(labels, colours, colour_of, probable, fold, models):
    """The first half of a GrabCut iteration: each pixel's component under the model of
    its side in (n,) uint8 ``labels``, the models learnt again ((2, 5, 13), in place),
    and the probable pixels' terminal weights, source minus sink, with their ``fold``
    ((v,) float64, from :func:`_graph`) added: (v,) float64.

    colours : (c, 3) float64 distinct colours; colour_of : (n,) int32 each pixel's;
    probable : (v,) int64 the probable pixels. Pixels of one colour and side share their
    component, so each colour is evaluated once per side."""
    n, nc = labels.shape[0], colours.shape[0]
    members = np.zeros((2, nc), np.int64)      # pixels of each colour on each side
    for i in range(n):
        side = 0 if labels[i] == _BGD or labels[i] == _PR_BGD else 1
        members[side, colour_of[i]] += 1
    g = _gaussians(models)
    sums = np.zeros((2, _COMPONENTS, 12))
    counts = np.zeros((2, _COMPONENTS), np.int64)
    for j in range(nc):
        r, gr, b = colours[j, 0], colours[j, 1], colours[j, 2]
        for side in range(2):
            if members[side, j] > 0:
                k = _likeliest(g[side], r, gr, b)
                _add(sums[side, k], counts[side], k, r, gr, b, members[side, j])
    _fit(models, sums, counts)
    g = _gaussians(models)
    computed = np.zeros(nc, np.bool_)
    data = np.zeros(nc)                        # source minus sink weight of each colour
    excess = np.empty(probable.shape[0])
    for v in range(probable.shape[0]):
        j = colour_of[probable[v]]
        if not computed[j]:
            r, gr, b = colours[j, 0], colours[j, 1], colours[j, 2]
            data[j] = -math.log(_mixture(g[0], r, gr, b)) - -math.log(_mixture(g[1], r, gr, b))
            computed[j] = True
        excess[v] = data[j] + fold[v]
    return excess


@njit(cache=True, nogil=True)
def _max_flow(first, head, after, capacity, excess):
    """Boykov-Kolmogorov max-flow as OpenCV's ``GCGraph::maxFlow`` runs it, step for step.

    first, head, after : the links (:func:`_graph`); capacity : (m,) float64, used up in
    place; excess : (n,) float64 source minus sink weight of each vertex, in place.
    Returns (n,) bool, the vertices on the source's side (OpenCV's ``inSourceSegment``:
    those not ending in the sink's tree).

    Each vertex's state: ``parent``, the edge from its parent (0: free, or
    :data:`_TERMINAL`, :data:`_ORPHAN`); ``tree``, 0 the source's, 1 the sink's;
    ``stamp`` and ``dist``, when its distance to the root was last known and that
    distance; ``queued``, the next vertex in the queue of active vertices (-1: not in it;
    the queue ends at the marker ``n``).
    """
    n = first.shape[0]
    queued = np.full(n + 1, -1, np.int64)
    parent = np.zeros(n, np.int64)
    stamp = np.zeros(n, np.int64)
    dist = np.zeros(n, np.int64)
    tree = np.zeros(n, np.uint8)
    orphans = np.empty(n + 1, np.int64)
    queued[n] = n
    last = n
    for i in range(n):                         # every vertex with a terminal weight: a root
        if excess[i] != 0:
            queued[last] = i
            last = i
            dist[i] = 1
            parent[i] = _TERMINAL
            tree[i] = 1 if excess[i] < 0 else 0
    front = queued[n]
    queued[last] = n
    queued[n] = -1
    now = 0
    while True:
        e0, front, last = _grow(first, head, after, capacity, parent, stamp, dist, tree, queued,
                                front, last)
        if e0 <= 0:
            return tree == 0
        n_orphans = _augment(e0, head, capacity, excess, parent, orphans)
        now += 1
        last = _adopt(first, head, after, capacity, parent, stamp, dist, tree, queued, orphans,
                      n_orphans, last, now)


@njit(cache=True, nogil=True)
def _grow(first, head, after, capacity, parent, stamp, dist, tree, queued, front, last):
    """Grow both search trees from the active vertices (:func:`_max_flow`'s state, in
    place) until an edge joins them: (that edge, from the source's side, or <= 0 when
    none is left; the queue's new front and last vertex)."""
    nil = first.shape[0]
    e0 = -1
    while front != nil:
        v = front
        if parent[v] != 0:
            vt = tree[v]
            ei = first[v]
            while ei != 0:
                if capacity[ei ^ vt] != 0:
                    u = head[ei]
                    if parent[u] == 0:
                        tree[u] = vt
                        parent[u] = ei ^ 1
                        stamp[u] = stamp[v]
                        dist[u] = dist[v] + 1
                        if queued[u] == -1:
                            queued[u] = nil
                            queued[last] = u
                            last = u
                    elif tree[u] != vt:
                        e0 = ei ^ vt
                        break
                    elif dist[u] > dist[v] + 1 and stamp[u] <= stamp[v]:
                        parent[u] = ei ^ 1
                        stamp[u] = stamp[v]
                        dist[u] = dist[v] + 1
                ei = after[ei]
            if e0 > 0:
                return e0, front, last
        front = queued[front]
        queued[v] = -1
    return e0, front, last


@njit(cache=True, nogil=True)
def _augment(e0, head, capacity, excess, parent, orphans):
    """Push the bottleneck of the path through edge ``e0`` from the source to the sink;
    the vertices whose link to their parent or terminal it saturates become orphans
    (listed in ``orphans``). Returns their number."""
    bottleneck = capacity[e0]
    for k in (1, 0):
        v = head[e0 ^ k]
        while parent[v] >= 0:
            ei = parent[v]
            bottleneck = min(bottleneck, capacity[ei ^ k])
            v = head[ei]
        bottleneck = min(bottleneck, abs(excess[v]))
    capacity[e0] -= bottleneck
    capacity[e0 ^ 1] += bottleneck
    n_orphans = 0
    for k in (1, 0):
        v = head[e0 ^ k]
        while parent[v] >= 0:
            ei = parent[v]
            capacity[ei ^ (k ^ 1)] += bottleneck
            capacity[ei ^ k] -= bottleneck
            if capacity[ei ^ k] == 0:
                orphans[n_orphans] = v
                n_orphans += 1
                parent[v] = _ORPHAN
            v = head[ei]
        excess[v] = excess[v] + bottleneck * (1 - k * 2)
        if excess[v] == 0:
            orphans[n_orphans] = v
            n_orphans += 1
            parent[v] = _ORPHAN
    return n_orphans


@njit(cache=True, nogil=True)
def _adopt(first, head, after, capacity, parent, stamp, dist, tree, queued, orphans,
           n_orphans, last, now):
    """Give each orphan (the last listed first) the nearest parent left in its tree, or
    free it, queueing its neighbours in the tree and orphaning its children. Returns the
    queue's last vertex."""
    nil = first.shape[0]
    while n_orphans > 0:
        n_orphans -= 1
        v = orphans[n_orphans]
        e0, best = _new_parent(v, first, head, after, capacity, parent, stamp, dist, tree, now)
        parent[v] = e0
        if e0 > 0:
            stamp[v] = now
            dist[v] = best
            continue
        stamp[v] = 0
        vt = tree[v]
        ei = first[v]
        while ei != 0:
            u = head[ei]
            ej = parent[u]
            if tree[u] == vt and ej != 0:
                if capacity[ei ^ (vt ^ 1)] != 0 and queued[u] == -1:
                    queued[u] = nil
                    queued[last] = u
                    last = u
                if ej > 0 and head[ej] == v:
                    orphans[n_orphans] = u
                    n_orphans += 1
                    parent[u] = _ORPHAN
            ei = after[ei]
    return last


@njit(cache=True, nogil=True)
def _new_parent(v, first, head, after, capacity, parent, stamp, dist, tree, now):
    """Orphan ``v``'s nearest parent in its tree through an unsaturated edge: (that edge,
    0 when there is none; its distance to the root), the distances found on the way
    stamped ``now``."""
    best, e0 = _INT_MAX, 0
    vt = tree[v]
    ei = first[v]
    while ei != 0:
        u = head[ei]
        if capacity[ei ^ (vt ^ 1)] != 0 and tree[u] == vt and parent[u] != 0:
            d = 0
            while True:                        # the distance to the tree's root
                if stamp[u] == now:
                    d += dist[u]
                    break
                ej = parent[u]
                d += 1
                if ej < 0:
                    if ej == _ORPHAN:
                        d = _INT_MAX - 1
                    else:
                        stamp[u] = now
                        dist[u] = 1
                    break
                u = head[ej]
            d += 1
            if d < _INT_MAX:
                if d < best:
                    best, e0 = d, ei
                u = head[ei]
                while stamp[u] != now:
                    stamp[u] = now
                    d -= 1
                    dist[u] = d
                    u = head[parent[u]]
        ei = after[ei]
    return e0, best
