"""Tests of the cloud of points (surface voxels, one per M x M x M block, outward normals)."""

import numpy as np
import pytest

from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.meshing.cloud import cloud_of_points, surface_voxels

from tolerances import ROUND_OFF

# Normals of a voxelised sphere of radius ~12 voxels, from the smoothed occupancy, deviate from
# the radial direction by the staircase of the voxels: about 11 degrees at most; allow 20.
NORMAL_COS_TOL = np.cos(np.radians(20.0))


def _sphere(resolution=30, radius=1.0):
    grid = VoxelGrid.cube([-1.2] * 3, [1.2] * 3, resolution)
    x, y, z = np.meshgrid(*[grid.centers_axis(a) for a in range(3)], indexing="ij")
    return x ** 2 + y ** 2 + z ** 2 <= radius ** 2, grid


def _as_set(ijk):
    return {tuple(v) for v in np.asarray(ijk).tolist()}


def test_surface_voxels_of_a_cube_are_all_but_its_centre():
    occ = np.zeros((5, 5, 5), dtype=bool)
    occ[1:4, 1:4, 1:4] = True
    surf = surface_voxels(occ)
    assert surf.dtype == np.int64 and surf.shape == (26, 3)
    assert (2, 2, 2) not in _as_set(surf)


def test_volume_border_counts_as_empty():
    occ = np.ones((3, 3, 3), dtype=bool)
    assert _as_set(surface_voxels(occ)) == _as_set(np.argwhere(occ)) - {(1, 1, 1)}


def test_surface_voxels_match_brute_force():
    occ, _ = _sphere(12)
    padded = np.pad(occ, 1)
    expected = set()
    for i, j, k in np.argwhere(occ):
        nb = [padded[i + 1 + di, j + 1 + dj, k + 1 + dk]
              for di, dj, dk in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))]
        if not all(nb):
            expected.add((i, j, k))
    assert _as_set(surface_voxels(occ)) == expected


def test_block_one_keeps_every_surface_voxel_at_its_centre():
    occ, grid = _sphere()
    cloud = cloud_of_points(occ, grid, block=1)
    assert _as_set(cloud.voxels) == _as_set(surface_voxels(occ))
    assert len(cloud.voxels) == len(surface_voxels(occ))
    np.testing.assert_allclose(cloud.points, grid.index_to_world(cloud.voxels))


@pytest.mark.parametrize("block", [2, 3, 5])
def test_one_point_per_block_nearest_to_the_block_centre(block):
    occ, grid = _sphere()
    cloud = cloud_of_points(occ, grid, block=block)
    surf = surface_voxels(occ)
    blocks_with_surface = _as_set(surf // block)
    chosen_blocks = cloud.voxels // block
    # At most one point per block, and one in every block that holds surface voxels.
    assert len(_as_set(chosen_blocks)) == len(cloud.voxels) == len(blocks_with_surface)
    assert _as_set(cloud.voxels) <= _as_set(surf)
    centre = (block - 1) / 2.0
    for voxel, blk in zip(cloud.voxels, chosen_blocks):
        inside = surf[np.all(surf // block == blk, axis=1)]
        dist = np.sum((inside - blk * block - centre) ** 2, axis=1)
        assert np.sum((voxel - blk * block - centre) ** 2) == dist.min()
    np.testing.assert_allclose(cloud.points, grid.index_to_world(cloud.voxels))


def test_normals_are_unit_and_outward_on_a_sphere():
    occ, grid = _sphere()
    cloud = cloud_of_points(occ, grid, block=2)
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=ROUND_OFF)
    radial = cloud.points / np.linalg.norm(cloud.points, axis=1, keepdims=True)
    cosine = np.einsum("ij,ij->i", cloud.normals, radial)
    assert np.all(cosine > NORMAL_COS_TOL)


def test_normals_on_box_faces_are_the_face_normals():
    grid = VoxelGrid([0, 0, 0], [1, 1, 1], 0.05)
    occ = np.zeros(grid.shape, dtype=bool)
    occ[4:16, 5:15, 6:14] = True
    cloud = cloud_of_points(occ, grid, block=1)
    # A voxel in the middle of the top face (away from edges by more than the 3-sigma kernel).
    top = np.flatnonzero(np.all(cloud.voxels == (10, 10, 13), axis=1))
    assert len(top) == 1
    np.testing.assert_allclose(cloud.normals[top[0]], (0.0, 0.0, 1.0), atol=ROUND_OFF)


def test_thin_sheet_gets_a_unit_normal():
    grid = VoxelGrid([0, 0, 0], [1, 1, 1], 0.1)
    occ = np.zeros(grid.shape, dtype=bool)
    occ[:, :, 5] = True
    cloud = cloud_of_points(occ, grid, block=1)
    assert np.all(np.isfinite(cloud.normals))
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=ROUND_OFF)


def test_bad_inputs_are_rejected():
    occ, grid = _sphere(10)
    with pytest.raises(ValueError, match="does not match grid shape"):
        cloud_of_points(occ[:-1], grid)
    with pytest.raises(ValueError, match="bool"):
        cloud_of_points(occ.astype(np.uint8), grid)
    with pytest.raises(ValueError, match="block"):
        cloud_of_points(occ, grid, block=0)
    with pytest.raises(ValueError, match="3-D"):
        surface_voxels(np.zeros((4, 4), dtype=bool))
