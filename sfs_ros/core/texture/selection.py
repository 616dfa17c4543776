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
the best of the views that *glimpse* it (:data:`GLIMPSE_RAMP_PX`: its centroid seen unhidden,
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

from collections.abc import Sequence

import cv2
import numpy as np
from numba import njit
from scipy import ndimage

from ..geometry.camera import Camera
from ..meshing.colour import (
    ANGLE_POWER,
    DEPTH_TOLERANCE_PX,
    EDGE_RAMP_PX,
    MIN_COS,
    sight_maps,
    sight_weight,
    view_point,
)
from ..outline import edges_by_lower_vertex
from ..render import as_mesh_arrays, depth_of_checked
from ..workers import map_in_threads

__all__ = ["CORNER_PULL", "GLIMPSE_RAMP_PX", "GLIMPSE_WEIGHT", "SMOOTHNESS", "face_neighbours",
           "face_qualities", "face_samples", "farthest_around", "label_faces", "sharpness",
           "towards_camera"]

#: The corners of a face are tested for visibility this fraction of the way towards its
#: centroid: a corner itself lies on the edge of the faces around it, some of which the
#: view may not see.
CORNER_PULL = 0.2
#: Cost of a seam (two neighbouring faces from different views) against the data cost in
#: [0, 1] of a face (:func:`label_faces`); chosen by measurement (doc/benchmarks.md).
SMOOTHNESS = 0.3
#: The looser test of a *glimpse* (:func:`face_qualities`): the face's centroid alone, half
#: a pixel of ramp off the outline and the depth steps instead of the full test's three.
GLIMPSE_RAMP_PX = 0.5
#: The sight test's options, as the vertex colours use them (the defaults of
#: :func:`~sfs_ros.core.meshing.colour.view_sight`): least cosine, angle power, pixels of
#: ramp off the edges and of depth tolerance.
_SIGHT_OPTIONS = (MIN_COS, ANGLE_POWER, EDGE_RAMP_PX, DEPTH_TOLERANCE_PX)
#: A face's area over the area of its corners pulled :data:`CORNER_PULL` towards its
#: centroid.
_AREA_OF_PULLED = (1 - CORNER_PULL) ** 2
#: A glimpse's weight against a full view's: it colours only faces no view sees fully.
GLIMPSE_WEIGHT = 1e-6
#: Faces a thread tests at a time (:func:`face_qualities`), and faces every view tests in
#: turn (their samples in the cache).
_FACES_A_TASK, _FACES_A_PASS = 1 << 16, 1 << 11
#: Most sweeps of iterated conditional modes (it stops earlier when no face changes).
MAX_SWEEPS = 20


def face_samples(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points a view must see to see a face: (m, 4, 3) metres (centroid, then the
    corners pulled :data:`CORNER_PULL` towards it), and the unit face normals (m, 3)
    (zero for a degenerate face)."""
    points, normals = np.empty((len(faces), 4, 3)), np.empty((len(faces), 3))
    _face_samples(vertices, faces, CORNER_PULL, points, normals)
    return points, normals


@njit(cache=True, nogil=True)
def _face_samples(vertices, faces, pull, points, normals):
    """:func:`face_samples` into ``points`` (m, 4, 3) and ``normals`` (m, 3)."""
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        for d in range(3):
            points[f, 0, d] = (vertices[a, d] + vertices[b, d] + vertices[c, d]) / 3.0
            for k in range(3):
                corner = vertices[faces[f, k], d]
                points[f, k + 1, d] = corner + pull * (points[f, 0, d] - corner)
        e1x, e1y, e1z = (vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1],
                         vertices[b, 2] - vertices[a, 2])
        e2x, e2y, e2z = (vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1],
                         vertices[c, 2] - vertices[a, 2])
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length > 0.0:
            normals[f, 0], normals[f, 1], normals[f, 2] = nx / length, ny / length, nz / length
        else:
            normals[f, 0] = normals[f, 1] = normals[f, 2] = 0.0


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


def face_qualities(vertices: np.ndarray, faces: np.ndarray, cameras: Sequence[Camera],
                   masks: Sequence, *, closed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(m, V) float64 quality of each view for each face (module docstring, without the
    sharpness factor; 0 where the view does not see the face) and (m, V) bool where it
    sees it fully (not a glimpse).

    ``vertices`` (n, 3) metres and ``faces`` (m, 3) outward; ``cameras`` the V views,
    ``masks`` their silhouettes, (H, W) bool or None each; ``closed``: the mesh is closed
    and outward (the z-buffers draw the faces turned towards the camera only). The views'
    z-buffers and edge maps are made side by side, then every face is tested in every
    view in one pass over the faces, blocks of them side by side.
    """
    vertices, faces = as_mesh_arrays(vertices, faces)            # (checked once, not per view)
    points, normals = face_samples(vertices, faces)

    def maps(view):
        camera, mask = view
        zbuf = depth_of_checked(vertices, faces, camera, closed=closed)
        return sight_maps(camera, zbuf, mask, farthest_around(zbuf))

    found = list(map_in_threads(maps, zip(cameras, masks)))
    # The maps as planes of one array (padded with zeros, never read, where sizes differ).
    height = max(edge.shape[0] for edge, *_ in found)
    width = max(edge.shape[1] for edge, *_ in found)
    edges = np.zeros((len(cameras), height, width, 1), np.float32)
    depths = np.zeros((len(cameras), height, width, 1))
    for j, (edge, depth, _, _) in enumerate(found):
        edges[j, :edge.shape[0], :edge.shape[1]] = edge
        depths[j, :depth.shape[0], :depth.shape[1]] = depth
    quality = np.zeros((len(faces), len(cameras)))
    full = np.zeros((len(faces), len(cameras)), bool)
    views = (np.array([c.R for c in cameras]), np.array([c.t for c in cameras]),
             np.array([c.K for c in cameras]), np.array([bool(c.orthographic) for c in cameras]),
             np.array([c.width - 1.0 for c in cameras]),
             np.array([c.height - 1.0 for c in cameras]), edges, depths,
             np.array([per_metre for _, _, per_metre, _ in found]),
             np.array([constant for *_, constant in found]), np.array(_SIGHT_OPTIONS))
    # Blocks of faces taken by the cores as each comes free (a core busy with other work
    # takes fewer).
    for _ in map_in_threads(lambda start: _face_sight(start, start + _FACES_A_TASK, points,
                                                      normals, *views, quality, full),
                            range(0, len(faces), _FACES_A_TASK)):
        pass
    return quality, full


@njit(cache=True, nogil=True)
def _face_sight(start, stop, points, normals, R, t, K, orthographic, last_u, last_v, edge_px,
                behind_all, per_metre, constant, options, quality, full):
    """:func:`face_qualities`' sight tests of faces ``start`` to ``stop`` (exclusive) into
    ``quality`` (m, V) and ``full`` (m, V):
    ``points`` (m, 4, 3) and ``normals`` (m, 3) the :func:`face_samples`; of each view
    ``j``, ``R[j]``, ``t[j]``, ``K[j]``, ``orthographic[j]``, its last pixel centres
    ``last_u[j]``, ``last_v[j]``, its
    :func:`~sfs_ros.core.meshing.colour.sight_maps` ``edge_px[j]`` and ``behind_all[j]``
    (H, W, 1) (the depths those :func:`farthest_around` the z-buffer), ``per_metre[j]`` and
    ``constant[j]``; ``options`` (4,) the sight test's :data:`_SIGHT_OPTIONS`. Views by
    faces a few thousand at a time: the faces' samples stay in the cache while every view
    tests them.

    The glimpse of the centroid first: its narrower ramp off the edges weighs a point
    above zero exactly where the full test does (the ramps start at one margin), so the
    faces it finds are those whose centroid passes the full test, and the others (most,
    on a refined mesh, half of them turned away) need no other point tested."""
    min_cos, power, ramp, tolerance = options[0], options[1], options[2], options[3]
    stop = min(stop, points.shape[0])
    for first in range(start, stop, _FACES_A_PASS):
        for j in range(R.shape[0]):
            Rj, tj, Kj, edge, depth = R[j], t[j], K[j], edge_px[j], behind_all[j]
            for f in range(first, min(first + _FACES_A_PASS, stop)):
                # (scalars, not the tuple of :func:`_point_weight`: most faces end here)
                u, v, z, cos = view_point(Rj, tj, Kj, orthographic[j], points[f, 0, 0],
                                          points[f, 0, 1], points[f, 0, 2], normals[f, 0],
                                          normals[f, 1], normals[f, 2])
                if (u >= 0.0 and u <= last_u[j] and v >= 0.0 and v <= last_v[j]
                        and cos > min_cos
                        and sight_weight(u, v, z, cos, edge, depth, min_cos, power,
                                         GLIMPSE_RAMP_PX, tolerance, per_metre[j],
                                         constant[j])[0] > 0.0):
                    view = (Rj, tj, Kj, orthographic[j], last_u[j], last_v[j], edge, depth,
                            per_metre[j], constant[j], min_cos, power, tolerance)
                    quality[f, j], full[f, j] = _fully(points, normals, f, view, ramp)


@njit(cache=True, nogil=True, inline="always")
def _fully(points, normals, f, view, ramp):
    """The full test of glimpsed face ``f`` (``points`` and ``normals`` as
    :func:`_face_sight`'s) in ``view`` (:func:`_point_weight`'s): ``(quality, full)``."""
    least = _point_weight(points, normals, f, 0, view, ramp)[0]
    w0, u0, v0 = _point_weight(points, normals, f, 1, view, ramp)
    w1, u1, v1 = _point_weight(points, normals, f, 2, view, ramp)
    w2, u2, v2 = _point_weight(points, normals, f, 3, view, ramp)
    least = min(least, w0, w1, w2)
    full = least > 0.0
    weight = least if full else \
        GLIMPSE_WEIGHT * _point_weight(points, normals, f, 0, view, GLIMPSE_RAMP_PX)[0]
    # The corners' projected area, scaled back to the whole face (NaN, so 0, where a
    # corner falls outside the image).
    area = 0.5 * abs((u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)) / _AREA_OF_PULLED
    return (weight * area if np.isfinite(area) else 0.0), full


@njit(cache=True, nogil=True, inline="always")
def _point_weight(points, normals, f, k, view, ramp):
    """The sight test of sample ``k`` of face ``f`` (``points`` and ``normals`` as
    :func:`_face_sight`'s) in
    ``view`` (``R, t, K, orthographic, last_u, last_v, edge_px, behind_all, per_metre,
    constant`` as :func:`_face_sight`'s of one view, then the least cosine, the angle's
    power and the depth tolerance) with ``ramp`` pixels off the edges: ``(weight, u, v)``,
    ``u, v`` pixels (NaN outside the image)."""
    (R, t, K, orthographic, last_u, last_v, edge_px, behind_all, per_metre, constant, min_cos,
     power, tolerance) = view
    u, v, z, cos = view_point(R, t, K, orthographic, points[f, k, 0], points[f, k, 1],
                              points[f, k, 2], normals[f, 0], normals[f, 1], normals[f, 2])
    if not (u >= 0.0 and u <= last_u and v >= 0.0 and v <= last_v):
        return 0.0, np.nan, np.nan
    if not cos > min_cos:
        return 0.0, u, v
    return sight_weight(u, v, z, cos, edge_px, behind_all, min_cos, power, ramp, tolerance,
                        per_metre, constant)[0], u, v


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
    faces = np.ascontiguousarray(faces, np.int64)
    neighbours = np.full((len(faces), 3), -1, np.int64)
    if len(faces):
        _face_neighbours(faces, int(faces.max()) + 1, neighbours)
    return neighbours


@njit(cache=True, nogil=True)
def _face_neighbours(faces, n_vertices, neighbours):
    """:func:`face_neighbours` into ``neighbours`` (m, 3) (all -1): the edges of the faces
    grouped by their lower vertex (:func:`~sfs_ros.core.outline.edges_by_lower_vertex`),
    the two of an edge found in its group."""
    start, edge = edges_by_lower_vertex(faces, n_vertices)
    # Each grouped edge's higher vertex, in the groups' order: the pairs are matched
    # within a group on these alone, read in a row rather than across the faces.
    high = np.empty(edge.size, np.int64)
    for i in range(edge.size):
        f, k = edge[i] // 3, edge[i] % 3
        high[i] = max(faces[f, k], faces[f, (k + 1) % 3])
    for low in range(n_vertices):
        for i in range(start[low], start[low + 1]):
            other, count = -1, 0
            for j in range(start[low], start[low + 1]):
                if high[j] == high[i]:
                    count += 1
                    if j != i:
                        other = edge[j] // 3
            if count == 2:                         # edges of exactly two faces
                neighbours[edge[i] // 3, edge[i] % 3] = other


@njit(cache=True, nogil=True)
def _icm(cost, seen, neighbours, labels, smoothness, max_sweeps):
    """Iterated conditional modes on ``labels`` (m,) in place, over the faces ``seen`` (s,)
    (increasing) whose costs are the rows of ``cost`` (s, V); returns the sweeps made."""
    n_views = cost.shape[1]
    for sweep in range(max_sweeps):
        changed = 0
        for i in range(seen.size):
            f = seen[i]
            best, best_cost = labels[f], np.inf
            for label in range(n_views):
                c = cost[i, label]
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
    quality = np.ascontiguousarray(quality, np.float64)
    labels = np.empty(len(quality), np.int64)
    seen = _best_views(quality, labels)
    # Only the seen faces' costs are made (often a minority of a refined mesh's faces).
    cost = np.empty((len(seen), quality.shape[1]))
    _costs(quality, seen, labels, cost)
    sweeps = (_icm(cost, seen, neighbours, labels, float(smoothness), MAX_SWEEPS)
              if smoothness else 0)
    return labels, sweeps


@njit(cache=True, nogil=True)
def _best_views(quality, labels):
    """Each face's best view (the first of the highest quality in ``quality`` (m, V)) into
    ``labels`` (m,), -1 where no view sees the face; returns the faces seen (s,)."""
    seen = np.empty(quality.shape[0], np.int64)
    n = 0
    for f in range(quality.shape[0]):
        best, label = quality[f, 0], 0
        for j in range(1, quality.shape[1]):
            if quality[f, j] > best:
                best, label = quality[f, j], j
        labels[f] = label if best > 0.0 else -1
        if best > 0.0:
            seen[n] = f
            n += 1
    return seen[:n]


@njit(cache=True, nogil=True)
def _costs(quality, seen, labels, cost):
    """The data costs (module docstring) of the faces ``seen`` (s,) into ``cost`` (s, V)
    (infinite where the view does not see the face), from ``quality`` (m, V) and the best
    views ``labels`` (m,)."""
    for i in range(seen.size):
        f = seen[i]
        best = quality[f, labels[f]]
        for j in range(quality.shape[1]):
            cost[i, j] = 1.0 - quality[f, j] / best if quality[f, j] > 0.0 else np.inf
