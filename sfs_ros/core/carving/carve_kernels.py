"""numba kernels behind :mod:`sfs_ros.core.carving.carve` (no validation here).

Every kernel decides "does voxel (i, j, k) fall into the silhouette of view v"
with the same arithmetic, so that all paths (line path, block path, batch,
incremental) agree bit for bit:

* ``coef`` (n_views, 3, 4) float64 holds, per view and per row ``r`` of the
  projection matrix, ``(c, a_i, a_j, a_k)`` with the homogeneous pixel row
  ``h_r(i, j, k) = ((c + i * a_i) + j * a_j) + k * a_k`` (always this order).
* pixel ``(u, v) = (h_0 / h_2, h_1 / h_2)``; column ``floor(u + 0.5)``, row
  ``floor(v + 0.5)``; ``h_2 <= 0`` (behind a pinhole camera) counts as outside
  the image. Orthographic views have ``h_2 == 1`` exactly.
* A voxel outside the image is a hit when ``keep`` is true, a miss otherwise.

Each ``h_r`` is monotone in each of ``i, j, k`` separately (every floating
point operation is monotone in its operands), which makes the corner bounds
of the block path and the interval search of the line path exact.

Helpers called in hot loops take only scalars and tuples: a helper taking an
array and holding branches gets reference-count updates on every call, and
those atomics, shared by the threads, cost more than the arithmetic.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

_NJIT = dict(cache=True, error_model="numpy")
#: Helpers of the line path inlined into :func:`carve_lines` (numba IR inlining: no call,
#: no reference counting of their array arguments).
_INLINE = dict(_NJIT, inline="always")

# Modes of :func:`carve_lines`.
LINES_INTERSECT = 0   #: batch, no miss allowed: survivor intervals intersected view by view
LINES_COUNT = 1       #: batch: misses counted per voxel (difference array)
LINES_ADD_VIEW = 2    #: incremental: one view's misses added to saturating counters

# Kinds of :func:`block_rect`.
RECT_IN_FRONT = 0     #: the rectangle is valid
RECT_BEHIND = 1       #: the whole box is behind the camera
RECT_STRADDLES = 2    #: the box straddles the camera plane

# Verdicts of a block against one view (:func:`rect_status`, :func:`count_status`).
BLOCK_HIT = 0         #: every voxel of the block falls into the silhouette
BLOCK_MISS = 1        #: no voxel does
BLOCK_UNDECIDED = 2   #: some may: split the block, or test voxel by voxel
BLOCK_COUNT = 3       #: count the rectangle's foreground pixels, then :func:`count_status`

# ---------------------------------------------------------------------------
# shared per-voxel arithmetic


@njit(**_NJIT)
def view_tuple(coef, v):
    """The 12 coefficients of view v as a tuple (row-major (3, 4))."""
    return (coef[v, 0, 0], coef[v, 0, 1], coef[v, 0, 2], coef[v, 0, 3],
            coef[v, 1, 0], coef[v, 1, 1], coef[v, 1, 2], coef[v, 1, 3],
            coef[v, 2, 0], coef[v, 2, 1], coef[v, 2, 2], coef[v, 2, 3])


@njit(**_NJIT)
def _h(cv, r, i, j, k):
    b = 4 * r
    return ((cv[b] + i * cv[b + 1]) + j * cv[b + 2]) + k * cv[b + 3]


@njit(**_NJIT)
def mask_hit(cv, i, j, k, W, H, masks, base, boxes, v, keep):
    """Whether voxel (i, j, k) lands in view ``v``'s silhouette (``keep`` when its pixel is
    outside the W x H image): the pixel's value in the mask's bounding box ``boxes[v]`` =
    (column, row, width, height), stored flat at ``masks[base:]`` (row-major, the box's
    width a row); outside the box there is no foreground."""
    h2 = _h(cv, 2, i, j, k)
    if not h2 > 0.0:
        return keep
    pu = np.floor(_h(cv, 0, i, j, k) / h2 + 0.5)
    pv = np.floor(_h(cv, 1, i, j, k) / h2 + 0.5)
    if not (pu >= 0.0 and pu < W and pv >= 0.0 and pv < H):
        return keep
    c = int(pu) - boxes[v, 0]
    r = int(pv) - boxes[v, 1]
    if c < 0 or c >= boxes[v, 2] or r < 0 or r >= boxes[v, 3]:
        return False
    return masks[base + r * boxes[v, 2] + c] != 0


# ---------------------------------------------------------------------------
# block path: conservative test of a box of voxels against one view


@njit(**_NJIT)
def _corner(cv, r, i0, i1, j0, j1, k0, k1, want_max):
    """Exact min (or max) of h_r over the box, from the monotone corner."""
    b = 4 * r
    i = i1 if (cv[b + 1] >= 0.0) == want_max else i0
    j = j1 if (cv[b + 2] >= 0.0) == want_max else j0
    k = k1 if (cv[b + 3] >= 0.0) == want_max else k0
    return _h(cv, r, i, j, k)


@njit(**_NJIT)
def block_rect(cv, ortho, i0, i1, j0, j1, k0, k1):
    """Pixel rectangle holding every voxel of the box [i0..i1]x[j0..j1]x[k0..k1].

    Returns ``(kind, c0, c1, r0, r1)``: kind :data:`RECT_IN_FRONT` with the
    inclusive column and row ranges (floats, may lie outside the image);
    :data:`RECT_BEHIND`: the whole box is behind the camera;
    :data:`RECT_STRADDLES`: the box straddles the camera plane.
    """
    if ortho:
        umin = _corner(cv, 0, i0, i1, j0, j1, k0, k1, False)
        umax = _corner(cv, 0, i0, i1, j0, j1, k0, k1, True)
        vmin = _corner(cv, 1, i0, i1, j0, j1, k0, k1, False)
        vmax = _corner(cv, 1, i0, i1, j0, j1, k0, k1, True)
    else:
        if not _corner(cv, 2, i0, i1, j0, j1, k0, k1, True) > 0.0:
            return RECT_BEHIND, 0.0, 0.0, 0.0, 0.0
        if not _corner(cv, 2, i0, i1, j0, j1, k0, k1, False) > 0.0:
            return RECT_STRADDLES, 0.0, 0.0, 0.0, 0.0
        # The projection of a box in front of the camera is the convex hull of
        # its projected corners; widen a hair for the rounding of the division.
        umin = np.inf
        umax = -np.inf
        vmin = np.inf
        vmax = -np.inf
        for c in range(8):
            i = i1 if c & 1 else i0
            j = j1 if c & 2 else j0
            k = k1 if c & 4 else k0
            h2 = _h(cv, 2, i, j, k)
            u = _h(cv, 0, i, j, k) / h2
            w = _h(cv, 1, i, j, k) / h2
            umin = min(umin, u)
            umax = max(umax, u)
            vmin = min(vmin, w)
            vmax = max(vmax, w)
        umin -= 1e-7 * (1.0 + abs(umin))
        umax += 1e-7 * (1.0 + abs(umax))
        vmin -= 1e-7 * (1.0 + abs(vmin))
        vmax += 1e-7 * (1.0 + abs(vmax))
    return (RECT_IN_FRONT, np.floor(umin + 0.5), np.floor(umax + 0.5), np.floor(vmin + 0.5),
            np.floor(vmax + 0.5))


@njit(**_NJIT)
def rect_status(kind, c0, c1, r0, r1, W, H, keep):
    """The verdict on a block from its :func:`block_rect`: :data:`BLOCK_HIT`,
    :data:`BLOCK_MISS`, :data:`BLOCK_UNDECIDED`, or :data:`BLOCK_COUNT`: count the
    foreground pixels of the rectangle clipped to the image and call
    :func:`count_status`."""
    if kind == RECT_BEHIND:
        return BLOCK_HIT if keep else BLOCK_MISS
    if kind == RECT_STRADDLES:
        return BLOCK_UNDECIDED
    if not (c1 >= 0.0 and c0 < W and r1 >= 0.0 and r0 < H):
        return BLOCK_HIT if keep else BLOCK_MISS  # entirely outside the image (NaN: never)
    return BLOCK_COUNT


@njit(**_NJIT)
def count_status(count, c0, c1, r0, r1, W, H, keep):
    """The verdict on a block whose rectangle holds ``count`` foreground pixels:
    :data:`BLOCK_HIT`, :data:`BLOCK_MISS` or :data:`BLOCK_UNDECIDED`."""
    a0 = max(c0, 0.0)
    a1 = min(c1, W - 1.0)
    b0 = max(r0, 0.0)
    b1 = min(r1, H - 1.0)
    area = (a1 - a0 + 1.0) * (b1 - b0 + 1.0)
    inside = c0 >= 0.0 and c1 < W and r0 >= 0.0 and r1 < H
    if keep:
        if count == area:
            return BLOCK_HIT
        if count == 0 and inside:
            return BLOCK_MISS
    else:
        if count == 0:
            return BLOCK_MISS
        if count == area and inside:
            return BLOCK_HIT
    return BLOCK_UNDECIDED


@njit(**_NJIT)
def _rect_count(integ, base, boxes, v, c0, c1, r0, r1, W, H):
    """Foreground pixels of view ``v`` in the rectangle clipped to the image, from its
    summed-area table at ``integ[base:]``, which covers only the mask's bounding box
    ``boxes[v]`` = (column, row, width, height): outside it there is no foreground."""
    x0 = boxes[v, 0]
    y0 = boxes[v, 1]
    a0 = max(int(max(c0, 0.0)), x0) - x0
    a1 = min(int(min(c1, W - 1.0)), x0 + boxes[v, 2] - 1) - x0
    b0 = max(int(max(r0, 0.0)), y0) - y0
    b1 = min(int(min(r1, H - 1.0)), y0 + boxes[v, 3] - 1) - y0
    if a1 < a0 or b1 < b0:
        return 0
    s = boxes[v, 2] + 1
    return (integ[base + (b1 + 1) * s + a1 + 1] - integ[base + b0 * s + a1 + 1]
            - integ[base + (b1 + 1) * s + a0] + integ[base + b0 * s + a0])


# ---------------------------------------------------------------------------
# block trees: top blocks of ``top`` voxels (C order), split in eight down to ``leaf``


@njit(**_NJIT)
def _tree_levels(top, leaf):
    """Levels of the block tree from ``top`` down to ``leaf`` voxels, plus one spare."""
    levels = 2
    size = top
    while size > leaf:
        size //= 2
        levels += 1
    return levels


@njit(**_NJIT)
def _top_block(b, nby, nbz, top):
    """First voxel (i0, j0, k0) of top block ``b`` of a grid ``nby`` x ``nbz`` blocks wide."""
    return (b // (nby * nbz)) * top, ((b // nbz) % nby) * top, (b % nbz) * top


@njit(**_NJIT)
def _block_last(i0, j0, k0, size, nx, ny, nz):
    """Last voxel (i1, j1, k1) of the block of ``size`` voxels from (i0, j0, k0), inside
    the grid (nx, ny, nz)."""
    return min(i0 + size, nx) - 1, min(j0 + size, ny) - 1, min(k0 + size, nz) - 1


@njit(**_INLINE)
def _push_children(stack, sp, i0, j0, k0, half, nx, ny, nz):
    """Push the children inside the grid of the block at (i0, j0, k0), ``half`` voxels
    each, as rows ``(i0, j0, k0, half)`` of ``stack`` from row ``sp``; the new height."""
    for c in range(8):
        ci = i0 + (half if c & 1 else 0)
        cj = j0 + (half if c & 2 else 0)
        ck = k0 + (half if c & 4 else 0)
        if ci < nx and cj < ny and ck < nz:
            stack[sp, 0] = ci
            stack[sp, 1] = cj
            stack[sp, 2] = ck
            stack[sp, 3] = half
            sp += 1
    return sp


@njit(parallel=True, cache=True, error_model="numpy")
def integral_images(masks, moff, boxes, ioff, integ):
    """Summed-area tables of the masks' bounding boxes ``boxes`` (n, 4) = (column, row,
    width, height), each box's pixels flat at ``masks[moff[v]:]`` (row-major):
    ``integ[ioff[v] + r * (w + 1) + c]`` = foreground pixels of
    ``mask[y0:y0 + r, x0:x0 + c]``."""
    for v in prange(moff.size):
        w = boxes[v, 2]
        s = w + 1
        b = ioff[v]
        for c in range(s):
            integ[b + c] = 0
        for r in range(boxes[v, 3]):
            run = 0
            integ[b + (r + 1) * s] = 0
            row = moff[v] + r * w
            for c in range(w):
                run += masks[row + c]
                integ[b + (r + 1) * s + c + 1] = integ[b + r * s + c + 1] + run


@njit(parallel=True, **_NJIT)
def carve_blocks(coef, ortho, masks, moff, integ, ioff, boxes, heights, widths, order, keep,
                 max_misses, top, leaf, out):
    """Batch coarse-to-fine carving into ``out`` (nx, ny, nz) bool, zero on entry.

    Blocks of ``top`` voxels are split in eight until ``leaf``; each level only
    re-tests the views the parent block left undecided.
    """
    nx, ny, nz = out.shape
    nby = (ny + top - 1) // top
    nbz = (nz + top - 1) // top
    n_views = order.size
    levels = _tree_levels(top, leaf)
    for b in prange(((nx + top - 1) // top) * nby * nbz):
        lists = np.empty((levels + 1, n_views), np.int64)
        lens = np.empty(levels + 1, np.int64)
        bases = np.empty(levels + 1, np.int64)
        lists[0, :] = order
        lens[0] = n_views
        bases[0] = 0
        stack = np.empty((8 * (levels + 1), 5), np.int64)
        stack[0, 0], stack[0, 1], stack[0, 2] = _top_block(b, nby, nbz, top)
        stack[0, 3] = top
        stack[0, 4] = 1
        sp = 1
        while sp > 0:
            sp -= 1
            i0 = stack[sp, 0]
            j0 = stack[sp, 1]
            k0 = stack[sp, 2]
            size = stack[sp, 3]
            lev = stack[sp, 4]
            i1, j1, k1 = _block_last(i0, j0, k0, size, nx, ny, nz)
            misses = bases[lev - 1]
            n_open = 0
            for t in range(lens[lev - 1]):
                v = lists[lev - 1, t]
                W = widths[v]
                H = heights[v]
                kind, c0, c1, r0, r1 = block_rect(view_tuple(coef, v), ortho[v], i0, i1, j0,
                                                  j1, k0, k1)
                st = rect_status(kind, c0, c1, r0, r1, W, H, keep)
                if st == BLOCK_COUNT:
                    st = count_status(_rect_count(integ, ioff[v], boxes, v, c0, c1, r0, r1, W, H),
                                      c0, c1, r0, r1, W, H, keep)
                if st == BLOCK_MISS:
                    misses += 1
                    if misses > max_misses:
                        break
                elif st == BLOCK_UNDECIDED:
                    lists[lev, n_open] = v
                    n_open += 1
            if misses > max_misses:
                continue
            if misses + n_open <= max_misses:
                out[i0:i1 + 1, j0:j1 + 1, k0:k1 + 1] = True
                continue
            if size <= leaf:
                for i in range(i0, i1 + 1):
                    for j in range(j0, j1 + 1):
                        for k in range(k0, k1 + 1):
                            m = misses
                            for t in range(n_open):
                                v = lists[lev, t]
                                if not mask_hit(view_tuple(coef, v), i, j, k, widths[v],
                                                heights[v], masks, moff[v], boxes, v, keep):
                                    m += 1
                                    if m > max_misses:
                                        break
                            if m <= max_misses:
                                out[i, j, k] = True
                continue
            lens[lev] = n_open
            bases[lev] = misses
            first = sp
            sp = _push_children(stack, sp, i0, j0, k0, size // 2, nx, ny, nz)
            stack[first:sp, 4] = lev + 1


@njit(parallel=True, **_NJIT)
def carve_blocks_one(coef, ortho, masks, integ, boxes, W, H, keep, cap, top, leaf, alive,
                     misses):
    """Add view 0 (its mask's bounding box ``boxes[0]``, the box's pixels ``masks`` flat,
    their summed-area table ``integ``) to the miss counters ``misses`` (nx, ny, nz),
    saturating at ``cap``.

    ``alive`` (n_blocks,) bool flags top blocks that may still hold a voxel
    below ``cap``; blocks flagged dead are skipped, flags are updated.
    """
    nx, ny, nz = misses.shape
    nby = (ny + top - 1) // top
    nbz = (nz + top - 1) // top
    levels = _tree_levels(top, leaf)
    cv = view_tuple(coef, 0)
    is_ortho = ortho[0]
    for b in prange(alive.size):
        if not alive[b]:
            continue
        bi, bj, bk = _top_block(b, nby, nbz, top)
        stack = np.empty((8 * (levels + 1), 4), np.int64)
        stack[0, 0] = bi
        stack[0, 1] = bj
        stack[0, 2] = bk
        stack[0, 3] = top
        sp = 1
        changed = False
        while sp > 0:
            sp -= 1
            i0 = stack[sp, 0]
            j0 = stack[sp, 1]
            k0 = stack[sp, 2]
            size = stack[sp, 3]
            i1, j1, k1 = _block_last(i0, j0, k0, size, nx, ny, nz)
            kind, c0, c1, r0, r1 = block_rect(cv, is_ortho, i0, i1, j0, j1, k0, k1)
            st = rect_status(kind, c0, c1, r0, r1, W, H, keep)
            if st == BLOCK_COUNT:
                st = count_status(_rect_count(integ, 0, boxes, 0, c0, c1, r0, r1, W, H), c0,
                                  c1, r0, r1, W, H, keep)
            if st == BLOCK_HIT:
                continue
            if st == BLOCK_MISS or size <= leaf:
                for i in range(i0, i1 + 1):
                    for j in range(j0, j1 + 1):
                        for k in range(k0, k1 + 1):
                            if misses[i, j, k] < cap:
                                if st == BLOCK_UNDECIDED:
                                    if mask_hit(cv, i, j, k, W, H, masks, 0, boxes, 0, keep):
                                        continue
                                misses[i, j, k] += 1
                                changed = True
                continue
            sp = _push_children(stack, sp, i0, j0, k0, size // 2, nx, ny, nz)
        if changed:
            alive[b] = np.any(misses[bi:bi + top, bj:bj + top, bk:bk + top] < cap)


# ---------------------------------------------------------------------------
# line path (orthographic views that map a whole grid line onto one image
# row or column): masks as runs of foreground, voxel lines as intervals


@njit(parallel=True, cache=True, error_model="numpy")
def count_runs(masks, by_row, counts):
    """counts[v, l] = number of foreground runs in image column l (by_row[v] false)
    or image row l (by_row[v] true) of masks[v] (H, W) bool."""
    n, H, W = masks.shape
    for v in prange(n):
        m = masks[v]
        counts[v, :] = 0
        if by_row[v]:
            for r in range(H):
                cnt = 0
                for c in range(W):
                    if m[r, c] and (c == 0 or not m[r, c - 1]):
                        cnt += 1
                counts[v, r] = cnt
        else:
            for r in range(H):
                for c in range(W):
                    if m[r, c] and (r == 0 or not m[r - 1, c]):
                        counts[v, c] += 1


@njit(parallel=True, cache=True, error_model="numpy")
def fill_runs(masks, by_row, offsets, run_lo, run_hi):
    """Write run bounds (inclusive pixel indices along the image line), in order;
    offsets (n * L + 1,) from the counts of :func:`count_runs`, L = its width."""
    n, H, W = masks.shape
    L = max(H, W)
    for v in prange(n):
        m = masks[v]
        base = v * L
        if by_row[v]:
            for r in range(H):
                p = offsets[base + r]
                for c in range(W):
                    if m[r, c]:
                        if c == 0 or not m[r, c - 1]:
                            run_lo[p] = c
                        if c == W - 1 or not m[r, c + 1]:
                            run_hi[p] = c
                            p += 1
        else:
            pos = offsets[base:base + W].copy()
            for r in range(H):
                for c in range(W):
                    if m[r, c]:
                        if r == 0 or not m[r - 1, c]:
                            run_lo[pos[c]] = r
                        if r == H - 1 or not m[r + 1, c]:
                            run_hi[pos[c]] = r
                            pos[c] += 1


@njit(**_NJIT)
def _terms(c, a0, a1, a2, axis, p, q):
    """(A, s, B1, B2) with ``((c + i a0) + j a1) + k a2`` of voxel t on line
    (p, q) along ``axis`` equal to ``((A + t * s) + B1) + B2`` bit for bit."""
    if axis == 2:
        return (c + p * a0) + q * a1, a2, 0.0, 0.0
    if axis == 1:
        return c + p * a0, a1, q * a2, 0.0
    return c, a0, p * a1, q * a2


@njit(**_NJIT)
def _pix_at(A, s, B1, B2, t):
    return np.floor((((A + t * s) + B1) + B2) + 0.5)


@njit(**_NJIT)
def _first_at_least(A, s, inv_s, B1, B2, target, lo, hi):
    """Increasing pixel (s > 0): smallest t in [lo, hi] with pix(t) >= target."""
    g = np.ceil((target - 0.5 - ((A + B1) + B2)) * inv_s)
    t = lo if g < lo else (hi if g > hi else int(g))
    while t > lo and _pix_at(A, s, B1, B2, t - 1) >= target:
        t -= 1
    while t < hi and _pix_at(A, s, B1, B2, t) < target:
        t += 1
    return t


@njit(**_NJIT)
def _first_at_most(A, s, inv_s, B1, B2, target, lo, hi):
    """Decreasing pixel (s < 0): smallest t in [lo, hi] with pix(t) <= target."""
    g = np.floor((target + 0.5 - ((A + B1) + B2)) * inv_s) + 1.0
    t = lo if g < lo else (hi if g > hi else int(g))
    while t > lo and _pix_at(A, s, B1, B2, t - 1) <= target:
        t -= 1
    while t < hi and _pix_at(A, s, B1, B2, t) > target:
        t += 1
    return t


@njit(**_INLINE)
def _append_interval(al_lo, al_hi, n_al, t0, t1):
    """Append ``[t0, t1)`` to the ``n_al`` intervals ``al_lo``, ``al_hi`` unless it is empty;
    how many there are then."""
    if t0 < t1:
        al_lo[n_al] = t0
        al_hi[n_al] = t1
        n_al += 1
    return n_al


@njit(**_INLINE)
def _allowed_rising(A, s, B1, B2, first, last, run_lo, run_hi, n_along, lo, hi, keep, al_lo,
                    al_hi):
    """Allowed intervals of a line whose pixel rises along it (s > 0): runs
    ``first..last`` of its image line, ascending; how many."""
    n_al = 0
    inv = 1.0 / s
    x_lo = _pix_at(A, s, B1, B2, lo)
    x_hi = _pix_at(A, s, B1, B2, hi - 1)
    if keep and x_lo < 0.0:
        t1 = _first_at_least(A, s, inv, B1, B2, 0.0, lo, hi)
        n_al = _append_interval(al_lo, al_hi, n_al, lo, t1)
    for idx in range(first, last):
        a = run_lo[idx]
        b = run_hi[idx]
        if b < x_lo:
            continue
        if a > x_hi:
            break
        t0 = lo if a <= x_lo else _first_at_least(A, s, inv, B1, B2, a, lo, hi)
        t1 = hi if b >= x_hi else _first_at_least(A, s, inv, B1, B2, b + 1.0, lo, hi)
        n_al = _append_interval(al_lo, al_hi, n_al, t0, t1)
    if keep and x_hi >= n_along:
        t0 = _first_at_least(A, s, inv, B1, B2, n_along, lo, hi)
        n_al = _append_interval(al_lo, al_hi, n_al, t0, hi)
    return n_al


@njit(**_INLINE)
def _allowed_falling(A, s, B1, B2, first, last, run_lo, run_hi, n_along, lo, hi, keep, al_lo,
                     al_hi):
    """Allowed intervals of a line whose pixel falls along it (s < 0): runs
    ``first..last`` of its image line taken backwards; how many."""
    n_al = 0
    inv = 1.0 / s
    x_hi = _pix_at(A, s, B1, B2, lo)
    x_lo = _pix_at(A, s, B1, B2, hi - 1)
    if keep and x_hi >= n_along:
        t1 = _first_at_most(A, s, inv, B1, B2, n_along - 1.0, lo, hi)
        n_al = _append_interval(al_lo, al_hi, n_al, lo, t1)
    for idx in range(last - 1, first - 1, -1):
        a = run_lo[idx]
        b = run_hi[idx]
        if a > x_hi:
            continue
        if b < x_lo:
            break
        t0 = lo if b >= x_hi else _first_at_most(A, s, inv, B1, B2, b, lo, hi)
        t1 = hi if a <= x_lo else _first_at_most(A, s, inv, B1, B2, a - 1.0, lo, hi)
        n_al = _append_interval(al_lo, al_hi, n_al, t0, t1)
    if keep and x_lo < 0.0:
        t0 = _first_at_most(A, s, inv, B1, B2, -1.0, lo, hi)
        n_al = _append_interval(al_lo, al_hi, n_al, t0, hi)
    return n_al


@njit(**_INLINE)
def _allowed(coef, v, by_row, offsets, run_lo, run_hi, L, H, W, axis, p, q, lo, hi, keep,
             al_lo, al_hi):
    """Intervals ``[al_lo, al_hi)`` of t in [lo, hi), ascending, where the voxels of line
    (p, q) fall into the silhouette of view v (or outside its image, with ``keep``); how
    many."""
    if by_row[v]:
        r_fix, r_along, n_fix, n_along = 1, 0, H, W
    else:
        r_fix, r_along, n_fix, n_along = 0, 1, W, H
    A, s, B1, B2 = _terms(coef[v, r_fix, 0], coef[v, r_fix, 1], coef[v, r_fix, 2],
                          coef[v, r_fix, 3], axis, p, q)
    f = _pix_at(A, s, B1, B2, 0)
    if not (f >= 0.0 and f < n_fix):
        if keep:
            al_lo[0] = lo
            al_hi[0] = hi
            return 1
        return 0
    first = offsets[v * L + int(f)]
    last = offsets[v * L + int(f) + 1]
    A, s, B1, B2 = _terms(coef[v, r_along, 0], coef[v, r_along, 1], coef[v, r_along, 2],
                          coef[v, r_along, 3], axis, p, q)
    if s > 0.0:
        return _allowed_rising(A, s, B1, B2, first, last, run_lo, run_hi, n_along, lo, hi,
                               keep, al_lo, al_hi)
    if s < 0.0:
        return _allowed_falling(A, s, B1, B2, first, last, run_lo, run_hi, n_along, lo, hi,
                                keep, al_lo, al_hi)
    x = _pix_at(A, s, B1, B2, lo)
    hit = keep and not (x >= 0.0 and x < n_along)
    for idx in range(first, last):
        if run_lo[idx] <= x and x <= run_hi[idx]:
            hit = True
    if hit:
        al_lo[0] = lo
        al_hi[0] = hi
        return 1
    return 0


@njit(**_INLINE)
def _intersect(cur_lo, cur_hi, w, n_cur, al_lo, al_hi, n_al):
    """Intersect the intervals in row ``w`` of ``cur_lo``/``cur_hi`` with the allowed
    ones into row ``1 - w``; how many."""
    a = 0
    b = 0
    n_new = 0
    while a < n_cur and b < n_al:
        s0 = max(cur_lo[w, a], al_lo[b])
        e0 = min(cur_hi[w, a], al_hi[b])
        if s0 < e0:
            cur_lo[1 - w, n_new] = s0
            cur_hi[1 - w, n_new] = e0
            n_new += 1
        if cur_hi[w, a] < al_hi[b]:
            a += 1
        else:
            b += 1
    return n_new


@njit(**_INLINE)
def _add_misses(misses, axis, p, q, start, end, cap):
    """Count a miss for voxels t in [start, end) of line (p, q), saturating at ``cap``."""
    for t in range(start, end):
        if axis == 2:
            if misses[p, q, t] < cap:
                misses[p, q, t] += 1
        elif axis == 1:
            if misses[p, t, q] < cap:
                misses[p, t, q] += 1
        elif misses[t, p, q] < cap:
            misses[t, p, q] += 1


@njit(**_INLINE)
def _survivors(count, nl, max_misses, cur_lo, cur_hi, w):
    """Intervals (row ``w`` of ``cur_lo``/``cur_hi``) where the prefix sum of the
    difference array ``count`` is at most ``max_misses``; how many. Clears ``count``."""
    run = 0
    n_cur = 0
    start = -1
    for t in range(nl + 1):
        if t < nl:
            run += count[t]
            count[t] = 0
        ok = t < nl and run <= max_misses
        if ok and start < 0:
            start = t
        elif not ok and start >= 0:
            cur_lo[w, n_cur] = start
            cur_hi[w, n_cur] = t
            n_cur += 1
            start = -1
    count[nl] = 0
    return n_cur


@njit(**_INLINE)
def _fill_line(out, axis, p, q, start, end):
    """Set voxels t in [start, end) of line (p, q)."""
    if axis == 2:
        out[p, q, start:end] = True
    elif axis == 1:
        out[p, start:end, q] = True
    else:
        out[start:end, p, q] = True


@njit(parallel=True, **_NJIT)
def carve_lines(coef, by_row, order, offsets, run_lo, run_hi, L, H, W, axis, keep, max_misses,
                chunk, mode, out, misses):
    """Carve along the grid lines of ``axis``.

    mode :data:`LINES_INTERSECT`: batch, ``max_misses == 0``: intervals of
    survivors intersected view by view, written to ``out`` (nx, ny, nz) bool,
    zero on entry;
    mode :data:`LINES_COUNT`: batch, misses counted per voxel (difference
    array), into ``out``;
    mode :data:`LINES_ADD_VIEW`: incremental, one view (``order == [0]``):
    ``misses`` (nx, ny, nz) incremented, saturating at ``max_misses + 1``,
    where the view misses.
    """
    shape = misses.shape if mode == LINES_ADD_VIEW else out.shape
    nl = shape[axis]
    n0 = shape[0] if axis != 0 else shape[1]
    n1 = shape[2] if axis != 2 else shape[1]
    n_lines = n0 * n1
    n_views = order.size
    cap = max_misses + 1
    for c in prange((n_lines + chunk - 1) // chunk):
        cur_lo = np.empty((2, nl + 1), np.int64)
        cur_hi = np.empty((2, nl + 1), np.int64)
        al_lo = np.empty(L + 4, np.int64)
        al_hi = np.empty(L + 4, np.int64)
        count = np.zeros(nl + 1, np.int64)
        for line in range(c * chunk, min(n_lines, (c + 1) * chunk)):
            p = line // n1
            q = line % n1
            w = 0
            n_cur = 1
            cur_lo[0, 0] = 0
            cur_hi[0, 0] = nl
            for tv in range(n_views):
                v = order[tv]
                lo = cur_lo[w, 0] if mode == LINES_INTERSECT else 0
                hi = cur_hi[w, n_cur - 1] if mode == LINES_INTERSECT else nl
                n_al = _allowed(coef, v, by_row, offsets, run_lo, run_hi, L, H, W, axis, p, q,
                                lo, hi, keep, al_lo, al_hi)
                if mode == LINES_INTERSECT:
                    if n_al == 1 and al_lo[0] == lo and al_hi[0] == hi:
                        continue
                    n_cur = _intersect(cur_lo, cur_hi, w, n_cur, al_lo, al_hi, n_al)
                    w = 1 - w
                    if n_cur == 0:
                        break
                else:
                    # the gaps between allowed intervals are misses
                    prev = 0
                    for a in range(n_al + 1):
                        end = al_lo[a] if a < n_al else nl
                        if mode == LINES_COUNT:
                            count[prev] += 1
                            count[end] -= 1
                        else:
                            _add_misses(misses, axis, p, q, prev, end, cap)
                        if a < n_al:
                            prev = al_hi[a]
            if mode == LINES_ADD_VIEW:
                continue
            if mode == LINES_COUNT:
                n_cur = _survivors(count, nl, max_misses, cur_lo, cur_hi, w)
            for a in range(n_cur):
                _fill_line(out, axis, p, q, cur_lo[w, a], cur_hi[w, a])
