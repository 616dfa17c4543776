"""Synthetic ground-truth objects with known geometry, resting on the turntable plate.

Each object is a union of analytic parts (:class:`Sphere`, :class:`Cylinder`,
:class:`Torus`, :class:`Box`) in the object frame (Z up, origin at the plate centre, metres).
Every object has ``z >= 0`` and fits in a 0.12 m box centred on the Z axis.

What each object offers:

* an exact inside test and an exact (closed-form or quadrature) volume,
* points sampled uniformly on the true outer surface (for Chamfer distances),
* a triangle mesh for rendering, outward-oriented, one closed mesh per part
  (the mesh of a union is the concatenation of its parts' meshes: silhouettes
  and z-buffered images of overlapping closed parts are those of the union),
* a smooth known colour pattern.

Meshes are inscribed (vertices on the true surface). ``mesh_error_m`` bounds the
distance between mesh and true surface: sphere 1.5e-5 m (20480 triangles), torus
4.4e-5 m (18432), mug 1.9e-5 m (25600), i.e. at most 0.19 px in a 512 px image
spanning 0.12 m (4267 px/m), which bounds the silhouette error.

Objects
-------
``sphere``
    Radius 0.05 m, touching the plate. Volume 4/3 pi r^3.
``torus``
    Lying flat on the plate, major radius 0.04 m, tube radius 0.015 m; its
    hole (radius 0.025 m) shows from above. Volume 2 pi^2 R r^2.
``mug``
    Solid cylinder body (radius 0.032 m, height 0.09 m) with a ring handle: a
    torus in the X-Z plane whose inner half lies inside the body. The handle's
    hole shows in side silhouettes (seen along Y), a concavity no convex hull
    has. Volume: body plus the part of the ring outside the body (quadrature).

The detailed object (:data:`DETAILED_OBJECT_NAMES`):

``chair``
    A detailed object, 70 x 56 x 115 mm: a seat 4 mm thick on four legs 3.5 mm square,
    a back with a hole (63 x 23 mm) through it, an antenna 1.2 mm square on the back, an
    open cup and a standing ring (its hole shows from the front) on the seat: thin
    parts, holes and concavities in silhouette. Its parts meet along faces or at a
    point only, so its volume is their sum.

Concave objects (:data:`CONCAVE_OBJECT_NAMES`), whose visual hull is not the object, and a
convex control, built from the parts of :mod:`.concave` (volumes exact):

``cup``
    Open cup: outer radius 40 mm, 90 mm tall, wall 5 mm, floor 12 mm (78 mm deep).
``bowl``
    Hemispherical shell: outer radius 50 mm, 5 mm thick, centre 49 mm above the plate,
    cut flat where it meets the plate (a foot of radius 9.9 mm; floor 4 mm).
``pocket_block``
    Block 80 x 60 x 50 mm with a blind pocket 50 x 30 mm, 35 mm deep, in its top.
``barrel``
    Convex solid of revolution (radius 30 mm at both ends, 40 mm at mid-height, 90 mm
    tall): its hull is itself, a control for methods that go below the hull.

Every object also has a solid colour texture (:meth:`SyntheticObject.texture_at`) to be
evaluated at the surface point each pixel sees (:func:`sfs_ros.core.render.render_image`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy import integrate

from .concave import PocketBlock, Revolved, box_distance, solid_texture

__all__ = ["Sphere", "Cylinder", "Torus", "Box", "SyntheticObject", "OBJECT_NAMES",
           "CONCAVE_OBJECT_NAMES", "DETAILED_OBJECT_NAMES", "ALL_OBJECT_NAMES", "fine_color_at",
           "make_object"]

#: The solid objects, those whose visual hull is (nearly) the object.
OBJECT_NAMES = ("sphere", "torus", "mug")
#: Objects with concavities no silhouette shows, and a convex textured control.
CONCAVE_OBJECT_NAMES = ("cup", "bowl", "pocket_block", "barrel")
#: Objects with thin parts, holes and many concavities in silhouette.
DETAILED_OBJECT_NAMES = ("chair",)
#: Names accepted by :func:`make_object`.
ALL_OBJECT_NAMES = OBJECT_NAMES + CONCAVE_OBJECT_NAMES + DETAILED_OBJECT_NAMES


def _as_points(points) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be an (n, 3) array, got shape {points.shape}")
    return points


def _rng(seed) -> np.random.Generator:
    return np.random.default_rng(seed)


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass(frozen=True)
class Sphere:
    """Solid ball: ``|p - center| <= radius`` (metres)."""

    center: tuple
    radius: float
    subdivisions: int = 5  # icosphere level: 20480 triangles

    @property
    def volume_m3(self) -> float:
        return 4.0 / 3.0 * math.pi * self.radius ** 3

    @property
    def area_m2(self) -> float:
        return 4.0 * math.pi * self.radius ** 2

    @property
    def bounds(self) -> np.ndarray:
        c = np.asarray(self.center, dtype=np.float64)
        return np.array([c - self.radius, c + self.radius])

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) exact signed distance to the sphere, metres (negative inside)."""
        return np.linalg.norm(points - np.asarray(self.center), axis=1) - self.radius

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return np.asarray(self.center) + self.radius * _unit_vectors(rng, n)

    def mesh(self) -> trimesh.Trimesh:
        m = trimesh.creation.icosphere(subdivisions=self.subdivisions, radius=self.radius)
        return trimesh.Trimesh(m.vertices + np.asarray(self.center), m.faces, process=False)


@dataclass(frozen=True)
class Cylinder:
    """Solid upright cylinder: ``x^2 + y^2 <= radius^2``, ``base_z <= z <= base_z + height``."""

    radius: float
    height: float
    base_z: float = 0.0
    sections: int = 256

    @property
    def volume_m3(self) -> float:
        return math.pi * self.radius ** 2 * self.height

    @property
    def area_m2(self) -> float:
        return 2.0 * math.pi * self.radius * (self.radius + self.height)

    @property
    def bounds(self) -> np.ndarray:
        r = self.radius
        return np.array([[-r, -r, self.base_z], [r, r, self.base_z + self.height]])

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) exact signed distance to the finite cylinder, metres (negative inside)."""
        half = 0.5 * self.height
        d_radial = np.hypot(points[:, 0], points[:, 1]) - self.radius
        d_axial = np.abs(points[:, 2] - (self.base_z + half)) - half
        outside = np.hypot(np.maximum(d_radial, 0.0), np.maximum(d_axial, 0.0))
        return outside + np.minimum(np.maximum(d_radial, d_axial), 0.0)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        r, h = self.radius, self.height
        on_side = rng.random(n) < (2.0 * math.pi * r * h) / self.area_m2
        angle = rng.uniform(0.0, 2.0 * math.pi, n)
        # side: radius r, uniform height; caps: uniform disc (radius r * sqrt(U)), top or bottom
        rho = np.where(on_side, r, r * np.sqrt(rng.random(n)))
        z = np.where(on_side, rng.uniform(0.0, h, n), h * (rng.random(n) < 0.5))
        return np.column_stack([rho * np.cos(angle), rho * np.sin(angle), self.base_z + z])

    def mesh(self) -> trimesh.Trimesh:
        n = self.sections
        a = 2.0 * math.pi * np.arange(n) / n
        ring = np.column_stack([self.radius * np.cos(a), self.radius * np.sin(a)])
        z0, z1 = self.base_z, self.base_z + self.height
        vertices = np.vstack([np.column_stack([ring, np.full(n, z0)]),
                              np.column_stack([ring, np.full(n, z1)]),
                              [[0.0, 0.0, z0], [0.0, 0.0, z1]]])
        i = np.arange(n)
        j = (i + 1) % n
        bottom_c, top_c = 2 * n, 2 * n + 1
        faces = np.vstack([
            np.column_stack([i, j, j + n]), np.column_stack([i, j + n, i + n]),  # side
            np.column_stack([np.full(n, bottom_c), j, i]),                       # bottom, normal -Z
            np.column_stack([np.full(n, top_c), i + n, j + n]),                  # top, normal +Z
        ])
        return trimesh.Trimesh(vertices, faces, process=False)


@dataclass(frozen=True, eq=False)
class Torus:
    """Solid torus: tube of radius ``minor_radius`` around a circle of radius ``major_radius``.

    ``rotation`` (3, 3) maps the torus frame (symmetry axis = local Z) to the
    object frame; ``center`` is the centre of the ring, metres.
    """

    center: tuple
    major_radius: float
    minor_radius: float
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    major_sections: int = 192
    minor_sections: int = 48

    def __post_init__(self) -> None:
        rotation = np.array(self.rotation, dtype=np.float64)
        if rotation.shape != (3, 3) or not np.allclose(rotation @ rotation.T, np.eye(3)) \
                or np.linalg.det(rotation) < 0:
            raise ValueError("torus rotation must be a (3, 3) rotation matrix (orthonormal, det +1)")
        rotation.setflags(write=False)
        object.__setattr__(self, "rotation", rotation)

    @property
    def volume_m3(self) -> float:
        return 2.0 * math.pi ** 2 * self.major_radius * self.minor_radius ** 2

    @property
    def area_m2(self) -> float:
        return 4.0 * math.pi ** 2 * self.major_radius * self.minor_radius

    @property
    def bounds(self) -> np.ndarray:
        axis = np.asarray(self.rotation)[:, 2]
        half = self.major_radius * np.sqrt(np.clip(1.0 - axis ** 2, 0.0, 1.0)) + self.minor_radius
        c = np.asarray(self.center, dtype=np.float64)
        return np.array([c - half, c + half])

    def _local(self, points: np.ndarray) -> np.ndarray:
        return (points - np.asarray(self.center)) @ np.asarray(self.rotation)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) exact signed distance to the torus, metres (negative inside)."""
        q = self._local(points)
        return np.hypot(np.hypot(q[:, 0], q[:, 1]) - self.major_radius, q[:, 2]) - self.minor_radius

    def _to_world(self, alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
        rho = self.major_radius + self.minor_radius * np.cos(beta)
        local = np.column_stack([rho * np.cos(alpha), rho * np.sin(alpha),
                                 self.minor_radius * np.sin(beta)])
        return local @ np.asarray(self.rotation).T + np.asarray(self.center)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        # Area element r (R + r cos beta) dalpha dbeta: rejection-sample beta.
        R, r = self.major_radius, self.minor_radius
        betas = np.empty(0)
        while betas.size < n:
            beta = rng.uniform(0.0, 2.0 * math.pi, 2 * n)
            keep = rng.random(2 * n) * (R + r) <= R + r * np.cos(beta)
            betas = np.concatenate([betas, beta[keep]])
        return self._to_world(rng.uniform(0.0, 2.0 * math.pi, n), betas[:n])

    def mesh(self) -> trimesh.Trimesh:
        na, nb = self.major_sections, self.minor_sections
        alpha, beta = np.meshgrid(2.0 * math.pi * np.arange(na) / na,
                                  2.0 * math.pi * np.arange(nb) / nb, indexing="ij")
        vertices = self._to_world(alpha.ravel(), beta.ravel())
        i, j = np.meshgrid(np.arange(na), np.arange(nb), indexing="ij")
        v00 = (i * nb + j).ravel()
        v10 = (((i + 1) % na) * nb + j).ravel()
        v01 = (i * nb + (j + 1) % nb).ravel()
        v11 = (((i + 1) % na) * nb + (j + 1) % nb).ravel()
        faces = np.vstack([np.column_stack([v00, v10, v11]), np.column_stack([v00, v11, v01])])
        return trimesh.Trimesh(vertices, faces, process=False)


@dataclass(frozen=True)
class Box:
    """Solid axis-aligned box ``lo <= p <= hi`` (metres, each a 3-tuple)."""

    lo: tuple
    hi: tuple

    def __post_init__(self) -> None:
        if not all(a < b for a, b in zip(self.lo, self.hi)):
            raise ValueError(f"a box needs lo < hi on every axis, got {self.lo} and {self.hi}")

    @property
    def _extent(self) -> np.ndarray:
        return np.asarray(self.hi, dtype=np.float64) - np.asarray(self.lo, dtype=np.float64)

    @property
    def volume_m3(self) -> float:
        return float(np.prod(self._extent))

    @property
    def area_m2(self) -> float:
        a, b, c = self._extent
        return float(2.0 * (a * b + b * c + c * a))

    @property
    def bounds(self) -> np.ndarray:
        return np.array([self.lo, self.hi], dtype=np.float64)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) exact signed distance to the box, metres (negative inside)."""
        return box_distance(points, self.lo, self.hi)

    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        # A face is picked by its area, then a point uniformly on it: every coordinate
        # uniform in the box but the face's axis, pinned to its side.
        extent = self._extent
        areas = np.array([extent[1] * extent[2], extent[0] * extent[2], extent[0] * extent[1]])
        axis = rng.choice(3, size=n, p=areas / areas.sum())
        points = np.asarray(self.lo) + rng.random((n, 3)) * extent
        side = rng.random(n) < 0.5
        rows = np.arange(n)
        points[rows, axis] = np.where(side, np.asarray(self.hi)[axis], np.asarray(self.lo)[axis])
        return points

    def mesh(self) -> trimesh.Trimesh:
        centre = 0.5 * (np.asarray(self.lo, dtype=np.float64) + np.asarray(self.hi))
        return trimesh.creation.box(extents=self._extent,
                                    transform=trimesh.transformations.translation_matrix(centre))


def _mesh_error(part, mesh: trimesh.Trimesh) -> float:
    """Largest |signed distance| of a part's mesh from the part's surface, metres.

    Evaluated on a barycentric lattice of step 1/4 on every face (15 points). The
    deviation of a small flat facet from a smooth surface is close to quadratic
    with its peak inside the facet, and the lattice comes within 1/8 of an edge of
    that peak, so it underestimates the maximum by under 5 %; 10 % is added.
    """
    steps = np.array([(a, b, 4 - a - b) for a in range(5) for b in range(5 - a)], float) / 4.0
    tri = mesh.vertices[mesh.faces]                                   # (m, 3, 3)
    pts = np.einsum("lk,mkd->mld", steps, tri).reshape(-1, 3)
    return 1.1 * float(np.max(np.abs(part.signed_distance(pts))))


class SyntheticObject:
    """A union of analytic parts with exact inside test, volume, surface samples and a mesh.

    Attributes
    ----------
    name : str
    parts : tuple of Sphere | Cylinder | Torus | Revolved | PocketBlock
    volume_m3 : float
        Exact volume of the union, cubic metres.
    bounds : (2, 3) float64
        Axis-aligned box ``[min, max]`` containing the object, metres.
    mesh : trimesh.Trimesh
        Rendering mesh: concatenation of the parts' closed, outward meshes.
    mesh_error_m : float
        Bound on the distance between ``mesh`` and the true surface, metres.
    """

    def __init__(self, name: str, parts, volume_m3: float):
        self.name = name
        self.parts = tuple(parts)
        self.volume_m3 = float(volume_m3)
        boxes = np.array([p.bounds for p in self.parts])
        self.bounds = np.array([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])
        meshes = [p.mesh() for p in self.parts]
        self.mesh_error_m = max(_mesh_error(p, m) for p, m in zip(self.parts, meshes))
        self.mesh = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]

    def __repr__(self) -> str:
        return f"SyntheticObject({self.name!r}, volume_m3={self.volume_m3:.6g})"

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) minimum over the parts of their exact signed distances, metres.

        Positive outside: there it is the exact distance to the object. Negative
        inside: its magnitude is a lower bound on the depth (exact for one part).
        """
        points = _as_points(points)
        return np.min([p.signed_distance(points) for p in self.parts], axis=0)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: which points ``(n, 3)`` (metres) lie inside the object (surface included)."""
        return self.signed_distance(points) <= 0.0

    def sample_surface(self, n: int, *, seed=None) -> np.ndarray:
        """(n, 3) float64 points uniformly distributed on the true outer surface, metres.

        Each part's surface is sampled in proportion to its area and samples
        lying inside another part are dropped, which leaves the union's surface.
        """
        if int(n) < 0:
            raise ValueError(f"number of surface samples must be >= 0, got {n}")
        n = int(n)
        rng = _rng(seed)
        areas = np.array([p.area_m2 for p in self.parts])
        kept, total = [], 0
        while total < n:
            counts = rng.multinomial(n, areas / areas.sum())
            for k, (part, count) in enumerate(zip(self.parts, counts)):
                pts = part.sample_surface(int(count), rng)
                inside_other = np.zeros(len(pts), dtype=bool)
                for other in self.parts[:k] + self.parts[k + 1:]:
                    # Within a nanometre: where two parts meet along a face, that face is
                    # inside the union (its points lie on both parts, up to rounding).
                    inside_other |= other.signed_distance(pts) < 1e-9
                kept.append(pts[~inside_other])
                total += int(np.count_nonzero(~inside_other))
        return np.concatenate(kept)[:n] if kept else np.empty((0, 3))

    def texture_at(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) uint8 RGB of the object's solid texture at points ``(n, 3)``, metres
        (:func:`.concave.solid_texture`: a colour per 2.5 mm lattice cell)."""
        return solid_texture(_as_points(points))

    def color_at(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) uint8 RGB of the object's colour pattern at points ``(n, 3)``, metres.

        Smooth by construction: red and green are sine stripes of wavelength
        0.06 m along X and Y, blue a vertical gradient over the object's height.
        Every channel stays in [30, 200] (never white, never black).
        """
        points = _as_points(points)
        wavelength_m = 0.06
        lo, hi = self.bounds[0, 2], self.bounds[1, 2]
        red = 0.5 + 0.5 * np.sin(2.0 * math.pi * points[:, 0] / wavelength_m)
        green = 0.5 + 0.5 * np.sin(2.0 * math.pi * points[:, 1] / wavelength_m + 1.0)
        blue = np.clip((points[:, 2] - lo) / (hi - lo), 0.0, 1.0)
        rgb = 30.0 + 170.0 * np.column_stack([red, green, blue])
        return np.round(rgb).astype(np.uint8)


def fine_color_at(points: np.ndarray, *, period_m: float = 0.005) -> np.ndarray:
    """(n, 3) float64 RGB in [30, 200] of a fine 3-D pattern at points ``(n, 3)``, metres:
    each channel a sine of period ``period_m`` along one axis (red X, green Y, blue Z),
    phases apart. Finer than a reconstruction's faces, coarser than the pixels of a
    scan's views: detail only a texture keeps.
    """
    points = _as_points(points)
    phase = 2.0 * math.pi * points / period_m + np.array([0.0, 1.0, 2.0])
    return 30.0 + 170.0 * (0.5 + 0.5 * np.sin(phase))


def _ring_outside_cylinder_m3(body: Cylinder, ring: Torus) -> float:
    """Volume of a ring lying in the X-Z plane (axis along Y) outside an upright body.

    In ring polar coordinates (rho, alpha) about the ring centre ``(x0, 0, zc)``,
    the tube spans ``|y| <= w(rho) = sqrt(r^2 - (rho - R)^2)`` and the body spans
    ``|y| <= a(x) = sqrt(Rc^2 - x^2)`` (the ring stays within the body's height),
    both centred on y = 0, so the part outside the body is
    ``integral 2 max(0, w - a) rho drho dalpha``, evaluated by adaptive quadrature
    split at the kinks (relative error ~1e-10).
    """
    x0 = float(ring.center[0])
    R, r, Rc = ring.major_radius, ring.minor_radius, body.radius

    def over_alpha(rho: float) -> float:
        w = math.sqrt(max(0.0, r * r - (rho - R) ** 2))
        x_start = math.sqrt(max(0.0, Rc * Rc - w * w))  # body thinner than tube beyond here
        c = (x_start - x0) / rho
        if c >= 1.0:
            return 0.0
        alpha_end = math.acos(max(-1.0, c))

        def integrand(alpha: float) -> float:
            x = x0 + rho * math.cos(alpha)
            return 2.0 * (w - math.sqrt(max(0.0, Rc * Rc - x * x))) * rho

        kink = [math.acos((Rc - x0) / rho)] if -1.0 < (Rc - x0) / rho < 1.0 else []
        kink = [k for k in kink if 0.0 < k < alpha_end]
        value, _ = integrate.quad(integrand, 0.0, alpha_end, points=kink or None,
                                  epsabs=0.0, epsrel=1e-11, limit=200)
        return 2.0 * value  # alpha and -alpha

    value, _ = integrate.quad(over_alpha, R - r, R + r, epsabs=0.0, epsrel=1e-10, limit=200)
    return value


def _ring_rotation_y() -> np.ndarray:
    """Rotation taking the torus axis (local Z) to -Y: local X -> X, local Y -> Z."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _arc(centre_z: float, radius: float, start_z: float, end_z: float,
         segments: int) -> list:
    """(segments + 1) profile points ``(r, z)`` on the circle of ``radius`` about
    ``(0, centre_z)`` from height ``start_z`` to ``end_z`` (r >= 0), metres."""
    a0, a1 = (math.asin(np.clip((z - centre_z) / radius, -1.0, 1.0)) for z in (start_z, end_z))
    return [(abs(radius * math.cos(a)), centre_z + radius * math.sin(a))
            for a in np.linspace(a0, a1, segments + 1)]


def _concave_object(name: str) -> SyntheticObject:
    """The object of :data:`CONCAVE_OBJECT_NAMES` called ``name``."""
    if name == "cup":
        part = Revolved(((0, 0), (0.04, 0), (0.04, 0.09), (0.035, 0.09), (0.035, 0.012),
                         (0, 0.012)))
    elif name == "bowl":
        outer = _arc(0.049, 0.05, 0.0, 0.049, 64)
        inner = _arc(0.049, 0.045, 0.049, 0.004, 64)
        part = Revolved(((0, 0), *outer, *inner[:-1], (0, 0.004)))
    elif name == "pocket_block":
        part = PocketBlock((0.08, 0.06, 0.05), (0.05, 0.03, 0.035))
    else:
        heights = np.linspace(0.0, 0.09, 49)
        part = Revolved(((0, 0), *[(0.03 + 0.01 * math.sin(math.pi * z / 0.09), z)
                                   for z in heights], (0, 0.09)))
    return SyntheticObject(name, [part], part.volume_m3)


def _chair() -> SyntheticObject:
    """The ``chair`` of the module's docstring: boxes, an open cup and a ring that meet
    along faces or at a point (millimetres below, metres returned)."""
    def box(lo, hi):
        return Box(tuple(1e-3 * np.asarray(lo, float)), tuple(1e-3 * np.asarray(hi, float)))

    seat_z, top_z = 35.0, 39.0
    parts = [box((-35, -28, seat_z), (35, 28, top_z))]
    for x in (-35.0, 31.5):
        for y in (-28.0, 24.5):
            parts.append(box((x, y, 0), (x + 3.5, y + 3.5, seat_z)))          # legs
        parts.append(box((x, 24.5, top_z), (x + 3.5, 28, 90)))                # back posts
    parts += [box((-31.5, 24.5, top_z), (31.5, 28, 55)),                      # back panel
              box((-31.5, 24.5, 78), (31.5, 28, 90)),                          # top rail
              box((19.4, 25.6, 90), (20.6, 26.8, 115))]                        # antenna
    cup = Revolved(tuple((1e-3 * r, 1e-3 * z) for r, z in
                         ((0, top_z), (9, top_z), (9, top_z + 18), (7.5, top_z + 18),
                          (7.5, top_z + 2), (0, top_z + 2))))
    # A ring standing on the seat in the X-Z plane (its hole seen from the front),
    # touching the seat at its lowest point.
    ring = Torus((-0.022, -0.01, 1e-3 * (top_z + 8.5)), 0.007, 0.0015,
                 rotation=_ring_rotation_y(), major_sections=128, minor_sections=24)
    parts += [cup, ring]
    return SyntheticObject("chair", parts, sum(p.volume_m3 for p in parts))


def make_object(name: str) -> SyntheticObject:
    """The synthetic object called ``name`` (one of :data:`ALL_OBJECT_NAMES`)."""
    if name in CONCAVE_OBJECT_NAMES:
        return _concave_object(name)
    if name == "sphere":
        radius = 0.05
        return SyntheticObject(name, [Sphere((0.0, 0.0, radius), radius)],
                               4.0 / 3.0 * math.pi * radius ** 3)
    if name == "torus":
        R, r = 0.04, 0.015
        return SyntheticObject(name, [Torus((0.0, 0.0, r), R, r)], 2.0 * math.pi ** 2 * R * r ** 2)
    if name == "mug":
        body = Cylinder(radius=0.032, height=0.09)
        # Ring centre 5 mm inside the wall: its inner half (x <= 0.027 m, |y| <= 7 mm,
        # x >= -2 mm) lies inside the body, so only the outer arc shows as a handle.
        ring = Torus((0.027, 0.0, 0.045), 0.022, 0.007, rotation=_ring_rotation_y(),
                     major_sections=256, minor_sections=48)
        volume = body.volume_m3 + _ring_outside_cylinder_m3(body, ring)
        return SyntheticObject(name, [body, ring], volume)
    if name == "chair":
        return _chair()
    raise ValueError(f"unknown object {name!r}; expected one of {ALL_OBJECT_NAMES}")
