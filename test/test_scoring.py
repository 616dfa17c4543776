"""Scoring against the truth: exact silhouettes and the true visual hull, and the fast
reprojection IoU of all views at once."""

import numpy as np
import pytest
import trimesh

from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.metrics import reprojection_iou, reprojection_ious
from sfs_ros.core.outline import edge_faces
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.synthetic import (
    exact_silhouettes,
    score_against_truth,
    true_visual_hull,
)


@pytest.fixture(scope="module")
def scored(mug, mug_views):
    cameras = [v.camera for v in mug_views.views][::4]  # 13 of the 49 views: enough, and quick
    grid = VoxelGrid.cube(*mug_views.bounds_m, 64)
    return cameras, grid


def test_all_views_at_once_equal_one_by_one(mug, scored):
    cameras, _ = scored
    v, f = mug.mesh.vertices, mug.mesh.faces
    # The masks: the mug's silhouettes shifted by a pixel, so the IoUs are not all 1.
    masks = [np.roll(rasterize_silhouette(v, f, c), 1, axis=1) for c in cameras]
    one_by_one = [reprojection_iou(v, f, c, m) for c, m in zip(cameras, masks)]
    # Same pixel-centre rule: equal to rounding; closed=True draws only the
    # faces turned to the camera, and a closed mesh's silhouette is theirs.
    assert reprojection_ious(v, f, cameras, masks) == pytest.approx(one_by_one, abs=1e-12)
    assert reprojection_ious(v, f, cameras, masks, closed=True) == pytest.approx(one_by_one,
                                                                                abs=1e-3)
    with pytest.raises(ValueError, match="bool array"):
        reprojection_ious(v, f, cameras, [m.astype(np.uint8) for m in masks])


def test_a_closed_mesh_is_covered_from_its_outline_as_drawn(mug, scored):
    cameras, _ = scored
    v, f = mug.mesh.vertices, mug.mesh.faces
    drawn = [rasterize_silhouette(v, f, c) for c in cameras]
    # The outline winds round exactly the centres the faces cover: the two may
    # differ only at a centre exactly on an outline edge, which none of these
    # views (at generic angles) has; the handle's hole is a second, inner loop.
    assert np.all(reprojection_ious(v, f, cameras, drawn, closed=True) == 1.0)


def test_views_moved_and_cut_by_the_image_border_cover_as_drawn_one_after_another(mug, scored):
    # Each view's crossings are counted in a scratch that the next view on its thread
    # reuses, those right of its box and out of the image too: views of the mug moved
    # sideways by a tenth of the image (its outline's crossings where the next view's
    # lie) and cut by the image's left, right, top or bottom border (the principal point
    # moved by half the image), two at a time between two whole views.
    cameras, _ = scored
    v, f = mug.mesh.vertices, mug.mesh.faces
    shifts = [(-0.1, 0.0), (0.1, 0.0), (-0.5, 0.0), (0.5, 0.0), (0.0, -0.5), (0.0, 0.5)]
    views = []
    for n, (dx, dy) in enumerate(shifts):
        moved = []
        for c in cameras[2 * n:2 * n + 2]:
            K = c.K.copy()
            K[0, 2] += dx * c.width
            K[1, 2] += dy * c.height
            moved.append(Camera(K=K, R=c.R, t=c.t, width=c.width, height=c.height))
        views += moved + cameras[2 * n:2 * n + 2]
    drawn = [rasterize_silhouette(v, f, c) for c in views]
    assert all(0 < d.sum() < d.size for d in drawn)
    assert np.all(reprojection_ious(v, f, views, drawn, closed=True) == 1.0)


def _bar_and_camera(far_end_m: float):
    """A bar along y from -0.1 m to ``far_end_m``, and a camera 1 m above it at y = 0.5
    looking along -y, 60 degrees down: the bar's far end runs towards the camera's plane
    (its top corners cross it at y = 2.06 m)."""
    bar = trimesh.creation.box(bounds=[[-0.1, -0.1, -0.1], [0.1, far_end_m, 0.1]])
    down = np.radians(60.0)
    R = np.array([[-1.0, 0.0, 0.0],                        # x: right in the image
                  [0.0, np.sin(down), -np.cos(down)],     # y: down in the image
                  [0.0, -np.cos(down), -np.sin(down)]])   # z: forward, along -y and down
    camera = Camera(K=np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]]), R=R,
                    t=-R @ np.array([0.0, 0.5, 1.0]), width=320, height=240)
    return np.asarray(bar.vertices), np.asarray(bar.faces), camera


def test_a_view_with_the_mesh_partly_behind_it_is_drawn():
    # The far end behind the camera, where the outline's projection would be
    # meaningless: the faces are drawn instead.
    v, f, camera = _bar_and_camera(5.0)
    assert camera.depth(v).min() < 0 < camera.depth(v).max()
    drawn = rasterize_silhouette(v, f, camera)
    assert 0 < drawn.sum() < drawn.size
    assert reprojection_ious(v, f, [camera], [drawn], closed=True)[0] == 1.0


def test_an_outline_reaching_far_out_of_the_image_covers_it_as_drawn():
    # The far end a micrometre in front of the camera's plane: its corners project
    # about 1e8 pixels away, the outline's edges cross the image steeply.
    top_crossing_m = 0.5 + 2.0 * np.sin(np.radians(60.0)) * 0.9
    v, f, camera = _bar_and_camera(top_crossing_m - 1e-6)
    assert 0 < camera.depth(v).min() < 1e-5
    assert np.abs(camera.project(v)).max() > 1e7
    drawn = rasterize_silhouette(v, f, camera)
    assert 0 < drawn.sum() < drawn.size
    assert reprojection_ious(v, f, [camera], [drawn], closed=True)[0] == 1.0


def test_edge_faces_pairs_each_edge_of_a_closed_mesh_and_only_of_one():
    tetrahedron = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    ends, sides = edge_faces(tetrahedron, 4)
    assert sorted(map(tuple, ends.tolist())) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3),
                                                 (2, 3)]
    for (a, b), (forward, backward) in zip(ends, sides):
        assert any(tetrahedron[forward, k] == a and tetrahedron[forward, (k + 1) % 3] == b
                   for k in range(3))
        assert any(tetrahedron[backward, k] == b and tetrahedron[backward, (k + 1) % 3] == a
                   for k in range(3))
    assert edge_faces(tetrahedron[:3], 4) is None                  # a face missing: open
    flipped = tetrahedron.copy()
    flipped[3] = flipped[3, ::-1]
    assert edge_faces(flipped, 4) is None                           # one face turned over
    assert edge_faces(np.vstack([tetrahedron, tetrahedron[:1]]), 4) is None  # an edge used 3x


def test_the_true_mesh_scores_perfectly_and_its_hull_contains_it(mug, scored):
    cameras, grid = scored
    score = score_against_truth(mug, mug.mesh.vertices, mug.mesh.faces, grid, cameras=cameras)
    # The true mesh's silhouettes are the exact silhouettes: IoU 1 in every view.
    assert score["exact_silhouette_iou"]["min"] == pytest.approx(1.0)
    # 13 views leave the hull wider than the mug (its handle's hole is not seen
    # through by all): the true hull is no closer than zero and, at 128 voxels
    # of ~1 mm along the longest side, its surface lies within a few voxels of
    # the mug's outside.
    assert 0.0 < score["chamfer_to_true_hull_m"] < 0.005
    hull_v, _ = true_visual_hull(cameras, exact_silhouettes(mug, cameras), grid)
    assert np.all(hull_v.min(axis=0) <= mug.mesh.vertices.min(axis=0) + grid.voxel_size)
    assert np.all(hull_v.max(axis=0) >= mug.mesh.vertices.max(axis=0) - grid.voxel_size)
