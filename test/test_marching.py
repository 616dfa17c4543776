"""Marching cubes on occupancies with known shapes."""

import numpy as np
import pytest
from scipy import ndimage

from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.meshing.lewiner import march_band
from sfs_ros.core.meshing.marching import (
    LEVEL,
    _contour,
    _oriented,
    band_voxel_indices,
    marching_cubes_mesh,
    voxel_centres,
)
from sfs_ros.core.meshing.mesh_checks import check_mesh

from tolerances import ROUND_OFF

RADIUS_M = 0.031
CENTRE_M = np.array([0.004, -0.003, 0.041])
#: Outward offset of the surface, in voxels, from contouring just below 0.5.
LEVEL_SHIFT = 0.5 - LEVEL


def sphere_occupancy(grid, centre, radius):
    """(nx, ny, nz) bool: voxel centres inside the ball."""
    ijk = np.indices(grid.shape).reshape(3, -1).T
    inside = np.linalg.norm(grid.index_to_world(ijk) - centre, axis=1) <= radius
    return inside.reshape(grid.shape)


def ball_volume(radius):
    return 4.0 / 3.0 * np.pi * radius ** 3


@pytest.fixture(scope="module")
def sphere():
    # Box larger than the ball and off-centre from it, so cropping and the
    # origin offset are exercised: 48 voxels across the longest side.
    grid = VoxelGrid.cube(CENTRE_M - 0.045, CENTRE_M + 0.05, 48)
    return grid, sphere_occupancy(grid, CENTRE_M, RADIUS_M)


@pytest.mark.parametrize("sigma", [0.0, 0.5])
def test_sphere_closed_outward_and_on_the_surface(sphere, sigma):
    grid, occ = sphere
    h = grid.voxel_size
    vertices, faces = marching_cubes_mesh(occ, grid, smooth_sigma_vox=sigma)
    assert vertices.dtype == np.float64 and faces.dtype == np.int64
    report = check_mesh(vertices, faces)
    assert report.watertight and report.vertex_manifold and report.consistently_oriented
    assert report.outward is True
    assert report.n_components == 1 and report.genus == 0
    assert report.degenerate_faces == 0 and report.duplicate_faces == 0

    distance = np.linalg.norm(vertices - CENTRE_M, axis=1) - RADIUS_M
    # Unsmoothed, each vertex is (up to LEVEL_SHIFT) the midpoint of a grid
    # edge whose ends lie on opposite sides of the sphere, so it is within
    # half a voxel of it. Smoothing (sigma 0.5 voxel) moves vertices by a
    # fraction of a voxel: allow one voxel.
    bound = (0.5 + LEVEL_SHIFT) * h if sigma == 0 else h
    assert np.max(np.abs(distance)) <= bound

    # Vertices lie within half a voxel of the sphere and triangles span one
    # cell (chord sag ~ h^2 / r << h), so the surface lies in the shell of
    # radii r -/+ one voxel: its volume lies between those two balls.
    assert ball_volume(RADIUS_M - h) < report.volume_m3 < ball_volume(RADIUS_M + h)


def test_object_touching_the_box_is_closed():
    # Every voxel occupied: the object fills the box. Unsmoothed, the surface
    # lies on the outer voxel faces, i.e. on the box itself.
    grid = VoxelGrid([0.1, -0.2, 0.0], [0.14, -0.17, 0.02], 0.005)
    occ = np.ones(grid.shape, dtype=bool)
    vertices, faces = marching_cubes_mesh(occ, grid, smooth_sigma_vox=0.0)
    report = check_mesh(vertices, faces)
    assert report.watertight and report.vertex_manifold and report.outward is True
    assert report.genus == 0
    h = grid.voxel_size
    # The iso-level sits LEVEL_SHIFT below 0.5, moving the surface outward by
    # LEVEL_SHIFT voxel (1e-12 m of rounding on top).
    np.testing.assert_allclose(vertices.min(axis=0), grid.bounds_min - LEVEL_SHIFT * h,
                               atol=ROUND_OFF)
    np.testing.assert_allclose(vertices.max(axis=0), grid.bounds_max + LEVEL_SHIFT * h,
                               atol=ROUND_OFF)
    # Edges and corners of the box are chamfered (a 45-degree cut of half a
    # voxel), so the volume is below the box's and above the box shrunk by
    # one voxel.
    extent = grid.bounds_max - grid.bounds_min
    assert np.prod(extent - h) < report.volume_m3 < np.prod(extent)


def test_half_sphere_cut_by_the_floor_is_closed():
    # Ball centred on the bottom face of the box: the occupancy is cut there.
    centre = np.array([0.0, 0.0, 0.0])
    grid = VoxelGrid([-0.04, -0.04, 0.0], [0.04, 0.04, 0.04], 0.002)
    occ = sphere_occupancy(grid, centre, 0.03)
    vertices, faces = marching_cubes_mesh(occ, grid, smooth_sigma_vox=0.0)
    report = check_mesh(vertices, faces)
    assert report.watertight and report.vertex_manifold and report.outward is True
    assert report.genus == 0
    # The cut is closed by a flat cap on the bottom voxel faces, z = 0.
    # (Moved out by LEVEL_SHIFT voxel, see marching.LEVEL.)
    assert vertices[:, 2].min() == pytest.approx(-LEVEL_SHIFT * grid.voxel_size, abs=ROUND_OFF)


@pytest.mark.parametrize("sigma", [0.0, 0.5])
def test_noisy_occupancy_gives_a_closed_manifold(sigma):
    # Random voxels touch each other along edges and at corners: the ambiguous
    # marching-cubes configurations. Every piece must still be closed,
    # manifold and outward.
    rng = np.random.default_rng(7)
    grid = VoxelGrid([0, 0, 0], [0.02, 0.02, 0.02], 0.001)
    occ = rng.random(grid.shape) > 0.7
    report = check_mesh(*marching_cubes_mesh(occ, grid, smooth_sigma_vox=sigma))
    assert report.watertight and report.vertex_manifold and report.consistently_oriented
    assert report.outward is True and report.duplicate_faces == 0


def test_torus_has_genus_one():
    grid = VoxelGrid([-0.05, -0.05, -0.02], [0.05, 0.05, 0.02], 0.002)
    world = grid.index_to_world(np.indices(grid.shape).reshape(3, -1).T)
    ring = np.hypot(world[:, 0], world[:, 1]) - 0.03
    occ = (np.hypot(ring, world[:, 2]) <= 0.012).reshape(grid.shape)
    report = check_mesh(*marching_cubes_mesh(occ, grid))
    assert report.watertight and report.outward is True and report.genus == 1


def test_invalid_input():
    grid = VoxelGrid([0, 0, 0], [0.01, 0.01, 0.01], 0.001)
    with pytest.raises(ValueError, match="empty"):
        marching_cubes_mesh(np.zeros(grid.shape, dtype=bool), grid)
    with pytest.raises(ValueError, match="does not match the grid shape"):
        marching_cubes_mesh(np.ones((3, 3, 3), dtype=bool), grid)
    with pytest.raises(ValueError, match="smooth_sigma_vox"):
        marching_cubes_mesh(np.ones(grid.shape, dtype=bool), grid, smooth_sigma_vox=-1)
    single = np.zeros(grid.shape, dtype=bool)
    single[5, 5, 5] = True
    with pytest.raises(ValueError, match="removes the whole object"):
        marching_cubes_mesh(single, grid, smooth_sigma_vox=2.0)


@pytest.mark.parametrize("steps", [1, 2, 3])
def test_band_voxels_are_scipy_dilation_less_erosion(steps):
    # The band of the hull mesher, found from the columns' runs, against scipy's 3^3
    # cube applied ``steps`` times (erosion with empty space beyond the array), on
    # volumes touching the array's sides, sparse and dense, with several runs a column.
    rng = np.random.default_rng(steps)
    cube = np.ones((3, 3, 3), bool)
    for shape in ((9, 7, 8), (2, 5, 3), (12, 1, 6), (17, 19, 23)):
        for fill in (0.1, 0.6, 0.95):
            volume = rng.random(shape) < fill
            expected = (ndimage.binary_dilation(volume, cube, iterations=steps)
                        & ~ndimage.binary_erosion(volume, cube, iterations=steps,
                                                  border_value=0))
            np.testing.assert_array_equal(band_voxel_indices(volume, steps),
                                          np.argwhere(expected))
    assert band_voxel_indices(np.zeros((4, 5, 6), bool), steps).shape == (0, 3)


def test_contouring_only_the_cubes_with_a_corner_in_the_band_gives_the_same_mesh():
    # A distance field clipped at +-2 voxels off a band 1.5 voxels wide, as the hull
    # mesher builds it: the level crosses only cubes with a corner in the band, so
    # visiting only those (march_band) gives scikit-image's mesh of the whole volume.
    grid = VoxelGrid.cube([-0.05] * 3, [0.05] * 3, 40)
    ijk = np.indices(grid.shape).reshape(3, -1).T
    depth = (0.031 - np.linalg.norm(grid.index_to_world(ijk), axis=1)) / grid.voxel_size
    depth = depth.reshape(grid.shape)
    band = np.abs(depth) < 1.5
    volume = np.where(band, depth, np.sign(depth) * 2.0).astype(np.float32)
    whole = _contour(volume, 0.0, np.zeros(3, np.int64), grid)
    voxels = np.argwhere(band)
    banded = _oriented(*march_band(depth > 0, 2.0, voxels, volume[band]),
                       np.zeros(3, np.int64), grid)
    assert len(whole[1]) > 1000
    for a, b in zip(whole, banded):
        np.testing.assert_array_equal(a, b)


def test_voxel_centres_are_the_grids_own_numbers():
    # The compiled pass against VoxelGrid.index_to_world, bit for bit, on a grid whose
    # origin and voxel are not round numbers, with crop offsets either side of zero.
    grid = VoxelGrid([-0.0731, 0.0193, -0.2417], [0.0816, 0.1704, -0.0311], 0.000731)
    rng = np.random.default_rng(4)
    voxels = rng.integers(0, 300, (5000, 3))
    for corner in (np.array([-3, -3, -3]), np.array([17, 0, 211])):
        np.testing.assert_array_equal(voxel_centres(grid, voxels, corner),
                                      grid.index_to_world(voxels + corner))
    assert voxel_centres(grid, voxels[:0], corner).shape == (0, 3)
    between = voxels + rng.random(voxels.shape)     # a mesh's vertices, in voxels
    np.testing.assert_array_equal(voxel_centres(grid, between, corner),
                                  grid.origin + (between + corner) * grid.voxel_size)
