"""The silhouette of a closed mesh from its outline edges, without drawing its faces.

A closed, consistently oriented mesh covers a pixel centre when a face turned
towards the camera covers it, and the faces turned towards the camera all wind
the same way round in the image. So the number of them over a point is, up to
its sign, the winding number there of their boundary; and the edges two such
faces share cancel out of it, leaving the *outline* edges, those between a face
turned towards the camera and one turned away. A pixel centre is covered when
the outline winds round it: the crossings of the outline with the centre's row,
left of the centre, do not sum to zero.

That draws a view in time proportional to its outline (a few thousand edges of
a mesh of a million faces), plus one test per face for which way it turns and
one pass over the image, instead of a visit to every face's pixel box. A row
counts the crossings of an edge whose ends lie at heights ``y0 < y1`` for
``y0 <= row < y1``, at the column where it crosses the row, and a centre exactly
on that column lies right of it and is not covered by it; the rasteriser's
tie rule for a centre exactly on an outline edge is another (see
:func:`sfs_ros.core.render.triangle_edges`), so the two can differ there.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .render import FRONT_FACING

__all__ = ["edge_faces", "edges_by_lower_vertex", "outline_cover"]


@njit(cache=True, nogil=True)
def edges_by_lower_vertex(faces, n):
    """The half-edges of ``faces`` (m, 3) int (half-edge ``3 t + k`` runs from corner
    ``k`` of face ``t`` to corner ``k + 1``) grouped by their lower vertex of ``n``, by a
    counting sort: ``(start (n + 1,), grouped (3 m,))`` int32 (3 m < 2^31), the half-edges
    of vertex ``i`` being ``grouped[start[i]:start[i + 1]]``, in the faces' order."""
    m = faces.shape[0]
    start = np.zeros(n + 1, np.int32)
    for t in range(m):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        start[min(a, b) + 1] += 1
        start[min(b, c) + 1] += 1
        start[min(c, a) + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    grouped = np.empty(3 * m, np.int32)
    fill = start[:-1].copy()
    for t in range(m):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        for k, low in enumerate((min(a, b), min(b, c), min(c, a))):
            grouped[fill[low]] = 3 * t + k
            fill[low] += 1
    return start, grouped


@njit(cache=True, nogil=True)
def _pair_half_edges(faces, n):
    """Undirected edges: ``ends`` ``(a, b)``, ``a < b`` vertex indices, and ``sides``
    ``(f_ab, f_ba)``, ``f_ab`` the face whose corner runs from ``a`` to ``b`` and ``f_ba``
    the one that runs back, (3 m / 2, 2) int32 each; and whether every half-edge found
    exactly one running back (a closed, consistently oriented, edge-manifold mesh without
    repeated corners). Half-edges are grouped by their lower vertex (a counting sort),
    then matched within each group."""
    m = faces.shape[0]
    ends = np.empty(((3 * m) // 2, 2), np.int32)
    sides = np.empty(((3 * m) // 2, 2), np.int32)
    if (3 * m) % 2:
        return ends, sides, False
    start, grouped = edges_by_lower_vertex(faces, n)
    count = 0
    for i in range(n):
        for p in range(start[i], start[i + 1]):
            hp = grouped[p]
            if hp < 0:
                continue   # matched already
            tail, head = faces[hp // 3, hp % 3], faces[hp // 3, (hp % 3 + 1) % 3]
            if tail == head:
                return ends, sides, False
            match = -1
            for q in range(p + 1, start[i + 1]):
                hq = grouped[q]
                if hq < 0:
                    continue
                other_tail = faces[hq // 3, hq % 3]
                other_head = faces[hq // 3, (hq % 3 + 1) % 3]
                if max(other_tail, other_head) != max(tail, head):
                    continue
                if match >= 0 or other_tail != head or other_head != tail:
                    return ends, sides, False   # a third use, or the same way round
                match = q
            if match < 0 or count == ends.shape[0]:
                return ends, sides, False       # a boundary edge
            forward, backward = (hp, grouped[match]) if tail < head else (grouped[match], hp)
            ends[count, 0], ends[count, 1] = min(tail, head), max(tail, head)
            sides[count, 0], sides[count, 1] = forward // 3, backward // 3
            grouped[match] = -1
            count += 1
    return ends, sides, count == ends.shape[0]


def edge_faces(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The edges of a closed mesh and the two faces that share each.

    Parameters
    ----------
    faces : (m, 3) int
        Vertex indices.
    n_vertices : int
        Vertices of the mesh.

    Returns
    -------
    (ends, sides) : two (3 m / 2, 2) int32, or None
        Per edge, ``ends = (a, b)``: its vertices, ``a < b``; ``sides = (f_ab,
        f_ba)``: the face that runs from ``a`` to ``b`` and the one that runs
        back. None unless every edge is used by exactly two faces, once each way
        (closed, consistently oriented, no corner repeated in a face).
    """
    ends, sides, closed = _pair_half_edges(np.ascontiguousarray(faces, np.int64),
                                           int(n_vertices))
    return (ends, sides) if closed else None


@njit(cache=True, inline="always")
def outline_cover(uv, faces, ends, sides, width, height, front, crossings, cover):
    """Coverage of a closed mesh at the pixel centres, from its outline.

    ``uv`` (n, 2): the pixels of the vertices, all in front of the camera;
    ``ends``, ``sides``: :func:`edge_faces`. Fills ``cover[row * width +
    col]`` (>= height * width uint8) with 1 where covered, 0 where not, inside the
    returned box ``(r0, r1, c0, c1)`` (inclusive; nothing is covered outside it,
    where ``cover`` is left as it was; ``r0 > r1`` when nothing is covered).
    Scratch: ``front`` (m,) bool; ``crossings`` (>= height * width) int32, zero on entry
    and left zero. Inlined where called.
    """
    for f in range(faces.shape[0]):
        # The sign of the face's area in the image: face_orientation's, all three corners
        # being in front of the camera (but where rounding decides an edge-on face).
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        area = ((uv[b, 0] - uv[a, 0]) * (uv[c, 1] - uv[a, 1])
                - (uv[b, 1] - uv[a, 1]) * (uv[c, 0] - uv[a, 0]))
        front[f] = area * FRONT_FACING > 0.0
    # The outline's crossings counted as its edges are found, in one pass over the edges.
    umin = vmin = np.inf
    umax = vmax = -np.inf
    for e in range(sides.shape[0]):
        forward = front[sides[e, 0]]
        if forward == front[sides[e, 1]]:
            continue   # not on the outline
        a, b = ends[e, 0], ends[e, 1]
        xa, ya, xb, yb = uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1]
        umin, umax = min(umin, xa, xb), max(umax, xa, xb)
        vmin, vmax = min(vmin, ya, yb), max(vmax, ya, yb)
        if ya == yb:
            continue   # crosses no row
        # Run as in the face turned towards the camera: a to b when it is f_ab.
        step = 1 if (yb > ya) == forward else -1
        slope = (xb - xa) / (yb - ya)
        for row in range(max(0, int(np.ceil(max(min(ya, yb), -1.0)))),   # (clamped for int)
                         min(height - 1, int(np.ceil(min(max(ya, yb), float(height)))) - 1) + 1):
            x = min(max(xa + (row - ya) * slope, -1.0), float(width))  # (clamped for int)
            col = max(0, int(np.floor(x)) + 1)   # the first centre right of the crossing
            if col < width:
                crossings[row * width + col] += step
    if umin > umax:
        return 0, -1, 0, -1   # no outline
    # Covered centres lie right of a crossing (col > umin) and left of one (col < umax):
    # the box. A crossing rounded to a column left of it counts from its first column, and
    # those right of it cover nothing; the rows r0..r1 hold every crossing.
    r0 = max(0, int(np.ceil(max(vmin, -1.0))))
    r1 = min(height - 1, int(np.ceil(min(vmax, float(height)))) - 1)
    c0 = max(0, int(np.floor(max(umin, -1.0))) + 1)
    c1 = min(width - 1, int(np.floor(min(umax, float(width)))))
    for row in range(r0, r1 + 1):
        base = row * width
        winding = 0
        for col in range(min(c0, width)):
            winding += crossings[base + col]
            crossings[base + col] = 0
        for col in range(c0, c1 + 1):
            winding += crossings[base + col]
            crossings[base + col] = 0
            cover[base + col] = 1 if winding != 0 else 0
        crossings[base + min(max(c0, c1 + 1), width):base + width] = 0
    if r0 > r1 or c0 > c1:
        return 0, -1, 0, -1
    return r0, r1, c0, c1
