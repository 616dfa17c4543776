"""Metrics: IoUs, ground-truth occupancy, mesh occupancy by column winding, Chamfer."""

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.metrics import (
    ChamferResult,
    chamfer_distance,
    mesh_occupancy,
    occupancy_from_contains,
    reprojection_iou,
    silhouette_iou,
    volume_iou,
)
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.objects import OBJECT_NAMES, make_object

from tolerances import ROUND_OFF


def test_volume_iou():
    a = np.zeros((4, 4, 4), bool)
    b = np.zeros((4, 4, 4), bool)
    a[:2] = True
    b[1:3] = True
    assert volume_iou(a, b) == pytest.approx(1 / 3, abs=ROUND_OFF)  # 16 shared of 48
    assert volume_iou(a, a) == 1.0
    assert volume_iou(a, ~a) == 0.0
    assert volume_iou(np.zeros((2, 2, 2), bool), np.zeros((2, 2, 2), bool)) == 1.0
    with pytest.raises(ValueError, match="same shape"):
        volume_iou(a, b[:3])
    with pytest.raises(ValueError, match="bool"):
        volume_iou(a.astype(np.uint8), b)


def test_silhouette_iou():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[2:6, 2:6] = True   # 16 px
    b[4:8, 2:6] = True   # 16 px, 8 shared
    assert silhouette_iou(a, b) == pytest.approx(8 / 24, abs=ROUND_OFF)
    assert silhouette_iou(b, a) == silhouette_iou(a, b)
    assert silhouette_iou(np.zeros((3, 3), bool), np.zeros((3, 3), bool)) == 1.0  # both empty
    assert silhouette_iou(a, np.zeros((10, 10), bool)) == 0.0
    with pytest.raises(ValueError, match="same shape"):
        silhouette_iou(a, b[:, :9])
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        silhouette_iou(a[None], b[None])


def test_reprojection_iou():
    """Against the exact disc image of the sphere: the inscribed mesh's silhouette lies
    between the discs of its inscribed ball and of the sphere, so the IoU is at least
    the ratio of their centre counts."""
    mesh = make_object("sphere").mesh
    camera = rig_camera(0.3, 0.6, RigCalibration(width=160, height=160, fx=1200.0, fy=1200.0,
                                                 aim_point_m=(0, 0, 0.05)))
    own = rasterize_silhouette(mesh.vertices, mesh.faces, camera)
    assert reprojection_iou(mesh.vertices, mesh.faces, camera, own) == 1.0
    v, u = np.mgrid[0:160, 0:160]
    cu, cv = camera.project(np.array([[0, 0, 0.05]]))[0]
    rho = np.hypot(u - cu, v - cv)
    r_in = np.min(np.abs(np.einsum("ij,ij->i", mesh.face_normals,
                                   mesh.vertices[mesh.faces[:, 0]] - [0, 0, 0.05])))
    outer, inner = rho <= 0.05 * 1200 * (1 + 1e-9), rho <= r_in * 1200 * (1 - 1e-9)
    iou = reprojection_iou(mesh.vertices, mesh.faces, camera, outer)
    assert inner.sum() / outer.sum() <= iou <= 1.0
    with pytest.raises(ValueError, match="does not match the camera"):
        reprojection_iou(mesh.vertices, mesh.faces, camera, outer[:, :100])


@pytest.fixture(scope="module")
def small_grid():
    return VoxelGrid([-0.03, -0.02, 0.0], [0.03, 0.025, 0.04], 0.0025)


def test_occupancy_from_contains(small_grid):
    grid = small_grid

    def ellipsoid(points):
        return ((points[:, 0] / 0.025) ** 2 + (points[:, 1] / 0.015) ** 2
                + ((points[:, 2] - 0.02) / 0.018) ** 2) <= 1.0

    ijk = np.indices(grid.shape).reshape(3, -1).T
    expected = ellipsoid(grid.index_to_world(ijk)).reshape(grid.shape)
    got = occupancy_from_contains(ellipsoid, grid)
    assert got.shape == grid.shape and got.dtype == bool and got.any()
    np.testing.assert_array_equal(got, expected)
    # chunks smaller than one X-plane still cover every voxel once
    np.testing.assert_array_equal(occupancy_from_contains(ellipsoid, grid, chunk_voxels=7),
                                  expected)
    with pytest.raises(ValueError, match="contains_fn must return"):
        occupancy_from_contains(lambda p: np.ones(3, bool), grid)
    with pytest.raises(ValueError, match="chunk_voxels"):
        occupancy_from_contains(ellipsoid, grid, chunk_voxels=0)


def box_mesh(lo, hi, *, bottom_diagonal, top_diagonal):
    """Outward box with chosen diagonals on the bottom and top faces ("main": corner 0-2 of
    the face, "anti": 1-3), so crossings through shared edges can be placed on columns."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)
    bottom = {"main": [[0, 2, 1], [0, 3, 2]], "anti": [[1, 0, 3], [1, 3, 2]]}[bottom_diagonal]
    top = {"main": [[4, 5, 6], [4, 6, 7]], "anti": [[5, 6, 7], [5, 7, 4]]}[top_diagonal]
    sides = [[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
             [3, 0, 4], [3, 4, 7]]
    return v, np.array(bottom + top + sides)


@pytest.mark.parametrize("diagonals", [("main", "anti"), ("anti", "main"), ("main", "main")])
def test_mesh_occupancy_exact_on_column_ties(diagonals):
    """Corners, edges and face diagonals exactly on column centres: every shared edge and
    vertex must be crossed once (counting a diagonal twice on the bottom and once on the
    top, or not at all, would leave the winding wrong above or inside the box)."""
    grid = VoxelGrid([0, 0, 0], [16, 16, 16], 1.0)  # centres at 0.5 + i
    vertices, faces = box_mesh((3.5, 3.5, 2.25), (10.5, 10.5, 9.75), bottom_diagonal=diagonals[0],
                               top_diagonal=diagonals[1])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    expected = np.zeros(grid.shape, bool)
    # Columns on the box's x = 3.5 and y = 3.5 edges count as inside and those on
    # x = 10.5, y = 10.5 as outside (ties go to the side of the (+eps, +eps^2) shift).
    expected[3:10, 3:10, 2:10] = True  # z centres 2.5 ... 9.5 lie in (2.25, 9.75)
    np.testing.assert_array_equal(mesh_occupancy(vertices, faces, grid), expected)


def test_mesh_occupancy_union_and_orientation():
    grid = VoxelGrid([0, 0, 0], [16, 16, 16], 1.0)
    a = box_mesh((1.2, 1.2, 1.2), (8.8, 8.8, 8.8), bottom_diagonal="main", top_diagonal="anti")
    b = box_mesh((5.2, 5.2, 5.2), (12.8, 12.8, 12.8), bottom_diagonal="anti", top_diagonal="main")
    vertices = np.vstack([a[0], b[0]])
    faces = np.vstack([a[1], b[1] + len(a[0])])
    expected = np.zeros(grid.shape, bool)
    expected[1:9, 1:9, 1:9] = True      # centres 1.5 ... 8.5
    expected[5:13, 5:13, 5:13] = True   # centres 5.5 ... 12.5
    np.testing.assert_array_equal(mesh_occupancy(vertices, faces, grid), expected)
    # an inward-facing (inverted) mesh has winding -1 inside: nothing is occupied
    assert not mesh_occupancy(a[0], a[1][:, ::-1], grid).any()


@pytest.mark.parametrize("name", OBJECT_NAMES)
def test_mesh_occupancy_matches_object(name):
    """Voxel centres classified differently from the exact inside test must lie within the
    mesh's faceting error of the true surface: a centre deeper than that inside some part is
    inside that part's closed mesh (winding >= 1), one farther than that from every part is
    outside all of them (winding 0). The grid is offset by a third of a voxel so no centre
    sits on a symmetry plane of the meshes."""
    obj = make_object(name)
    lo, hi = obj.bounds
    grid = VoxelGrid(lo - 0.002 + 0.0003, hi + 0.002, 0.001)
    occupancy = mesh_occupancy(obj.mesh.vertices, obj.mesh.faces, grid)
    truth = occupancy_from_contains(obj.contains, grid)
    wrong = grid.index_to_world(np.argwhere(occupancy != truth))
    assert np.all(np.abs(obj.signed_distance(wrong)) <= obj.mesh_error_m)
    assert volume_iou(occupancy, truth) > 0.99


def test_mesh_occupancy_bad_input():
    grid = VoxelGrid([0, 0, 0], [4, 4, 4], 1.0)
    with pytest.raises(ValueError, match="face indices"):
        mesh_occupancy(np.zeros((3, 3)), np.array([[0, 1, 3]]), grid)
    assert not mesh_occupancy(np.zeros((0, 3)), np.zeros((0, 3), int), grid).any()


def test_chamfer_identical_and_shifted():
    g = np.arange(0.0, 0.05, 0.01)
    a = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    same = chamfer_distance(a, a)
    assert isinstance(same, ChamferResult)
    assert same.a_to_b_mean == same.b_to_a_mean == same.mean == same.hausdorff == 0.0
    # a shift shorter than half the spacing: every nearest neighbour is the shifted twin
    shift = np.array([0.001, -0.002, 0.002])  # |shift| = 3 mm < 5 mm
    moved = chamfer_distance(a, a + shift)
    for value in (moved.a_to_b_mean, moved.b_to_a_mean, moved.mean, moved.hausdorff):
        assert value == pytest.approx(0.003, abs=ROUND_OFF)


def test_chamfer_asymmetric():
    a = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0]])
    b = np.vstack([a, [[0.02, 0.05, 0]]])  # one extra point 0.05 m from its nearest in a
    r = chamfer_distance(a, b)
    assert r.a_to_b_mean == 0.0
    assert r.b_to_a_mean == pytest.approx(0.05 / 4, abs=ROUND_OFF)
    assert r.mean == pytest.approx(0.05 / 8, abs=ROUND_OFF)
    assert r.hausdorff == pytest.approx(0.05, abs=ROUND_OFF)
    with pytest.raises(ValueError, match="points_b must be a non-empty"):
        chamfer_distance(a, np.zeros((0, 3)))
    with pytest.raises(ValueError, match="points_a"):
        chamfer_distance(a[:, :2], b)


def test_reprojection_iou_of_empty_mesh():
    camera = Camera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=5, height=4, orthographic=True)
    assert reprojection_iou(np.zeros((0, 3)), np.zeros((0, 3), int), camera,
                            np.zeros((4, 5), bool)) == 1.0


def test_mesh_occupancy_of_marching_cubes_mesh_is_its_occupancy():
    # Marching cubes puts vertices and vertical faces exactly on voxel-column
    # lines: the degenerate case for ray parity. The mesh surrounds exactly the
    # occupied voxel centres, so the round trip must be exact, voxel for voxel.
    from sfs_ros.core.meshing.marching import marching_cubes_mesh

    rng = np.random.default_rng(3)
    grid = VoxelGrid([0, 0, 0], [1, 1, 1], 1 / 40)
    occupancy = ndimage.binary_opening(rng.random(grid.shape) < 0.6, iterations=1)
    for sigma in (0.0, 0.5):
        vertices, faces = marching_cubes_mesh(occupancy, grid, smooth_sigma_vox=sigma)
        np.testing.assert_array_equal(mesh_occupancy(vertices, faces, grid), occupancy)
