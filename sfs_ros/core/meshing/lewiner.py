"""Lewiner's marching cubes over only the cubes with a corner in a band of voxels.

The volume is given as an occupancy (``+-pad`` off the band) and the values at the band's
voxels; the cubes visited are those with a corner in the band, found from the band's
voxels row by row (a row: the voxels of one ``[i, j]``), so the work is the band's, not the
volume's. The triangulation is Lewiner et al.'s (2003), with the tables scikit-image
ships; the mesh is the one ``skimage.measure.marching_cubes(volume, 0,
allow_degenerate=False, mask=cubes)`` gives with ``cubes`` the mask of those cubes: the
same vertices (float32 as it computes them) and faces in the same order (cubes in C order,
each cube's triangles in table order, a vertex made at its first use, degenerate faces
dropped and their vertices merged the same way). A vertex lying on a grid edge that has a
precomputed crossing is then placed on it.

Corners of a cube ``[i, j, k]`` in Lewiner's numbering, ``(di, dj, dk)``: 0 ``(0, 0, 0)``,
1 ``(0, 0, 1)``, 2 ``(0, 1, 1)``, 3 ``(0, 1, 0)``, 4-7 the same at ``di = 1``.
"""

from __future__ import annotations

import base64
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit
from skimage.measure import _marching_cubes_lewiner_luts as _luts

__all__ = ["band_rows", "march_band"]


def _table(name: str) -> np.ndarray:
    """One of scikit-image's Lewiner tables: int8, its shape."""
    shape, text = getattr(_luts, name)
    return np.frombuffer(base64.decodebytes(text.encode("ascii")), np.int8).reshape(shape)


_NAMES = ("CASES", "TEST3", "TEST4", "TEST6", "TEST7", "TEST10", "TEST12", "TEST13",
          "SUBCONFIG13", "TILING1", "TILING2", "TILING3_1", "TILING3_2", "TILING4_1",
          "TILING4_2", "TILING5", "TILING6_1_1", "TILING6_1_2", "TILING6_2", "TILING7_1",
          "TILING7_2", "TILING7_3", "TILING7_4_1", "TILING7_4_2", "TILING8", "TILING9",
          "TILING10_1_1", "TILING10_1_1_", "TILING10_1_2", "TILING10_2", "TILING10_2_",
          "TILING11", "TILING12_1_1", "TILING12_1_1_", "TILING12_1_2", "TILING12_2",
          "TILING12_2_", "TILING13_1", "TILING13_1_", "TILING13_2", "TILING13_2_",
          "TILING13_3", "TILING13_3_", "TILING13_4", "TILING13_5_1", "TILING13_5_2",
          "TILING14")
(CASES, TEST3, TEST4, TEST6, TEST7, TEST10, TEST12, TEST13, SUBCONFIG13, T1, T2, T3_1, T3_2,
 T4_1, T4_2, T5, T6_1_1, T6_1_2, T6_2, T7_1, T7_2, T7_3, T7_4_1, T7_4_2, T8, T9, T10_1_1,
 T10_1_1_, T10_1_2, T10_2, T10_2_, T11, T12_1_1, T12_1_1_, T12_1_2, T12_2, T12_2_, T13_1,
 T13_1_, T13_2, T13_2_, T13_3, T13_3_, T13_4, T13_5_1, T13_5_2, T14) = range(len(_NAMES))


def _packed_tables() -> tuple[np.ndarray, np.ndarray]:
    """All the tables in one int8 array, and per table (rows in :data:`_NAMES`' order) its
    offset, its stride per configuration and its stride per sub-configuration (0 for a
    table of one tiling per configuration): entry ``n`` of configuration ``c``,
    sub-configuration ``s`` is at ``offset + c * per_config + s * per_sub + n``."""
    tables = [_table(name) for name in _NAMES]
    at = np.zeros((len(tables), 3), np.int64)
    offset = 0
    for row, table in enumerate(tables):
        per_config = int(np.prod(table.shape[1:], dtype=np.int64))
        at[row] = offset, per_config, table.shape[2] if table.ndim == 3 else 0
        offset += table.size
    return np.concatenate([t.ravel() for t in tables]), at


LUT, LUT_AT = _packed_tables()

#: The cases with no ambiguity to test: case -> (table, triangles); -1: a case with tests.
_PLAIN = np.full((15, 2), -1, np.int64)
_PLAIN[[1, 2, 5, 8, 9, 11, 14]] = [[T1, 1], [T2, 2], [T5, 3], [T8, 2], [T9, 4], [T11, 4],
                                   [T14, 4]]
#: Lewiner corner -> its offset (di, dj, dk) in the cube.
_CORNER = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 1], [0, 1, 0],
                    [1, 0, 0], [1, 0, 1], [1, 1, 1], [1, 1, 0]], np.int64)
#: (di, dj, dk) as ``4 di + 2 dj + dk`` -> Lewiner corner.
_CORNER_AT = np.array([0, 1, 3, 2, 4, 5, 7, 6], np.int64)
#: Lewiner edge -> its lower corner, its upper corner (along the edge's axis) and the
#: axis it runs along (0, 1, 2: i, j, k).
_EDGE = np.array([[0, 1, 2], [1, 2, 1], [3, 2, 2], [0, 3, 1],
                  [4, 5, 2], [5, 6, 1], [7, 6, 2], [4, 7, 1],
                  [0, 4, 0], [1, 5, 0], [2, 6, 0], [3, 7, 0]], np.int64)
#: Cube faces for the face test, corners A, B, C, D (Lewiner's faces 1-6).
_FACE = np.array([[0, 4, 5, 1], [1, 5, 6, 2], [2, 6, 7, 3], [3, 7, 4, 0],
                  [0, 3, 2, 1], [4, 7, 6, 5]], np.int64)
#: For the interior test of a case with a reference edge e: the corners whose values
#: give t (``v[a] / (v[a] - v[b])``) and then Bt, Ct, Dt, each interpolated at t from
#: its pair: rows e = 0..11 of (a, b, B0, B1, C0, C1, D0, D1).
_INTERNAL = np.array([[0, 1, 3, 2, 7, 6, 4, 5], [1, 2, 0, 3, 4, 7, 5, 6],
                      [2, 3, 1, 0, 5, 4, 6, 7], [3, 0, 2, 1, 6, 5, 7, 4],
                      [4, 5, 7, 6, 3, 2, 0, 1], [5, 6, 4, 7, 0, 3, 1, 2],
                      [6, 7, 5, 4, 1, 0, 2, 3], [7, 4, 6, 5, 2, 1, 3, 0],
                      [0, 4, 3, 7, 2, 6, 1, 5], [1, 5, 0, 4, 3, 7, 2, 6],
                      [2, 6, 1, 5, 0, 4, 3, 7], [3, 7, 2, 6, 1, 5, 0, 4]], np.int64)
#: Guard of the ambiguity tests and weights, as scikit-image's (double's epsilon).
_EPS = float(np.spacing(1.0))
#: A vertex is on a grid edge when one coordinate is further than this from an integer
#: and the two others nearer (voxels).
_ON_GRID = 1e-4


def band_rows(voxels: np.ndarray, n0: int, n1: int) -> np.ndarray:
    """(n0 * n1 + 1,) int64: where each row ``[i, j]`` of the band's voxels (n, 3), in C
    order, starts in them (row ``i * n1 + j``; the last entry is n)."""
    return _row_starts(np.ascontiguousarray(voxels[:, 0]), np.ascontiguousarray(voxels[:, 1]),
                       n0, n1)


def march_band(crop: np.ndarray, pad: float, voxels: np.ndarray, values: np.ndarray,
               ordinal: np.ndarray | None = None, crossings: np.ndarray | None = None,
               *, margin: float = 0.0, slabs: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lewiner's marching cubes, at level 0, of the volume that is ``values`` (n,) float32 at
    the band's ``voxels`` (n, 3) (C order) and ``pad`` where ``crop`` (3-D bool) is
    occupied, ``-pad`` elsewhere; only the cubes with a corner in the band are visited.

    ``ordinal`` (n, 6) int32 and ``crossings`` (m,) float32 (``marching.crossing_edges``): a vertex
    on a grid edge with a crossing is placed on it, at its fraction of the edge from the
    lower end clipped to ``[margin, 1 - margin]``; None: every vertex where the linear
    interpolation puts it.

    ``slabs``: how many slabs of planes (along the first axis) are marched side by side
    (None: as many as numba has threads, each with at least :data:`SLAB_VOXELS` of the
    band's voxels); the mesh is the same.

    Returns ``(vertices (v, 3) float64, faces (f, 3) int64)``: voxel indices of ``crop``,
    faces as scikit-image's (counter-clockwise seen from where the volume is smaller).
    """
    crop = np.ascontiguousarray(crop, dtype=bool)
    n0, n1, _ = crop.shape
    rows = band_rows(voxels, n0, n1)
    if ordinal is None or crossings is None:
        ordinal = np.full((0, 6), -1, np.int32)
        crossings = np.zeros(0, np.float32)
    band_k = np.ascontiguousarray(voxels[:, 2], dtype=np.int64)
    values = np.ascontiguousarray(values, dtype=np.float32)
    if slabs is None:
        slabs = min(numba.get_num_threads(), len(voxels) // SLAB_VOXELS)
    bounds = _slab_bounds(voxels[:, 0], n0, slabs)

    def slab(s: int) -> tuple:
        return _march_slab(crop, np.float32(pad), rows, band_k, values, ordinal,
                           bounds[s], bounds[s + 1])

    if len(bounds) == 2:
        parts = [slab(0)]
    else:   # the kernels release Python's lock: the slabs run side by side
        with ThreadPoolExecutor(len(bounds) - 1) as pool:
            parts = list(pool.map(slab, range(len(bounds) - 1)))
    return _finish(*_stitched(parts, bounds), crossings, float(margin))


#: Band voxels a slab of planes takes at least before the cubes are cut into slabs
#: marched side by side.
SLAB_VOXELS = 200_000


def _slab_bounds(planes: np.ndarray, n0: int, slabs: int) -> list[int]:
    """The first cube plane of each of at most ``slabs`` slabs and the end (``n0 - 1``),
    each slab holding about as many of the band's voxels (whose i are ``planes``, sorted)."""
    n = len(planes)
    slabs = max(1, min(slabs, n))
    cuts = {int(planes[n * s // slabs]) for s in range(1, slabs)}
    return [0] + sorted(c for c in cuts if 0 < c < n0 - 1) + [n0 - 1]


def _stitched(parts: list[tuple], bounds: list[int]) -> tuple:
    """The slabs' meshes as one, in the order one slab after another would have made it:
    a vertex a slab made on its first plane's edges (its seam key) is the previous slab's
    where that one had made it already (on the top of its last cubes). Returns the
    vertices (v, 3) float32, their crossings (v, 3) and the faces (f, 3)."""
    points, place, faces = [], [], []
    count = 0
    previous = None
    for s, (pts, plc, fcs, slots, start) in enumerate(parts):
        number = np.empty(len(pts), np.int64)
        kept = np.ones(len(pts), bool)
        if previous is not None:
            slots_before, start_before, number_before = previous
            seam = np.flatnonzero(plc[:, 3] >= 0)
            made = slots_before[bounds[s] & 1, plc[seam, 3]]
            again = made >= start_before
            kept[seam[again]] = False
            number[seam[again]] = number_before[made[again]]
        number[kept] = count + np.arange(np.count_nonzero(kept))
        count += np.count_nonzero(kept)
        points.append(pts[kept])
        place.append(plc[kept, :3])
        faces.append(number[fcs])
        previous = slots, start, number
    return np.concatenate(points), np.concatenate(place), np.concatenate(faces)


@njit(cache=True, nogil=True)
def _row_starts(vi, vj, n0, n1):
    """:func:`band_rows` of the voxels' i ``vi`` and j ``vj`` (n,), sorted by row."""
    starts = np.zeros(n0 * n1 + 1, np.int64)
    for n in range(vi.shape[0]):
        starts[vi[n] * n1 + vj[n] + 1] += 1
    for r in range(n0 * n1):
        starts[r + 1] += starts[r]
    return starts


@njit(cache=True, nogil=True)
def _lut(table, config, sub, n):
    """Entry ``n`` of configuration ``config``, sub-configuration ``sub`` of a table."""
    return LUT[LUT_AT[table, 0] + config * LUT_AT[table, 1] + sub * LUT_AT[table, 2] + n]


@njit(cache=True, nogil=True)
def _face_test(v, face):
    """Lewiner's face test: whether the surface joins the face's diagonal of positive
    corners, signed by ``face`` (its number, 1-6, negated to invert)."""
    f = abs(face) - 1
    a, b, c, d = v[_FACE[f, 0]], v[_FACE[f, 1]], v[_FACE[f, 2]], v[_FACE[f, 3]]
    ac_bd = a * c - b * d
    if -_EPS < ac_bd < _EPS:
        return face >= 0
    return face * a * ac_bd >= 0


@njit(cache=True, nogil=True)
def _internal_test(v, case, edge, s):
    """Lewiner's interior test of an ambiguous cube (cases 4, 6, 7, 10, 12, 13): whether
    the surface joins the cube's interior, signed by ``s``; ``edge``: the case's
    reference edge (cases 6, 7, 12, 13)."""
    if case == 4 or case == 10:
        a = (v[4] - v[0]) * (v[6] - v[2]) - (v[7] - v[3]) * (v[5] - v[1])
        b = (v[2] * (v[4] - v[0]) + v[0] * (v[6] - v[2]) - v[1] * (v[7] - v[3])
             - v[3] * (v[5] - v[1]))
        t = -b / (2 * a + _EPS)
        if t < 0 or t > 1:
            return s > 0
        at = v[0] + (v[4] - v[0]) * t
        bt = v[3] + (v[7] - v[3]) * t
        ct = v[2] + (v[6] - v[2]) * t
        dt = v[1] + (v[5] - v[1]) * t
    else:
        r = _INTERNAL[edge]
        t = v[r[0]] / (v[r[0]] - v[r[1]] + _EPS)
        at = 0.0
        bt = v[r[2]] + (v[r[3]] - v[r[2]]) * t
        ct = v[r[4]] + (v[r[5]] - v[r[4]]) * t
        dt = v[r[6]] + (v[r[7]] - v[r[6]]) * t
    test = (at >= 0) + 2 * (bt >= 0) + 4 * (ct >= 0) + 8 * (dt >= 0)
    if test == 5:
        return s > 0 if at * ct - bt * dt < _EPS else False
    if test == 10:
        return s > 0 if at * ct - bt * dt >= _EPS else False
    if test == 7 or test == 11 or test == 13 or test == 14 or test == 15:
        return s < 0
    return s > 0


@njit(cache=True, nogil=True)
def _tiling(v, case, config):
    """Lewiner's choice of triangles for a cube: ``(table, sub-configuration, triangles)``
    (table -1: none)."""
    if _PLAIN[case, 0] >= 0:
        return _PLAIN[case, 0], 0, _PLAIN[case, 1]
    if case == 3:
        if _face_test(v, _lut(TEST3, config, 0, 0)):
            return T3_2, 0, 4
        return T3_1, 0, 2
    if case == 4:
        if _internal_test(v, case, -1, _lut(TEST4, config, 0, 0)):
            return T4_1, 0, 2
        return T4_2, 0, 6
    if case == 6:
        if _face_test(v, _lut(TEST6, config, 0, 0)):
            return T6_2, 0, 5
        if _internal_test(v, case, _lut(TEST6, config, 0, 2),
                          _lut(TEST6, config, 0, 1)):
            return T6_1_1, 0, 3
        return T6_1_2, 0, 9
    if case == 7:
        sub = 0
        for n in range(3):
            if _face_test(v, _lut(TEST7, config, 0, n)):
                sub += 1 << n
        if sub == 0:
            return T7_1, 0, 3
        if sub == 1 or sub == 2 or sub == 4:
            return T7_2, sub >> 1, 5
        if sub == 3 or sub == 5 or sub == 6:
            return T7_3, (sub == 5) + 2 * (sub == 6), 9
        if _internal_test(v, case, _lut(TEST7, config, 0, 4),
                          _lut(TEST7, config, 0, 3)):
            return T7_4_2, 0, 9
        return T7_4_1, 0, 5
    if case == 10 or case == 12:
        test = TEST10 if case == 10 else TEST12
        first = _face_test(v, _lut(test, config, 0, 0))
        second = _face_test(v, _lut(test, config, 0, 1))
        if first and second:
            return (T10_1_1_ if case == 10 else T12_1_1_), 0, 4
        if first:
            return (T10_2 if case == 10 else T12_2), 0, 8
        if second:
            return (T10_2_ if case == 10 else T12_2_), 0, 8
        edge = -1 if case == 10 else _lut(TEST12, config, 0, 3)
        if _internal_test(v, case, edge, _lut(test, config, 0, 2)):
            return (T10_1_1 if case == 10 else T12_1_1), 0, 4
        return (T10_1_2 if case == 10 else T12_1_2), 0, 8
    if case == 13:
        sub = 0
        for n in range(6):
            if _face_test(v, _lut(TEST13, config, 0, n)):
                sub += 1 << n
        sub = _lut(SUBCONFIG13, sub, 0, 0)
        if sub == 0:
            return T13_1, 0, 4
        if sub <= 6:
            return T13_2, sub - 1, 6
        if sub <= 18:
            return T13_3, sub - 7, 10
        if sub <= 22:
            return T13_4, sub - 19, 12
        if sub <= 26:
            sub -= 23
            if _internal_test(v, case, _lut(T13_5_1, config, sub, 0),
                              _lut(TEST13, config, 0, 6)):
                return T13_5_1, sub, 6
            return T13_5_2, sub, 10
        if sub <= 38:
            return T13_3_, sub - 27, 10
        if sub <= 44:
            return T13_2_, sub - 39, 6
        if sub == 45:
            return T13_1_, 0, 4
        return -1, 0, 0
    return -1, 0, 0


@njit(cache=True, nogil=True)
def _grown(a, n):
    """``a`` with room for at least ``n`` rows (doubled), its first rows kept."""
    if n <= a.shape[0]:
        return a
    b = np.empty((max(n, 2 * a.shape[0]),) + a.shape[1:], a.dtype)
    b[:a.shape[0]] = a
    return b


@njit(cache=True, nogil=True)
def _crossing_of(p, i, j, k, shape, bi, ordinal):
    """The crossing (its row of the crossings, else -1) of the grid edge vertex ``p``
    (3,) float32 lies on, if it lies on one (:data:`_ON_GRID`) of the cube ``[i, j, k]``
    whose corners' band rows are ``bi`` (-1: off the band); and the edge's axis and
    lower end along it. (A centre vertex near an edge: the edges' own vertices take the
    shorter way of :func:`_new_vertex`, the same test.)"""
    c0, c1, c2 = np.float64(p[0]), np.float64(p[1]), np.float64(p[2])
    r0, r1, r2 = np.rint(c0), np.rint(c1), np.rint(c2)
    o0, o1, o2 = abs(c0 - r0), abs(c1 - r1), abs(c2 - r2)
    axis = 0
    if o1 > o0:
        axis = 1
    if o2 > (o1 if axis == 1 else o0):
        axis = 2
    middle = max(min(o0, o1), min(max(o0, o1), o2))
    if not ((o0, o1, o2)[axis] > _ON_GRID and middle < _ON_GRID):
        return -1, axis, 0
    lower = (np.floor(c0) if axis == 0 else r0, np.floor(c1) if axis == 1 else r1,
             np.floor(c2) if axis == 2 else r2)
    d = 0
    for a in range(3):
        at = np.int64(lower[a])
        step = at - (i, j, k)[a]
        if at < 0 or at >= shape[a] - 1 or step < 0 or step > 1:
            return -1, axis, 0
        d = 2 * d + step
    return (_edge_crossing(bi, _CORNER_AT[d], _CORNER_AT[d + (4 >> axis)], axis, ordinal),
            axis, np.int64(lower[axis]))


@njit(cache=True, nogil=True)
def _edge_crossing(bi, lo, up, axis, ordinal):
    """The crossing (its row of the crossings, else -1) of the cube's grid edge from
    corner ``lo`` to corner ``up`` along ``axis``, whose corners' band rows are ``bi``
    (-1: off the band): numbered at its lower end, or at its upper end when the lower
    is off the band (``marching.crossing_edges``)."""
    which = ordinal[bi[lo], axis] if bi[lo] >= 0 else -1
    if which < 0 and bi[up] >= 0:
        which = ordinal[bi[up], axis + 3]
    return which


@njit(cache=True, nogil=True)
def _march_slab(crop, pad, rows, band_k, values, ordinal, first, last):
    """:func:`march_band`'s cubes of planes ``first .. last - 1`` from the band's rows
    (:func:`band_rows`) and their voxels' k: the vertices (float32), their crossings and
    seam keys (:func:`_stitched`), the faces, the vertices by slot and the vertices made
    before the last plane."""
    n0, n1, n2 = crop.shape
    points = np.empty((1024, 3), np.float32)
    place = np.empty((1024, 4), np.int64)   # crossing row (or -1), axis, lower end, seam key
    faces = np.empty((1024, 3), np.int64)
    count = 0
    n_faces = 0
    # Vertex of each (grid point, slot) of two i-planes (by parity): slots 0-2 the edges
    # along k, j, i from the point, 3 the centre of the cube at it. A stored vertex is
    # the plane's when made since the previous plane began (older entries are stale).
    slots = np.full((2, n1 * n2 * 4), -1, np.int64)
    start = np.zeros(2, np.int64)      # vertices when the previous plane, this one began
    v = np.empty(8)
    bi = np.empty(8, np.int64)
    ptr = np.empty(4, np.int64)
    end = np.empty(4, np.int64)
    shape = np.array([n0, n1, n2], np.int64)
    for i in range(first, last):
        start[0], start[1] = start[1], count
        for j in range(n1 - 1):
            if not _corner_rows(rows, i, j, n1, ptr, end):
                continue
            k = -1
            while True:
                k = _next_cube(band_k, ptr, end, k, n2)
                if k < 0:
                    break
                index = _corners(crop, pad, values, band_k, ptr, end, i, j, k, v, bi)
                case, config = _lut(CASES, index, 0, 0), _lut(CASES, index, 0, 1)
                if case <= 0:
                    continue
                table, sub, nt = _tiling(v, case, config)
                if count + 3 * nt > points.shape[0]:
                    points, place = _grown(points, count + 3 * nt), _grown(place, count + 3 * nt)
                if n_faces + nt > faces.shape[0]:
                    faces = _grown(faces, n_faces + nt)
                for t in range(nt):
                    for e in range(3):
                        edge = _lut(table, config, sub, 3 * t + e)
                        layer, key, di = _slot(edge, i, j, k, n2)
                        made = slots[layer, key]
                        if made < start[di]:
                            made = count
                            _new_vertex(edge, i, j, k, v, bi, shape, ordinal, points[made],
                                        place[made])
                            place[made, 3] = key if i == first and di == 0 else -1
                            slots[layer, key] = made
                            count += 1
                        faces[n_faces, 2 - e] = made    # scikit-image reverses each face
                    n_faces += 1
    return points[:count], place[:count], faces[:n_faces], slots, start[1]


@njit(cache=True, nogil=True)
def _slot(edge, i, j, k, n2):
    """Where the vertex on Lewiner edge ``edge`` (12: the centre) of cube ``[i, j, k]`` is
    kept: ``(plane parity, key in the plane, whether the plane is the next one)``."""
    if edge == 12:
        return i & 1, (j * n2 + k) * 4 + 3, 0
    lo = _EDGE[edge, 0]
    di = _CORNER[lo, 0]
    key = ((j + _CORNER[lo, 1]) * n2 + k + _CORNER[lo, 2]) * 4 + 2 - _EDGE[edge, 2]
    return (i + di) & 1, key, di


@njit(cache=True, nogil=True)
def _new_vertex(edge, i, j, k, v, bi, shape, ordinal, point, place):
    """Into ``point`` (3,) float32 the new vertex on Lewiner edge ``edge`` (12: the centre)
    of cube ``[i, j, k]``, into ``place`` (3,) its crossing (:func:`_crossing_of`)."""
    if edge == 12:
        _centre(v, i, j, k, point)
    else:
        _on_edge(v, edge, i, j, k, point)
    place[0], place[1], place[2] = -1, 0, 0
    if ordinal.shape[0] == 0:
        return
    if edge == 12:
        place[0], place[1], place[2] = _crossing_of(point, i, j, k, shape, bi, ordinal)
        return
    # On its own edge, unless the interpolation put it within _ON_GRID of an end.
    lo, up, axis = _EDGE[edge, 0], _EDGE[edge, 1], _EDGE[edge, 2]
    at = np.float64(point[axis])
    if not abs(at - np.rint(at)) > _ON_GRID:
        return
    if (i + _CORNER[lo, 0] >= shape[0] - 1 or j + _CORNER[lo, 1] >= shape[1] - 1
            or k + _CORNER[lo, 2] >= shape[2] - 1):
        return
    place[0], place[1], place[2] = (_edge_crossing(bi, lo, up, axis, ordinal), axis,
                                    (i, j, k)[axis] + _CORNER[lo, axis])


@njit(cache=True, nogil=True)
def _corner_rows(rows, i, j, n1, ptr, end):
    """Set ``ptr``, ``end`` to the band's voxels of the four rows holding the corners of
    the cubes of row ``[i, j]``: (i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1); whether
    any has one."""
    any_voxel = False
    for s in range(4):
        r = (i + (s >> 1)) * n1 + j + (s & 1)
        ptr[s], end[s] = rows[r], rows[r + 1]
        any_voxel |= ptr[s] < end[s]
    return any_voxel


@njit(cache=True, nogil=True)
def _next_cube(band_k, ptr, end, k, n2):
    """The first cube after ``k`` along the row with a corner in the band (a band voxel at
    its k or k + 1), -1 if none; moves ``ptr`` to the rows' first voxels from it."""
    nxt = n2
    for s in range(4):
        while ptr[s] < end[s] and band_k[ptr[s]] < k + 1:
            ptr[s] += 1
        if ptr[s] < end[s]:
            nxt = min(nxt, max(band_k[ptr[s]] - 1, k + 1))
    return nxt if nxt <= n2 - 2 else -1


@njit(cache=True, nogil=True)
def _corners(crop, pad, values, band_k, ptr, end, i, j, k, v, bi):
    """Into ``v`` (8,) and ``bi`` (8,), by Lewiner corner of cube ``[i, j, k]``: the
    volume's value and the corner's row in the band (-1 off it); returns the cube's
    case index (bit c: corner c is inside, its value above 0)."""
    index = 0
    for s in range(4):
        di, dj = s >> 1, s & 1
        for dk in range(2):
            c = _CORNER_AT[4 * di + 2 * dj + dk]
            p = ptr[s]
            if dk == 1 and p < end[s] and band_k[p] == k:
                p += 1
            if p < end[s] and band_k[p] == k + dk:
                bi[c] = p
                v[c] = np.float64(values[p])
            else:
                bi[c] = -1
                v[c] = np.float64(pad) if crop[i + di, j + dj, k + dk] else -np.float64(pad)
            if v[c] > 0.0:
                index += 1 << c
    return index


@njit(cache=True, nogil=True)
def _on_edge(v, edge, i, j, k, out):
    """Into ``out`` (3,) float32: the vertex on Lewiner edge ``edge`` of cube ``[i, j, k]``,
    where scikit-image interpolates it (each end weighted by the inverse of its value)."""
    lo, up, axis = _EDGE[edge, 0], _EDGE[edge, 1], _EDGE[edge, 2]
    w_lo = 1.0 / (_EPS + abs(v[lo]))
    w_up = 1.0 / (_EPS + abs(v[up]))
    out[0] = np.float32(i + _CORNER[lo, 0])
    out[1] = np.float32(j + _CORNER[lo, 1])
    out[2] = np.float32(k + _CORNER[lo, 2])
    out[axis] = np.float32(np.float64(out[axis]) + w_up / (w_lo + w_up))


@njit(cache=True, nogil=True)
def _centre(v, i, j, k, out):
    """Into ``out`` (3,) float32: the vertex at the centre of cube ``[i, j, k]`` (Lewiner's
    edge 12), the corners weighted by the inverse of their values."""
    w0, w1, w2, w3 = (1.0 / (_EPS + abs(v[0])), 1.0 / (_EPS + abs(v[1])),
                      1.0 / (_EPS + abs(v[2])), 1.0 / (_EPS + abs(v[3])))
    w4, w5, w6, w7 = (1.0 / (_EPS + abs(v[4])), 1.0 / (_EPS + abs(v[5])),
                      1.0 / (_EPS + abs(v[6])), 1.0 / (_EPS + abs(v[7])))
    total = ((((((w0 + w1) + w2) + w3) + w4) + w5) + w6) + w7
    out[0] = np.float32(i + (((w4 + w5) + w6) + w7) / total)
    out[1] = np.float32(j + (((w2 + w3) + w6) + w7) / total)
    out[2] = np.float32(k + (((w1 + w2) + w5) + w6) / total)


@njit(cache=True, nogil=True)
def _finish(points, place, faces, crossings, margin):
    """Drop the faces with two vertices at the same point, merging those vertices into the
    first (as scikit-image's ``remove_degenerate_faces``), then place the kept vertices
    with a crossing on it: ``(vertices (v, 3) float64, faces (f, 3) int64)``."""
    n = points.shape[0]
    merged = np.arange(n)
    kept_face = np.ones(faces.shape[0], np.bool_)
    for f in range(faces.shape[0]):
        for a, b in ((0, 1), (0, 2), (1, 2)):
            p, q = faces[f, a], faces[f, b]
            if (points[p, 0] == points[q, 0] and points[p, 1] == points[q, 1]
                    and points[p, 2] == points[q, 2]):
                m = min(merged[p], merged[q])
                merged[p] = m
                merged[q] = m
                kept_face[f] = False
    renumber = np.empty(n, np.int64)
    kept = 0
    for p in range(n):
        if merged[p] == p:
            kept += 1
        renumber[p] = kept - 1
    vertices = np.empty((kept, 3))
    for p in range(n):
        if merged[p] == p:
            row = renumber[p]
            for a in range(3):
                vertices[row, a] = np.float64(points[p, a])
            which = place[p, 0]
            if which >= 0:
                fraction = min(max(np.float64(crossings[which]), margin), 1.0 - margin)
                vertices[row, place[p, 1]] = place[p, 2] + fraction
    out = np.empty((kept_face.sum(), 3), np.int64)
    row = 0
    for f in range(faces.shape[0]):
        if kept_face[f]:
            for a in range(3):
                out[row, a] = renumber[merged[faces[f, a]]]
            row += 1
    return vertices, out
