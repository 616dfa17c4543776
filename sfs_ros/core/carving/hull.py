"""Clean-up of a carved visual hull."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..union_find import join, settle

__all__ = ["column_runs", "drop_specks", "occupied_bounds", "surface_voxels"]


def drop_specks(occupancy: np.ndarray, *, min_fraction: float = 0.01) -> tuple[np.ndarray, int]:
    """Remove connected parts smaller than ``min_fraction`` of the largest.

    A visual hull can hold small phantom pieces where the viewing cones of a
    few views happen to overlap away from the object; a real second object on
    the turntable is large and is kept. Voxels are connected through faces,
    edges and corners (26 neighbours).

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
    min_fraction : float
        Parts with fewer voxels than this fraction of the largest part go.

    Returns
    -------
    (nx, ny, nz) bool, int
        The cleaned occupancy and the number of parts removed.
    """
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction must be in [0, 1], got {min_fraction}")
    occ = np.ascontiguousarray(occupancy, dtype=bool)
    if occ.ndim != 3:
        raise ValueError(f"occupancy must be an (nx, ny, nz) array, got shape {occ.shape}")
    column_start, run_lo, run_hi = column_runs(occ)
    part = _run_parts(column_start, run_lo, run_hi, occ.shape[1])
    sizes = np.bincount(part, weights=run_hi - run_lo + 1).astype(np.int64)
    n = np.count_nonzero(sizes)
    if n <= 1:
        return occupancy, 0
    drop = sizes < min_fraction * sizes.max()
    drop[sizes == 0] = False  # (not a part's representative)
    if not drop.any():
        return occupancy, 0
    cleaned = occ.copy()
    _clear_runs(cleaned, column_start, run_lo, run_hi, drop[part])
    return cleaned, int(np.count_nonzero(drop))


def occupied_bounds(occ: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Half-open index box ``[lo, hi)`` (two (3,) int64) around the occupied voxels of a
    3-D bool ``occ``; None if there is none."""
    column = occ.any(axis=2)
    xs = np.flatnonzero(column.any(axis=1))
    if xs.size == 0:
        return None
    ys = np.flatnonzero(column.any(axis=0))
    x0, x1, y0, y1 = xs[0], xs[-1] + 1, ys[0], ys[-1] + 1
    zs = np.flatnonzero(occ[x0:x1, y0:y1].any(axis=(0, 1)))
    lo = np.array([x0, y0, zs[0]], dtype=np.int64)
    hi = np.array([x1, y1, zs[-1] + 1], dtype=np.int64)
    return lo, hi


def surface_voxels(occupancy: np.ndarray) -> np.ndarray:
    """(n, 3) int64 indices, in C order, of the occupied voxels of a 3-D bool
    ``occupancy`` with an empty 6-neighbour (beyond the array counts as empty, so occupied
    voxels on its border are surface voxels). Within the occupied box, in compiled passes
    over its x-planes: a count, then the indices."""
    occ = np.ascontiguousarray(occupancy, dtype=bool)
    box = occupied_bounds(occ)
    if box is None:
        return np.zeros((0, 3), np.int64)
    lo, hi = box
    counts = np.zeros(int(hi[0] - lo[0]) + 1, np.int64)
    _surface_pass(occ, lo, hi, counts, np.zeros((0, 3), np.int64))
    np.cumsum(counts, out=counts)    # counts[i + 1] - counts[i]: the voxels of plane i
    out = np.empty((counts[-1], 3), np.int64)
    _surface_pass(occ, lo, hi, counts, out)
    return out


@njit(parallel=True, cache=True, nogil=True)
def _surface_pass(occ, lo, hi, counts, out):
    """With an empty ``out``: ``counts[1 + p]`` = the surface voxels of x-plane ``lo[0] +
    p``. Else (``counts`` their running sum from 0): their indices into ``out`` from row
    ``counts[p]``, in C order."""
    nx, ny, nz = occ.shape
    fill = out.shape[0] > 0
    for p in prange(hi[0] - lo[0]):
        i = lo[0] + p
        row = counts[p] if fill else 0
        for j in range(lo[1], hi[1]):
            for k in range(lo[2], hi[2]):
                if not occ[i, j, k]:
                    continue
                if (i > 0 and occ[i - 1, j, k] and i < nx - 1 and occ[i + 1, j, k]
                        and j > 0 and occ[i, j - 1, k] and j < ny - 1 and occ[i, j + 1, k]
                        and k > 0 and occ[i, j, k - 1] and k < nz - 1 and occ[i, j, k + 1]):
                    continue
                if fill:
                    out[row, 0], out[row, 1], out[row, 2] = i, j, k
                row += 1
        if not fill:
            counts[1 + p] = row


def column_runs(occ: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The occupied runs along z of every (i, j) column of a C-ordered 3-D bool ``occ``:
    column ``c = i * ny + j`` holds runs ``column_start[c]:column_start[c + 1]``, run r
    covering ``z = run_lo[r] .. run_hi[r]`` (inclusive), in increasing z; all three
    int64. In compiled passes over the x-planes: a count, then the runs."""
    nx, ny, _ = occ.shape
    column_start = np.zeros(nx * ny + 1, np.int64)
    _run_counts(occ, column_start)
    np.cumsum(column_start, out=column_start)
    run_lo = np.empty(column_start[-1], np.int64)
    run_hi = np.empty(column_start[-1], np.int64)
    if len(run_lo):
        _run_ends(occ, column_start, run_lo, run_hi)
    return column_start, run_lo, run_hi


@njit(parallel=True, cache=True, nogil=True)
def _run_counts(occ, column_start):
    """``column_start[c + 1]`` = the runs of column c (c = i * ny + j): its voxels occupied
    after an empty one (or first), counted without a branch a voxel."""
    nx, ny, nz = occ.shape
    if nz == 0:
        return          # (no voxel: no run; ``column_start`` stays 0)
    for i in prange(nx):
        for j in range(ny):
            column = occ[i, j]
            n = np.int64(column[0])
            for k in range(1, nz):
                n += column[k] > column[k - 1]
            column_start[i * ny + j + 1] = n


@njit(parallel=True, cache=True, nogil=True)
def _run_ends(occ, column_start, run_lo, run_hi):
    """The runs of column c from ``column_start[c]`` (their running count from 0) into
    ``run_lo`` and ``run_hi``: where the column changes, the columns without runs
    skipped."""
    nx, ny, nz = occ.shape
    for i in prange(nx):
        for j in range(ny):
            r = column_start[i * ny + j]
            if r == column_start[i * ny + j + 1]:
                continue
            column = occ[i, j]
            previous = False
            for k in range(nz):
                if column[k] != previous:
                    previous = column[k]
                    if previous:
                        run_lo[r] = k
                    else:
                        run_hi[r] = k - 1
                        r += 1
            if previous:
                run_hi[r] = nz - 1


@njit(cache=True)
def _run_parts(column_start, run_lo, run_hi, ny):
    """(n_runs,) int64: the connected part of each run, named by its first run. Two runs
    in neighbouring columns (the 8 around) touch when their z ranges overlap or meet
    corner to corner (within 1); runs of one column are apart by a gap."""
    parent = np.arange(run_lo.size)
    n_columns = column_start.size - 1
    for c in range(n_columns):
        i, j = c // ny, c % ny
        # each pair of columns once: the neighbours before this one in (i, j) order
        for di, dj in ((-1, -1), (-1, 0), (-1, 1), (0, -1)):
            if i + di < 0 or j + dj < 0 or j + dj >= ny:
                continue
            d = (i + di) * ny + (j + dj)
            a, a_end = column_start[c], column_start[c + 1]
            b, b_end = column_start[d], column_start[d + 1]
            while a < a_end and b < b_end:
                if run_lo[a] <= run_hi[b] + 1 and run_lo[b] <= run_hi[a] + 1:
                    join(parent, a, b)
                if run_hi[a] < run_hi[b]:  # the run that ends first can touch no later one
                    a += 1
                else:
                    b += 1
    settle(parent)
    return parent


@njit(cache=True)
def _clear_runs(occ, column_start, run_lo, run_hi, drop):
    """Empty the voxels of the runs marked in ``drop``."""
    ny = occ.shape[1]
    for c in range(column_start.size - 1):
        for r in range(column_start[c], column_start[c + 1]):
            if drop[r]:
                occ[c // ny, c % ny, run_lo[r]:run_hi[r] + 1] = False
