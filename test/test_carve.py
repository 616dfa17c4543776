"""Carving: exact agreement with a per-voxel reference, and ground-truth shapes."""

import importlib
import math

import numpy as np
import pytest

from sfs_ros.core.carving.bounds import seen_by
from sfs_ros.core.carving.carve import Carver, PreparedMasks, carve, view_coefficients
from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera

from analytic_masks import sphere_mask
from tolerances import HALF_PIXEL_DIAGONAL_PX

# The module itself (the package's ``carve`` attribute is the function of that name).
carve_module = importlib.import_module("sfs_ros.core.carving.carve")


def naive_carve(grid, cameras, masks, max_misses=0, keep=True):
    """Reference: project every voxel centre into every view."""
    pts = grid.index_to_world(np.indices(grid.shape).reshape(3, -1).T)
    misses = np.zeros(len(pts), int)
    for cam, mask in zip(cameras, masks):
        uv = cam.project(pts)
        with np.errstate(invalid="ignore"):
            pu, pv = np.floor(uv[:, 0] + 0.5), np.floor(uv[:, 1] + 0.5)
        inside = (pu >= 0) & (pu < cam.width) & (pv >= 0) & (pv < cam.height)
        hit = np.full(len(pts), keep)
        hit[inside] = mask[pv[inside].astype(int), pu[inside].astype(int)]
        misses += ~hit
    return (misses <= max_misses).reshape(grid.shape)


def rig_set(projection, convention="physical", width=90, height=80):
    """16 views on two rings plus a steep one; the grid below sticks out of
    some images so that outside_image matters."""
    f = 260.0 if projection == "orthographic" else 200.0
    cal = RigCalibration(width=width, height=height, projection=projection, fx=f, fy=f * 1.1,
                         camera_distance_m=0.8, convention=convention)
    thetas = np.linspace(0, 2 * np.pi, 8, endpoint=False) + 0.07
    return [rig_camera(t, p, cal) for p in (0.12, -0.5) for t in thetas] + \
        [rig_camera(0.3, 1.2, cal)]


def oblique_set():
    """Orthographic views with generic rotations: no grid line keeps a pixel row."""
    rng = np.random.default_rng(3)
    cams = []
    for _ in range(10):
        q = rng.normal(size=4)
        a, b, c, d = q / np.linalg.norm(q)
        R = np.array([[a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
                      [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
                      [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d]])
        K = np.array([[250.0, 0.0, 44.3], [0.0, 250.0, 38.9], [0.0, 0.0, 1.0]])
        cams.append(Camera(K, R, np.array([0.01, -0.02, 1.0]), 90, 80, orthographic=True))
    return cams


SMALL_GRID = VoxelGrid([-0.19, -0.17, -0.16], [0.2, 0.18, 0.21], 0.0113)
SPHERE_C, SPHERE_R = np.array([0.021, -0.013, 0.034]), 0.12

CAMERA_SETS = {
    "orthographic-physical": (lambda: rig_set("orthographic"), 2),
    "orthographic-paper": (lambda: rig_set("orthographic", "paper"), 0),
    "orthographic-oblique": (oblique_set, None),
    "pinhole": (lambda: rig_set("pinhole"), None),
}


@pytest.mark.parametrize("name", sorted(CAMERA_SETS))
@pytest.mark.parametrize("max_misses", [0, 1])
@pytest.mark.parametrize("outside_image", ["keep", "carve"])
def test_matches_naive_reference(name, max_misses, outside_image):
    make, line_axis = CAMERA_SETS[name]
    cams = make()
    masks = [sphere_mask(c, SPHERE_C, SPHERE_R) for c in cams]
    # The set exercises the path it is meant to (line path along line_axis, or block path).
    setup = carve_module._line_setup(view_coefficients(SMALL_GRID, cams), cams)
    assert (setup is None) == (line_axis is None)
    if setup is not None:
        assert setup[0] == line_axis
    got = carve(SMALL_GRID, cams, masks, max_misses=max_misses, outside_image=outside_image)
    want = naive_carve(SMALL_GRID, cams, masks, max_misses, outside_image == "keep")
    assert got.dtype == bool and got.shape == SMALL_GRID.shape
    assert 0 < want.sum() < want.size  # neither trivially empty nor full
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("name", ["orthographic-physical", "pinhole"])
def test_prepared_masks_carve_every_grid_as_the_masks_do(name):
    make, _ = CAMERA_SETS[name]
    cams = make()
    masks = [sphere_mask(c, SPHERE_C, SPHERE_R) for c in cams]
    prepared = PreparedMasks(cams, masks)
    # Reused over grids and options (line path and block path): bit for bit the same.
    coarse = VoxelGrid([-0.19, -0.17, -0.16], [0.2, 0.18, 0.21], 0.02)
    for grid in (SMALL_GRID, coarse):
        for max_misses in (0, 1):
            np.testing.assert_array_equal(carve(grid, cams, prepared, max_misses=max_misses),
                                          carve(grid, cams, masks, max_misses=max_misses))
    with pytest.raises(ValueError, match="other cameras"):
        carve(SMALL_GRID, cams[:-1], prepared)


@pytest.mark.parametrize("name", ["pinhole", "orthographic-oblique"])
@pytest.mark.parametrize("max_misses", [0, 3])
def test_a_mask_shared_by_views_is_tabled_once_and_carves_as_copies(name, max_misses):
    make, _ = CAMERA_SETS[name]
    cams = make()
    own = [sphere_mask(c, SPHERE_C, SPHERE_R) for c in cams]
    # Every other view shares one of two arrays (as seen_by's full frames do); the rest
    # keep their own masks, so shared and distinct tables sit side by side.
    a, b = own[0], own[1]
    shared = [a if v % 4 == 0 else b if v % 4 == 2 else m for v, m in enumerate(own)]
    copies = [m.copy() for m in shared]
    for outside_image in ("keep", "carve"):
        got = carve(SMALL_GRID, cams, shared, max_misses=max_misses, outside_image=outside_image)
        np.testing.assert_array_equal(got, naive_carve(SMALL_GRID, cams, copies, max_misses,
                                                       outside_image == "keep"))
    _, flat, moff, _, ioff, boxes, _, _ = PreparedMasks(cams, shared).block_tables()
    distinct = [v for v in range(len(cams)) if v % 2 == 1 or v < 2]
    assert flat.size == sum(boxes[v, 2] * boxes[v, 3] for v in distinct)
    assert moff[4] == moff[0] and ioff[6] == ioff[2] and (boxes[8] == boxes[0]).all()


def test_seen_by_counts_the_views_whose_image_holds_the_voxel_centre():
    cams = rig_set("pinhole")  # the grid sticks out of some images
    centres = SMALL_GRID.index_to_world(np.argwhere(np.ones(SMALL_GRID.shape, bool)))
    inside = np.zeros(len(centres), np.int64)
    for c in cams:
        uv = c.project(centres)
        # The carving's pixel test: the nearest pixel centre lies in the image.
        inside += (c.depth(centres) > 0) & (np.floor(uv[:, 0] + 0.5) >= 0) \
            & (np.floor(uv[:, 0] + 0.5) < c.width) & (np.floor(uv[:, 1] + 0.5) >= 0) \
            & (np.floor(uv[:, 1] + 0.5) < c.height)
    for n_views in (1, 9, len(cams)):
        want = (inside >= n_views).reshape(SMALL_GRID.shape)
        assert 0 < want.sum() < want.size or n_views == 1
        np.testing.assert_array_equal(seen_by(SMALL_GRID, cams, n_views), want)


def test_outside_image_matters_on_this_grid():
    cams = rig_set("orthographic", "paper")
    masks = [sphere_mask(c, SPHERE_C, SPHERE_R) for c in cams]
    keep = carve(SMALL_GRID, cams, masks, outside_image="keep")
    cut = carve(SMALL_GRID, cams, masks, outside_image="carve")
    assert np.all(cut <= keep) and keep.sum() > cut.sum()


@pytest.mark.parametrize("max_misses", [0, 2])
@pytest.mark.parametrize("outside_image", ["keep", "carve"])
def test_incremental_equals_batch_across_paths(max_misses, outside_image):
    # Physical and paper views share no line axis: the batch takes the block
    # path while the Carver takes a line path per view (Z-lines, X-lines);
    # pinhole views add the block path to the Carver too.
    cams = rig_set("orthographic")[::2] + rig_set("orthographic", "paper")[1::2] + \
        rig_set("pinhole")[::3]
    masks = [sphere_mask(c, SPHERE_C, SPHERE_R) for c in cams]
    assert carve_module._line_setup(view_coefficients(SMALL_GRID, cams), cams) is None
    carver = Carver(SMALL_GRID, max_misses=max_misses, outside_image=outside_image)
    for n, (cam, mask) in enumerate(zip(cams, masks), start=1):
        carver.add_view(cam, mask)
        assert carver.n_views == n
        if n in (1, 5, 9, len(cams)):
            np.testing.assert_array_equal(
                carver.occupancy,
                carve(SMALL_GRID, cams[:n], masks[:n], max_misses=max_misses,
                      outside_image=outside_image))


def test_sphere_hull_brackets_the_sphere():
    n_theta = 24
    cal = RigCalibration(width=160, height=160, projection="orthographic", fx=500.0, fy=500.0)
    cams = [rig_camera(t, math.radians(p), cal)
            for p in (0, 35, 70) for t in np.linspace(0, 2 * np.pi, n_theta, endpoint=False)]
    centre, radius = np.array([0.01, -0.02, 0.015]), 0.1
    grid = VoxelGrid.cube([-0.14] * 3, [0.14] * 3, 70)  # 4 mm voxels = 2 px
    occ = carve(grid, cams, [sphere_mask(c, centre, radius) for c in cams])
    dist = np.linalg.norm(grid.index_to_world(np.indices(grid.shape).reshape(3, -1).T) - centre,
                          axis=1).reshape(grid.shape)
    pixel_m = 1.0 / cal.fx
    # Inside: a centre within radius - half a pixel diagonal projects onto a
    # pixel whose centre is inside the silhouette disc, in every view; one
    # voxel (2 px) is more than that margin.
    assert np.all(occ[dist <= radius - grid.voxel_size])
    # Outside: a kept centre is within radius + half a pixel diagonal of the
    # axis of every view; the horizontal ring has a view within half a theta
    # step of perpendicular to any direction, so |x| cos(step / 2) <= that.
    outer = (radius + HALF_PIXEL_DIAGONAL_PX * pixel_m) / math.cos(math.pi / n_theta)
    assert not np.any(occ[dist > outer])
    assert np.sum(occ) < np.sum(dist <= outer)


def _axis_camera(forward, right, scale_px_per_m, size, centre_px):
    down = np.cross(forward, right)
    R = np.array([right, down, forward], dtype=float)
    K = np.array([[scale_px_per_m, 0, centre_px], [0, scale_px_per_m, centre_px], [0, 0, 1.0]])
    return Camera(K, R, np.zeros(3), size, size, orthographic=True)


def _box_mask(camera, lo, hi):
    """(H, W) bool: pixels whose centre's line of sight crosses the box."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    xc = (u - camera.K[0, 2]) / camera.K[0, 0]
    yc = (v - camera.K[1, 2]) / camera.K[1, 1]
    mask = np.ones_like(u, dtype=bool)
    for row, coord in ((camera.R[0], xc), (camera.R[1], yc)):
        axis = int(np.argmax(np.abs(row)))  # axis-aligned views: one world axis per image axis
        world = coord * row[axis]
        mask &= (world >= lo[axis]) & (world <= hi[axis])
    return mask


@pytest.mark.parametrize("with_pinhole", [False, True])
def test_cuboid_from_three_axis_views_is_exact(with_pinhole):
    voxel = 0.01
    grid = VoxelGrid([-0.2] * 3, [0.2] * 3, voxel)
    lo, hi = np.array([-0.123, -0.052, -0.171]), np.array([0.088, 0.147, 0.031])
    # 1 px per voxel with pixel centres on voxel centres; the box faces lie
    # between voxel centres, so nothing is on a boundary.
    scale, size = 1.0 / voxel, 60
    c = (size - 1) / 2.0  # with origin -0.195 m: voxel i lands on pixel centre i + 10
    cams = [_axis_camera([1, 0, 0], [0, 1, 0], scale, size, c),   # along X
            _axis_camera([0, 1, 0], [0, 0, 1], scale, size, c),   # along Y, image turned
            _axis_camera([0, 0, 1], [1, 0, 0], scale, size, c)]   # along Z
    masks = [_box_mask(cam, lo, hi) for cam in cams]
    if with_pinhole:  # a view seeing everything forces the block path, changes nothing
        cams.append(Camera(np.array([[300.0, 0, 40], [0, 300.0, 40], [0, 0, 1]]), np.eye(3),
                           [0, 0, 2.0], 80, 80))
        masks.append(np.ones((80, 80), bool))
    assert (carve_module._line_setup(view_coefficients(grid, cams), cams) is None) == with_pinhole
    centres = grid.index_to_world(np.indices(grid.shape).reshape(3, -1).T)
    want = np.all((centres >= lo) & (centres <= hi), axis=1).reshape(grid.shape)
    np.testing.assert_array_equal(carve(grid, cams, masks), want)


def test_integer_masks_accepted():
    cams = rig_set("orthographic")[:4]
    masks = [sphere_mask(c, SPHERE_C, SPHERE_R) for c in cams]
    np.testing.assert_array_equal(carve(SMALL_GRID, cams, [m.astype(np.uint8) for m in masks]),
                                  carve(SMALL_GRID, cams, masks))


def test_no_views_keeps_everything():
    assert carve(SMALL_GRID, [], []).all()
    assert Carver(SMALL_GRID).occupancy.all()


def test_bad_mask_shape_names_the_view():
    cams = rig_set("orthographic")[:3]
    masks = [np.zeros((80, 90), bool), np.zeros((90, 80), bool), np.zeros((80, 90), bool)]
    with pytest.raises(ValueError, match=r"view 1 has shape \(90, 80\).*\(80, 90\)"):
        carve(SMALL_GRID, cams, masks)
    with pytest.raises(ValueError, match=r"view 0 has shape \(80, 90, 3\)"):
        Carver(SMALL_GRID).add_view(cams[0], np.zeros((80, 90, 3), bool))


def test_bad_mask_values_and_counts():
    cams = rig_set("orthographic")[:2]
    with pytest.raises(ValueError, match="view 1 must be bool or hold only 0 and 1"):
        carve(SMALL_GRID, cams, [np.zeros((80, 90)), np.full((80, 90), 255, np.uint8)])
    with pytest.raises(ValueError, match="2 cameras but 1 masks"):
        carve(SMALL_GRID, cams, [np.zeros((80, 90), bool)])


@pytest.mark.parametrize("kwargs", [{"max_misses": -1}, {"max_misses": 1.5},
                                    {"outside_image": "drop"}])
def test_bad_options(kwargs):
    with pytest.raises(ValueError):
        carve(SMALL_GRID, [], [], **kwargs)
    with pytest.raises(ValueError):
        Carver(SMALL_GRID, **kwargs)
