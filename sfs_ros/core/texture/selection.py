"""Which view colours each face of a mesh: the quality of every view for every face, and
a labelling that trades quality against seams.

A view *sees* a face when it sees four points of it (the centroid and the three corners
pulled :data:`CORNER_PULL` of the way towards it) by the test the vertex colours use
(:func:`~sfs_ros.core.meshing.colour.view_sight`): in the image, facing the camera,
inside the silhouette, off its edges and depth steps, and not hidden by the mesh (its
z-buffer). A face may be smaller than a pixel, and the z-buffer holds the surface at
the pixel centres only: a point is hidden when it lies behind the surface drawn at every
one of the four pixel centres around it (at least: :func:`farthest_around`), by more than the
sight test's tolerance (a pixel's footprint, more on a slope), not behind their
bilinear blend: a sub-pixel face that loses the pixel centres to its neighbours is
still seen. The face's quality in that view is

    ``q = min(weights of the four points) * projected area (pixels^2) * sharpness``,

the weight falling with the angle from the normal (frontal), the projected area growing
as the camera comes nearer (``1 / depth^2``) and faces it, and ``sharpness`` the view's
variance of the Laplacian inside its silhouette relative to the sharpest view's (a
shot blurred by motion or focus loses to its neighbours). A face no view sees so takes
the best of the views that *glimpse* it (:data:`GLIMPSE`: its centroid seen unhidden,
a pixel and a half from an outline or a depth step, where its corners may lie nearer),
their weights scaled by :data:`GLIMPSE_WEIGHT` so that they never compete with a full
view: a rim a few pixels wide then keeps its detail rather than colours interpolated
from its corners.

The labelling (in the spirit of Waechter, Moehrle and Goesele, "Let there be color!",
2014) minimises ``sum_f cost(f, l_f) + smoothness * #{neighbouring faces with different
labels}`` with ``cost(f, l) = 1 - q(f, l) / max_l q(f, l)`` (infinite where ``l`` does
not see ``f``), by iterated conditional modes from the best view of each face: each
face in turn takes the label that minimises its cost plus its seams, until no face
changes. Faces no view sees get the label -1.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit
from scipy import ndimage

from ..geometry.camera import Camera
from ..meshing.colour import view_sight
from ..render import rasterize_depth

__all__ = ["CORNER_PULL", "GLIMPSE", "GLIMPSE_WEIGHT", "SMOOTHNESS", "face_neighbours", "face_quality",
           "farthest_around",
           "label_faces", "towards_camera",
           "sharpness"]

#: The corners of a face are tested for visibility this fraction of the way towards its
#: centroid: a corner itself lies on the edge of the faces around it, some of which the
#: view may not see.
CORNER_PULL = 0.2
#: Cost of a seam (two neighbouring faces from different views) against the data cost in
#: [0, 1] of a face (:func:`label_faces`); chosen by measurement (doc/benchmarks.md).
SMOOTHNESS = 0.3
#: The looser test of a *glimpse* (:func:`face_quality`): the face's centroid alone, half
#: a pixel of ramp off the outline and the depth steps instead of three.
GLIMPSE = {"edge_ramp_px": 0.5}
#: A glimpse's weight against a full view's: it colours only faces no view sees fully.
GLIMPSE_WEIGHT = 1e-6
#: Faces whose centroid sees the camera at a cosine at most this are not tested (the
#: sight test's least cosine is 0.2).
_FACING_COS = 0.1
#: Most sweeps of iterated conditional modes (it stops earlier when no face changes).
MAX_SWEEPS = 20


def face_samples(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points a view must see to see a face: (m, 4, 3) metres (centroid, then the
    corners pulled :data:`CORNER_PULL` towards it), and the unit face normals (m, 3)
    (zero for a degenerate face)."""
    corners = vertices[faces]                                       # (m, 3, 3)
    centroid = corners.mean(axis=1, keepdims=True)
    pulled = corners + CORNER_PULL * (centroid - corners)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    return np.concatenate([centroid, pulled], axis=1), normal


def sharpness(image: np.ndarray, mask: np.ndarray | None) -> float:
    """Variance of the Laplacian of ``image`` (H, W, 3) uint8's grey levels inside ``mask``
    (H, W) bool eroded by two pixels (the outline's own step left out), or over the
    image without a mask; grey levels squared."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    laplacian = cv2.Laplacian(grey, cv2.CV_32F)
    if mask is None:
        return float(laplacian.var())
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return float(laplacian[inner].var()) if inner.sum() > 1 else 0.0


def towards_camera(camera: Camera, points: np.ndarray) -> np.ndarray:
    """(k, 3) unit vectors from ``points`` (k, 3) metres towards ``camera`` (for an
    orthographic camera, against its viewing direction)."""
    if camera.orthographic:
        return np.broadcast_to(-camera.R[2], points.shape)
    to_camera = camera.center - points
    length = np.sqrt(np.einsum("kd,kd->k", to_camera, to_camera))
    return to_camera / np.maximum(length, 1e-300)[:, None]


def face_quality(vertices: np.ndarray, faces: np.ndarray, camera: Camera,
                 mask: np.ndarray | None, *, closed: bool = False, samples: tuple | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(m,) float64 quality of ``camera``'s view for each face (module docstring, without
    the sharpness factor; 0 where the view does not see the face) and (m,) bool where it
    sees it fully (not a glimpse).

    ``vertices`` (n, 3) metres and ``faces`` (m, 3) outward; ``mask`` (H, W) bool the
    view's silhouette or None; ``closed``: the mesh is closed and outward (the z-buffer
    draws the faces turned towards the camera only).
    ``samples``: the mesh's :func:`face_samples`, when the caller has them (one mesh,
    many views).
    """
    points, normals = face_samples(vertices, faces) if samples is None else samples
    zbuf = rasterize_depth(vertices, faces, camera, closed=closed)
    behind_all = farthest_around(zbuf)
    # Only faces turned towards the camera can pass (the sight test's angle, less a
    # margin for the samples' directions): the others are not tested.
    facing = np.flatnonzero(_facing_cos(camera, points[:, 0], normals) > _FACING_COS)

    def sight(chosen: np.ndarray, corners: bool = False, **options):
        """The sight test of the centroids (or the three pulled corners) of ``chosen``."""
        at = slice(1, 4) if corners else slice(0, 1)
        return view_sight(camera, points[chosen, at].reshape(-1, 3),
                          np.repeat(normals[chosen], at.stop - at.start, axis=0), zbuf, mask,
                          depth_zbuf=behind_all, **options)

    # The glimpse of every facing face first: its narrower ramp off the edges weighs a
    # point above zero exactly where the full test does (the ramps start at one margin),
    # so the faces it finds are those whose centroid passes the full test, and the
    # others (most, on a refined mesh) need no other point tested.
    weight = np.zeros(len(faces))
    weight[facing] = GLIMPSE_WEIGHT * sight(facing, **GLIMPSE).weight
    candidates = facing[weight[facing] > 0]
    at_corners = sight(candidates, corners=True)
    least = np.minimum(sight(candidates).weight, at_corners.weight.reshape(-1, 3).min(axis=1))
    full = np.zeros(len(faces), bool)
    full[candidates] = least > 0
    weight[full] = least[least > 0]
    area_px = np.zeros(len(faces))
    area_px[candidates] = _projected_area(at_corners)
    return np.where(weight > 0, weight * np.nan_to_num(area_px), 0.0), full


def _facing_cos(camera: Camera, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(m,) cosine between each unit normal (m, 3) and the direction from its point
    (m, 3) metres towards ``camera``."""
    if camera.orthographic:
        return normals @ -camera.R[2]
    out = np.empty(len(points))
    _cos_towards(points, normals, camera.center, out)
    return out


@njit(cache=True, nogil=True)
def _cos_towards(points, normals, centre, out):
    """:func:`_facing_cos` of a pinhole camera at ``centre`` (3,) metres, into ``out``."""
    for i in range(points.shape[0]):
        dx, dy, dz = centre[0] - points[i, 0], centre[1] - points[i, 1], centre[2] - points[i, 2]
        length = max(np.sqrt(dx * dx + dy * dy + dz * dz), 1e-300)
        out[i] = (normals[i, 0] * dx + normals[i, 1] * dy + normals[i, 2] * dz) / length


def _projected_area(corners) -> np.ndarray:
    """(k,) area in pixels^2 of the faces whose three pulled corners' sight test
    (``corners.u``, ``corners.v`` (3k,)) is given, scaled back to the whole face (NaN
    where a corner falls outside the image)."""
    u, v = corners.u.reshape(-1, 3), corners.v.reshape(-1, 3)
    return 0.5 * np.abs((u[:, 1] - u[:, 0]) * (v[:, 2] - v[:, 0])
                        - (u[:, 2] - u[:, 0]) * (v[:, 1] - v[:, 0])) / (1 - CORNER_PULL) ** 2


def farthest_around(zbuf: np.ndarray) -> np.ndarray:
    """(H, W) float64: each pixel's farthest finite depth among the 3 x 3 pixels around it
    in ``zbuf`` (H, W) metres (inf where all nine are inf).

    Read bilinearly at a point, this is at least the farthest depth drawn at the four
    pixel centres around the point (each of the four values read covers all four): a
    point behind it is behind the surface at every one of them (module docstring)."""
    out = ndimage.maximum_filter(np.where(np.isfinite(zbuf), zbuf, -np.inf), size=3,
                                 mode="nearest")
    return np.where(np.isneginf(out), np.inf, out)


def face_neighbours(faces: np.ndarray) -> np.ndarray:
    """(m, 3) int64: the face across each edge of each face (edge k joins corners k and
    k + 1), -1 where the edge has no face or more than one across it."""
    m = len(faces)
    ends = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.sort(ends, axis=1)
    key = key[:, 0] * (int(faces.max()) + 1) + key[:, 1]
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    starts = np.flatnonzero(np.concatenate([[True], sorted_key[1:] != sorted_key[:-1]]))
    pair = starts[np.diff(np.append(starts, len(key))) == 2]   # edges of exactly two faces
    a, b = order[pair], order[pair + 1]
    neighbours = np.full(3 * m, -1, np.int64)
    neighbours[a], neighbours[b] = b // 3, a // 3
    return neighbours.reshape(m, 3)


@njit(cache=True, nogil=True)
def _icm(cost, neighbours, labels, smoothness, max_sweeps):
    """Iterated conditional modes on ``labels`` (m,) in place; returns the sweeps made."""
    m, n_views = cost.shape
    for sweep in range(max_sweeps):
        changed = 0
        for f in range(m):
            if labels[f] < 0:
                continue
            best, best_cost = labels[f], np.inf
            for label in range(n_views):
                c = cost[f, label]
                if not np.isfinite(c):
                    continue
                for k in range(3):
                    g = neighbours[f, k]
                    if g >= 0 and labels[g] >= 0 and labels[g] != label:
                        c += smoothness
                if c < best_cost:
                    best, best_cost = label, c
            if best != labels[f]:
                labels[f] = best
                changed += 1
        if changed == 0:
            return sweep + 1
    return max_sweeps


def label_faces(quality: np.ndarray, neighbours: np.ndarray, *,
                smoothness: float = SMOOTHNESS) -> tuple[np.ndarray, int]:
    """The view of each face (module docstring): ``(labels (m,) int64, -1 where no view
    sees the face; sweeps made)``, from ``quality`` (m, V) float (0: not seen) and
    ``neighbours`` (m, 3) (:func:`face_neighbours`). ``smoothness`` 0: the best view of
    each face."""
    if not (np.isfinite(smoothness) and smoothness >= 0):
        raise ValueError(f"smoothness must be a finite number >= 0, got {smoothness}")
    best = quality.max(axis=1)
    labels = np.where(best > 0, quality.argmax(axis=1), -1).astype(np.int64)
    # Only the seen faces' costs are read (often a minority of a refined mesh's faces).
    seen = np.flatnonzero(best > 0)
    cost = np.full(quality.shape, np.inf)
    cost[seen] = np.where(quality[seen] > 0, 1.0 - quality[seen] / best[seen, None], np.inf)
    sweeps = _icm(cost, neighbours, labels, float(smoothness), MAX_SWEEPS) if smoothness else 0
    return labels, sweeps
