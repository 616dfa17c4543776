"""Tests of the advancing-front triangulation and its edge-swap clean-up."""

from collections import defaultdict

import numpy as np
import pytest
from scipy.spatial import cKDTree

from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.meshing.advancing_front import advancing_front, estimate_normals
from sfs_ros.core.meshing.cloud import cloud_of_points
from sfs_ros.core.meshing.edge_swap import swap_edges

# A mesh whose vertices lie on a sphere is a polyhedron inscribed in it: star-shaped around the
# centre, its volume is at most the ball's. With ~1500 evenly spread points the missing caps
# over the faces take well under 2 % (measured 0.4 %), hence the one-sided band [0.98 V, V].
INSCRIBED_MIN_FRACTION = 0.98
# A torus is not convex (its inner side is concave), so the polyhedron can lie on both sides of
# the surface: two-sided 2 % (measured -0.8 % with 4000 points).
TORUS_REL_TOL = 0.02


def fibonacci_sphere(n, radius=1.0):
    """(n, 3) points evenly spread on a sphere and their outward unit normals."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azimuth = np.pi * (1.0 + 5.0 ** 0.5) * i
    normals = np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar),
                        np.cos(polar)], axis=1)
    return radius * normals, normals


def torus_sample(n, major=1.0, minor=0.4, seed=0):
    """(n, 3) points uniform by area on a torus around Z and their outward unit normals."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0, 2 * np.pi, 4 * n)
    v = rng.uniform(0, 2 * np.pi, 4 * n)
    keep = rng.uniform(0, 1, 4 * n) < (major + minor * np.cos(v)) / (major + minor)
    u, v = u[keep][:n], v[keep][:n]
    ring = major + minor * np.cos(v)
    points = np.stack([ring * np.cos(u), ring * np.sin(u), minor * np.sin(v)], axis=1)
    normals = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], axis=1)
    return points, normals


def edge_counts(faces):
    """Undirected edge -> number of faces; directed edge -> number of faces."""
    undirected, directed = defaultdict(int), defaultdict(int)
    for face in faces.tolist():
        for i in range(3):
            u, w = face[i], face[(i + 1) % 3]
            undirected[(min(u, w), max(u, w))] += 1
            directed[(u, w)] += 1
    return undirected, directed


def assert_closed_oriented_manifold(faces):
    """Every edge in two faces, used once in each direction, and one fan at every vertex."""
    undirected, directed = edge_counts(faces)
    assert set(undirected.values()) == {2}
    # Consistent orientation: the two faces at an edge use it in opposite directions.
    assert set(directed.values()) == {1}
    link = defaultdict(dict)
    for a, b, c in faces.tolist():
        link[a][b] = c
        link[b][c] = a
        link[c][a] = b
    for vertex, nxt in link.items():
        start = next(iter(nxt))
        walk, steps = nxt[start], 1
        while walk != start:
            walk, steps = nxt[walk], steps + 1
        assert steps == len(nxt), f"vertex {vertex} has more than one fan of faces"


def euler_characteristic(faces):
    undirected, _ = edge_counts(faces)
    return len(np.unique(faces)) - len(undirected) + len(faces)


def signed_volume(points, faces):
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def box_grid(resolution=40):
    grid = VoxelGrid.cube([-1.1] * 3, [1.1] * 3, resolution)
    return grid, np.meshgrid(*[grid.centers_axis(a) for a in range(3)], indexing="ij")


@pytest.mark.parametrize("with_normals", [True, False])
def test_fibonacci_sphere_gives_closed_inscribed_sphere(with_normals):
    points, normals = fibonacci_sphere(1500)
    result = advancing_front(points, normals if with_normals else None)
    faces = result.faces
    assert faces.dtype == np.int64 and faces.shape[1] == 3
    assert_closed_oriented_manifold(faces)
    assert euler_characteristic(faces) == 2
    volume = signed_volume(points, faces)
    ball = 4.0 / 3.0 * np.pi
    assert INSCRIBED_MIN_FRACTION * ball < volume <= ball
    stats = result.stats
    assert stats["closed"] and stats["n_front_edges_left"] == 0 and stats["n_holes_left"] == 0
    assert stats["n_nonmanifold_edges"] == 0 and stats["n_nonmanifold_vertices"] == 0
    assert stats["n_seeds"] == 1 and stats["n_faces"] == len(faces)
    # Euler: a closed sphere with V vertices has 2 V - 4 faces.
    assert len(faces) == 2 * stats["n_points_used"] - 4


def test_faces_point_along_the_normals():
    points, normals = fibonacci_sphere(800)
    faces = advancing_front(points, normals).faces
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    face_normal = np.cross(b - a, c - a)
    assert np.all(np.einsum("ij,ij->i", face_normal, (a + b + c) / 3.0) > 0)


def test_torus_has_euler_characteristic_zero():
    points, normals = torus_sample(3000)
    result = advancing_front(points, normals)
    assert_closed_oriented_manifold(result.faces)
    assert euler_characteristic(result.faces) == 0
    expected = 2.0 * np.pi ** 2 * 1.0 * 0.4 ** 2
    assert signed_volume(points, result.faces) == pytest.approx(expected, rel=TORUS_REL_TOL)


def test_two_components_get_two_seeds():
    points, normals = fibonacci_sphere(600)
    both = np.concatenate([points, 0.5 * points + (3.0, 0.0, 0.0)])
    result = advancing_front(both, np.concatenate([normals, normals]))
    assert result.stats["n_seeds"] == 2
    assert_closed_oriented_manifold(result.faces)
    assert euler_characteristic(result.faces) == 4


def test_voxel_sphere_cloud_closes():
    grid, (x, y, z) = box_grid(40)
    cloud = cloud_of_points(x ** 2 + y ** 2 + z ** 2 <= 1.0, grid, block=2)
    result = advancing_front(cloud.points, cloud.normals)
    assert_closed_oriented_manifold(result.faces)
    assert euler_characteristic(result.faces) == 2
    # Vertices are voxel centres inside the ball: the polyhedron is inside it (one-sided).
    assert 0 < signed_volume(cloud.points, result.faces) < 4.0 / 3.0 * np.pi


def test_voxel_cuboid_cloud_closes_to_the_box_of_voxel_centres():
    grid, (x, y, z) = box_grid(40)
    occupancy = (np.abs(x) < 0.8) & (np.abs(y) < 0.5) & (np.abs(z) < 0.3)
    cloud = cloud_of_points(occupancy, grid, block=1)
    result = advancing_front(cloud.points, cloud.normals)
    assert_closed_oriented_manifold(result.faces)
    assert euler_characteristic(result.faces) == 2
    # All points lie on the box spanned by the extreme voxel centres, so the polyhedron is
    # inside it (one-sided); flat sides are tiled exactly, only the twelve box edges may be
    # bevelled by at most half a voxel row: allow 3 %.
    box = np.prod(np.ptp(cloud.points, axis=0))
    volume = signed_volume(cloud.points, result.faces)
    assert 0.97 * box < volume <= box * (1 + 1e-9)


def test_voxel_torus_cloud_has_euler_characteristic_zero():
    grid, (x, y, z) = box_grid(48)
    occupancy = (np.hypot(x, y) - 0.6) ** 2 + z ** 2 <= 0.3 ** 2
    cloud = cloud_of_points(occupancy, grid, block=2)
    result = advancing_front(cloud.points, cloud.normals)
    assert_closed_oriented_manifold(result.faces)
    assert euler_characteristic(result.faces) == 0


def test_estimated_normals_point_outward_on_a_sphere():
    points, _ = fibonacci_sphere(500)
    knn = cKDTree(points).query(points, k=11)[1][:, 1:]
    normals = estimate_normals(points, knn)
    # PCA of 10 neighbours on a unit sphere sampled this densely is within a few degrees.
    assert np.all(np.einsum("ij,ij->i", normals, points) > np.cos(np.radians(10.0)))


def test_edge_swap_turns_a_bad_diagonal():
    # Unit-square-like quad squashed along y: diagonal 0-2 is long, 1-3 is the Delaunay one.
    points = np.array([[0.0, 0.0, 0.0], [1.0, -0.3, 0.0], [2.0, 0.0, 0.0], [1.0, 0.3, 0.0]])
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    # Vertices 0 and 2 would drop to one face each: the swap needs more faces around them.
    same, n_swaps = swap_edges(points, normals, faces)
    assert n_swaps == 0 and np.array_equal(same, faces)
    # Close the quad into a double-sided pillow around a far point below so degrees allow it.
    apex = np.array([[1.0, 0.0, -5.0]])
    pts = np.concatenate([points, apex])
    nrm = np.concatenate([normals, [[0.0, 0.0, 1.0]]])
    pillow = np.array([[0, 1, 2], [0, 2, 3], [1, 0, 4], [2, 1, 4], [3, 2, 4], [0, 3, 4]])
    swapped, n_swaps = swap_edges(pts, nrm, pillow)
    assert n_swaps == 1
    top = {tuple(sorted(f)) for f in swapped[:2].tolist()}
    assert top == {(0, 1, 3), (1, 2, 3)}
    assert_closed_oriented_manifold(swapped)


def test_bad_inputs_are_rejected():
    points, normals = fibonacci_sphere(50)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        advancing_front(points[:, :2])
    with pytest.raises(ValueError, match="normals"):
        advancing_front(points, normals[:-1])
    with pytest.raises(ValueError, match="k must"):
        advancing_front(points, normals, k=2)
    with pytest.raises(ValueError, match="duplicates"):
        advancing_front(np.concatenate([points, points[:1]]))
