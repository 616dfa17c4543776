"""The voxel size from the cameras and the memory budget, and the refined carving box."""

import math

import numpy as np
import pytest

from sfs_ros.core.carving.bounds import BoxCarve, footprint_masks, refine_bounds, seen_by
from sfs_ros.core.carving.carve import KeptCarve, carve
from sfs_ros.core.carving.resolution import (
    BYTES_PER_VOXEL,
    COARSE_FOOTPRINTS,
    THIN_PART_PX,
    THIN_SHARE_MAX,
    choose_voxel_size,
    grid_shape,
    parse_memory,
    pixel_footprints_m,
)
from sfs_ros.core.carving.thin_parts import thin_share
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.settings import RESOLUTION

from analytic_masks import sphere_mask

DISTANCE_M, FX = 0.6, 1200.0
RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=FX, fy=FX + 100.0,
                     camera_distance_m=DISTANCE_M, aim_point_m=(0.0, 0.0, 0.0))
BOX = np.array([[-0.05, -0.04, -0.03], [0.05, 0.04, 0.03]])  # centred on the aim point
GIB = 1 << 30


def ring(calibration=RIG, n=8, phi_deg=30.0):
    return [rig_camera(t, math.radians(phi_deg), calibration)
            for t in np.linspace(0, 2 * np.pi, n, endpoint=False)]


def test_footprint_is_depth_over_focal_length():
    # Every camera looks at the box centre from DISTANCE_M: one pixel there is
    # DISTANCE_M / fx metres (the smaller focal length: the coarser direction).
    assert pixel_footprints_m(ring(), BOX.mean(axis=0)) == pytest.approx(DISTANCE_M / FX)
    ortho = RigCalibration(width=320, height=240, projection="orthographic", fx=FX, fy=FX,
                           camera_distance_m=DISTANCE_M)
    assert pixel_footprints_m(ring(ortho), BOX.mean(axis=0)) == pytest.approx(1 / FX)


def test_default_voxel_is_the_finest_footprint():
    near = RigCalibration(width=320, height=240, projection="pinhole", fx=FX, fy=FX,
                          camera_distance_m=0.4, aim_point_m=(0.0, 0.0, 0.0))
    cameras = ring() + ring(near, n=2)
    choice = choose_voxel_size(BOX, cameras, max_memory_bytes=GIB)
    assert choice.source == "footprint"
    assert choice.voxel_size_m == pytest.approx(0.4 / FX)  # the nearer views' pixels
    assert choice.footprint_median_m == pytest.approx(DISTANCE_M / FX)
    assert choice.shape == grid_shape(BOX, 0.4 / FX)
    assert choice.memory_bytes == np.prod(choice.shape) * BYTES_PER_VOXEL
    assert "finest pixel footprint" in choice.reason


def disk_with_strip(strip_width_px: int, frame=(300, 400)) -> tuple[np.ndarray, int]:
    """A disk of radius 80 px with a horizontal strip ``strip_width_px`` wide and 100 px
    long standing out of it, and the strip's pixels outside the disk."""
    rows, cols = np.mgrid[:frame[0], :frame[1]]
    disk = (rows - 150) ** 2 + (cols - 150) ** 2 <= 80 ** 2
    strip = np.zeros(frame, dtype=bool)
    strip[150 - strip_width_px // 2:150 + strip_width_px - strip_width_px // 2, 200:330] = True
    return disk | strip, int(np.count_nonzero(strip & ~disk))


def test_the_thin_share_is_the_area_of_the_parts_narrower_than_the_disk():
    mask, strip_px = disk_with_strip(3)
    share = thin_share([mask], THIN_PART_PX)
    # The strip (3 x 100 px outside the disk) is thin, the disk is not, to within a few
    # pixels where the strip meets the disk (a 7 px disk there holds some of the strip and
    # trims the digital circle's steps).
    assert strip_px - 8 <= share * np.count_nonzero(mask) <= strip_px + 2 * 8
    wide, _ = disk_with_strip(THIN_PART_PX + 2)
    assert thin_share([wide], THIN_PART_PX) * np.count_nonzero(wide) <= 2 * 8
    # A thick part cut by the frame is not thin: the frame's edge is not the object's.
    assert thin_share([mask[:, :220]], THIN_PART_PX) * np.count_nonzero(mask[:, :220]) <= 2 * 8
    # Over several masks the share is of their area together; no foreground, no share.
    empty = np.zeros_like(mask)
    assert thin_share([mask, wide, empty], THIN_PART_PX) == pytest.approx(
        (share * np.count_nonzero(mask) + thin_share([wide], THIN_PART_PX)
         * np.count_nonzero(wide)) / (np.count_nonzero(mask) + np.count_nonzero(wide)))
    assert thin_share([empty], THIN_PART_PX) == 0.0
    with pytest.raises(ValueError, match="odd"):
        thin_share([mask], 6)


def test_silhouettes_without_thin_parts_get_a_coarser_voxel():
    finest = DISTANCE_M / FX
    coarse = choose_voxel_size(BOX, ring(), max_memory_bytes=GIB, thin_share=THIN_SHARE_MAX)
    assert coarse.source == "footprint" and coarse.thin_share == THIN_SHARE_MAX
    assert coarse.voxel_size_m == pytest.approx(COARSE_FOOTPRINTS * finest)
    assert f"{COARSE_FOOTPRINTS:.3g} times the finest pixel footprint" in coarse.reason
    fine = choose_voxel_size(BOX, ring(), max_memory_bytes=GIB, thin_share=2 * THIN_SHARE_MAX)
    assert fine.voxel_size_m == pytest.approx(finest)
    assert "keeping the parts under 7 px wide (0.4 % of the silhouettes' area)" in fine.reason
    given = choose_voxel_size(BOX, ring(), resolution=100, max_memory_bytes=GIB, thin_share=0.0)
    assert max(given.shape) == 100 and given.thin_share is None
    # The setting's words for its default (the help and doc/reference.md) say the same.
    assert f"({COARSE_FOOTPRINTS:.3g} of it" in RESOLUTION.default_text
    assert f"under {THIN_PART_PX} px wide" in RESOLUTION.default_text


def test_memory_budget_coarsens_the_footprint():
    budget = 8 << 20  # 8 MiB: 512 Ki voxels at 16 bytes each
    choice = choose_voxel_size(BOX, ring(), max_memory_bytes=budget)
    assert choice.source == "memory"
    assert choice.memory_bytes <= budget
    # Within the 1 % steps of the search, the grid fills the budget: the voxel
    # is the cube root of box volume / voxels allowed, up to whole-voxel rounding.
    ideal = (np.prod(BOX[1] - BOX[0]) / (budget // BYTES_PER_VOXEL)) ** (1 / 3)
    assert ideal <= choice.voxel_size_m <= 1.1 * ideal
    assert "coarsened" in choice.reason


def test_a_given_resolution_the_budget_cannot_hold_is_refused_with_the_figure():
    with pytest.raises(ValueError, match=r"needs 1\.00 GiB.*budget is 0\.50 GiB"):
        # 1024 x 1024 x 1024 voxels of a cube at 16 bytes: 16 GiB; a 1024 x 512 x 128 box: 1 GiB
        choose_voxel_size([[0, 0, 0], [1.024, 0.512, 0.128]], ring(), resolution=1024,
                          max_memory_bytes=GIB // 2)
    choice = choose_voxel_size(BOX, ring(), resolution=100, max_memory_bytes=GIB)
    assert choice.source == "resolution" and max(choice.shape) == 100
    choice = choose_voxel_size(BOX, ring(), voxel_size_m=0.002, max_memory_bytes=GIB)
    assert choice.source == "voxel-size" and choice.shape == (50, 40, 30)


@pytest.mark.parametrize("text, expected", [("2G", 2 * GIB), ("512M", 512 << 20),
                                            ("1.5GiB", int(1.5 * GIB)), ("800mb", 800 << 20),
                                            ("3000000", 3000000)])
def test_memory_sizes_are_parsed(text, expected):
    assert parse_memory(text) == expected


@pytest.mark.parametrize("text", ["2X", "", "-1G", "12K"])
def test_bad_memory_sizes_are_refused(text):
    with pytest.raises(ValueError, match="memory size"):
        parse_memory(text)


def test_refined_box_holds_the_sphere_tightly():
    centre, radius = np.array([0.01, -0.005, 0.0]), 0.03
    cameras = [rig_camera(t, math.radians(p), RIG) for p in (0, 40, 80)
               for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    masks = [sphere_mask(c, centre, radius) for c in cameras]
    loose = np.array([[-0.1, -0.1, -0.1], [0.1, 0.1, 0.1]])
    box = refine_bounds(cameras, masks, loose, resolution=100, margin_voxels=2.0)
    # The sphere's box grown by at most the margin (2.5 voxels of 2 mm) plus
    # the hull's excess over the sphere (24 views: under 10 % of the radius).
    assert np.all(box[0] <= centre - radius) and np.all(box[1] >= centre + radius)
    assert np.all(box[0] >= centre - radius - 0.005 - 0.1 * radius)
    assert np.all(box[1] <= centre + radius + 0.005 + 0.1 * radius)


def test_a_box_carve_kept_view_by_view_refines_to_the_same_box():
    # BoxCarve counts, a view at a time, what refine_bounds carves at once: for the same
    # views, in any order, the same voxels and so the same box, bit for bit. The box is
    # wider than the frames (0.6 m away, 160 px / 1200 px = 0.08 m half-width), so the
    # framing counts matter, and one mask lost a bite, so the miss counts do.
    centre, radius = np.array([0.01, -0.005, 0.0]), 0.03
    cameras = [rig_camera(t, math.radians(p), RIG) for p in (0, 40, 80)
               for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    masks = [sphere_mask(c, centre, radius) for c in cameras]
    masks[5][:, :170] = False
    loose = np.array([[-0.3, -0.3, -0.3], [0.3, 0.3, 0.3]])
    known = BoxCarve(loose, resolution=64)
    for i in np.random.default_rng(1).permutation(len(cameras)):
        known.add(cameras[i], masks[i])
    grid = VoxelGrid.cube(loose[0], loose[1], 64)
    assert not seen_by(grid, cameras, 12).all()
    for misses in (0, 1, 2):
        expected = refine_bounds(cameras, masks, loose, resolution=64, max_misses=misses)
        assert np.array_equal(refine_bounds(cameras, masks, loose, resolution=64,
                                            max_misses=misses, known=known), expected)
        held, reach = known.carved(grid, cameras, masks, misses, 12)
        framed = seen_by(grid, cameras, 12)
        assert np.array_equal(held, carve(grid, cameras, masks, max_misses=misses) & framed)
        assert np.array_equal(reach, carve(grid, cameras, footprint_masks(cameras, masks, grid))
                              & framed)
    # Not these views, not this grid, more misses than it counts: it says so (None).
    bitten = [m.copy() for m in masks]
    bitten[3][100:, :] = False
    assert known.carved(grid, cameras, bitten, 1, 12) is None
    assert known.carved(grid, cameras[:-1], masks[:-1], 1, 12) is None
    assert known.carved(VoxelGrid.cube(loose[0], loose[1], 65), cameras, masks, 1, 12) is None
    assert known.carved(grid, cameras, masks, BoxCarve.MOST_MISSES + 1, 12) is None
    # ... and refine_bounds then carves: the bitten masks' box, as without the store.
    assert np.array_equal(
        refine_bounds(cameras, bitten, loose, resolution=64, max_misses=1, known=known),
        refine_bounds(cameras, bitten, loose, resolution=64, max_misses=1))
    # Without the masks, from its counts alone: the same box again.
    for misses in (0, 1, 2):
        assert np.array_equal(known.refined(misses), refine_bounds(
            cameras, masks, loose, resolution=64, max_misses=misses))


def test_a_carve_kept_view_by_view_is_the_carve_even_with_repaired_masks():
    # KeptCarve counts the misses a view at a time; for the same views in any order it
    # gives carve's voxels bit for bit, at every tolerance it counts. Views that come
    # back with another mask (a bite filled, a bite taken) are taken back and counted
    # again: still carve's voxels of the masks given, up to MOST_REPLACED of them.
    centre, radius = np.array([0.01, -0.005, 0.0]), 0.03
    cameras = [rig_camera(t, math.radians(p), RIG) for p in (0, 40, 80)
               for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    masks = [sphere_mask(c, centre, radius) for c in cameras]
    masks[5][:, :170] = False
    grid = VoxelGrid.cube(BOX[0], BOX[1], 48)
    kept = KeptCarve(grid, most_misses=2)
    for i in np.random.default_rng(2).permutation(len(cameras)):
        kept.add(cameras[i], masks[i])
    for misses in (0, 1, 2):
        assert np.array_equal(kept.carved(grid, cameras, masks, misses),
                              carve(grid, cameras, masks, max_misses=misses))
    repaired = [m.copy() for m in masks]
    repaired[5] = sphere_mask(cameras[5], centre, radius)           # the bite filled
    for n in range(1, KeptCarve.MOST_REPLACED):
        repaired[6 + n][:, 150:] = False                             # bites taken
    for misses in (0, 1, 2):
        expected = carve(grid, cameras, repaired, max_misses=misses)
        assert not np.array_equal(expected, carve(grid, cameras, masks, max_misses=misses))
        assert np.array_equal(kept.carved(grid, cameras, repaired, misses), expected)
    # More masks replaced than it takes back, other views, another grid, more misses
    # than it counts: None (the caller carves).
    repaired[20][:, :100] = False
    assert kept.carved(grid, cameras, repaired, 0) is None
    assert kept.carved(grid, cameras[:-1], masks[:-1], 0) is None
    assert kept.carved(VoxelGrid.cube(BOX[0], BOX[1], 47), cameras, masks, 0) is None
    assert kept.carved(grid, cameras, masks, 3) is None
