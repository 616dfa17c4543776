"""Consistency checks: a bad mask is found, a clipping bounding box is reported."""

import math

import numpy as np
import pytest

from sfs_ros.core.carving.carve import carve
from sfs_ros.core.carving.consistency import (
    bbox_clips_object,
    hull_silhouettes,
)
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera

from analytic_masks import sphere_mask

CENTRE, RADIUS = np.array([0.004, -0.006, 0.01]), 0.08
GRID = VoxelGrid.cube([-0.12] * 3, [0.12] * 3, 64)
BAD = 5


def scan(projection, phis_deg=(0, 35, 70), n_theta=8):
    f = 700.0 if projection == "orthographic" else 500.0
    cal = RigCalibration(width=160, height=160, projection=projection, fx=f, fy=f,
                         camera_distance_m=0.7)
    cams = [rig_camera(t, math.radians(p), cal)
            for p in phis_deg for t in np.linspace(0, 2 * np.pi, n_theta, endpoint=False)]
    return cams, [sphere_mask(c, CENTRE, RADIUS) for c in cams]


def erase_half(mask):
    """The mask with the left half of its foreground erased (a segmentation failure)."""
    out = mask.copy()
    cols = np.nonzero(mask.any(axis=0))[0]
    out[:, :(cols[0] + cols[-1]) // 2] = False
    return out


@pytest.mark.parametrize("projection", ["orthographic", "pinhole"])
def test_tolerant_hull_survives_one_bad_view(projection):
    cams, masks = scan(projection)
    good_only = carve(GRID, cams[:BAD] + cams[BAD + 1:], masks[:BAD] + masks[BAD + 1:])
    masks[BAD] = erase_half(masks[BAD])
    strict = carve(GRID, cams, masks)
    tolerant = carve(GRID, cams, masks, max_misses=1)
    # Strict carving loses about half of the object to the bad view ...
    assert strict.sum() < 0.7 * good_only.sum()
    # ... with max_misses=1 every voxel the good views agree on stays (a voxel
    # missed only by the bad view has one miss).
    assert np.all(tolerant >= good_only)
    centres = GRID.index_to_world(np.indices(GRID.shape).reshape(3, -1).T)
    inside = (np.linalg.norm(centres - CENTRE, axis=1) <= RADIUS - GRID.voxel_size)
    assert np.all(tolerant.reshape(-1)[inside])


def test_hull_silhouette_of_a_single_voxel_is_its_footprint():
    cams, _ = scan("orthographic", phis_deg=(0,), n_theta=1)
    occ = np.zeros(GRID.shape, bool)
    occ[30, 31, 32] = True
    (image,), half = hull_silhouettes(GRID, occ, cams)
    # theta = 0, phi = 0: the cube's face is seen head on, 700 px/m x 3.75 mm
    # = 2.6 px wide: half-size 1.31 px around the projected centre.
    assert half[0] == pytest.approx(0.5 * 700.0 * GRID.voxel_size)
    u, v = cams[0].project(GRID.index_to_world([[30, 31, 32]]))[0]
    rows, cols = np.nonzero(image)
    assert set(cols) == {c for c in range(160) if abs(c - u) <= half[0]}
    assert set(rows) == {r for r in range(160) if abs(r - v) <= half[0]}


@pytest.mark.parametrize("projection", ["orthographic", "pinhole"])
def test_bbox_clips_object(projection):
    cams, masks = scan(projection, phis_deg=(0, 90), n_theta=6)
    assert bbox_clips_object(GRID, cams, masks) == []
    # The box top at z = 0.05 m cuts the sphere's cap (top at 0.09 m): the six
    # side views see foreground above the box; the six from above do not.
    low = VoxelGrid([-0.12, -0.12, -0.12], [0.12, 0.12, 0.05], GRID.voxel_size)
    assert bbox_clips_object(low, cams, masks) == list(range(6))


def test_bad_thresholds():
    cams, masks = scan("orthographic", phis_deg=(0,), n_theta=2)
    with pytest.raises(ValueError):
        bbox_clips_object(GRID, cams, masks, tolerance_px=-1)
