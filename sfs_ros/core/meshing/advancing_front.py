"""Advancing-front triangulation of a cloud of points (paper, section 4.2).

The paper's algorithm, after Hoppe and Oblonsek:

1. Seed triangle at the highest point A (largest Z). The plane through A
   orthogonal to Z is tilted until it touches two more points: if points of the
   neighbourhood already lie in that plane, the two closest are taken; otherwise
   the tilted plane is the face of the neighbourhood's convex hull at A with the
   smallest tilt. Of the two normals of the seed triangle, the one forming the
   smaller angle with +Z is chosen (when normals are given, the one agreeing
   with them; both coincide for outward normals at the highest point).
2. Its edges AB, BC, CA are the active front. For an active edge, the
   k-neighbours of its ends are projected to the approximate tangent plane
   (normal = mean of the two point normals), split by the edge into LEFT (the
   side of the existing triangle) and RIGHT. Among the points on the RIGHT, the
   one seeing the edge under the largest angle APB with no other point inside
   the new triangle becomes its third vertex. The edge becomes inactive; new
   edges that are not already on the front become active (zero, one or two).
3. Stop when no active edge is left; then swap edges to the Delaunay
   (max-min-angle) diagonal in the local tangent plane.

Robustness rules added to the paper's description (standard for such fronts):
a new face may not put a third face on an edge, disagree with the point
normals, fold back onto its neighbour, overlap the faces already around its
vertices, or cross a front edge; a 3-edge front loop is closed directly; edges
left without a vertex are retried with looser normal limits; remaining front
loops are filled by ear clipping in their mean tangent plane (a loop that
cannot be filled has the faces at its vertices removed and is tried again). A new component
is seeded at the highest point whose neighbours are all unused.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import ConvexHull, QhullError, cKDTree

from .edge_swap import swap_edges

__all__ = ["AdvancingFrontResult", "advancing_front", "estimate_normals"]

#: Strict / relaxed lower bound on (face normal . point normal) for a new face.
_MIN_DOT = (0.2, -0.2)
#: Strict / relaxed lower bound on (new face normal . normal of the face across the edge).
_FOLD_DOT = (-0.5, -0.9)


# ---- numba kernel ------------------------------------------------------------
# The main loop of the advancing front, compiled with numba.
#
# Mesh state, all per vertex with fixed capacity:
#
# * ``nbr[v, s]``: the ``s``-th vertex joined to ``v`` by an edge, ``deg[v]`` of them;
#   ``eout[v, s]`` / ``ein[v, s]`` count faces using the edge as ``v -> w`` / ``w -> v``.
#   Faces are counter-clockwise seen from outside, so a *front* edge is a directed
#   edge ``a -> b`` used by exactly one face (``eout == 1``, ``ein == 0``); the face
#   still to be built on it is ``(b, a, p)``, on its RIGHT seen from outside.
# * ``bcnt[v]``: edges at ``v`` used by one face (``v`` is on the front when > 0).
# * ``vf[v, :nvf[v]]``: faces using ``v``.

#: Most edges / faces one vertex may carry; candidates that would exceed it are rejected.
_CAPACITY = 40

_TWO_PI = 2.0 * np.pi
_ANGLE_EPS = 1e-7


@njit(cache=True)
def _slot(nbr, deg, v, w):
    for s in range(deg[v]):
        if nbr[v, s] == w:
            return s
    return -1


@njit(cache=True)
def _link(nbr, eout, ein, deg, v, w):
    s = _slot(nbr, deg, v, w)
    if s >= 0:
        return s
    s = deg[v]
    nbr[v, s] = w
    eout[v, s] = 0
    ein[v, s] = 0
    deg[v] += 1
    return s


@njit(cache=True)
def _is_front(nbr, eout, ein, deg, a, b):
    """True when ``a -> b`` is used by one face and ``b -> a`` by none."""
    s = _slot(nbr, deg, a, b)
    return s >= 0 and eout[a, s] == 1 and ein[a, s] == 0


@njit(cache=True)
def _add_face(a, b, c, nbr, eout, ein, deg, bcnt, vf, nvf, faces, nfaces):
    """Store face ``(a, b, c)`` and update the edge counts."""
    for e in range(3):
        if e == 0:
            u, v = a, b
        elif e == 1:
            u, v = b, c
        else:
            u, v = c, a
        su = _link(nbr, eout, ein, deg, u, v)
        sv = _link(nbr, eout, ein, deg, v, u)
        before = eout[u, su] + ein[u, su]
        eout[u, su] += 1
        ein[v, sv] += 1
        if before == 0:
            bcnt[u] += 1
            bcnt[v] += 1
        elif before == 1:
            bcnt[u] -= 1
            bcnt[v] -= 1
    f = nfaces[0]
    faces[f, 0] = a
    faces[f, 1] = b
    faces[f, 2] = c
    nfaces[0] = f + 1
    vf[a, nvf[a]] = f
    nvf[a] += 1
    vf[b, nvf[b]] = f
    nvf[b] += 1
    vf[c, nvf[c]] = f
    nvf[c] += 1


@njit(cache=True)
def _unit_normal(P, a, b, c):
    ux = P[b, 0] - P[a, 0]
    uy = P[b, 1] - P[a, 1]
    uz = P[b, 2] - P[a, 2]
    vx = P[c, 0] - P[a, 0]
    vy = P[c, 1] - P[a, 1]
    vz = P[c, 2] - P[a, 2]
    nx = uy * vz - uz * vy
    ny = uz * vx - ux * vz
    nz = ux * vy - uy * vx
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    if norm == 0.0:
        return 0.0, 0.0, 0.0
    return nx / norm, ny / norm, nz / norm


@njit(cache=True)
def _has_room(deg, nvf, v):
    return deg[v] <= _CAPACITY - 2 and nvf[v] <= _CAPACITY - 1


@njit(cache=True)
def _cross2(ax, ay, bx, by, cx, cy):
    """Twice the signed area of the 2-D triangle (a, b, c)."""
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(cache=True)
def _segments_cross(ax, ay, bx, by, cx, cy, dx, dy, eps):
    """Proper crossing of segments ab and cd (touching does not count)."""
    d1 = _cross2(ax, ay, bx, by, cx, cy)
    d2 = _cross2(ax, ay, bx, by, dx, dy)
    d3 = _cross2(cx, cy, dx, dy, ax, ay)
    d4 = _cross2(cx, cy, dx, dy, bx, by)
    return ((d1 > eps and d2 < -eps) or (d1 < -eps and d2 > eps)) and \
        ((d3 > eps and d4 < -eps) or (d3 < -eps and d4 > eps))


@njit(cache=True)
def _inside(px, py, ax, ay, bx, by, cx, cy, eps):
    """Strictly inside the counter-clockwise 2-D triangle (a, b, c)."""
    return (_cross2(ax, ay, bx, by, px, py) > eps and _cross2(bx, by, cx, cy, px, py) > eps
            and _cross2(cx, cy, ax, ay, px, py) > eps)


@njit(cache=True)
def _project(P, frame, v):
    """Coordinates of point v in the tangent frame (origin vertex, e1, e2)."""
    o, e1, e2 = frame
    rx = P[v, 0] - P[o, 0]
    ry = P[v, 1] - P[o, 1]
    rz = P[v, 2] - P[o, 2]
    return (rx * e1[0] + ry * e1[1] + rz * e1[2], rx * e2[0] + ry * e2[1] + rz * e2[2])


@njit(cache=True)
def _arc(P, frame, v, y, z):
    """Start angle and width of the counter-clockwise corner of face (v, y, z) at v, in the frame."""
    vx, vy = _project(P, frame, v)
    yx, yy = _project(P, frame, y)
    zx, zy = _project(P, frame, z)
    start = np.arctan2(yy - vy, yx - vx)
    width = (np.arctan2(zy - vy, zx - vx) - start) % _TWO_PI
    return start, width


@njit(cache=True)
def _corner_overlaps(P, frame, faces, vf, nvf, v, y, z):
    """True if the new corner (v, y, z) overlaps the corner of an existing face at v."""
    s1, w1 = _arc(P, frame, v, y, z)
    for i in range(nvf[v]):
        f = vf[v, i]
        if faces[f, 0] == v:
            fy, fz = faces[f, 1], faces[f, 2]
        elif faces[f, 1] == v:
            fy, fz = faces[f, 2], faces[f, 0]
        else:
            fy, fz = faces[f, 0], faces[f, 1]
        s2, w2 = _arc(P, frame, v, fy, fz)
        if (s2 - s1) % _TWO_PI < w1 - _ANGLE_EPS or (s1 - s2) % _TWO_PI < w2 - _ANGLE_EPS:
            return True
    return False


@njit(cache=True)
def _face_across(faces, vf, nvf, a, b):
    """The face using directed edge a -> b, or -1."""
    for i in range(nvf[a]):
        f = vf[a, i]
        for e in range(3):
            if faces[f, e] == a and faces[f, (e + 1) % 3] == b:
                return f
    return -1


@njit(cache=True)
def _valid(a, b, p, ip, frame, ncand, cand, cx, cy, L, n, P, N, nbr, eout, ein, deg, bcnt,
           vf, nvf, faces, min_dot, fold_dot):
    """All robustness rules for the new face (b, a, p)."""
    # Edges: a -> p and p -> b may exist only as front edges p -> a and b -> p.
    s = _slot(nbr, deg, a, p)
    if s >= 0 and not (eout[a, s] == 0 and ein[a, s] == 1):
        return False
    s = _slot(nbr, deg, p, b)
    if s >= 0 and not (eout[p, s] == 0 and ein[p, s] == 1):
        return False
    if not (_has_room(deg, nvf, a) and _has_room(deg, nvf, b) and _has_room(deg, nvf, p)):
        return False
    # Orientation: the face must agree with the point normals and not fold onto its neighbour.
    fx, fy, fz = _unit_normal(P, b, a, p)
    for v in (a, b, p):
        if fx * N[v, 0] + fy * N[v, 1] + fz * N[v, 2] < min_dot:
            return False
    f0 = _face_across(faces, vf, nvf, a, b)
    if f0 >= 0:
        gx, gy, gz = _unit_normal(P, faces[f0, 0], faces[f0, 1], faces[f0, 2])
        if fx * gx + fy * gy + fz * gz < fold_dot:
            return False
    px = cx[ip]
    py = cy[ip]
    eps = 1e-12 * L * L
    # Empty triangle: no candidate on the same side of the surface inside (a, p, b) in the plane.
    for j in range(ncand):
        c = cand[j]
        if j == ip or c == p:
            continue
        if N[c, 0] * n[0] + N[c, 1] * n[1] + N[c, 2] * n[2] <= 0.0:
            continue
        if _inside(cx[j], cy[j], 0.0, 0.0, px, py, L, 0.0, eps):
            return False
    # No overlap with the faces already at a, b and p (corners in the tangent plane).
    if _corner_overlaps(P, frame, faces, vf, nvf, a, p, b):
        return False
    if _corner_overlaps(P, frame, faces, vf, nvf, b, a, p):
        return False
    if deg[p] > 0 and _corner_overlaps(P, frame, faces, vf, nvf, p, b, a):
        return False
    # No crossing of the front edges near the candidates.
    for j in range(ncand):
        c = cand[j]
        if bcnt[c] == 0:
            continue
        for s in range(deg[c]):
            if eout[c, s] + ein[c, s] != 1:
                continue
            w = nbr[c, s]
            wx, wy = _project(P, frame, w)
            if w != a and w != b and w != p and \
                    N[w, 0] * n[0] + N[w, 1] * n[1] + N[w, 2] * n[2] > 0.0 and \
                    _inside(wx, wy, 0.0, 0.0, px, py, L, 0.0, eps):
                return False
            if c != a and c != p and w != a and w != p and \
                    _segments_cross(0.0, 0.0, px, py, cx[j], cy[j], wx, wy, eps):
                return False
            if c != b and c != p and w != b and w != p and \
                    _segments_cross(L, 0.0, px, py, cx[j], cy[j], wx, wy, eps):
                return False
    return True


@njit(cache=True)
def _close_triangle(a, b, nbr, eout, ein, deg, faces, vf, nvf):
    """A front vertex c closing a 3-edge front loop a -> b -> c -> a, or -1.

    The loop made by the three edges of a single face (a lone seed) is not a hole.
    """
    f0 = _face_across(faces, vf, nvf, a, b)
    for s in range(deg[b]):
        c = nbr[b, s]
        if c == a or not (eout[b, s] == 1 and ein[b, s] == 0):
            continue
        if f0 >= 0 and (faces[f0, 0] == c or faces[f0, 1] == c or faces[f0, 2] == c):
            continue
        if _is_front(nbr, eout, ein, deg, c, a):
            return c
    return -1


@njit(cache=True)
def _best_vertex(a, b, P, N, knn, nbr, eout, ein, deg, bcnt, vf, nvf, faces,
                 mark, stamp, cand, cx, cy, score, min_dot, fold_dot):
    """The vertex p of the new face (b, a, p) on front edge a -> b, or -1."""
    nx = N[a, 0] + N[b, 0]
    ny = N[a, 1] + N[b, 1]
    nz = N[a, 2] + N[b, 2]
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    if norm < 1e-9:
        return -1
    n = np.array((nx / norm, ny / norm, nz / norm))
    d = P[b] - P[a]
    d = d - np.dot(d, n) * n
    L = np.sqrt(np.dot(d, d))
    if L == 0.0:
        return -1
    e1 = d / L
    e2 = np.cross(n, e1)
    frame = (a, e1, e2)
    # Candidates: the k-neighbours of a and b, plus the vertices joined to them along the front.
    ncand = 0
    mark[a] = stamp
    mark[b] = stamp
    k = knn.shape[1]
    for src in range(2 * k + 2 * _CAPACITY):
        if src < 2 * k:
            v = knn[a, src] if src < k else knn[b, src - k]
        else:
            j = src - 2 * k
            u = a if j < _CAPACITY else b
            j = j % _CAPACITY
            if j >= deg[u] or eout[u, j] + ein[u, j] != 1:
                continue
            v = nbr[u, j]
        if v < 0 or mark[v] == stamp:
            continue
        mark[v] = stamp
        cand[ncand] = v
        cx[ncand], cy[ncand] = _project(P, frame, v)
        ncand += 1
    # Score: cosine of the angle a-p-b (smaller = larger angle) for points on the RIGHT side.
    for j in range(ncand):
        v = cand[j]
        score[j] = np.inf
        if cy[j] >= -1e-9 * L:
            continue
        if deg[v] > 0 and bcnt[v] == 0:
            continue  # interior vertex: its fan is closed
        if N[v, 0] * n[0] + N[v, 1] * n[1] + N[v, 2] * n[2] < min_dot:
            continue
        ax = -cx[j]
        ay = -cy[j]
        bx = L - cx[j]
        by = -cy[j]
        score[j] = (ax * bx + ay * by) / np.sqrt((ax * ax + ay * ay) * (bx * bx + by * by))
    while True:
        best = -1
        best_score = np.inf
        for j in range(ncand):
            if score[j] < best_score:
                best_score = score[j]
                best = j
        if best < 0:
            return -1
        p = cand[best]
        if _valid(a, b, p, best, frame, ncand, cand, cx, cy, L, n, P, N, nbr, eout, ein, deg,
                  bcnt, vf, nvf, faces, min_dot, fold_dot):
            return p
        score[best] = np.inf


@njit(cache=True)
def _grow(P, N, knn, nbr, eout, ein, deg, bcnt, vf, nvf, faces, nfaces, queue, qhead, qtail,
         failed, nfailed, mark, stamp, min_dot, fold_dot):
    """Advance the front from the edges in ``queue[qhead:qtail]`` (circular) until it is empty.

    Edges without a valid new vertex go to ``failed``. Returns the number of faces added
    and the updated stamp.
    """
    qsize = queue.shape[0]
    k = knn.shape[1]
    m = 2 * k + 2 * _CAPACITY
    cand = np.empty(m, dtype=np.int64)
    cx = np.empty(m)
    cy = np.empty(m)
    score = np.empty(m)
    added = 0
    while qhead[0] != qtail[0]:
        a = queue[qhead[0], 0]
        b = queue[qhead[0], 1]
        qhead[0] = (qhead[0] + 1) % qsize
        if not _is_front(nbr, eout, ein, deg, a, b):
            continue
        if nfaces[0] >= faces.shape[0]:
            failed[nfailed[0], 0] = a
            failed[nfailed[0], 1] = b
            nfailed[0] += 1
            continue
        p = _close_triangle(a, b, nbr, eout, ein, deg, faces, vf, nvf)
        if p < 0:
            stamp += 1
            p = _best_vertex(a, b, P, N, knn, nbr, eout, ein, deg, bcnt, vf, nvf, faces,
                             mark, stamp, cand, cx, cy, score, min_dot, fold_dot)
        if p < 0:
            failed[nfailed[0], 0] = a
            failed[nfailed[0], 1] = b
            nfailed[0] += 1
            continue
        _add_face(b, a, p, nbr, eout, ein, deg, bcnt, vf, nvf, faces, nfaces)
        added += 1
        for u, v in ((a, p), (p, b)):
            if _is_front(nbr, eout, ein, deg, u, v):
                queue[qtail[0], 0] = u
                queue[qtail[0], 1] = v
                qtail[0] = (qtail[0] + 1) % qsize
    return added, stamp


@dataclass(frozen=True, eq=False)
class AdvancingFrontResult:
    """Faces of the advancing-front mesh and what happened on the way.

    Attributes
    ----------
    faces : (m, 3) int64
        Vertex indices into the input points, counter-clockwise seen from outside.
    normals : (n, 3) float64
        The unit outward point normals used (given or estimated).
    stats : dict
        ``n_points``, ``n_points_used``, ``n_faces``, ``n_seeds`` (components started),
        ``n_seed_attempts``, ``n_relaxed_faces`` (added with looser normal limits),
        ``n_hole_faces`` (added by ear clipping), ``n_faces_removed`` (grown faces
        removed around loops ear clipping could not fill, to retry a larger hole),
        ``n_holes_filled``, ``n_holes_left`` (front loops that stayed open),
        ``n_front_edges_left`` (edges used by one face at the end),
        ``n_nonmanifold_edges`` (used by more than two faces, 0 by
        construction), ``n_nonmanifold_vertices`` (vertices whose faces form more than one
        fan), ``n_swaps``, ``closed`` (every edge used by exactly two faces).
    """

    faces: np.ndarray
    normals: np.ndarray
    stats: dict = field(default_factory=dict)


@njit(cache=True)
def _orient_along_tree(normals, order, predecessors):
    for i in order[1:]:
        p = predecessors[i]
        dot = normals[i, 0] * normals[p, 0] + normals[i, 1] * normals[p, 1] + normals[i, 2] * normals[p, 2]
        if dot < 0.0:
            normals[i] = -normals[i]


def estimate_normals(points, knn: np.ndarray) -> np.ndarray:
    """Unit normals by local PCA, oriented consistently (Hoppe's spanning tree).

    Parameters
    ----------
    points : (n, 3) float64
        Points, metres.
    knn : (n, k) int64
        Indices of the k nearest neighbours of each point (itself excluded).

    Returns
    -------
    (n, 3) float64
        Unit normals; the highest point's normal points up (+Z) and the rest follow
        it along the minimum spanning tree of the neighbour graph weighted by
        ``1 - |n_i . n_j|``. For a closed surface they point outward.
    """
    P = np.asarray(points, dtype=np.float64)
    nb = P[knn] - P[knn].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    normals = np.linalg.eigh(cov)[1][:, :, 0]
    rows = np.repeat(np.arange(len(P)), knn.shape[1])
    weight = 1.0 + 1e-6 - np.abs(np.einsum("ij,ij->i", normals[rows], normals[knn.ravel()]))
    graph = coo_matrix((weight, (rows, knn.ravel())), shape=(len(P), len(P))).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T))
    top = int(np.argmax(P[:, 2]))
    if normals[top, 2] < 0:
        normals[top] = -normals[top]
    order, predecessors = breadth_first_order(tree, top, directed=False)
    _orient_along_tree(normals, order, predecessors)
    # Other connected components: orient each from its own highest point.
    seen = np.zeros(len(P), dtype=bool)
    seen[order] = True
    while not seen.all():
        rest = np.flatnonzero(~seen)
        start = int(rest[np.argmax(P[rest, 2])])
        if normals[start, 2] < 0:
            normals[start] = -normals[start]
        order, predecessors = breadth_first_order(tree, start, directed=False)
        _orient_along_tree(normals, order, predecessors)
        seen[order] = True
    return normals


def _seed_triangle(P, N, knn, candidates):
    """Seed (a, b, c), counter-clockwise from outside, at the highest candidate point, or None."""
    a = int(candidates[np.argmax(P[candidates, 2])])
    nb = knn[a]
    spacing = np.linalg.norm(P[nb] - P[a], axis=1)
    level = np.abs(P[nb, 2] - P[a, 2]) <= 1e-9 * max(float(spacing.max()), 1e-300)
    pair = None
    if level.sum() >= 2:
        # Points in the horizontal plane already: the two closest (not on one line with A).
        flat = nb[level][np.argsort(spacing[level], kind="stable")]
        b = int(flat[0])
        for c in flat[1:]:
            cross = np.cross(P[b] - P[a], P[c] - P[a])
            if np.linalg.norm(cross) > 1e-3 * np.linalg.norm(P[b] - P[a]) * np.linalg.norm(P[c] - P[a]):
                pair = (b, int(c))
                break
    if pair is None:
        # Tilt the plane: the convex hull face at A with the smallest tilt from horizontal.
        local = np.concatenate(([a], nb))
        try:
            hull = ConvexHull(P[local])
        except QhullError:
            return a, None
        at_a = np.any(hull.simplices == 0, axis=1)
        if not np.any(at_a):
            return a, None
        best = np.flatnonzero(at_a)[np.argmax(hull.equations[at_a, 2])]
        b, c = (int(local[v]) for v in hull.simplices[best] if v != 0)
        pair = (b, c)
    b, c = pair
    normal = np.cross(P[b] - P[a], P[c] - P[a])
    if np.dot(normal, N[a] + N[b] + N[c]) < 0:
        b, c = c, b
    return a, (b, c)


def _defects(faces, n_points):
    """Edges used by one face, edges used by more than two, vertices with several fans."""
    if len(faces) == 0:
        return 0, 0, 0
    m = len(faces)
    half = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.min(half, axis=1) * n_points + np.max(half, axis=1)
    _, edge, counts = np.unique(key, return_inverse=True, return_counts=True)
    # Corners (vertex, face) are nodes; two corners at a vertex are joined when their
    # faces share an edge at that vertex. A manifold vertex has one group of corners.
    corner = np.arange(3 * m).reshape(3, m).T  # corner id of faces[f, i]
    start = np.concatenate([corner[:, 0], corner[:, 1], corner[:, 2]])
    end = np.concatenate([corner[:, 1], corner[:, 2], corner[:, 0]])
    pairs = np.flatnonzero(counts[edge] == 2)
    order = pairs[np.argsort(edge[pairs], kind="stable")]
    first, second = order[0::2], order[1::2]
    # Half-edges u->w (first) and w->u (second): start of one meets end of the other.
    rows = np.concatenate([start[first], end[first]])
    cols = np.concatenate([end[second], start[second]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * m, 3 * m))
    _, label = connected_components(graph, directed=False)
    vertex = faces.T.ravel()
    groups = np.unique(np.stack([vertex, label[np.arange(3 * m)]], axis=1), axis=0)[:, 0]
    fans = np.bincount(groups, minlength=n_points)
    return int(np.sum(counts == 1)), int(np.sum(counts > 2)), int(np.sum(fans > 1))


def _fill_holes(P, N, faces):
    """Ear-clip every front loop in its mean tangent plane.

    Returns the new faces, the number of loops filled and the vertex lists of the
    loops that could not be filled.
    """
    if len(faces) == 0:
        return np.empty((0, 3), np.int64), 0, []
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.min(directed, axis=1) * len(P) + np.max(directed, axis=1)
    uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    boundary = directed[counts[inverse] == 1]
    if len(boundary) == 0:
        return np.empty((0, 3), np.int64), 0, []
    edges = {(int(u), int(v)) for u, v in zip(*np.divmod(uniq, len(P)))}
    succ: dict[int, list[int]] = {}
    for u, v in boundary:
        succ.setdefault(int(u), []).append(int(v))
    new_faces = []
    filled = 0
    failed = []
    while succ:
        start = next(iter(succ))
        loop = [start]
        v = start
        while v in succ:
            nxt = succ[v].pop()
            if not succ[v]:
                del succ[v]
            if nxt == start:
                break
            loop.append(nxt)
            v = nxt
        tris = _ear_clip(P, N, loop[::-1], edges) if nxt == start else None
        if tris is None:
            failed.append(loop)
            continue
        filled += 1
        for t in tris:
            new_faces.append(t)
            for i in range(3):
                u, w = t[i], t[(i + 1) % 3]
                edges.add((min(u, w), max(u, w)))
    return np.array(new_faces, dtype=np.int64).reshape(-1, 3), filled, failed


def _close_holes(P, N, faces, rounds: int = 3):
    """Fill front loops; around a loop that cannot be filled, remove the faces at its
    vertices and try the larger hole again (``rounds`` times).

    Returns faces, loops filled, loops left, faces removed.
    """
    filled = removed = 0
    for attempt in range(rounds + 1):
        new, n_filled, failed = _fill_holes(P, N, faces)
        faces = np.concatenate([faces, new])
        filled += n_filled
        if not failed or attempt == rounds:
            break
        bad = np.unique(np.concatenate([np.asarray(loop) for loop in failed]))
        keep = ~np.any(np.isin(faces, bad), axis=1)
        removed += int(np.sum(~keep))
        faces = faces[keep]
    return faces, filled, len(failed), removed


def _ear_clip(P, N, poly, edges):
    """Triangulate a counter-clockwise (seen from outside) polygon of vertex ids, or None."""
    poly = list(poly)
    normal = N[poly].sum(axis=0)
    if np.linalg.norm(normal) < 1e-9:
        return None
    normal /= np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.5:
        e1 = np.cross(normal, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    xy = {v: (float(P[v] @ e1), float(P[v] @ e2)) for v in poly}
    tris = []
    while len(poly) > 3:
        best, best_quality = None, -np.inf
        m = len(poly)
        for i in range(m):
            u, v, w = poly[i - 1], poly[i], poly[(i + 1) % m]
            if len({u, v, w}) < 3 or (min(u, w), max(u, w)) in edges:
                continue
            (ux, uy), (vx, vy), (wx, wy) = xy[u], xy[v], xy[w]
            area = (vx - ux) * (wy - uy) - (vy - uy) * (wx - ux)
            if area <= 0:
                continue
            if any(_in_triangle(xy[q], xy[u], xy[v], xy[w]) for q in poly if q not in (u, v, w)):
                continue
            quality = _min_angle(P[u], P[v], P[w])
            if quality > best_quality:
                best, best_quality = i, quality
        if best is None:
            return None
        m = len(poly)
        u, v, w = poly[best - 1], poly[best], poly[(best + 1) % m]
        tris.append((u, v, w))
        edges = edges | {(min(u, w), max(u, w))}
        del poly[best]
    if len(set(poly)) < 3:
        return None
    tris.append(tuple(poly))
    return tris


def _in_triangle(q, a, b, c):
    def side(p0, p1, p2):
        return (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p1[1] - p0[1]) * (p2[0] - p0[0])
    return side(a, b, q) > 0 and side(b, c, q) > 0 and side(c, a, q) > 0


def _min_angle(a, b, c):
    angles = []
    for p, q, r in ((a, b, c), (b, c, a), (c, a, b)):
        u, v = q - p, r - p
        angles.append(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v)))
    return min(angles)


class _Front:
    """Mesh and front state shared with the numba kernel."""

    def __init__(self, P, N, knn):
        n = len(P)
        cap = _CAPACITY
        self.P, self.N, self.knn = P, N, knn
        self.nbr = np.full((n, cap), -1, dtype=np.int64)
        self.eout = np.zeros((n, cap), dtype=np.int8)
        self.ein = np.zeros((n, cap), dtype=np.int8)
        self.deg = np.zeros(n, dtype=np.int64)
        self.bcnt = np.zeros(n, dtype=np.int64)
        self.vf = np.full((n, cap), -1, dtype=np.int64)
        self.nvf = np.zeros(n, dtype=np.int64)
        self.faces = np.empty((2 * n + 64, 3), dtype=np.int64)
        self.nfaces = np.zeros(1, dtype=np.int64)
        self.queue = np.empty((6 * n + 64, 2), dtype=np.int64)
        self.qhead = np.zeros(1, dtype=np.int64)
        self.qtail = np.zeros(1, dtype=np.int64)
        self.failed = np.empty_like(self.queue)
        self.nfailed = np.zeros(1, dtype=np.int64)
        self.mark = np.zeros(n, dtype=np.int64)
        self.stamp = 0

    def add_seed(self, a, b, c):
        _add_face(a, b, c, self.nbr, self.eout, self.ein, self.deg, self.bcnt, self.vf,
                    self.nvf, self.faces, self.nfaces)
        self.push(np.array([[a, b], [b, c], [c, a]], dtype=np.int64))

    def push(self, edges):
        size = len(self.queue)
        for u, v in edges:
            self.queue[self.qtail[0]] = (u, v)
            self.qtail[0] = (self.qtail[0] + 1) % size

    def grow(self, relaxed: bool) -> int:
        added, self.stamp = _grow(
            self.P, self.N, self.knn, self.nbr, self.eout, self.ein, self.deg, self.bcnt,
            self.vf, self.nvf, self.faces, self.nfaces, self.queue, self.qhead, self.qtail,
            self.failed, self.nfailed, self.mark, self.stamp,
            _MIN_DOT[int(relaxed)], _FOLD_DOT[int(relaxed)])
        return int(added)

    def requeue_failed(self) -> int:
        edges = self.failed[:self.nfailed[0]].copy()
        self.nfailed[0] = 0
        self.push(edges)
        return len(edges)


def _points_and_neighbours(points, k, swap_passes, max_seeds) -> tuple[np.ndarray, np.ndarray]:
    """The points (n, 3) float64, checked with :func:`advancing_front`'s options, and
    each one's ``k`` nearest neighbours (n, k) int64, itself left out."""
    P = np.ascontiguousarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), got shape {P.shape}")
    if len(P) < 4:
        raise ValueError(f"need at least 4 points, got {len(P)}")
    if not np.all(np.isfinite(P)):
        raise ValueError("points must be finite")
    k = int(k)
    if not 3 <= k < len(P):
        raise ValueError(f"k must be in 3..{len(P) - 1} (number of points - 1), got {k}")
    if int(swap_passes) < 0 or int(max_seeds) < 1:
        raise ValueError(f"swap_passes must be >= 0 and max_seeds >= 1, got {swap_passes}, {max_seeds}")
    dist, knn = cKDTree(P).query(P, k=k + 1)
    if np.any(dist[:, 1] == 0.0):
        raise ValueError("points contain duplicates; remove them first")
    # Drop each point itself (the first hit, distance 0) from its neighbour list.
    return P, np.ascontiguousarray(knn[:, 1:], dtype=np.int64)


def _unit_normals(P: np.ndarray, normals, knn: np.ndarray) -> np.ndarray:
    """(n, 3) unit outward normals: ``normals`` checked and normalised, or estimated."""
    if normals is None:
        N = estimate_normals(P, knn)
    else:
        N = np.array(normals, dtype=np.float64)
        if N.shape != P.shape:
            raise ValueError(f"normals must be (n, 3) like points {P.shape}, got {N.shape}")
        length = np.linalg.norm(N, axis=1, keepdims=True)
        if not np.all(np.isfinite(N)) or np.any(length == 0):
            raise ValueError("normals must be finite and non-zero")
        N = N / length
    return np.ascontiguousarray(N)


def advancing_front(points, normals=None, *, k: int = 20, swap_passes: int = 10,
                    max_seeds: int = 100) -> AdvancingFrontResult:
    """Triangulate a cloud of surface points by the paper's advancing front.

    Parameters
    ----------
    points : (n, 3) float64
        Points on a surface, metres; n >= 4, no duplicates.
    normals : (n, 3) float64 or None
        Outward normals (need not be unit). None: estimated by local PCA and oriented
        from the highest point, whose normal is taken as +Z (see ``estimate_normals``).
    k : int
        Neighbours per point searched for the next vertex (3 <= k < n).
    swap_passes : int
        Most sweeps of the edge-swap clean-up (0 disables it).
    max_seeds : int
        Most seed triangles (connected components) started.

    Returns
    -------
    AdvancingFrontResult
        Faces counter-clockwise seen from outside (along the normals), and statistics.
        Points the front passes without using stay unreferenced (``n_points_used``).
    """
    P, knn = _points_and_neighbours(points, k, swap_passes, max_seeds)
    N = _unit_normals(P, normals, knn)
    front = _Front(P, N, knn)
    n_seeds = n_seed_attempts = n_relaxed = 0
    tried = np.zeros(len(P), dtype=bool)
    while n_seeds < max_seeds:
        free = (front.deg == 0) & ~tried
        # Seeds only where the whole neighbourhood is unused (a new component).
        candidates = np.flatnonzero(free & np.all(front.deg[knn] == 0, axis=1))
        if len(candidates) == 0:
            break
        n_seed_attempts += 1
        a, pair = _seed_triangle(P, N, knn, candidates)
        tried[a] = True
        if pair is None:
            continue
        n_seeds += 1
        front.add_seed(a, *pair)
        for relaxed in (False, True):
            # Retry failed edges while the front still moves, strict first, then relaxed.
            while True:
                added = front.grow(relaxed)
                n_relaxed += added if relaxed else 0
                if front.nfailed[0] == 0 or added == 0:
                    break
                front.requeue_failed()
            front.requeue_failed()
        front.qhead[0] = front.qtail[0]

    grown = front.faces[:front.nfaces[0]].copy()
    faces, holes_filled, holes_left, n_removed = _close_holes(P, N, grown)
    faces, n_swaps = swap_edges(P, N, faces, max_passes=int(swap_passes))

    n_open, n_over, n_pinched = _defects(faces, len(P))
    return AdvancingFrontResult(faces=faces, normals=N, stats={
        "n_points": len(P),
        "n_points_used": int(len(np.unique(faces))),
        "n_faces": len(faces),
        "n_seeds": n_seeds,
        "n_seed_attempts": n_seed_attempts,
        "n_relaxed_faces": n_relaxed,
        "n_hole_faces": len(faces) - len(grown) + n_removed,
        "n_faces_removed": n_removed,
        "n_holes_filled": holes_filled,
        "n_holes_left": holes_left,
        "n_front_edges_left": n_open,
        "n_nonmanifold_edges": n_over,
        "n_nonmanifold_vertices": n_pinched,
        "n_swaps": n_swaps,
        "closed": bool(len(faces) > 0 and n_open == 0 and n_over == 0),
    })

