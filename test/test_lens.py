"""Lens distortion through the renderer and the carving: against exact ray-sphere silhouettes.

The lens is the calibration scene's (k1 = -0.18, k2 = 0.08, small tangential terms):
about 9 pixels of barrel at the corners of a 640 x 480 image with f = 1400 px, and
30 px at the corners with f = 800 px (the scene's own lens).
"""

import math

import numpy as np
import pytest

from sfs_ros.core.carving.carve import carve
from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.geometry.lens import distort_mask, ideal_camera, undistort_image, undistort_mask
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.metrics import occupancy_from_contains, silhouette_iou, volume_iou
from sfs_ros.core.render import rasterize_silhouette

from analytic_masks import sphere_mask

LENS = (-0.18, 0.08, 0.0012, -0.0008, 0.0)
CENTRE, RADIUS = np.array([0.04, -0.005, 0.05]), 0.045   # off the axis: more bending
RIG = RigCalibration(width=640, height=480, projection="pinhole", fx=800.0, fy=800.0,
                     cx=324.5, cy=236.0, camera_distance_m=0.3, aim_point_m=(0.0, 0.0, 0.05),
                     distortion=LENS)
VIEWS = [(math.radians(t), math.radians(p)) for p in (5, 35, 65) for t in range(0, 360, 45)]
# A pixel-centre test is exact up to the pixels on the silhouette's edge: the renderer's
# nearest-pixel resampling may move the edge by one pixel, about 1 % of a 50 px disc's area.
EDGE_PIXELS_IOU = 0.99


def test_the_rendered_silhouette_is_the_lens_image_of_the_sphere():
    # Ground truth: the ray of every pixel centre through the lens meets the sphere.
    from sfs_ros.core.simulation.objects import make_object
    sphere = make_object("sphere")
    shift = np.array([0.04, 0.0, 0.0])          # off the axis, where the lens bends more
    centre, radius = np.array([0.0, 0.0, 0.05]) + shift, 0.05
    for theta, phi in VIEWS[::5]:
        camera = rig_camera(theta, phi, RIG)
        got = rasterize_silhouette(sphere.mesh.vertices + shift, sphere.mesh.faces, camera)
        truth = sphere_mask(camera, centre, radius)
        ideal = sphere_mask(ideal_camera(camera), centre, radius)
        # The faceted mesh lies inside the sphere (its edge pixels differ) and the
        # resampling moves the edge by under a pixel; ignoring the lens is far worse.
        assert silhouette_iou(got, truth) > 0.99
        assert 1 - silhouette_iou(got, truth) < 0.5 * (1 - silhouette_iou(ideal, truth))


def test_undistorting_a_mask_gives_the_ideal_cameras_mask():
    for theta, phi in VIEWS[::3]:
        camera = rig_camera(theta, phi, RIG)
        taken = sphere_mask(camera, CENTRE, RADIUS)
        ideal = sphere_mask(ideal_camera(camera), CENTRE, RADIUS)
        got = silhouette_iou(undistort_mask(taken, camera), ideal)
        assert got > EDGE_PIXELS_IOU
        assert 1 - got < 0.5 * (1 - silhouette_iou(taken, ideal))   # the lens matters here


def test_distorting_the_ideal_cameras_mask_gives_the_lens_image():
    for theta, phi in VIEWS[::3]:
        camera = rig_camera(theta, phi, RIG)
        taken = sphere_mask(camera, CENTRE, RADIUS)
        ideal = sphere_mask(ideal_camera(camera), CENTRE, RADIUS)
        got = silhouette_iou(distort_mask(ideal, camera), taken)
        assert got > EDGE_PIXELS_IOU
        assert 1 - got < 0.5 * (1 - silhouette_iou(ideal, taken))   # the lens matters here
        # The way there and back moves only edge pixels.
        assert silhouette_iou(distort_mask(undistort_mask(taken, camera), camera),
                              taken) > EDGE_PIXELS_IOU
    plain = ideal_camera(rig_camera(*VIEWS[0], RIG))
    mask = sphere_mask(plain, CENTRE, RADIUS)
    np.testing.assert_array_equal(distort_mask(mask, plain), mask)


def _grid():
    return VoxelGrid.cube(CENTRE - 1.2 * RADIUS, CENTRE + 1.2 * RADIUS, 96)


def _exact_distorted_carve(grid, cameras, masks):
    """Reference: every voxel centre projected through the lens, tested in its pixel."""
    centres = grid.index_to_world(np.indices(grid.shape).reshape(3, -1).T)
    keep = np.ones(len(centres), bool)
    for camera, mask in zip(cameras, masks):
        uv = np.rint(camera.project_distorted(centres))
        inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) \
            & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
        col = np.where(inside, uv[:, 0], 0).astype(int)
        row = np.where(inside, uv[:, 1], 0).astype(int)
        keep &= ~inside | mask[row, col]
    return keep.reshape(grid.shape)


def test_carving_undistorted_masks_is_the_exact_distorted_projection():
    cameras = [rig_camera(t, p, RIG) for t, p in VIEWS]
    masks = [sphere_mask(c, CENTRE, RADIUS) for c in cameras]
    grid = _grid()
    truth = occupancy_from_contains(
        lambda x: np.linalg.norm(x - CENTRE, axis=1) <= RADIUS, grid)
    exact = _exact_distorted_carve(grid, cameras, masks)
    undistorted = carve(grid, [ideal_camera(c) for c in cameras],
                        [undistort_mask(m, c) for m, c in zip(masks, cameras)])
    as_if_ideal = carve(grid, [ideal_camera(c) for c in cameras], masks)
    # Undistorting the masks once carves what projecting every voxel through the lens
    # carves, up to voxels whose centre sits within a pixel of a silhouette edge (the
    # nearest-pixel resampling adds half a pixel to the rounding's): measured 0.9949
    # agreement, 0.9926 against the truth for 0.9938 exact (0.9740 ignoring the lens).
    assert volume_iou(undistorted, exact) > 0.99
    assert volume_iou(undistorted, truth) == pytest.approx(volume_iou(exact, truth), abs=0.002)
    # Ignoring the lens carves real object away.
    assert volume_iou(as_if_ideal, truth) < volume_iou(undistorted, truth) - 0.01


def test_an_undistorted_image_keeps_its_channels_and_blanks_what_the_lens_does_not_see():
    camera = Camera(K=[[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]], R=np.eye(3),
                    t=[0.0, 0.0, 1.0], width=320, height=240, distortion=(0.3, 0, 0, 0, 0))
    image = np.full((240, 320, 3), 200, np.uint8)
    out = undistort_image(image, camera)
    assert out.shape == image.shape and out.dtype == np.uint8
    # Pincushion: the ideal corners lie outside the lens's image, the centre inside.
    assert not out[0, 0].any() and (out[120, 160] == 200).all()
    with pytest.raises(ValueError, match=r"expected the camera's \(height, width\) = \(240, 320\)"):
        undistort_image(image[:100], camera)
