"""Parts with concavities no silhouette shows, and a solid colour texture to match on.

:class:`Revolved` is a solid of revolution about the object's Z axis, given by a
polygonal profile in the meridian half-plane ``(r, z)``; a cup, a bowl and a
barrel are profiles. :class:`PocketBlock` is a box with a blind rectangular
pocket sunk into its top face. Both have an exact inside test, an exact distance
to their surface, an exact volume, uniform surface samples and a closed,
outward rendering mesh (inscribed for :class:`Revolved`, exact for the block).

:func:`solid_texture` colours a 3-D point by the cell of a cubic lattice it lies in
(a pseudo-random colour per cell, hashed from the cell's integer coordinates):
evaluated at the surface point each pixel sees, it paints the surface with a
pattern that is the same from every view, like a real object's albedo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh
from numba import njit, prange

__all__ = ["PocketBlock", "Revolved", "box_distance", "solid_texture"]

#: Edge of the texture's lattice cells, metres (5.8 px at the demo camera's 0.43 mm/px).
TEXTURE_CELL_M = 0.0025


def solid_texture(points: np.ndarray, *, cell_m: float = TEXTURE_CELL_M,
                  seed: int = 0) -> np.ndarray:
    """(n, 3) uint8 RGB of the solid texture at points (n, 3), metres.

    Every lattice cell of edge ``cell_m`` gets its own colour, each channel in
    [40, 220], from an integer hash of the cell's coordinates and ``seed``.
    """
    cells = np.floor(np.asarray(points, dtype=np.float64) / cell_m).astype(np.int64)
    key = (cells[:, 0] * 73856093) ^ (cells[:, 1] * 19349663) ^ (cells[:, 2] * 83492791) \
        ^ (int(seed) * 2654435761)
    rgb = np.empty((len(cells), 3), dtype=np.uint8)
    for channel in range(3):
        key = (key * 6364136223846793005 + 1442695040888963407) & 0x7FFFFFFFFFFFFFFF
        rgb[:, channel] = 40 + ((key >> 33) % 181)
    return rgb


@njit(parallel=True, cache=True)
def _polygon_distance(xz, polygon, out):
    """``out[p]``: signed distance (positive outside) of the 2-D points ``xz`` (n, 2) to
    the closed polygon (k, 2) (even-odd inside test)."""
    k = polygon.shape[0]
    for p in prange(xz.shape[0]):
        x, z = xz[p, 0], xz[p, 1]
        best = np.inf
        inside = False
        for s in range(k):
            ax, az = polygon[s, 0], polygon[s, 1]
            bx, bz = polygon[(s + 1) % k, 0], polygon[(s + 1) % k, 1]
            ex, ez = bx - ax, bz - az
            length2 = ex * ex + ez * ez
            t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, ((x - ax) * ex + (z - az) * ez)
                                                        / length2))
            dx, dz = x - ax - t * ex, z - az - t * ez
            best = min(best, dx * dx + dz * dz)
            if (az > z) != (bz > z) and x < ax + (z - az) * ex / ez:
                inside = not inside
        out[p] = -math.sqrt(best) if inside else math.sqrt(best)


@dataclass(frozen=True, eq=False)
class Revolved:
    """Solid of revolution about Z of a polygonal profile.

    ``profile`` (k, 2): ``(r, z)`` vertices in metres, ``r >= 0``, from a point on the
    axis round the meridian section to another point on the axis (the axis closes it);
    the section must be a simple polygon. ``sections``: segments of the rendering
    mesh around the axis (its vertices lie on the true surface).
    """

    profile: tuple
    sections: int = 256

    def __post_init__(self) -> None:
        prof = np.asarray(self.profile, dtype=np.float64)
        if prof.ndim != 2 or prof.shape[1] != 2 or len(prof) < 3 or prof[0, 0] != 0 \
                or prof[-1, 0] != 0 or np.any(prof[1:-1, 0] <= 0):
            raise ValueError("profile must be (k >= 3, 2) points (r, z), on the axis (r = 0) "
                             "at both ends only")
        object.__setattr__(self, "profile", tuple(map(tuple, prof)))

    @property
    def _half(self) -> np.ndarray:
        return np.asarray(self.profile)

    @property
    def _mirrored(self) -> np.ndarray:
        """(2k - 2, 2) the section and its mirror image across the axis: one closed polygon
        in ``(x, z)`` whose boundary is the surface's meridian (no edge on the axis)."""
        half = self._half
        mirror = half[-2:0:-1] * [-1.0, 1.0]
        return np.ascontiguousarray(np.vstack([half, mirror]))

    @property
    def volume_m3(self) -> float:
        r, z = self._half[:, 0], self._half[:, 1]
        r1, r2, dz = r, np.roll(r, -1), np.roll(z, -1) - z
        return float(abs(math.pi * np.sum(dz * (r1 * r1 + r1 * r2 + r2 * r2) / 3.0)))

    @property
    def _segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Starts (s, 2), ends (s, 2) and lateral areas (s,) m^2 of the profile's segments."""
        half = self._half
        a, b = half[:-1], half[1:]
        area = math.pi * (a[:, 0] + b[:, 0]) * np.linalg.norm(b - a, axis=1)
        return a, b, area

    @property
    def area_m2(self) -> float:
        return float(self._segments[2].sum())

    @property
    def bounds(self) -> np.ndarray:
        half = self._half
        r = half[:, 0].max()
        return np.array([[-r, -r, half[:, 1].min()], [r, r, half[:, 1].max()]])

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) exact signed distance to the surface, metres (negative inside): the
        distance in the point's meridian half-plane to the profile."""
        points = np.asarray(points, dtype=np.float64)
        xz = np.ascontiguousarray(np.column_stack([np.hypot(points[:, 0], points[:, 1]),
                                                   points[:, 2]]))
        out = np.empty(len(points))
        _polygon_distance(xz, self._mirrored, out)
        return out

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        a, b, area = self._segments
        picks = rng.choice(len(area), size=n, p=area / area.sum())
        # Along a segment the area element grows with r: rejection-sample the position.
        t = np.empty(n)
        todo = np.arange(n)
        while todo.size:
            trial = rng.random(todo.size)
            ra, rb = a[picks[todo], 0], b[picks[todo], 0]
            keep = rng.random(todo.size) * np.maximum(ra, rb) <= ra + (rb - ra) * trial
            t[todo[keep]] = trial[keep]
            todo = todo[~keep]
        rz = a[picks] + t[:, None] * (b[picks] - a[picks])
        angle = rng.uniform(0.0, 2.0 * math.pi, n)
        return np.column_stack([rz[:, 0] * np.cos(angle), rz[:, 0] * np.sin(angle), rz[:, 1]])

    def mesh(self) -> trimesh.Trimesh:
        half, n = self._half, self.sections
        angle = 2.0 * math.pi * np.arange(n) / n
        first, vertices, faces = [], [], []
        count = 0
        for r, z in half:
            first.append(count)
            ring = [[0.0, 0.0, z]] if r == 0 else np.column_stack(
                [r * np.cos(angle), r * np.sin(angle), np.full(n, z)])
            vertices.append(np.asarray(ring))
            count += len(ring)
        i = np.arange(n)
        j = (i + 1) % n
        for s in range(len(half) - 1):
            p, q = first[s], first[s + 1]
            if half[s, 0] == 0:
                faces.append(np.column_stack([np.full(n, p), q + i, q + j]))
            elif half[s + 1, 0] == 0:
                faces.append(np.column_stack([p + i, np.full(n, q), p + j]))
            else:
                faces += [np.column_stack([p + i, q + i, q + j]),
                          np.column_stack([p + i, q + j, p + j])]
        mesh = trimesh.Trimesh(np.vstack(vertices), np.vstack(faces), process=False)
        return mesh if mesh.volume > 0 else trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1],
                                                            process=False)


def box_distance(points: np.ndarray, lo, hi) -> np.ndarray:
    """(n,) exact signed distance to the box ``[lo, hi]``, metres (negative inside)."""
    centre = 0.5 * (np.asarray(lo) + np.asarray(hi))
    q = np.abs(points - centre) - 0.5 * (np.asarray(hi) - np.asarray(lo))
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


@dataclass(frozen=True)
class PocketBlock:
    """A box ``|x| <= size[0]/2, |y| <= size[1]/2, 0 <= z <= size[2]`` with a blind pocket
    ``|x| <= pocket[0]/2, |y| <= pocket[1]/2, z >= size[2] - pocket[2]`` cut from its top
    (metres)."""

    size: tuple
    pocket: tuple

    def __post_init__(self) -> None:
        if not all(0 < p < s for p, s in zip(self.pocket, self.size)):
            raise ValueError(f"the pocket {self.pocket} must fit inside the block {self.size}")

    @property
    def _pocket_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The pocket as a box reaching beyond the top face (so its opening is open)."""
        h, (pa, pb, d) = self.size[2], self.pocket
        return np.array([-pa / 2, -pb / 2, h - d]), np.array([pa / 2, pb / 2, h + d])

    @property
    def volume_m3(self) -> float:
        return float(np.prod(self.size) - np.prod(self.pocket))

    @property
    def bounds(self) -> np.ndarray:
        a, b, h = self.size
        return np.array([[-a / 2, -b / 2, 0.0], [a / 2, b / 2, h]])

    def _rectangles(self) -> tuple[np.ndarray, np.ndarray]:
        """The surface as axis-aligned rectangles: corners ``lo`` (14, 3) and ``hi`` (14, 3)
        (each flat along one axis)."""
        (a, b, h), (pa, pb, d) = self.size, self.pocket
        x, y, px, py, f = a / 2, b / 2, pa / 2, pb / 2, h - d
        boxes = [
            ((-x, -y, 0), (x, y, 0)),                                  # bottom
            ((-x, -y, 0), (-x, y, h)), ((x, -y, 0), (x, y, h)),        # outer walls
            ((-x, -y, 0), (x, -y, h)), ((-x, y, 0), (x, y, h)),
            ((-x, -y, h), (-px, y, h)), ((px, -y, h), (x, y, h)),      # top around the pocket
            ((-px, -y, h), (px, -py, h)), ((-px, py, h), (px, y, h)),
            ((-px, -py, f), (px, py, f)),                              # pocket floor
            ((-px, -py, f), (-px, py, h)), ((px, -py, f), (px, py, h)),  # pocket walls
            ((-px, -py, f), (px, -py, h)), ((-px, py, f), (px, py, h))]
        lo, hi = (np.array([box[k] for box in boxes], dtype=np.float64) for k in (0, 1))
        return lo, hi

    @property
    def area_m2(self) -> float:
        lo, hi = self._rectangles()
        extent = np.sort(hi - lo, axis=1)
        return float(np.sum(extent[:, 1] * extent[:, 2]))

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) exact signed distance to the surface, metres (negative inside)."""
        points = np.asarray(points, dtype=np.float64)
        lo, hi = self._rectangles()
        unsigned = np.full(len(points), np.inf)
        for a, b in zip(lo, hi):
            unsigned = np.minimum(unsigned, np.linalg.norm(points - np.clip(points, a, b),
                                                           axis=1))
        block = box_distance(points, *self.bounds)
        inside = np.maximum(block, -box_distance(points, *self._pocket_box)) <= 0.0
        return np.where(inside, -unsigned, unsigned)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        lo, hi = self._rectangles()
        extent = np.sort(hi - lo, axis=1)
        area = extent[:, 1] * extent[:, 2]
        picks = rng.choice(len(area), size=n, p=area / area.sum())
        return lo[picks] + rng.random((n, 3)) * (hi[picks] - lo[picks])

    def mesh(self) -> trimesh.Trimesh:
        (a, b, h), (pa, pb, d) = self.size, self.pocket
        square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) / 2
        outer, inner = square * [a, b], square * [pa, pb]
        vertices = np.vstack([np.column_stack([outer, np.zeros(4)]),       # 0-3 bottom
                              np.column_stack([outer, np.full(4, h)]),     # 4-7 top
                              np.column_stack([inner, np.full(4, h)]),     # 8-11 pocket rim
                              np.column_stack([inner, np.full(4, h - d)])])  # 12-15 floor
        faces = [[0, 2, 1], [0, 3, 2], [12, 13, 14], [12, 14, 15]]
        for k in range(4):
            m = (k + 1) % 4
            faces += [[k, m, 4 + m], [k, 4 + m, 4 + k],                  # outer wall
                      [4 + k, 4 + m, 8 + m], [4 + k, 8 + m, 8 + k],      # top
                      [8 + k, 8 + m, 12 + m], [8 + k, 12 + m, 12 + k]]   # pocket wall
        mesh = trimesh.Trimesh(vertices, np.array(faces), process=False)
        return mesh if mesh.volume > 0 else trimesh.Trimesh(vertices, mesh.faces[:, ::-1],
                                                            process=False)
