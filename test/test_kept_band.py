"""The hull's signed distance near its surface kept as the views arrive (KeptBand): the
marching cubes' input bit for bit as evaluated after the last view, for any order of the
views and any hull followed on the way.

Both sides read the same distance images (``known``), as a scan's reconstruction does:
OpenCV's precise distance transform, run on several threads, can place a value an ulp
apart from one call to the next."""

import math

import numpy as np
import pytest

from sfs_ros.core.carving.carve import carve, view_key
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.meshing.hull_distance import DistanceImages, HullDistance
from sfs_ros.core.meshing.kept_band import KeptBand
from sfs_ros.core.meshing.marching import (
    CROSSING_ITERATIONS,
    BandEdges,
    band_values,
    band_voxel_indices,
    hull_band_distance,
    hull_band_floor_m,
    padded_crop,
)

from analytic_masks import sphere_mask

RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=1200.0, fy=1300.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.0))
BOX = np.array([[-0.05, -0.04, -0.03], [0.05, 0.04, 0.03]])
CENTRE, RADIUS = np.array([0.01, -0.005, 0.0]), 0.03


@pytest.fixture(scope="module")
def views():
    cameras = [rig_camera(t, math.radians(p), RIG) for p in (0, 40, 80)
               for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    masks = [sphere_mask(c, CENTRE, RADIUS) for c in cameras]
    masks[5][:, :170] = False     # a bite out of one view: a hull that is not the sphere's
    return cameras, masks


def kept_as_they_arrive(grid, cameras, masks, order, max_misses, follow_every):
    """A KeptBand fed the views in ``order``, following the hull carved so far every
    ``follow_every`` views (never after the last: the band reached since is evaluated
    after it); and the distance images it was given."""
    known = DistanceImages()
    band = KeptBand(grid, max_misses=max_misses, known=known)
    for n, i in enumerate(order, start=1):
        known.add(masks[i])
        band.add(cameras[i], masks[i])
        if n % follow_every == 0 and n < len(order):
            taken = list(order[:n])
            band.follow(carve(grid, [cameras[j] for j in taken], [masks[j] for j in taken],
                              max_misses=max_misses))
    return band, known


@pytest.mark.parametrize("max_misses", [0, 1])
@pytest.mark.parametrize("follow_every", [1, 5])
def test_the_band_kept_as_the_views_arrive_is_the_band_evaluated_after_them(
        views, max_misses, follow_every):
    cameras, masks = views
    grid = VoxelGrid.cube(BOX[0], BOX[1], 48)
    order = np.random.default_rng(3).permutation(len(cameras))
    band, known = kept_as_they_arrive(grid, cameras, masks, order, max_misses, follow_every)
    occupancy = carve(grid, cameras, masks, max_misses=max_misses)
    box = (grid.bounds_min, grid.bounds_max)
    evaluated = hull_band_distance(occupancy, grid, HullDistance(
        cameras, masks, max_misses=max_misses, bounds_m=box, known=known))
    assert band.holds(grid, [view_key(c, m) for c, m in zip(cameras, masks)], max_misses)
    kept = hull_band_distance(occupancy, grid, HullDistance(
        cameras, masks, max_misses=max_misses, bounds_m=box, known=known, kept=band))
    np.testing.assert_array_equal(kept.values, evaluated.values)
    # The marching cubes' vertices too: the zeros along the edges, kept or found again.
    np.testing.assert_array_equal(kept.crossings, evaluated.crossings)
    # Not vacuous: most of the final band was kept, not evaluated after the last view,
    # and with the band followed at every view most of its edges' zeros were kept too.
    crop, corner = padded_crop(occupancy, 1)
    voxels = band_voxel_indices(crop, 1)
    _, missing = band._kept_at(band._linear(voxels + corner))
    assert missing.mean() < 0.5, missing.mean()
    edges = BandEdges.of(crop, corner, voxels, evaluated.values, grid, 1)
    _, rows = band._edges._found(band._linear, edges)
    assert len(edges) > 100
    if follow_every == 1:
        assert (rows >= 0).mean() > 0.5, (rows >= 0).mean()


def test_a_zero_is_kept_only_while_no_view_raises_the_distance_where_it_was_stepped(views):
    cameras, masks = views
    grid = VoxelGrid.cube(BOX[0], BOX[1], 40)
    box = (grid.bounds_min, grid.bounds_max)
    floor = hull_band_floor_m(grid, 1)
    first = HullDistance(cameras[:12], masks[:12], bounds_m=box)
    occupancy = carve(grid, cameras[:12], masks[:12])
    crop, corner = padded_crop(occupancy, 1)
    voxels = band_voxel_indices(crop, 1)
    values = band_values(first(grid.index_to_world(voxels + corner), floor_m=floor), grid, 1)
    edges = BandEdges.of(crop, corner, voxels, values, grid, 1)
    zeros, trace = edges.zeros(first, traced=True)
    np.testing.assert_array_equal(zeros, edges.zeros(first))     # traced or not, the same
    assert trace.counts.min() >= 1 and trace.counts.max() <= CROSSING_ITERATIONS
    every = HullDistance(cameras, masks, bounds_m=box)
    raised = np.zeros(len(edges), bool)
    for camera, mask in zip(cameras[12:], masks[12:]):
        raised |= HullDistance([camera], [mask]).raises(trace)
    # Where no later view raised the distance at the steps, all views find the same zero;
    # the later views cut the hull of the first twelve, so some zeros move.
    again = edges.zeros(every)
    np.testing.assert_array_equal(again[~raised], zeros[~raised])
    assert 0 < raised.sum() < len(edges)
    assert np.any(again[raised] != zeros[raised])


def test_a_band_holds_only_the_views_it_was_given(views):
    cameras, masks = views
    grid = VoxelGrid.cube(BOX[0], BOX[1], 48)
    band, _ = kept_as_they_arrive(grid, cameras, masks, range(len(cameras)), 0, 4)
    keys = [view_key(c, m) for c, m in zip(cameras, masks)]
    assert band.holds(grid, keys[::-1], 0)                      # in any order
    assert not band.holds(grid, keys[:-1], 0)                   # a view fewer
    assert not band.holds(grid, keys, 1)                        # another tolerance
    assert not band.holds(VoxelGrid.cube(BOX[0], BOX[1], 47), keys, 0)   # another grid
    repaired = [m.copy() for m in masks]
    repaired[5] = sphere_mask(cameras[5], CENTRE, RADIUS)       # the bite filled
    assert not band.holds(grid, [view_key(c, m) for c, m in zip(cameras, repaired)], 0)


def test_a_band_that_followed_no_hull_evaluates_every_voxel_the_same(views):
    cameras, masks = views
    grid = VoxelGrid.cube(BOX[0], BOX[1], 40)
    band, known = kept_as_they_arrive(grid, cameras, masks, range(len(cameras)), 0,
                                      len(cameras))
    occupancy = carve(grid, cameras, masks)
    box = (grid.bounds_min, grid.bounds_max)
    np.testing.assert_array_equal(
        hull_band_distance(occupancy, grid, HullDistance(cameras, masks, bounds_m=box,
                                                         known=known, kept=band)).values,
        hull_band_distance(occupancy, grid, HullDistance(cameras, masks, bounds_m=box,
                                                         known=known)).values)
