"""Topology and geometry checks of a triangle mesh, without modifying it.

Everything is computed from the arrays as given (no vertex merging, no
re-orientation): two vertices at the same position are two vertices.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numba import njit

from ..outline import edge_faces
from ..union_find import join, set_count, settle

__all__ = ["MeshReport", "check_mesh"]

#: A face is degenerate when twice its area is below this times the squared
#: extent of the mesh (or when it repeats a vertex index).
DEGENERATE_REL_AREA = 1e-12


@dataclass(frozen=True)
class MeshReport:
    """What :func:`check_mesh` found.

    Attributes
    ----------
    n_vertices, n_faces : int
        Array sizes (unreferenced vertices included in ``n_vertices``).
    watertight : bool
        Every undirected edge belongs to exactly two faces.
    edge_manifold : bool
        No undirected edge belongs to more than two faces.
    vertex_manifold : bool
        Edge-manifold, and the faces around every referenced vertex form a
        single fan (a closed disc or an open fan), so no two sheets touch at
        a vertex.
    consistently_oriented : bool
        Edge-manifold, and no directed edge is used twice: each interior edge
        is traversed once in each direction by its two faces.
    outward : bool or None
        Signed volume > 0; None unless the mesh is watertight and
        consistently oriented.
    n_boundary_loops : int
        Connected pieces of the boundary (edges used by one face), i.e. holes.
    n_components : int
        Connected pieces of the mesh (faces linked through shared vertices).
    euler_characteristic : int
        V - E + F, with V counting referenced vertices only.
    genus : int or None
        Total genus ``(2 * n_components - euler_characteristic) / 2``; None
        unless the mesh is watertight, vertex-manifold and consistently
        oriented (a closed orientable surface).
    volume_m3 : float
        Signed enclosed volume (divergence theorem), cubic metres; meaningful
        only for closed meshes.
    area_m2 : float
        Total surface area, square metres.
    degenerate_faces : int
        Faces with a repeated vertex index or (relatively) zero area.
    duplicate_faces : int
        Faces whose vertex set repeats an earlier face (any order/orientation).
    """

    n_vertices: int
    n_faces: int
    watertight: bool
    edge_manifold: bool
    vertex_manifold: bool
    consistently_oriented: bool
    outward: bool | None
    n_boundary_loops: int
    n_components: int
    euler_characteristic: int
    genus: int | None
    volume_m3: float
    area_m2: float
    degenerate_faces: int
    duplicate_faces: int

    def as_dict(self) -> dict:
        """JSON-ready dict (Python bool/int/float/None values)."""
        return asdict(self)


def check_mesh(vertices, faces, *, edges=None) -> MeshReport:
    """Check a triangle mesh's topology and measure it.

    Parameters
    ----------
    vertices : (n, 3) float64
        Positions, metres.
    faces : (m, 3) int
        Vertex indices, m >= 1; counter-clockwise seen from outside is
        reported as ``outward``.
    edges : optional
        :func:`~sfs_ros.core.outline.edge_faces` of these faces and vertices, when made
        already (it is made here otherwise): a mesh it pairs every edge of is closed,
        consistently oriented and edge-manifold, and is checked from those pairs.

    Returns
    -------
    MeshReport
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must be an (n, 3) array, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices must be finite")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ValueError(f"faces must be an (m, 3) array with m >= 1, got shape {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must hold integer vertex indices, got dtype {f.dtype}")
    f = np.ascontiguousarray(f, dtype=np.int64)
    n, m = len(v), len(f)
    if f.min() < 0 or f.max() >= n:
        raise ValueError(f"face indices must lie in [0, {n}), got [{f.min()}, {f.max()}]")

    paired = edge_faces(f, n) if edges is None else edges
    referenced = _referenced(f, n)
    topology = _open_topology(f, n, referenced) if paired is None else \
        _closed_topology(f, n, referenced, *paired)
    watertight, edge_manifold, consistently_oriented, vertex_manifold, n_edges, \
        n_components, n_boundary_loops, duplicates = topology
    euler = int(np.count_nonzero(referenced)) - n_edges + m

    double_area, six_volume = _face_measures(v, f)
    area = 0.5 * float(double_area.sum())
    volume = float(six_volume.sum()) / 6.0
    extent = _referenced_extent(v, referenced)
    degenerate = _count_degenerate(f, double_area, DEGENERATE_REL_AREA * extent * extent)

    closed = watertight and consistently_oriented
    genus = None
    if closed and vertex_manifold:
        genus = (2 * n_components - euler) // 2
    return MeshReport(
        n_vertices=n,
        n_faces=m,
        watertight=watertight,
        edge_manifold=edge_manifold,
        vertex_manifold=bool(vertex_manifold),
        consistently_oriented=bool(consistently_oriented),
        outward=bool(volume > 0) if closed else None,
        n_boundary_loops=int(n_boundary_loops),
        n_components=int(n_components),
        euler_characteristic=int(euler),
        genus=None if genus is None else int(genus),
        volume_m3=volume,
        area_m2=area,
        degenerate_faces=int(degenerate),
        duplicate_faces=int(duplicates),
    )


def _open_topology(f: np.ndarray, n: int, referenced: np.ndarray) -> tuple:
    """:func:`check_mesh`'s topology of any mesh, from its half-edges sorted by edge:
    ``(watertight, edge_manifold, consistently_oriented, vertex_manifold, n_edges,
    n_components, n_boundary_loops, duplicate faces)``; ``referenced``: :func:`_referenced`."""
    # Half-edges: face t, corner k goes from f[t, k] to f[t, (k + 1) % 3].
    start = f.reshape(-1)
    end = f[:, [1, 2, 0]].reshape(-1)
    order, edge_of_sorted, counts, opposite, lo, hi = _sorted_half_edges(start, end, n)
    watertight = bool(np.all(counts == 2))
    edge_manifold = bool(np.all(counts <= 2))
    # On an edge-manifold mesh, consecutive sorted half-edges of the same edge are the two
    # uses of an interior edge: they must start at different ends (``opposite``).
    pair = edge_of_sorted[1:] == edge_of_sorted[:-1]
    consistently_oriented = edge_manifold and opposite
    vertex_manifold = edge_manifold and _count_fans(start, end, order, pair) == \
        np.count_nonzero(referenced)
    n_components = _count_roots(_roots(n, start, end), referenced)
    n_boundary_loops = 0
    if not watertight:
        boundary = counts[edge_of_sorted] == 1
        n_boundary_loops = _count_loops(lo[order][boundary], hi[order][boundary], n)
    return (watertight, edge_manifold, consistently_oriented, vertex_manifold, len(counts),
            n_components, n_boundary_loops, _count_duplicate_faces(f, n))


def _closed_topology(f: np.ndarray, n: int, referenced: np.ndarray, ends: np.ndarray,
                     sides: np.ndarray) -> tuple:
    """:func:`_open_topology` of a mesh whose every edge :func:`~sfs_ros.core.outline.
    edge_faces` paired (``ends``, ``sides``): closed, consistently oriented and
    edge-manifold; its fans, pieces and duplicate faces from those pairs."""
    fans, duplicates = _closed_fans_and_duplicates(f, ends, sides)
    vertex_manifold = fans == np.count_nonzero(referenced)
    n_components = _count_roots(_roots(n, ends[:, 0], ends[:, 1]), referenced)
    return True, True, True, vertex_manifold, len(ends), n_components, 0, duplicates


@njit(cache=True, nogil=True)
def _referenced(f, n):
    """(n,) bool: which of the ``n`` vertices the faces ``f`` (m, 3) use."""
    seen = np.zeros(n, np.bool_)
    for t in range(f.shape[0]):
        for k in range(3):
            seen[f[t, k]] = True
    return seen


@njit(cache=True, nogil=True)
def _closed_fans_and_duplicates(f, ends, sides):
    """The fans (:func:`_count_fans`) and duplicate faces (:func:`_count_duplicate_faces`)
    of a closed mesh, from its paired edges.

    Fans: each corner ``3 t + k`` is followed, round its vertex ``a``, by the corner at
    ``a`` of the face across the edge that leaves ``a`` in face ``t``; the fans are the
    cycles of that order. Duplicates: every edge is used by two faces, so a face can
    repeat the vertices of one other face only, the face across each of its three edges;
    such a pair is found at its three edges, as faces whose third vertices are the same.
    (Corners numbered in int32: 3 m < 2^31.)
    """
    following = np.empty(3 * f.shape[0], np.int32)
    same_third = 0
    for e in range(ends.shape[0]):
        a = ends[e, 0]
        forward, backward = sides[e, 0], sides[e, 1]   # a to b, b to a
        p0, p1, p2 = f[forward, 0], f[forward, 1], f[forward, 2]
        q0, q1, q2 = f[backward, 0], f[backward, 1], f[backward, 2]
        i = 0 if p0 == a else (1 if p1 == a else 2)     # a at corner i of forward, b at i + 1
        j = 2 if q0 == a else (0 if q1 == a else 1)     # b at corner j of backward, a at j + 1
        following[3 * forward + i] = 3 * backward + (j + 1) % 3            # round a
        following[3 * backward + j] = 3 * forward + (i + 1) % 3            # round b
        if p0 + p1 + p2 == q0 + q1 + q2:
            same_third += 1
    fans = 0
    for corner in range(following.size):
        if following[corner] < 0:
            continue   # on a fan counted already
        fans += 1
        x = corner
        while following[x] >= 0:
            after = following[x]
            following[x] = -1
            x = after
    return fans, same_third // 3


@njit(cache=True, nogil=True)
def _referenced_extent(v, referenced):
    """The largest side, metres, of the box around the vertices ``v`` (n, 3) that the faces
    use (``referenced``, (n,) bool)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(v.shape[0]):
        if referenced[i]:
            for axis in range(3):
                lo[axis] = min(lo[axis], v[i, axis])
                hi[axis] = max(hi[axis], v[i, axis])
    return max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])


@njit(cache=True, nogil=True)
def _count_degenerate(f, double_area, least):
    """Faces with a repeated vertex index or twice their area at most ``least``."""
    count = 0
    for t in range(f.shape[0]):
        a, b, c = f[t, 0], f[t, 1], f[t, 2]
        if a == b or b == c or c == a or double_area[t] <= least:
            count += 1
    return count


@njit(cache=True, nogil=True)
def _sorted_half_edges(start, end, n):
    """The half-edges ``start[h] -> end[h]`` in the order of their undirected edge (lower
    vertex, then higher; ties in index order: a stable argsort of ``lo * n + hi``), by a
    counting sort on the lower vertex and an insertion sort of each vertex's few.

    Returns ``order`` (h,), the edge number of each sorted half-edge (h,), the number of
    half-edges of each edge (e,), whether every two consecutive sorted half-edges of one edge start
    at different vertices, and ``lo``, ``hi`` (h,): each half-edge's lower and higher
    vertex (all int64 but the flag)."""
    h = start.size
    lo = np.empty(h, np.int64)
    hi = np.empty(h, np.int64)
    bucket = np.zeros(n + 1, np.int64)
    for i in range(h):
        a, b = start[i], end[i]
        if a > b:
            a, b = b, a
        lo[i], hi[i] = a, b
        bucket[a + 1] += 1
    for v in range(n):
        bucket[v + 1] += bucket[v]
    order = np.empty(h, np.int64)
    upper = np.empty(h, np.int64)   # hi of the sorted half-edges (read in order, not scattered)
    fill = bucket[:-1].copy()
    for i in range(h):
        p = fill[lo[i]]
        order[p], upper[p] = i, hi[i]
        fill[lo[i]] += 1
    for v in range(n):
        for j in range(bucket[v] + 1, bucket[v + 1]):
            x, key = order[j], upper[j]
            k = j - 1
            while k >= bucket[v] and upper[k] > key:
                order[k + 1], upper[k + 1] = order[k], upper[k]
                k -= 1
            order[k + 1], upper[k + 1] = x, key
    edge_of_sorted = np.empty(h, np.int64)
    opposite = True
    e = -1
    for v in range(n):
        for p in range(bucket[v], bucket[v + 1]):
            if p == bucket[v] or upper[p] != upper[p - 1]:
                e += 1
            elif start[order[p]] == start[order[p - 1]]:
                opposite = False
            edge_of_sorted[p] = e
    counts = np.zeros(e + 1, np.int64)
    for p in range(h):
        counts[edge_of_sorted[p]] += 1
    return order, edge_of_sorted, counts, opposite, lo, hi


@njit(cache=True, nogil=True)
def _count_fans(start, end, order, pair):
    """Connected pieces of the graph of corners (``3 t + k``: face t, slot k) in which
    consecutive sorted half-edges of one undirected edge (``pair[p]``: the half-edges
    ``order[p]`` and ``order[p + 1]``) link their corners at the lower vertex, and those
    at the higher vertex (union-find)."""
    parent = np.arange(start.size)
    for p in range(pair.size):
        if pair[p]:
            low_a, high_a = _corners(start, end, order[p])
            low_b, high_b = _corners(start, end, order[p + 1])
            join(parent, low_a, low_b)
            join(parent, high_a, high_b)
    return set_count(parent)


@njit(cache=True, nogil=True, inline="always")
def _corners(start, end, h):
    """The corners at the lower and at the higher vertex of half-edge ``h = 3 t + k``,
    which runs from corner ``h`` to corner ``3 t + (k + 1) % 3``."""
    other = h - h % 3 + (h % 3 + 1) % 3
    return (h, other) if start[h] < end[h] else (other, h)


def _count_loops(lo, hi, n) -> int:
    """Connected pieces of the graph of boundary edges ``(lo[i], hi[i])``."""
    if len(lo) == 0:
        return 0
    on_boundary = np.zeros(n, bool)
    on_boundary[lo] = on_boundary[hi] = True
    return _count_roots(_roots(n, lo, hi), on_boundary)


@njit(cache=True, nogil=True)
def _roots(n, a, b):
    """(n,) int64: a representative node of each node's connected component, in the
    undirected graph of ``n`` nodes and edges ``(a[i], b[i])`` (union-find)."""
    parent = np.arange(n)
    for i in range(a.shape[0]):
        join(parent, a[i], b[i])
    settle(parent)
    return parent


@njit(cache=True, nogil=True)
def _count_roots(roots, among) -> int:
    """Connected components among the nodes where ``among`` ((n,) bool) holds, given
    :func:`_roots`."""
    seen = np.zeros(roots.size, np.bool_)
    count = 0
    for x in range(roots.size):
        if among[x] and not seen[roots[x]]:
            seen[roots[x]] = True
            count += 1
    return count


@njit(cache=True, nogil=True)
def _face_measures(v, f):
    """Per face t: twice its area, ``|(p1 - p0) x (p2 - p0)|``, and six times the signed
    volume of the tetrahedron (origin, p0, p1, p2), ``p0 . ((p1 - p0) x (p2 - p0))``
    (= ``p0 . (p1 x p2)``), metres; (m,) float64 each."""
    double_area = np.empty(f.shape[0])
    six_volume = np.empty(f.shape[0])
    for t in range(f.shape[0]):
        a, b, c = f[t, 0], f[t, 1], f[t, 2]
        e0, e1, e2 = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        g0, g1, g2 = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        x = e1 * g2 - e2 * g1
        y = e2 * g0 - e0 * g2
        z = e0 * g1 - e1 * g0
        double_area[t] = np.sqrt(x * x + y * y + z * z)
        six_volume[t] = v[a, 0] * x + v[a, 1] * y + v[a, 2] * z
    return double_area, six_volume


@njit(cache=True, nogil=True)
def _count_duplicate_faces(f, n) -> int:
    """Faces with the same three vertex indices as an earlier face (in any order): the
    faces grouped by their smallest index (a counting sort), each group sorted by the
    other two."""
    m = f.shape[0]
    low = np.empty(m, np.int64)
    rest = np.empty(m, np.int64)   # the other two indices, sorted, as one key
    for t in range(m):
        a, b, c = f[t, 0], f[t, 1], f[t, 2]
        if a > b:
            a, b = b, a
        if b > c:
            b, c = c, b
        if a > b:
            a, b = b, a
        low[t] = a
        rest[t] = b * n + c
    start = np.zeros(n + 1, np.int64)
    for t in range(m):
        start[low[t] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    grouped = np.empty(m, np.int64)
    fill = start[:-1].copy()
    for t in range(m):
        grouped[fill[low[t]]] = rest[t]
        fill[low[t]] += 1
    duplicates = 0
    for i in range(n):
        # Insertion sort of the group in place: a vertex's faces are a handful.
        for j in range(start[i] + 1, start[i + 1]):
            key = grouped[j]
            k = j - 1
            while k >= start[i] and grouped[k] > key:
                grouped[k + 1] = grouped[k]
                k -= 1
            grouped[k + 1] = key
        for j in range(start[i] + 1, start[i + 1]):
            if grouped[j] == grouped[j - 1]:
                duplicates += 1
    return duplicates
