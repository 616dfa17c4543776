"""Edge-swap clean-up of a triangle mesh in the local tangent planes.

An edge ``a - b`` shared by faces ``(a, b, c)`` and ``(b, a, d)`` is replaced by
``c - d`` when, projected to the tangent plane of the four points, the pair is
not Delaunay (the angles at ``c`` and ``d`` sum to more than pi) and the quad is
strictly convex there. A swap never creates an edge that already exists and
never leaves a vertex with fewer than three faces, so a closed manifold mesh
stays closed and manifold.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["swap_edges"]

#: Most faces per vertex the swap keeps track of; vertices above it are left alone.
_CAPACITY = 64


@njit(cache=True)
def _angle(ux, uy, vx, vy):
    return np.arctan2(abs(ux * vy - uy * vx), ux * vx + uy * vy)


@njit(cache=True)
def _remove(vf, nvf, v, f):
    for i in range(nvf[v]):
        if vf[v, i] == f:
            vf[v, i] = vf[v, nvf[v] - 1]
            nvf[v] -= 1
            return


@njit(cache=True)
def _other_face(faces, vf, nvf, f, a, b):
    """The face other than f using directed edge b -> a, and its third vertex."""
    for i in range(nvf[a]):
        g = vf[a, i]
        if g == f:
            continue
        for e in range(3):
            if faces[g, e] == b and faces[g, (e + 1) % 3] == a:
                return g, faces[g, (e + 2) % 3]
    return -1, -1


@njit(cache=True)
def _joined(faces, vf, nvf, c, d):
    for i in range(nvf[c]):
        g = vf[c, i]
        if faces[g, 0] == d or faces[g, 1] == d or faces[g, 2] == d:
            return True
    return False


@njit(cache=True)
def _swap_kernel(P, N, faces, max_passes):
    n = P.shape[0]
    vf = np.empty((n, _CAPACITY), dtype=np.int64)
    nvf = np.zeros(n, dtype=np.int64)
    full = np.zeros(n, dtype=np.bool_)
    for f in range(faces.shape[0]):
        for e in range(3):
            v = faces[f, e]
            if nvf[v] < _CAPACITY:
                vf[v, nvf[v]] = f
                nvf[v] += 1
            else:
                full[v] = True
    swaps = 0
    for _ in range(max_passes):
        changed = 0
        for f in range(faces.shape[0]):
            for e in range(3):
                a = faces[f, e]
                b = faces[f, (e + 1) % 3]
                c = faces[f, (e + 2) % 3]
                if full[a] or full[b] or full[c] or nvf[a] <= 3 or nvf[b] <= 3:
                    continue
                g, d = _other_face(faces, vf, nvf, f, a, b)
                if g < 0 or full[d] or d == c or nvf[c] >= _CAPACITY or nvf[d] >= _CAPACITY:
                    continue
                nx = N[a, 0] + N[b, 0] + N[c, 0] + N[d, 0]
                ny = N[a, 1] + N[b, 1] + N[c, 1] + N[d, 1]
                nz = N[a, 2] + N[b, 2] + N[c, 2] + N[d, 2]
                length = np.sqrt(nx * nx + ny * ny + nz * nz)
                if length < 1e-9:
                    continue
                nx, ny, nz = nx / length, ny / length, nz / length
                # Tangent frame: e1 along a -> b in the plane, e2 = n x e1.
                ux = P[b, 0] - P[a, 0]
                uy = P[b, 1] - P[a, 1]
                uz = P[b, 2] - P[a, 2]
                h = ux * nx + uy * ny + uz * nz
                ux, uy, uz = ux - h * nx, uy - h * ny, uz - h * nz
                l1 = np.sqrt(ux * ux + uy * uy + uz * uz)
                if l1 == 0.0:
                    continue
                ux, uy, uz = ux / l1, uy / l1, uz / l1
                vx = ny * uz - nz * uy
                vy = nz * ux - nx * uz
                vz = nx * uy - ny * ux
                bx, by = l1, 0.0
                rx, ry, rz = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
                cx, cy = rx * ux + ry * uy + rz * uz, rx * vx + ry * vy + rz * vz
                rx, ry, rz = P[d, 0] - P[a, 0], P[d, 1] - P[a, 1], P[d, 2] - P[a, 2]
                dx, dy = rx * ux + ry * uy + rz * uz, rx * vx + ry * vy + rz * vz
                angle_c = _angle(-cx, -cy, bx - cx, by - cy)
                angle_d = _angle(-dx, -dy, bx - dx, by - dy)
                if angle_c + angle_d <= np.pi + 1e-9:
                    continue
                # New faces (a, d, c) and (b, c, d) must be counter-clockwise in the plane.
                area1 = dx * cy - dy * cx
                area2 = (cx - bx) * (dy - by) - (cy - by) * (dx - bx)
                if area1 <= 1e-12 * l1 * l1 or area2 <= 1e-12 * l1 * l1:
                    continue
                if _joined(faces, vf, nvf, c, d):
                    continue
                faces[f, 0], faces[f, 1], faces[f, 2] = a, d, c
                faces[g, 0], faces[g, 1], faces[g, 2] = b, c, d
                _remove(vf, nvf, a, g)
                _remove(vf, nvf, b, f)
                vf[c, nvf[c]] = g
                nvf[c] += 1
                vf[d, nvf[d]] = f
                nvf[d] += 1
                changed += 1
                break  # face f changed: its other edges are looked at in the next pass
        swaps += changed
        if changed == 0:
            break
    return swaps


def swap_edges(points, normals, faces, *, max_passes: int = 10) -> tuple[np.ndarray, int]:
    """Delaunay edge swaps in the local tangent planes.

    Parameters
    ----------
    points : (n, 3) float64
        Vertices, metres.
    normals : (n, 3) float64
        Unit outward vertex normals (they define the tangent planes).
    faces : (m, 3) int64
        Counter-clockwise (outward) faces; every swapped edge must be shared by
        two consistently oriented faces.
    max_passes : int
        Most sweeps over all faces.

    Returns
    -------
    faces : (m, 3) int64
        The swapped faces (a new array).
    n_swaps : int
        Number of edges swapped.
    """
    P = np.ascontiguousarray(points, dtype=np.float64)
    N = np.ascontiguousarray(normals, dtype=np.float64)
    F = np.array(faces, dtype=np.int64).reshape(-1, 3)
    if P.ndim != 2 or P.shape[1] != 3 or N.shape != P.shape:
        raise ValueError(f"points and normals must both be (n, 3), got {P.shape} and {N.shape}")
    if len(F) and (F.min() < 0 or F.max() >= len(P)):
        raise ValueError(f"faces index vertices outside 0..{len(P) - 1}")
    if int(max_passes) < 0:
        raise ValueError(f"max_passes must be >= 0, got {max_passes}")
    n_swaps = _swap_kernel(P, N, F, int(max_passes)) if len(F) else 0
    return F, int(n_swaps)
