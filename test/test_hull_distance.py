"""Signed distance to the visual hull, and the meshes made on its zero level.

References: half-plane silhouettes (the distance is linear in closed form) and
exact silhouettes of a sphere seen by orthographic cameras from all around,
whose visual hull has a closed form: in the direction ``u`` from the centre it
reaches ``r / sqrt(1 - min_i (u . d_i)^2)`` (the cylinder of view ``d_i``
tangent to the sphere, the one nearest ``u`` binding).
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sfs_ros.core.carving.carve import carve
from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.meshing.advancing_front import advancing_front
from sfs_ros.core.meshing.cloud import cloud_of_points
from sfs_ros.core.meshing.hull_distance import DistanceImages, HullDistance, _groups
from sfs_ros.core.meshing.marching import (
    FoundBand,
    band_marching_cubes,
    hull_band_distance,
    hull_marching_cubes_mesh,
    marching_cubes_mesh,
)
from sfs_ros.core.meshing.mesh_checks import check_mesh

from analytic_masks import sphere_mask

WIDTH, HEIGHT = 200, 160
FOCAL_PX = 500.0


def looking_along(direction, *, orthographic, scale, width, height, distance_m=0.5):
    """Camera at ``-distance_m * direction`` looking along ``direction`` at the origin."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, d)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(d, x), d])
    K = [[scale, 0.0, (width - 1) / 2], [0.0, scale, (height - 1) / 2], [0.0, 0.0, 1.0]]
    return Camera(K=K, R=R, t=[0.0, 0.0, distance_m], width=width, height=height,
                  orthographic=orthographic)


def half_plane(camera, last_column):
    """(H, W) bool mask of the columns ``0..last_column``: its edge is at u = last_column + 1/2."""
    mask = np.zeros((camera.height, camera.width), bool)
    mask[:, :last_column + 1] = True
    return mask


def points_near_column(camera, u_values, rng):
    """World points projecting to columns ``u_values`` on random rows, at random depths."""
    n = len(u_values)
    v = rng.uniform(20, camera.height - 20, n)
    depth = rng.uniform(0.4, 0.6, n)
    K = camera.K
    if camera.orthographic:
        xc = np.column_stack([(u_values - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], depth])
    else:
        xc = np.column_stack([(u_values - K[0, 2]) / K[0, 0] * depth,
                              (v - K[1, 2]) / K[1, 1] * depth, depth])
    return (xc - camera.t) @ camera.R


@pytest.mark.parametrize("orthographic", [False, True])
def test_half_plane_distance_is_the_distance_to_its_back_projection(orthographic):
    rng = np.random.default_rng(3)
    # Orthographic scale in pixels per metre, so that a pixel is a millimetre or so.
    camera = looking_along([0.3, 1.0, -0.2], orthographic=orthographic,
                           scale=FOCAL_PX if not orthographic else 1000.0,
                           width=WIDTH, height=HEIGHT)
    hull = HullDistance([camera], [half_plane(camera, 90)])
    # Within the stored crop (CROP_MARGIN_PX = 8 columns beyond the last
    # foreground one) the distance is exact; the edge is at u = 90.5.
    u = rng.uniform(75.0, 98.0, 500)
    points = points_near_column(camera, u, rng)

    def metres_per_px(points):
        """depth / f (pinhole), 1 / scale (orthographic)."""
        return np.full(len(points), 1e-3) if orthographic else camera.depth(points) / FOCAL_PX

    # Along a straight edge the distance image is exactly linear across rows;
    # float32 storage of pixel distances (< 16 px) leaves ~1e-6 px.
    scale = metres_per_px(points)
    np.testing.assert_allclose(hull(points), (u - 90.5) * scale, rtol=0, atol=1e-5 * scale.max())
    # Beyond the crop: a lower bound of the distance, never below the margin
    # (8 px from the last crop column to the edge at its foreground's side, 7.5 px).
    u_far = rng.uniform(99.0, 190.0, 200)
    far = points_near_column(camera, u_far, rng)
    value_px = hull(far) / metres_per_px(far)
    assert np.all(value_px <= u_far - 90.5 + 1e-6) and np.all(value_px >= 7.5)


def test_views_intersect_and_misses_are_tolerated():
    rng = np.random.default_rng(4)
    cameras = [looking_along(d, orthographic=True, scale=1000.0, width=WIDTH, height=HEIGHT)
               for d in ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.5])]
    masks = [half_plane(c, col) for c, col in zip(cameras, (95, 100, 105))]
    points = rng.uniform(-0.02, 0.02, (300, 3))
    each = np.stack([HullDistance([c], [m])(points) for c, m in zip(cameras, masks)], axis=1)
    # Inside the hull = inside every silhouette: the largest view value ...
    np.testing.assert_array_equal(HullDistance(cameras, masks)(points), each.max(axis=1))
    # ... and with one miss allowed, the second largest (as the carver counts misses).
    np.testing.assert_array_equal(HullDistance(cameras, masks, max_misses=1)(points),
                                  np.sort(each, axis=1)[:, -2])
    # Allowing every view to miss leaves only the box: its signed distance.
    box = np.array([[-0.01, -0.02, -0.03], [0.01, 0.02, 0.03]])
    only_box = HullDistance(cameras, masks, max_misses=3, bounds_m=box)(points)
    np.testing.assert_allclose(only_box, np.max(np.maximum(box[0] - points, points - box[1]),
                                                axis=1))


def test_a_view_that_does_not_see_a_point_does_not_decide_it():
    camera = looking_along([0.0, 1.0, 0.0], orthographic=True, scale=1000.0,
                           width=WIDTH, height=HEIGHT)
    hull = HullDistance([camera], [half_plane(camera, 90)], bounds_m=[[-1, -1, -1], [1, 1, 1]])
    # The image spans +-0.1 m across: a point 0.5 m to the side projects outside it.
    far = camera.center + 0.5 * camera.R[0]
    beyond = camera.center - 0.5 * camera.R[0]
    values = hull(np.stack([far, beyond]))
    # Only the box (1 m around) bounds such points: minus their depth inside it.
    np.testing.assert_allclose(values, np.max(np.abs(np.stack([far, beyond])), axis=1) - 1.0)


def test_bad_input_is_refused():
    camera = looking_along([1.0, 0.0, 0.0], orthographic=True, scale=1000.0,
                           width=WIDTH, height=HEIGHT)
    mask = half_plane(camera, 50)
    with pytest.raises(ValueError, match="mask of view 0 has shape"):
        HullDistance([camera], [mask[:-1]])
    with pytest.raises(ValueError, match="view 0: a mask is empty"):
        HullDistance([camera], [np.zeros_like(mask)])
    with pytest.raises(ValueError, match="max_misses must be an integer >= 0"):
        HullDistance([camera], [mask], max_misses=-1)
    with pytest.raises(ValueError, match="bounds_m must be"):
        HullDistance([camera], [mask], bounds_m=[[0, 0, 0], [1, -1, 1]])
    with pytest.raises(ValueError, match="at least one camera"):
        HullDistance([], [])
    hull = HullDistance([camera], [mask])
    with pytest.raises(ValueError, match=r"points must be an \(n, 3\) array"):
        hull(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="directions must be finite and non-zero"):
        hull.project(np.zeros((1, 3)), np.zeros((1, 3)), reach_m=0.01)
    grid = VoxelGrid.cube([-0.01] * 3, [0.01] * 3, 8)
    with pytest.raises(ValueError, match="occupancy is empty"):
        hull_marching_cubes_mesh(np.zeros(grid.shape, bool), grid, hull)
    with pytest.raises(ValueError, match="does not match the grid shape"):
        hull_marching_cubes_mesh(np.ones((4, 4, 4), bool), grid, hull)
    with pytest.raises(ValueError, match="band_voxels must be an integer >= 1"):
        hull_marching_cubes_mesh(np.ones(grid.shape, bool), grid, hull, band_voxels=0)


# ---- a sphere seen from all around ----------------------------------------------------

SPHERE_RADIUS_M = 0.03
SPHERE_CENTRE_M = np.array([0.0, 0.0, 0.0])
#: Orthographic image scale (pixels per metre): a pixel is 0.17 mm, 0.11 of the voxel below.
SPHERE_SCALE = 6000.0
SPHERE_IMAGE = 400
SPHERE_VIEWS = 60


def fibonacci_directions(n):
    """(n, 3) unit vectors spread evenly over the sphere."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    a = np.pi * (1.0 + 5 ** 0.5) * k
    s = np.sqrt(1.0 - z * z)
    return np.column_stack([s * np.cos(a), s * np.sin(a), z])


@pytest.fixture(scope="module")
def sphere_scan():
    directions = fibonacci_directions(SPHERE_VIEWS)
    cameras = [looking_along(d, orthographic=True, scale=SPHERE_SCALE, width=SPHERE_IMAGE,
                             height=SPHERE_IMAGE) for d in directions]
    masks = [sphere_mask(c, SPHERE_CENTRE_M, SPHERE_RADIUS_M) for c in cameras]
    grid = VoxelGrid.cube(SPHERE_CENTRE_M - 0.035, SPHERE_CENTRE_M + 0.035, 48)
    occupancy = carve(grid, cameras, masks)
    hull = HullDistance(cameras, masks, bounds_m=(grid.bounds_min, grid.bounds_max))
    return directions, grid, occupancy, hull


def hull_radius_error(points, directions):
    """(n,) radial distance (metres) of ``points`` from the exact visual hull of the sphere."""
    offset = points - SPHERE_CENTRE_M
    radius = np.linalg.norm(offset, axis=1)
    cosine = np.min(np.abs((offset / radius[:, None]) @ directions.T), axis=1)
    return radius - SPHERE_RADIUS_M / np.sqrt(1.0 - cosine ** 2)


#: The masks are exact at pixel centres, so the silhouette edge they define lies
#: within half a pixel diagonal (0.71 px) of the true circle; the hull's surface,
#: hence any vertex on it, lies that close to the exact hull (0.12 mm = 0.08 voxel).
PIXEL_BOUND_M = 0.71 / SPHERE_SCALE


def test_sphere_marching_cubes_lies_on_the_hull(sphere_scan):
    directions, grid, occupancy, hull = sphere_scan
    vertices, faces = hull_marching_cubes_mesh(occupancy, grid, hull)
    report = check_mesh(vertices, faces)
    assert report.watertight and report.vertex_manifold and report.outward is True
    assert report.n_components == 1 and report.genus == 0
    assert report.degenerate_faces == 0 and report.duplicate_faces == 0
    error = hull_radius_error(vertices, directions)
    # Linear interpolation between voxel centres of a distance whose level sets
    # curve with radius 30 mm errs by about h^2 / (8 r) = 0.009 mm; with the
    # pixel bound this is 0.13 mm (0.09 voxel). Measured: max 0.08 mm, rms
    # 0.03 mm; the 0/1 occupancy mesher (sigma 0.5) on the same hull: max
    # 0.66 mm (0.46 voxel), rms 0.25 mm.
    assert np.max(np.abs(error)) <= PIXEL_BOUND_M + grid.voxel_size ** 2 / (8 * SPHERE_RADIUS_M)
    old_vertices, _ = marching_cubes_mesh(occupancy, grid)
    old_error = hull_radius_error(old_vertices, directions)
    # The reason for the distance: several times closer than the staircase mesh.
    assert np.sqrt(np.mean(error ** 2)) <= 0.25 * np.sqrt(np.mean(old_error ** 2))


def test_sphere_cloud_moved_onto_the_hull(sphere_scan):
    directions, grid, occupancy, hull = sphere_scan
    cloud = cloud_of_points(occupancy, grid, block=2)
    before = hull_radius_error(cloud.points, directions)
    points, found = hull.project(cloud.points, cloud.normals, reach_m=2 * grid.voxel_size)
    assert found.all()
    # Bisection leaves the points within (2 voxels / 4) / 2^20 = 5e-7 voxel of the
    # zero level, where the distance changes by at most about as much.
    assert np.max(np.abs(hull(points))) <= 1e-5 * grid.voxel_size
    error = hull_radius_error(points, directions)
    # Surface voxel centres sit inside the surface by up to a voxel (measured:
    # mean -0.45 voxel, max 1.5 mm off); moved along the normals they lie on
    # the hull within the pixel bound (measured max 0.08 mm, rms 0.04 mm).
    assert np.mean(before) < -0.3 * grid.voxel_size
    assert np.max(np.abs(error)) <= PIXEL_BOUND_M
    result = advancing_front(points, cloud.normals)
    assert result.stats["closed"]
    report = check_mesh(points, result.faces)
    assert report.watertight and report.outward is True and report.genus == 0


# ---- a floor: the values the meshers clip anyway, spared ---------------------------------

def pinhole_sphere_views(n=12):
    """``n`` pinhole cameras 0.5 m from the sphere, all around it, and its exact masks."""
    cameras = [looking_along(d, orthographic=False, scale=FOCAL_PX, width=WIDTH, height=HEIGHT)
               for d in fibonacci_directions(n)]
    return cameras, [sphere_mask(c, SPHERE_CENTRE_M, SPHERE_RADIUS_M) for c in cameras]


@pytest.mark.parametrize("max_misses", [0, 1])
@pytest.mark.parametrize("floor_voxels", [0.5, 2.0, 6.0])
def test_a_floor_raises_the_deeper_values_to_it_and_changes_nothing_else(
        sphere_scan, max_misses, floor_voxels):
    rng = np.random.default_rng(9)
    _, grid, _, orthographic = sphere_scan
    cameras, masks = pinhole_sphere_views()
    pinhole = HullDistance(cameras, masks, max_misses=max_misses,
                           bounds_m=(grid.bounds_min, grid.bounds_max))
    # Every voxel centre of the grid (deep inside, across the surface, far outside,
    # beyond the box) and scattered points, some behind no camera's image.
    points = np.concatenate([grid.index_to_world(np.argwhere(np.ones(grid.shape, bool))),
                             rng.uniform(-0.3, 0.3, (2000, 3))])
    floor = -floor_voxels * grid.voxel_size
    for hull in (orthographic, pinhole):
        # Exactly: the views left out are those that could only give values below the floor.
        np.testing.assert_array_equal(hull(points, floor_m=floor),
                                      np.maximum(hull(points), floor))


def test_a_view_is_left_out_only_where_all_its_values_are_below_the_floor():
    from sfs_ros.core.meshing.hull_distance import _below_floor

    rng = np.random.default_rng(10)
    cameras, masks = pinhole_sphere_views()
    hull = HullDistance(cameras, masks)
    singles = [HullDistance([c], [m]) for c, m in zip(cameras, masks)]
    floor = -0.001
    left_out = 0
    for _ in range(300):
        centre = rng.normal(0.0, 0.6 * SPHERE_RADIUS_M, 3)
        half = rng.uniform(0.0005, 0.006, 3)
        lo, hi = centre - half, centre + half
        inside = rng.uniform(lo, hi, (400, 3))
        for v, single in enumerate(singles):
            if _below_floor(hull._kernel_data, v, lo, hi, floor):
                left_out += 1
                assert single(inside).max() < floor
    # Boxes deep inside the sphere are left out by most views; the test is not vacuous.
    assert left_out > 300


def test_a_floor_must_be_a_negative_distance():
    camera = looking_along([1.0, 0.0, 0.0], orthographic=True, scale=1000.0,
                           width=WIDTH, height=HEIGHT)
    hull = HullDistance([camera], [half_plane(camera, 50)])
    for floor in (0.0, 0.001, float("nan"), float("-inf")):
        with pytest.raises(ValueError, match="floor_m must be a finite distance < 0 metres"):
            hull(np.zeros((1, 3)), floor_m=floor)
    assert hull(np.zeros((0, 3)), floor_m=-0.001).shape == (0,)


def test_distance_images_given_beforehand_give_the_same_hull():
    """A live scan computes each mask's distance image as it arrives: the hull made with
    them is the hull made without, bit for bit, and a mask that changed since (here one
    with a hole punched) is computed anew rather than taken for the one kept."""
    cameras = [looking_along(d, orthographic=True, scale=SPHERE_SCALE, width=SPHERE_IMAGE,
                             height=SPHERE_IMAGE) for d in fibonacci_directions(SPHERE_VIEWS)]
    # Off the cameras' common centre the sphere's disc lies elsewhere in every view.
    centre = SPHERE_CENTRE_M + [0.004, -0.003, 0.002]
    masks = [sphere_mask(c, centre, SPHERE_RADIUS_M) for c in cameras]
    known = DistanceImages()
    for mask in masks:
        known.add(mask.copy())        # the same pixels in another array: found by content
    known.add(masks[0])               # a mask given twice is kept once
    assert len(known) == SPHERE_VIEWS
    assert known.get(masks[5]) is known.get(masks[5].copy())   # found, not computed again
    box = (centre - 0.035, centre + 0.035)
    points = np.random.default_rng(3).uniform(box[0], box[1], (4000, 3))
    expected = HullDistance(cameras, masks, bounds_m=box)(points)
    assert np.array_equal(HullDistance(cameras, masks, bounds_m=box, known=known)(points),
                          expected)

    punched = [m.copy() for m in masks]
    rows, cols = np.nonzero(punched[0])
    middle = int(rows.mean()), int(cols.mean())
    punched[0][middle[0] - 20:middle[0] + 20, middle[1] - 20:middle[1] + 20] = False
    punched_expected = HullDistance(cameras, punched, bounds_m=box)(points)
    assert np.array_equal(HullDistance(cameras, punched, bounds_m=box, known=known)(points),
                          punched_expected)
    assert not np.array_equal(punched_expected, expected)   # the hole is seen: can fail
    with pytest.raises(ValueError, match="empty"):
        known.add(np.zeros((SPHERE_IMAGE, SPHERE_IMAGE), bool))


def disk_coverage(width, height, centre_uv, radius_px, samples=16):
    """(H, W) float32: the fraction of each pixel (centres on integers) inside the disk,
    from ``samples`` x ``samples`` points a pixel."""
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    u = (np.arange(width)[:, None] + offsets).ravel()
    v = (np.arange(height)[:, None] + offsets).ravel()
    inside = (u[None, :] - centre_uv[0]) ** 2 + (v[:, None] - centre_uv[1]) ** 2 < radius_px ** 2
    return inside.reshape(height, samples, width, samples).mean(axis=(1, 3)).astype(np.float32)


def points_at_pixels(camera, u, v, depth):
    """World points an orthographic ``camera`` sees at pixels ``(u, v)`` (n,), ``depth`` ahead."""
    K = camera.K
    xc = np.column_stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1],
                          np.full(len(u), depth)])
    return (xc - camera.t) @ camera.R


def test_coverage_places_the_silhouette_edge_within_the_pixels():
    # A straight edge 0.3 px into a column of pixels (their coverage 0.8): the binary
    # mask puts it on the pixel edge, 0.2 px off; the coverage puts it where it is
    # (Gustavson and Strand's edge distance is exact for a straight edge). At 0.1 px
    # into the column the pixel centres stay the margin (a quarter pixel) inside.
    camera = looking_along([1.0, 0.0, 0.0], orthographic=True, scale=1000.0,
                           width=WIDTH, height=HEIGHT)
    px = 1.0 / 1000.0
    rng = np.random.default_rng(5)
    for into, placed in ((0.3, 0.3), (0.1, 0.25)):
        alpha = np.zeros((HEIGHT, WIDTH), np.float32)
        alpha[:, :50] = 1.0
        alpha[:, 50] = 0.5 + into
        mask = alpha > 0.5
        at = points_near_column(camera, np.full(50, 50.0 + placed), rng)
        assert np.allclose(HullDistance([camera], [mask])(at) / px, placed - 0.5, atol=1e-4)
        assert np.allclose(HullDistance([camera], [mask], coverage=[alpha])(at) / px, 0.0,
                           atol=1e-4)


def test_coverage_places_a_round_edge_within_the_margin():
    # A disk's antialiased alpha: the binary mask's edge follows the pixel staircase (up
    # to half a pixel off the circle, 0.2 px on average); with the coverage, 0.07 px on
    # average, and a quarter pixel at most (where the circle passes nearer a pixel
    # centre than the margin); the same with the coverage rounded to 8 bits.
    camera = looking_along([1.0, 0.0, 0.0], orthographic=True, scale=1000.0,
                           width=WIDTH, height=HEIGHT)
    centre, radius = np.array([97.3, 81.6]), 31.7
    coverage = disk_coverage(WIDTH, HEIGHT, centre, radius)
    mask = coverage > 0.5
    angle = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    on_circle = points_at_pixels(camera, centre[0] + radius * np.cos(angle),
                                 centre[1] + radius * np.sin(angle), 0.5)
    px = 1.0 / 1000.0
    binary = HullDistance([camera], [mask])(on_circle) / px
    assert np.abs(binary).max() > 0.45 and np.abs(binary).mean() > 0.15
    for given in (coverage, np.round(255 * coverage).astype(np.uint8)):
        hull = HullDistance([camera], [mask], coverage=[given])
        error = np.abs(hull(on_circle) / px)
        assert error.max() < 0.26 and error.mean() < 0.09, (error.max(), error.mean())
        # A pixel and a half out and in, the coverage moves the distance by half a
        # pixel at most.
        for step in (-1.5, 1.5):
            off = points_at_pixels(camera, centre[0] + (radius + step) * np.cos(angle),
                                   centre[1] + (radius + step) * np.sin(angle), 0.5)
            moved = hull(off) - HullDistance([camera], [mask])(off)
            assert np.abs(moved).max() <= 0.5 * px + 1e-9
        # The floor still leaves out only views below it everywhere (the slack).
        assert np.allclose(hull(on_circle, floor_m=-2 * px),
                           np.maximum(hull(on_circle), -2 * px))


def test_coverage_of_the_wrong_size_is_refused():
    camera = looking_along([1.0, 0.0, 0.0], orthographic=True, scale=1000.0,
                           width=WIDTH, height=HEIGHT)
    mask = half_plane(camera, 50)
    with pytest.raises(ValueError, match=r"view 0: coverage is \(159, 200\), expected"):
        HullDistance([camera], [mask], coverage=[np.ones((HEIGHT - 1, WIDTH))])
    with pytest.raises(ValueError, match="one image \\(or None\\) per view"):
        HullDistance([camera], [mask], coverage=[None, None])


#: The tilted cube: its half side in pixels of the three orthographic views along its
#: axes (1000 px a metre: 20 mm), each an exact square of pixels.
CUBE_HALF_PX = 20
CUBE_PX_PER_M = 1000.0


def test_vertices_on_the_hull_sharp_edges_are_found_on_it():
    # A cube tilted against the grid, seen along its three axes: its visual hull is the
    # cube, whose surface is known in closed form (max_i |p . e_i| = a). Along a grid edge
    # that passes a cube edge, the hull's distance is the larger of two views' values
    # and kinks; the chord between the edge's two samples places the vertex inside the
    # corner. The crossings place it on the distance's zero. Measured (voxels): the
    # chord max 0.34 rms 0.029; the crossings max 0.114 rms 0.0102, as fully converged
    # (20 steps): what is left is the hull's own, the bilinear distance image rounding
    # each square's corners within a pixel (0.5 voxel here).
    axes = Rotation.from_euler("xyz", [20, 35, 10], degrees=True).as_matrix().T  # rows: e_i
    size = 160
    K = [[CUBE_PX_PER_M, 0.0, (size - 1) / 2], [0.0, CUBE_PX_PER_M, (size - 1) / 2],
         [0.0, 0.0, 1.0]]
    cameras = [Camera(K=K, R=np.roll(axes, -k, axis=0), t=[0.0, 0.0, 0.5], width=size,
                      height=size, orthographic=True) for k in range(3)]
    square = np.zeros((size, size), bool)
    first = size // 2 - CUBE_HALF_PX
    square[first:first + 2 * CUBE_HALF_PX, first:first + 2 * CUBE_HALF_PX] = True
    masks = [square] * 3
    grid = VoxelGrid.cube(np.full(3, -0.04), np.full(3, 0.04), 40)
    occupancy = carve(grid, cameras, masks)
    hull = HullDistance(cameras, masks, bounds_m=(grid.bounds_min, grid.bounds_max))
    band = hull_band_distance(occupancy, grid, hull)
    errors = {}
    for name, given in (("crossings", band), ("chord", replace(band, crossings=None))):
        vertices, faces = band_marching_cubes(occupancy, grid, given)
        report = check_mesh(vertices, faces)
        assert report.watertight and report.vertex_manifold and report.outward is True
        assert report.degenerate_faces == 0 and report.duplicate_faces == 0
        errors[name] = (np.max(np.abs(vertices @ axes.T), axis=1)
                        - CUBE_HALF_PX / CUBE_PX_PER_M) / grid.voxel_size
    rms = {name: np.sqrt(np.mean(e ** 2)) for name, e in errors.items()}
    assert np.max(np.abs(errors["crossings"])) < 0.13 and rms["crossings"] < 0.012, rms
    assert rms["chord"] > 2.0 * rms["crossings"] and np.max(np.abs(errors["chord"])) > 0.3


def test_segment_zeros_find_where_two_views_meet():
    # Two orthographic half-planes at right angles (1 px = 1 mm): the hull's distance is
    # the larger of two linear values, with a kink where they are equal. A segment
    # crossing the kink: the chord of its ends' values misses the zero, a few steps on
    # the distance find it (with a floor far below, the same), and the first step is
    # exact where one view decides the whole segment.
    one = looking_along([0.0, 1.0, 0.0], orthographic=True, scale=1000.0, width=WIDTH,
                        height=HEIGHT)
    other = looking_along([1.0, 0.0, 0.0], orthographic=True, scale=1000.0, width=WIDTH,
                          height=HEIGHT)
    hull = HullDistance([one, other], [half_plane(one, 90), half_plane(other, 90)])
    # the crossing's world point: the two views' edges (u = 90.5) back-projected
    x0 = ((90.5 - one.K[0, 2]) / 1000.0 * one.R[0])[0]
    y0 = ((90.5 - other.K[0, 2]) / 1000.0 * other.R[0])[1]
    assert abs(hull(np.array([[x0, y0, 0.0]]))[0]) < 1e-9
    # One view's distance grows by a millimetre per millimetre along sx * x, the other's
    # along sy * y. The first segment's offsets from the crossing (mm): x -4 -> 1,
    # y -1 -> 0.25, both zero at 4/5 of it (the distance -1 at its start, 1 at its end:
    # the chord says 1/2); the second's x -3 -> 2 at y -10: the first view alone decides,
    # linearly, zero at 3/5.
    sx, sy = np.sign(one.R[0, 0]), np.sign(other.R[0, 1])
    offsets = np.array([[[-4.0, -1.0], [1.0, 0.25]], [[-3.0, -10.0], [2.0, -10.0]]]) * 1e-3
    starts, ends = ([[x0 + sx * o[0], y0 + sy * o[1], 0.0] for o in offsets[:, end]]
                    for end in (0, 1))
    starts, ends = np.array(starts), np.array(ends)
    f_start, f_end = hull(starts), hull(ends)
    truth = np.array([0.8, 0.6])
    chord = f_start / (f_start - f_end)
    np.testing.assert_allclose(chord, [0.5, 0.6], atol=1e-6)
    for floor in (None, -0.05):
        found = hull.segment_zeros(starts, ends, f_start, f_end, iterations=20, floor_m=floor)
        np.testing.assert_allclose(found, truth, atol=1e-6)
    # Each step brings the kinked segment's zero nearer (measured: 0.636, 0.742, then
    # 0.8 to 1e-14 after 4); the linear one is exact from the chord on.
    errors = [np.abs(hull.segment_zeros(starts, ends, f_start, f_end, iterations=n) - truth)
              for n in (1, 2, 4)]
    assert errors[0][0] > errors[1][0] > 0.01 > 1e-9 > errors[2][0]
    assert max(e[1] for e in errors) < 1e-9
    with pytest.raises(ValueError, match="opposite signs"):
        hull.segment_zeros(starts, ends, f_start, f_start, iterations=2)
    with pytest.raises(ValueError, match="iterations"):
        hull.segment_zeros(starts, ends, f_start, f_end, iterations=-1)
    with pytest.raises(ValueError, match="floor_m"):
        hull.segment_zeros(starts, ends, f_start, f_end, iterations=2, floor_m=0.0)


def sorted_cubes(points, edge_m):
    """:func:`_groups` written out with numpy: each point's cube of ``edge_m`` from the
    points' lowest corner as one C-order key, the points ordered by it stably."""
    cells = np.floor((points - points.min(axis=0)) / edge_m).astype(np.int64)
    size = cells.max(axis=0) + 1
    keys = (cells[:, 0] * size[1] + cells[:, 1]) * size[2] + cells[:, 2]
    order = np.argsort(keys, kind="stable")
    starts = np.flatnonzero(np.diff(keys[order])) + 1
    return order, np.concatenate([[0], starts, [len(points)]])


@pytest.mark.parametrize("n, spread_m, edge_m", [
    (1, 1.0, 0.1), (2000, 1.0, 0.01), (200_000, 0.3, 0.002),   # counted
    (50, 1.0, 1e-4)])                                          # far more cubes than points
def test_points_are_grouped_in_cubes_in_the_order_a_stable_sort_gives(n, spread_m, edge_m):
    points = np.random.default_rng(n).random((n, 3)) * spread_m
    points[: n // 3] = points[0]    # points sharing a cube keep their order
    order, starts = _groups(points, edge_m)
    expected_order, expected_starts = sorted_cubes(points, edge_m)
    np.testing.assert_array_equal(order, expected_order)
    np.testing.assert_array_equal(starts, expected_starts)


def test_the_band_found_by_its_distance_gives_the_mesh_of_the_band_found_again(sphere_scan):
    # hull_band_distance hands band_marching_cubes the crop, the band's voxels and the
    # crossings per plane it found; without them (as after crossing a process) they are
    # found again: the same mesh, bit for bit.
    _, grid, occupancy, hull = sphere_scan
    band = hull_band_distance(occupancy, grid, hull)
    assert isinstance(band.found, FoundBand) and band.found.values is band.values
    kept = band_marching_cubes(occupancy, grid, band)
    again = band_marching_cubes(occupancy, grid, replace(band, found=None))
    for a, b in zip(kept, again):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
