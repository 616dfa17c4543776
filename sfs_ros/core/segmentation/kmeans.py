"""OpenCV's k-means with its k-means++ start, and OpenCV's random generator: the same
clusters as ``cv2.kmeans(samples, k, None, criteria, 1, cv2.KMEANS_PP_CENTERS)``, bit
for bit, for a fraction of the work on colours.

The samples are colours of an image (whole numbers 0..255 in three channels): many
share a colour, and every distance OpenCV computes for a sample is that of its colour.
So the distances are computed once per distinct colour; what depends on the samples'
order (the k-means++ draw, its sums, the centres' sums, an emptied cluster refilled)
runs over the samples in their order, as OpenCV runs it.

:class:`OpenCVRandom` is OpenCV's ``cv::RNG`` (a multiply-with-carry generator):
seeded with 0 it draws what ``cv2.setRNGSeed(0)`` makes ``cv2.kmeans`` draw.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["OpenCVRandom", "distinct_colours", "kmeans_colours"]

#: cv::RNG's multiplier, and the factor turning two 32-bit draws into a double in [0, 1).
_MULTIPLIER = np.uint64(4164903690)
_LOW_32 = np.uint64(0xFFFFFFFF)
_SHIFT_32 = np.uint64(32)
_TO_UNIT = 5.4210108624275221700372640043497e-20
#: k-means++ candidates tried per centre (OpenCV's SPP_TRIALS).
_TRIALS = 3
_DBL_MAX = 1.7976931348623157e308


class OpenCVRandom:
    """OpenCV's random generator ``cv::RNG``: state ``seed`` (0 stands for 0xffffffff, as
    in OpenCV). ``state`` : (1,) uint64, advanced in place by the draws."""

    def __init__(self, seed: int = 0):
        self.state = np.array([seed if seed else 0xFFFFFFFF], np.uint64)


@njit(cache=True, nogil=True, inline="always")
def _draw(state):
    """cv::RNG::next(): the next 32-bit draw (as uint64) of (1,) uint64 ``state``."""
    s = state[0]
    s = (s & _LOW_32) * _MULTIPLIER + (s >> _SHIFT_32)
    state[0] = s
    return s & _LOW_32


@njit(cache=True, nogil=True)
def distinct_colours(pixels):
    """The distinct colours of (n, 3) uint8 ``pixels`` in order of first appearance,
    (c, 3) float64, and each pixel's, (n,) int32 (an open-addressing hash table)."""
    n = pixels.shape[0]
    size = 1
    while size < 2 * n:
        size *= 2
    slots = np.full(size, -1, np.int64)        # colour code of the slot; -1: empty
    ids = np.empty(size, np.int32)
    colours = np.empty((n, 3))
    colour_of = np.empty(n, np.int32)
    c = 0
    for i in range(n):
        code = (np.int64(pixels[i, 0]) << 16) | (np.int64(pixels[i, 1]) << 8) | pixels[i, 2]
        slot = (code * 2654435761) & (size - 1)
        while slots[slot] != -1 and slots[slot] != code:
            slot = (slot + 1) & (size - 1)
        if slots[slot] == -1:
            slots[slot] = code
            ids[slot] = c
            for a in range(3):
                colours[c, a] = pixels[i, a]
            c += 1
        colour_of[i] = ids[slot]
    return colours[:c], colour_of


@njit(cache=True, nogil=True, inline="always")
def _unit(state):
    """cv::RNG's double in [0, 1): two draws, the first the high 32 bits."""
    high = _draw(state)
    return np.float64((high << _SHIFT_32) | _draw(state)) * _TO_UNIT


def kmeans_colours(colours: np.ndarray, colour_of: np.ndarray, k: int, random: OpenCVRandom,
                   *, max_iterations: int, epsilon: float | None = None) -> np.ndarray:
    """Cluster labels of samples given by their colours, as ``cv2.kmeans`` with
    ``KMEANS_PP_CENTERS``, one attempt, drawing from ``random``.

    colours : (c, 3) the distinct colours (:func:`distinct_colours`); colour_of : (n,)
    int32 each sample's colour (0 < k <= n); max_iterations and
    epsilon : the termination criteria (``TERM_CRITERIA_MAX_ITER`` and, when given,
    ``TERM_CRITERIA_EPS``). Returns (n,) int32 labels.
    """
    n = len(colour_of)
    if not 0 < k <= n:
        raise ValueError(f"expected 0 < k <= samples, got k = {k} and {n} samples")
    # OpenCV's criteria: the epsilon squared (FLT_EPSILON without EPS), 2..100 iterations.
    eps = max(epsilon, 0.0) if epsilon is not None else float(np.finfo(np.float32).eps)
    count = min(max(max_iterations, 2), 100) if k > 1 else 2
    return _kmeans(np.ascontiguousarray(colours, np.float32),
                   np.ascontiguousarray(colour_of, np.int32), k, count, eps * eps, random.state)


@njit(cache=True, nogil=True, inline="always")
def _squared(a, b):
    """hal::normL2Sqr_ of two (3,) float32 rows, in single precision and OpenCV's order."""
    d = np.float32(0.0)
    for j in range(3):
        t = a[j] - b[j]
        d += t * t
    return d


@njit(cache=True, nogil=True)
def _to_centre(colours, centre, used, out):
    """(c,) float32 squared distance of every used colour to (3,) float32 ``centre``."""
    for c in range(colours.shape[0]):
        if used[c]:
            out[c] = _squared(colours[c], centre)


@njit(cache=True, nogil=True)
def _kmeans(colours, colour_of, k, max_count, epsilon_sq, state):
    n = colour_of.shape[0]
    nc = colours.shape[0]
    used = np.zeros(nc, np.bool_)
    for i in range(n):
        used[colour_of[i]] = True
    centres = _plus_plus(colours, colour_of, used, k, state)
    labels = np.empty(n, np.int32)
    best = np.empty(nc, np.int32)
    _assign(colours, colour_of, used, centres, best, labels)
    iteration = 1
    while True:
        old = centres.copy()
        centres = _centres(colours, colour_of, labels, k)
        shift = 0.0
        for c in range(k):
            moved = 0.0
            for j in range(3):
                t = np.float64(centres[c, j] - old[c, j])
                moved += t * t
            shift = max(shift, moved)
        iteration += 1
        if iteration == max_count or shift <= epsilon_sq:
            return labels
        _assign(colours, colour_of, used, centres, best, labels)


@njit(cache=True, nogil=True)
def _plus_plus(colours, colour_of, used, k, state):
    """OpenCV's generateCentersPP: (k, 3) float32 centres, samples drawn by k-means++."""
    n = colour_of.shape[0]
    dist = np.empty(n, np.float32)
    tdist = np.empty(n, np.float32)
    tdist2 = np.empty(n, np.float32)
    to_centre = np.empty(colours.shape[0], np.float32)
    chosen = np.empty(k, np.int64)
    chosen[0] = np.int64(_draw(state) % np.uint64(n))
    _to_centre(colours, colours[colour_of[chosen[0]]], used, to_centre)
    total = 0.0
    for i in range(n):
        dist[i] = to_centre[colour_of[i]]
        total += dist[i]
    for c in range(1, k):
        best_sum, best = _DBL_MAX, -1
        for _ in range(_TRIALS):
            p = _unit(state) * total
            ci = 0
            while ci < n - 1:
                p -= dist[ci]
                if p <= 0:
                    break
                ci += 1
            _to_centre(colours, colours[colour_of[ci]], used, to_centre)
            for i in range(n):
                d = to_centre[colour_of[i]]
                tdist2[i] = dist[i] if dist[i] < d else d
            s = _unrolled_sum(tdist2)
            if s < best_sum:
                best_sum, best = s, ci
                tdist, tdist2 = tdist2, tdist
        if best < 0:
            raise ValueError("k-means: no centre could be drawn (huge or NaN distances)")
        chosen[c] = best
        total = best_sum
        dist, tdist = tdist, dist
    centres = np.empty((k, 3), np.float32)
    for c in range(k):
        centres[c] = colours[colour_of[chosen[c]]]
    return centres


@njit(cache=True, nogil=True)
def _unrolled_sum(values):
    """OpenCV's sum of (n,) float32 ``values`` into a double: eight at a time added in
    single precision, then each group to the total."""
    s = 0.0
    n = values.shape[0]
    i = 0
    while i + 7 < n:
        s += values[i] + values[i + 1] + values[i + 2] + values[i + 3] + values[i + 4] \
            + values[i + 5] + values[i + 6] + values[i + 7]
        i += 8
    while i < n:
        s += values[i]
        i += 1
    return s


@njit(cache=True, nogil=True)
def _assign(colours, colour_of, used, centres, best, labels):
    """Each sample's nearest centre (the first of equals), through its colour's."""
    k = centres.shape[0]
    for c in range(colours.shape[0]):
        if not used[c]:
            continue
        k_best, least = 0, _DBL_MAX
        for j in range(k):
            d = np.float64(_squared(colours[c], centres[j]))
            if least > d:
                least, k_best = d, j
        best[c] = k_best
    for i in range(colour_of.shape[0]):
        labels[i] = best[colour_of[i]]


@njit(cache=True, nogil=True)
def _centres(colours, colour_of, labels, k):
    """The clusters' means (k, 3) float32, as OpenCV computes them: sums in single
    precision, times the reciprocal of the count; an empty cluster takes the sample
    farthest from the largest cluster's mean (the last of equals) from it."""
    n = colour_of.shape[0]
    sums = np.zeros((k, 3), np.float32)
    counts = np.zeros(k, np.int64)
    for i in range(n):
        c = labels[i]
        for j in range(3):
            sums[c, j] += colours[colour_of[i], j]
        counts[c] += 1
    for c in range(k):
        if counts[c] != 0:
            continue
        largest = 0
        for c1 in range(1, k):
            if counts[largest] < counts[c1]:
                largest = c1
        scale = np.float32(1.0) / np.float32(counts[largest])
        mean = sums[largest] * scale
        farthest, most = -1, 0.0
        for i in range(n):
            if labels[i] != largest:
                continue
            d = np.float64(_squared(colours[colour_of[i]], mean))
            if most <= d:
                most, farthest = d, i
        counts[largest] -= 1
        counts[c] += 1
        labels[farthest] = c
        for j in range(3):
            sums[largest, j] -= colours[colour_of[farthest], j]
            sums[c, j] += colours[colour_of[farthest], j]
    for c in range(k):
        scale = np.float32(1.0) / np.float32(counts[c])
        for j in range(3):
            sums[c, j] *= scale
    return sums
