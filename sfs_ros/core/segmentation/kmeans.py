"""OpenCV's k-means with its k-means++ start, and OpenCV's random generator: the same
clusters as ``cv2.kmeans(samples, k, None, criteria, 1, cv2.KMEANS_PP_CENTERS)``, bit
for bit, for a fraction of the work on colours.

The samples are colours of an image (whole numbers 0..255 in three channels): many
share a colour, and every distance OpenCV computes for a sample is that of its colour.
So the distances are computed once per distinct colour. What OpenCV sums over the
samples in their order is summed over the colours times their samples where the sums
are whole numbers that no rounding touches: the k-means++ distances (exact in single
precision by eights and in double precision in total) and the centres' sums while
they stay within 2^24; the draw's walk along the samples, the centres' larger sums and
an emptied cluster refilled run over the samples in their order, as OpenCV runs them.

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
#: Knuth's multiplier (2^32 over the golden ratio) of the colours' hash table, and the
#: table's least and largest first size (2^bits slots). At most 2^24 colours fill half of
#: 2^25 slots, whose numbers are the high bits of the product's low 32 (its low bits
#: would depend on the last channels alone).
_GOLDEN = 2654435761
_FIRST_TABLE_BITS = 8
_LAST_TABLE_BITS = 25
#: k-means++ candidates tried per centre (OpenCV's SPP_TRIALS).
_TRIALS = 3
_DBL_MAX = 1.7976931348623157e308
#: Samples per block of the k-means++ draw's running sums.
_BLOCK = 256
#: Whole numbers up to this are exact in single precision.
_EXACT_SINGLE = 1 << 24


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
    (c, 3) float64, and each pixel's, (n,) int32: an open-addressing hash table of about
    as many slots as pixels (a photograph's working copy has a quarter as many colours),
    doubled and the pixels hashed again should the colours fill half of it."""
    n = pixels.shape[0]
    bits = _FIRST_TABLE_BITS
    while (1 << bits) < n and bits < _LAST_TABLE_BITS:
        bits += 1
    colour_of = np.empty(n, np.int32)
    codes = np.full(1 << bits, -1, np.int32)   # colour code of each slot; -1: empty
    ids = np.empty(1 << bits, np.int32)
    c = _hash_colours(pixels, bits, codes, ids, colour_of)
    while c < 0:
        bits += 1
        codes = np.full(1 << bits, -1, np.int32)
        ids = np.empty(1 << bits, np.int32)
        c = _hash_colours(pixels, bits, codes, ids, colour_of)
    colours = np.empty((c, 3))
    for slot in range(codes.shape[0]):
        if codes[slot] != -1:
            colours[ids[slot], 0] = codes[slot] >> 16
            colours[ids[slot], 1] = (codes[slot] >> 8) & 255
            colours[ids[slot], 2] = codes[slot] & 255
    return colours, colour_of


@njit(cache=True, nogil=True)
def _hash_colours(pixels, bits, codes, ids, colour_of):
    """Each pixel's colour number (in order of first appearance) into ``colour_of``,
    through the empty hash table ``codes`` ((2^bits,) int32 colour codes, -1: empty)
    and ``ids`` ((2^bits,) int32 their numbers). Linear probing from the high bits of
    the code times Knuth's multiplier (they depend on every channel). Returns the
    number of colours, or -1 when they would fill more than half of the table."""
    mask = (1 << bits) - 1
    c = 0
    for i in range(pixels.shape[0]):
        code = (np.int32(pixels[i, 0]) << 16) | (np.int32(pixels[i, 1]) << 8) \
            | np.int32(pixels[i, 2])
        slot = ((np.int64(code) * _GOLDEN) & 0xFFFFFFFF) >> (32 - bits)
        while codes[slot] != -1 and codes[slot] != code:
            slot = (slot + 1) & mask
        if codes[slot] == -1:
            if 2 * (c + 1) > mask + 1:
                return -1
            codes[slot] = code
            ids[slot] = c
            c += 1
        colour_of[i] = ids[slot]
    return c


@njit(cache=True, nogil=True, inline="always")
def _unit(state):
    """cv::RNG's double in [0, 1): two draws, the first the high 32 bits."""
    high = _draw(state)
    return np.float64((high << _SHIFT_32) | _draw(state)) * _TO_UNIT


def kmeans_colours(colours: np.ndarray, colour_of: np.ndarray, k: int, random: OpenCVRandom,
                   *, max_iterations: int, epsilon: float | None = None) -> np.ndarray:
    """Cluster labels of samples given by their colours, as ``cv2.kmeans`` with
    ``KMEANS_PP_CENTERS``, one attempt, drawing from ``random``.

    colours : (c, 3) the distinct colours, whole numbers 0..255 (:func:`distinct_colours`);
    colour_of : (n,) int32 each sample's colour (0 < k <= n); max_iterations and
    epsilon : the termination criteria (``TERM_CRITERIA_MAX_ITER`` and, when given,
    ``TERM_CRITERIA_EPS``). Returns (n,) int32 labels.
    """
    n = len(colour_of)
    if not 0 < k <= n:
        raise ValueError(f"expected 0 < k <= samples, got k = {k} and {n} samples")
    colours = np.asarray(colours)
    if colours.size and (colours.min() < 0 or colours.max() > 255
                         or np.any(colours != np.floor(colours))):
        raise ValueError("expected colours of whole numbers 0..255")
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
    samples = np.zeros(nc, np.int64)           # samples of each colour
    for i in range(n):
        samples[colour_of[i]] += 1
    used = samples > 0
    centres = _plus_plus(colours, colour_of, samples, k, state)
    labels = np.empty(n, np.int32)
    best = np.empty(nc, np.int32)
    _assign(colours, used, centres, best)
    by_colour = True                           # the labels are best[colour_of], not written yet
    iteration = 1
    while True:
        old = centres.copy()
        centres, exact = _centres_by_colour(colours, samples, best, k)
        if not exact:
            _label(colour_of, best, labels)
            centres = _centres(colours, colour_of, labels, k)
            by_colour = False
        shift = 0.0
        for c in range(k):
            moved = 0.0
            for j in range(3):
                t = np.float64(centres[c, j] - old[c, j])
                moved += t * t
            shift = max(shift, moved)
        iteration += 1
        if iteration == max_count or shift <= epsilon_sq:
            if by_colour:
                _label(colour_of, best, labels)
            return labels
        _assign(colours, used, centres, best)
        by_colour = True


@njit(cache=True, nogil=True)
def _plus_plus(colours, colour_of, samples, k, state):
    """OpenCV's generateCentersPP: (k, 3) float32 centres, samples drawn by k-means++.

    Every distance OpenCV sums here is a whole number (a squared difference of two
    colours, below 2^18), and so are its sums of eight in single precision and its
    totals in double precision (below 2^53): each is the exact sum, taken here over the
    colours times their ``samples`` ((c,) int64). The draw walks the samples subtracting
    their distances from a double ``p``; every difference that stays positive is exact
    (a multiple of ``p``'s last bit, below ``p``), so it stops at the first sample where
    the running sum of the distances reaches ``p`` (:func:`_drawn_sample`)."""
    n = colour_of.shape[0]
    nc = colours.shape[0]
    used = samples > 0
    dist = np.empty(nc, np.float32)            # each colour's distance to the nearest centre
    trial = np.empty(nc, np.float32)
    kept = np.empty(nc, np.float32)
    to_centre = np.empty(nc, np.float32)
    blocks = np.empty((n + _BLOCK - 1) // _BLOCK)
    chosen = np.empty(k, np.int64)
    chosen[0] = np.int64(_draw(state) % np.uint64(n))
    _to_centre(colours, colours[colour_of[chosen[0]]], used, dist)
    total = _block_sums(colour_of, dist, blocks)
    for c in range(1, k):
        best_sum, best = _DBL_MAX, -1
        for _ in range(_TRIALS):
            ci = _drawn_sample(_unit(state) * total, colour_of, dist, blocks)
            _to_centre(colours, colours[colour_of[ci]], used, to_centre)
            s = 0.0
            for j in range(nc):
                if used[j]:
                    trial[j] = dist[j] if dist[j] < to_centre[j] else to_centre[j]
                    s += samples[j] * np.float64(trial[j])
            if s < best_sum:
                best_sum, best = s, ci
                trial, kept = kept, trial
        if best < 0:
            raise ValueError("k-means: no centre could be drawn (huge or NaN distances)")
        chosen[c] = best
        dist, kept = kept, dist
        total = _block_sums(colour_of, dist, blocks)
    centres = np.empty((k, 3), np.float32)
    for c in range(k):
        centres[c] = colours[colour_of[chosen[c]]]
    return centres


@njit(cache=True, nogil=True)
def _block_sums(colour_of, dist, blocks):
    """The samples' distances (their colours' in (c,) float32 ``dist``, whole numbers)
    summed by blocks of ``_BLOCK`` samples into ``blocks``; returns their total. Exact."""
    n = colour_of.shape[0]
    total = 0.0
    for b in range(blocks.shape[0]):
        s = 0.0
        for i in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            s += dist[colour_of[i]]
        blocks[b] = s
        total += s
    return total


@njit(cache=True, nogil=True)
def _drawn_sample(p, colour_of, dist, blocks):
    """The sample OpenCV's k-means++ draws for ``p``: the first whose running sum of
    distances reaches ``p``, at most the last (the sums exact: :func:`_plus_plus`)."""
    n = colour_of.shape[0]
    reached = 0.0
    for b in range(blocks.shape[0]):
        if reached + blocks[b] < p:
            reached += blocks[b]
            continue
        for i in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            reached += dist[colour_of[i]]
            if reached >= p:
                return i
    return n - 1


@njit(cache=True, nogil=True)
def _centres_by_colour(colours, samples, best, k):
    """The clusters' means as :func:`_centres` computes them, from each colour's cluster
    ``best`` ((c,) int32) and ``samples``: (k, 3) float32, and whether they are exact.
    OpenCV's single-precision sums of whole numbers are exact while they stay within
    2^24; when a sum goes beyond, or a cluster is empty (refilled sample by sample), they
    are not (False: take :func:`_centres`)."""
    sums = np.zeros((k, 3), np.int64)
    counts = np.zeros(k, np.int64)
    for c in range(colours.shape[0]):
        if samples[c] == 0:
            continue
        counts[best[c]] += samples[c]
        for j in range(3):
            sums[best[c], j] += samples[c] * np.int64(colours[c, j])
    centres = np.empty((k, 3), np.float32)
    for c in range(k):
        if counts[c] == 0:
            return centres, False
        scale = np.float32(1.0) / np.float32(counts[c])
        for j in range(3):
            if sums[c, j] > _EXACT_SINGLE:
                return centres, False
            centres[c, j] = np.float32(sums[c, j]) * scale
    return centres, True


@njit(cache=True, nogil=True)
def _label(colour_of, best, labels):
    """Each sample's cluster, its colour's ``best``, into ``labels``."""
    for i in range(colour_of.shape[0]):
        labels[i] = best[colour_of[i]]


@njit(cache=True, nogil=True)
def _assign(colours, used, centres, best):
    """Each used colour's nearest centre (the first of equals) into ``best``."""
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
