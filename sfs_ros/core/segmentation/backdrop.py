"""Backdrop model from the image border: what the object is *not*.

A real backdrop is rarely one colour: a black or white sweep, a turntable
plate reaching the frame, a dark cloth hanging in from one side. Each of
these covers a good share of the image border, while an object touching the
frame covers little of it (the Middlebury dino, partly out of frame, covers
at most 6 % of its border band). So the backdrop is modelled as the largest
colour clusters (k-means) of the border band that together hold most of it
(90 %), every cluster with its mean and covariance. How far a pixel is from
the backdrop is its smallest Mahalanobis distance to a cluster. Shading is not
modelled: a cast shadow is near the backdrop only where its colours are near a
cluster's (the graph cut decides the rest).

One image's border can mislead: seen from low down the plate lies wholly in the
frame, so no cluster models it and it looks like object; an object partly out of
frame puts its own colours into the band. A scan has many views of one backdrop:
:func:`fit_scan_backdrop` clusters the border bands of all of them, and
:meth:`BackdropModel.adapted_to` makes a view's model agree with it (the plate
added where the view's border does not reach it, the object's colours left out).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from .kmeans import OpenCVRandom, distinct_colours, kmeans_colours

__all__ = ["BackdropModel", "band_samples", "border_band", "fit_backdrop", "fit_scan_backdrop"]

#: Noise floor of every cluster's standard deviation, grey levels (0..255): a
#: perfectly flat backdrop must not make the slightest noise look like object.
_SIGMA_FLOOR = 4.0
_CLUSTERS = 6
_SAMPLES = 4000  # border pixels clustered, at most (about)
#: A colour reaches a view's border when more than this fraction of the border band is
#: within a cluster's reach of it. Below: the pixels blended where an edge crosses the
#: band (a few per crossing: 0 to 0.07 % of the band for the plate wholly in the frame of
#: the hostile cell's lowest views); above: a backdrop the view's frame shows but too
#: little of to be one of its clusters (3.6 to 7.7 % for the Middlebury temple's cloth).
_REACH_FRACTION = 0.01


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
        out = np.empty(rgb.shape[:-1], np.float32)
        _min_mahalanobis(*_planes(rgb), self.means, self.inverse_covariances, out.reshape(-1))
        return out

    def adapted_to(self, scan: BackdropModel, band: np.ndarray, near_sigma: float,
                   far_sigma: float) -> BackdropModel:
        """This view's model (``self``, learnt from its border ``band``, (n, 3) uint8)
        made to agree with the backdrop of the whole scan (``scan``,
        :func:`fit_scan_backdrop`):

        * its clusters whose colour is further than ``far_sigma`` standard deviations
          from the scan's backdrop (a colour the scan's backdrop takes for object) are
          left out: the object reaching this view's frame (unless that leaves none:
          another backdrop);
        * the scan's clusters of a colour its border does not reach are added: a
          turntable plate wholly in the frame. A colour reaches the border when more
          than ``_REACH_FRACTION`` of ``band`` lies within ``near_sigma`` of it, and a
          scan's cluster is one of this model's when either's mean lies within
          ``near_sigma`` of the other.

        Returns ``self`` when nothing changes."""
        keep = scan.distance(np.clip(np.rint(self.means), 0, 255).astype(np.uint8)) <= far_sigma
        if not keep.any():
            keep[:] = True
        add = ~self._overlaps(scan, near_sigma).any(axis=0)
        for k in np.flatnonzero(add):
            one = BackdropModel(scan.means[k:k + 1], scan.inverse_covariances[k:k + 1])
            add[k] = np.count_nonzero(one.distance(band) <= near_sigma) \
                < _REACH_FRACTION * len(band)
        if keep.all() and not add.any():
            return self
        return BackdropModel(np.concatenate([self.means[keep], scan.means[add]]),
                             np.concatenate([self.inverse_covariances[keep],
                                             scan.inverse_covariances[add]]))

    def _overlaps(self, other: BackdropModel, sigma: float) -> np.ndarray:
        """(k, m) bool: whether cluster i here and cluster j of ``other`` are one colour,
        either's mean within ``sigma`` standard deviations of the other (by that one's
        covariance)."""
        step = self.means[:, None, :] - other.means[None, :, :]      # (k, m, 3)
        by_other = np.einsum("kmi,mij,kmj->km", step, other.inverse_covariances, step)
        by_self = np.einsum("kmi,kij,kmj->km", step, self.inverse_covariances, step)
        return np.minimum(by_other, by_self) <= sigma ** 2

    def nearest(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The smallest Mahalanobis distance of each colour of ``rgb`` ((..., 3) uint8) to
        a backdrop cluster ((...) float32, standard deviations) and that cluster's
        index ((...) int32)."""
        out = np.empty(rgb.shape[:-1], np.float32)
        index = np.empty(rgb.shape[:-1], np.int32)
        _nearest_cluster(*_planes(rgb), self.means, self.inverse_covariances, out.reshape(-1),
                         index.reshape(-1))
        return out, index


def _planes(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The red, green and blue values of ``rgb`` ((..., 3) uint8), each (n,) uint8: the
    kernels below read three planes, whose loops vectorise (reading the interleaved
    pixels does not)."""
    pixels = np.ascontiguousarray(rgb, dtype=np.uint8).reshape(-1, 1, 3)
    return tuple(plane.reshape(-1) for plane in cv2.split(pixels))


@njit(cache=True, nogil=True, inline="always")
def _quadratic_form(means, inverses, k):
    """Cluster k's mean and the six coefficients of its (symmetric) inverse covariance:
    r^T A r = a00 r0^2 + a11 r1^2 + a22 r2^2 + a01 r0 r1 + a02 r0 r2 + a12 r1 r2."""
    m = inverses[k]
    return (means[k, 0], means[k, 1], means[k, 2], m[0, 0], m[1, 1], m[2, 2],
            m[0, 1] + m[1, 0], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1])


@njit(cache=True, nogil=True, inline="always")
def _squared(red, green, blue, i, c):
    """Squared Mahalanobis distance of pixel ``i`` (its values in the three planes) for
    form ``c``."""
    r0 = np.float32(red[i]) - c[0]
    r1 = np.float32(green[i]) - c[1]
    r2 = np.float32(blue[i]) - c[2]
    return (r0 * (c[3] * r0 + c[6] * r1 + c[7] * r2) + r1 * (c[4] * r1 + c[8] * r2)
            + c[5] * r2 * r2)


@njit(cache=True, nogil=True, fastmath=True)
def _min_mahalanobis(red, green, blue, means, inverses, out):
    """``out[i]`` = min over clusters k of sqrt(r^T inverses[k] r), r = pixel i - means[k].
    Cluster by cluster over all pixels: the inner loop vectorises."""
    out[:] = np.inf
    for k in range(means.shape[0]):
        c = _quadratic_form(means, inverses, k)
        for i in range(out.size):
            out[i] = min(out[i], _squared(red, green, blue, i, c))
    for i in range(out.size):
        out[i] = np.sqrt(max(out[i], np.float32(0.0)))


@njit(cache=True, nogil=True)
def _nearest_cluster(red, green, blue, means, inverses, out, index):
    """As :func:`_min_mahalanobis`, and ``index[i]`` = the nearest cluster k."""
    out[:] = np.inf
    index[:] = 0
    for k in range(means.shape[0]):
        c = _quadratic_form(means, inverses, k)
        for i in range(out.size):
            q = _squared(red, green, blue, i, c)
            if q < out[i]:
                out[i] = q
                index[i] = k
    for i in range(out.size):
        out[i] = np.sqrt(max(out[i], np.float32(0.0)))


def _band_width(height: int, width: int, border_fraction: float) -> int:
    """Width in pixels of :func:`border_band`."""
    return max(2, int(round(border_fraction * min(height, width))))


def border_band(height: int, width: int, border_fraction: float) -> np.ndarray:
    """(H, W) bool: the band along the image edges, ``border_fraction`` of the smaller
    side wide (at least 2 pixels)."""
    b = _band_width(height, width, border_fraction)
    band = np.zeros((height, width), bool)
    band[:b] = band[-b:] = True
    band[:, :b] = band[:, -b:] = True
    return band


def _band_pixels(rgb: np.ndarray, border_fraction: float) -> np.ndarray:
    """The pixels of :func:`border_band` of ``rgb`` ((H, W, 3)), in row-major order as
    ``rgb[border_band(...)]``, without a full-image mask: (n, 3)."""
    h, w = rgb.shape[:2]
    b = _band_width(h, w, border_fraction)
    if 2 * b >= h or 2 * b >= w:
        return rgb[border_band(h, w, border_fraction)]
    sides = np.concatenate([rgb[b:h - b, :b], rgb[b:h - b, w - b:]], axis=1)
    return np.concatenate([rgb[:b].reshape(-1, 3), sides.reshape(-1, 3),
                           rgb[h - b:].reshape(-1, 3)])


def band_samples(rgb: np.ndarray, border_fraction: float = 0.02) -> np.ndarray:
    """About ``_SAMPLES`` pixels of the border band of ``rgb`` ((H, W, 3) uint8), evenly
    along the border: (n, 3) uint8, what :func:`fit_backdrop` clusters."""
    band = _band_pixels(rgb, border_fraction)
    return np.ascontiguousarray(band[:: max(1, len(band) // _SAMPLES)])


def fit_backdrop(rgb: np.ndarray | None = None, *, border_fraction: float = 0.02,
                 cover: float = 0.9, random: OpenCVRandom | None = None,
                 samples: np.ndarray | None = None) -> BackdropModel:
    """Fit the backdrop clusters to the border band of ``rgb`` ((H, W, 3) uint8).

    Clusters are kept largest first until they hold ``cover`` of the band's
    pixels: an object touching the frame, holding less than ``1 - cover`` of
    the band, stays out of the backdrop. Deterministic: the k-means (OpenCV's) draws
    from ``random``, OpenCV's generator seeded with 0 when None (advanced in place).
    ``samples`` ((n, 3) uint8, the image's :func:`band_samples`) stands for ``rgb``
    when given: the same model.
    """
    if samples is None:
        if rgb is None:
            raise ValueError("fit_backdrop needs an image or its border's samples")
        samples = band_samples(rgb, border_fraction)
    return _fit_clusters(samples, cover,
                         OpenCVRandom(0) if random is None else random)


def fit_scan_backdrop(samples: list[np.ndarray], *, cover: float = 0.9) -> BackdropModel:
    """The backdrop of a whole scan: the clusters of the border bands of all its views
    (``samples``: each view's :func:`band_samples`, (n_i, 3) uint8), each view weighing
    the same, kept largest first until they hold ``cover`` of the pixels.

    A turntable plate reaching the frame in most views is a cluster here, though it lies
    wholly in the frame in a few (seen from low down); an object's colours, reaching the
    frame in a few views by a small part of their border, hold too little of the pooled
    band to be kept. Deterministic (OpenCV's generator seeded with 0)."""
    if not samples:
        raise ValueError("no view to learn the scan's backdrop from")
    step = len(samples)  # about as many pixels in all as one view's band
    pooled = np.concatenate([s[::step] for s in samples])
    return _fit_clusters(np.ascontiguousarray(pooled, np.uint8), cover, OpenCVRandom(0))


def _fit_clusters(band: np.ndarray, cover: float, random: OpenCVRandom) -> BackdropModel:
    """The largest k-means clusters of ``band`` ((n, 3) uint8 colours) that together hold
    ``cover`` of them, each with its mean and (noise-floored) covariance."""
    if not 0 < cover <= 1:
        raise ValueError(f"cover must be in (0, 1], got {cover}")
    colours, colour_of = distinct_colours(band)
    k = min(_CLUSTERS, len(colours))
    labels = kmeans_colours(colours, colour_of, k, random, max_iterations=20, epsilon=0.5)
    pixels = band.astype(np.float32)
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
