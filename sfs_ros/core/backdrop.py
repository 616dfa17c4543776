"""Backdrop model from the image border: what the object is *not*.

A real backdrop is rarely one colour: a black or white sweep, a turntable
plate reaching the frame, a dark cloth hanging in from one side. Each of
these covers a good share of the image border, while an object touching the
frame covers little of it (the Middlebury dino, partly out of frame, covers
at most 6 % of its border band). So the backdrop is modelled as the largest
colour clusters (k-means) of the border band that together hold most of it
(90 %), every cluster with its mean and covariance. How far a pixel is from
the backdrop is its smallest Mahalanobis distance to a cluster, where the
cluster's colour may also be darkened (a cast shadow darkens a surface but
keeps its hue).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

__all__ = ["BackdropModel", "fit_backdrop", "border_band"]

#: Noise floor of every cluster's standard deviation, grey levels (0..255): a
#: perfectly flat backdrop must not make the slightest noise look like object.
_SIGMA_FLOOR = 4.0
_CLUSTERS = 6
_SAMPLES = 4000  # border pixels clustered, at most (about)


class BackdropModel:
    """Colour clusters of the backdrop.

    means : (k, 3) float32, RGB 0..255
    inverse_covariances : (k, 3, 3) float32, of the cluster colours (noise floor added)
    """

    def __init__(self, means: np.ndarray, inverse_covariances: np.ndarray):
        self.means = np.asarray(means, np.float32).reshape(-1, 3)
        self.inverse_covariances = np.asarray(inverse_covariances, np.float32).reshape(-1, 3, 3)

    def distance(self, rgb: np.ndarray) -> np.ndarray:
        """Smallest Mahalanobis distance of each colour of ``rgb`` ((..., 3) uint8, e.g.
        an (H, W, 3) image or (n, 3) pixels) to a backdrop cluster: (...) float32, in
        standard deviations."""
        pixels = np.ascontiguousarray(rgb).reshape(-1, 3)
        out = np.empty(len(pixels), np.float32)
        _min_mahalanobis(pixels, self.means, self.inverse_covariances, out)
        return out.reshape(rgb.shape[:-1])


@njit(cache=True, nogil=True)
def _min_mahalanobis(pixels, means, inverses, out):
    """``out[i]`` = min over clusters k of sqrt(r^T inverses[k] r), r = pixels[i] - means[k]."""
    for i in range(pixels.shape[0]):
        best = np.inf
        for k in range(means.shape[0]):
            r0 = pixels[i, 0] - means[k, 0]
            r1 = pixels[i, 1] - means[k, 1]
            r2 = pixels[i, 2] - means[k, 2]
            m = inverses[k]
            q = (r0 * (m[0, 0] * r0 + m[0, 1] * r1 + m[0, 2] * r2)
                 + r1 * (m[1, 0] * r0 + m[1, 1] * r1 + m[1, 2] * r2)
                 + r2 * (m[2, 0] * r0 + m[2, 1] * r1 + m[2, 2] * r2))
            best = min(best, q)
        out[i] = np.sqrt(max(best, 0.0))


def border_band(height: int, width: int, border_fraction: float) -> np.ndarray:
    """(H, W) bool: the band along the image edges, ``border_fraction`` of the smaller
    side wide (at least 2 pixels)."""
    b = max(2, int(round(border_fraction * min(height, width))))
    band = np.zeros((height, width), bool)
    band[:b] = band[-b:] = True
    band[:, :b] = band[:, -b:] = True
    return band


def fit_backdrop(rgb: np.ndarray, *, border_fraction: float = 0.02,
                 cover: float = 0.9) -> BackdropModel:
    """Fit the backdrop clusters to the border band of ``rgb`` ((H, W, 3) uint8).

    Clusters are kept largest first until they hold ``cover`` of the band's
    pixels: an object touching the frame, holding less than ``1 - cover`` of
    the band, stays out of the backdrop. Deterministic (fixed k-means seed).
    """
    if not 0 < cover <= 1:
        raise ValueError(f"cover must be in (0, 1], got {cover}")
    h, w = rgb.shape[:2]
    pixels = rgb[border_band(h, w, border_fraction)].astype(np.float32)
    pixels = pixels[:: max(1, len(pixels) // _SAMPLES)]  # an even subsample along the border
    k = min(_CLUSTERS, len(np.unique(pixels, axis=0)))
    cv2.setRNGSeed(0)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)
    _, labels, _ = cv2.kmeans(pixels, k, None, criteria, 1, cv2.KMEANS_PP_CENTERS)
    labels = labels.ravel()
    counts = np.bincount(labels, minlength=k)
    means, inverses, held = [], [], 0
    for j in np.argsort(-counts):
        if held >= cover * len(pixels):
            break
        held += counts[j]
        members = pixels[labels == j]
        covariance = np.cov(members.T) if len(members) > 1 else np.zeros((3, 3))
        means.append(members.mean(axis=0))
        inverses.append(np.linalg.inv(covariance + _SIGMA_FLOOR ** 2 * np.eye(3)))
    return BackdropModel(np.array(means), np.array(inverses))
