"""GrabCut's graph cut with frozen colour models, on the undecided pixels only.

``cv2.grabCut(image, labels, None, bgd, fgd, 1, cv2.GC_EVAL_FREEZE_MODEL)`` builds a
graph over every pixel of the image, also the sure ones, whose labels it never
changes. When the undecided pixels are a narrow band (an outline to re-decide at full
resolution), nearly all that work is spent on fixed pixels. :func:`band_cut` builds the
same energy over the undecided pixels alone, with the graph and the max-flow of
:mod:`.grabcut` (OpenCV's: the data term of the colour models, smoothness
``gamma = 50`` weighted by the colour contrast with GrabCut's ``beta`` over the whole
image, 8 neighbours, Boykov-Kolmogorov's max-flow): a sure neighbour is folded into the
pixel's terminal weights, where it pulls the same way it would as a node of the full
graph. The minimum cut is then the full graph's (up to ties between equal cuts), and
the work releases Python's lock.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numba import njit

from ..mask_box import foreground_box
from .grabcut import _gaussians, _graph, _max_flow, _mixture, grabcut
from .kmeans import OpenCVRandom, distinct_colours

__all__ = ["band_cut", "coarse_to_fine_grabcut", "frozen_data_term", "grabcut_beta"]

#: Neighbour offsets (rows, columns) of GrabCut's graph: left, up-left, up, up-right
#: (each pair once; the edges are symmetric).
_OFFSETS = ((0, -1), (-1, -1), (-1, 0), (-1, 1))
#: A data term past any finite weight, for a colour one model gives no probability
#: (infinite in GrabCut); 0 when neither does.
_HUGE = 1e300


def frozen_data_term(models: tuple[np.ndarray, np.ndarray], colours: np.ndarray) -> np.ndarray:
    """GrabCut's terminal weight of each colour, source (object) minus sink (backdrop):
    ``-log P(colour | backdrop) + log P(colour | object)`` under the mixtures ``models``
    (the backdrop's and the object's, (1, 65) float64 each as ``cv2.grabCut`` fills them:
    5 weights, 5 x 3 means, 5 x 3 x 3 covariances), each density in OpenCV's order of
    operations. colours : (n, 3) uint8 or float64. Returns (n,) float64; a colour one
    model gives no probability ``+-1e300``, one neither does 0."""
    colours = np.ascontiguousarray(colours, np.float64).reshape(-1, 3)
    return _data_term(_gaussians(np.stack([_components(m) for m in models])), colours)


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


def _components(model: np.ndarray) -> np.ndarray:
    """A (1, 65) GrabCut model as :mod:`.grabcut` holds it: (5, 13), per component its
    weight, mean (3) and covariance (9)."""
    m = np.asarray(model, np.float64).ravel()
    return np.concatenate([m[:5, None], m[5:20].reshape(5, 3), m[20:65].reshape(5, 9)], axis=1)


@njit(cache=True, nogil=True)
def _data_term(g, colours):
    """(n,) float64 terminal weights of (n, 3) float64 ``colours`` under the Gaussians
    ``g`` ((2, 5, 16) from :func:`~.grabcut._gaussians`, backdrop then object), source
    minus sink (:func:`frozen_data_term`)."""
    out = np.empty(colours.shape[0])
    for v in range(colours.shape[0]):
        r, gr, b = colours[v, 0], colours[v, 1], colours[v, 2]
        backdrop, thing = _mixture(g[0], r, gr, b), _mixture(g[1], r, gr, b)
        if backdrop > 0.0 and thing > 0.0:
            data = -math.log(backdrop) - -math.log(thing)
        elif thing > 0.0:
            data = _HUGE
        elif backdrop > 0.0:
            data = -_HUGE
        else:
            data = 0.0
        out[v] = data
    return out


def band_cut(image: np.ndarray, labels: np.ndarray, models: tuple[np.ndarray, np.ndarray]) -> None:
    """Decide the undecided pixels of ``labels`` in place, as ``cv2.grabCut`` with
    ``GC_EVAL_FREEZE_MODEL`` and one iteration would.

    image : (h, w, 3) uint8; labels : (h, w) uint8 ``cv2.GC_*`` values (probable object
    and probable backdrop are decided, sure labels stay); models : the backdrop's and the
    object's (1, 65) float64 GrabCut models. The contrast scale ``beta`` is GrabCut's over
    the whole ``image``.
    """
    free = (labels == cv2.GC_PR_FGD) | (labels == cv2.GC_PR_BGD)
    if not free.any():
        return
    image = np.ascontiguousarray(image, np.uint8)
    first, head, after, capacity, fold = _graph(image, grabcut_beta(image), free, labels)
    colours, colour_of = distinct_colours(image[free])   # a band has half as many colours
    excess = frozen_data_term(models, colours)[colour_of] + fold
    chosen = _max_flow(first, head, after, capacity, excess)
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
    box = foreground_box(band)
    if box is None:
        return chosen
    # Outside the band the reduced cut stands (as sure labels); inside, the prior's.
    fine = np.where(chosen[box] > 0, cv2.GC_FGD, cv2.GC_BGD).astype(np.uint8)
    fine[band[box]] = labels[box][band[box]]
    band_cut(np.ascontiguousarray(features[box]), fine, models)
    chosen[box] = (fine == cv2.GC_FGD) | (fine == cv2.GC_PR_FGD)
    return chosen
