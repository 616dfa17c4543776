"""COLMAP text model input: cameras and poses against the ones written, lenses, bad files,
and a scan through a distorted lens reconstructing as well as through an ideal one."""

import math
import shutil
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sfs_ros.core.exchange.colmap import read_colmap
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.pose_export import write_colmap
from sfs_ros.core.exchange.views import ViewError
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.metrics import mesh_occupancy, volume_iou
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.render import render_image
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth

# Poses go through a quaternion printed with repr(): exact to float64 round-off, far
# below a pixel at these distances.
PROJECTION_PX = 1e-8


def test_the_exported_model_reads_back_as_the_same_cameras(mug_views, tmp_path):
    model = write_colmap(mug_views, tmp_path / "sparse" / "0")
    (tmp_path / "images").mkdir()
    for view in mug_views.views:
        shutil.copy(view.image_path, tmp_path / "images" / view.name)
    views = load_views(model)
    assert views.source == "colmap" and not views.rejected
    assert [v.name for v in views.views] == [v.name for v in mug_views.views]
    points = np.array([[0.0, 0.0, 0.0], [0.03, -0.02, 0.05], [-0.04, 0.01, 0.09]])
    for got, want in zip(views.views, mug_views.views):
        np.testing.assert_allclose(got.camera.project(points), want.camera.project(points),
                                   atol=PROJECTION_PX)
        assert (got.camera.width, got.camera.height) == (want.camera.width, want.camera.height)
        assert not np.any(got.camera.distortion)
    assert len(load_views(model / "images.txt").views) == len(mug_views.views)


def _model(folder, camera_line, *, image_lines=None):
    (folder / "images").mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "images" / "a.png"), np.zeros((30, 40, 3), np.uint8))
    (folder / "cameras.txt").write_text("# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
                                        + camera_line + "\n")
    lines = image_lines or ["1 1 0 0 0 0.1 0.2 2.0 1 a.png", ""]
    (folder / "images.txt").write_text("# header\n" + "\n".join(lines) + "\n")
    return folder


@pytest.mark.parametrize("line, K, lens", [
    ("1 SIMPLE_PINHOLE 40 30 50 20 15", (50, 50, 19.5, 14.5), (0, 0, 0, 0, 0)),
    ("1 PINHOLE 40 30 50 52 20.5 15", (50, 52, 20, 14.5), (0, 0, 0, 0, 0)),
    ("1 SIMPLE_RADIAL 40 30 50 20 15 -0.1", (50, 50, 19.5, 14.5), (-0.1, 0, 0, 0, 0)),
    ("1 RADIAL 40 30 50 20 15 -0.1 0.02", (50, 50, 19.5, 14.5), (-0.1, 0.02, 0, 0, 0)),
    ("1 OPENCV 40 30 50 52 20 15 -0.1 0.02 0.001 -0.002", (50, 52, 19.5, 14.5),
     (-0.1, 0.02, 0.001, -0.002, 0)),
])
def test_camera_models(tmp_path, line, K, lens):
    view = read_colmap(_model(tmp_path, line)).views[0]
    camera = view.camera
    np.testing.assert_array_equal([camera.K[0, 0], camera.K[1, 1], camera.K[0, 2],
                                   camera.K[1, 2]], K)
    np.testing.assert_array_equal(camera.distortion, lens)
    np.testing.assert_array_equal(camera.R, np.eye(3))       # the identity quaternion
    np.testing.assert_array_equal(camera.t, [0.1, 0.2, 2.0])
    assert view.image_path == tmp_path / "images" / "a.png"


@pytest.mark.parametrize("line, images, message", [
    ("1 FULL_OPENCV 40 30 50 52 20 15 0 0 0 0 0 0 0 0", None,
     "camera model 'FULL_OPENCV' is not supported; expected one of SIMPLE_PINHOLE"),
    ("1 PINHOLE 40 30 50 52 20", None, r"a PINHOLE camera has 4 parameters \(fx fy cx cy\)"),
    ("1 PINHOLE 40.5 30 50 52 20 15", None, "whole numbers of pixels"),
    ("1 PINHOLE 40 30 50 nan 20 15", None, "values must be finite"),
    ("1 PINHOLE 40 30 50 52 20 15", ["1 1 0 0 0 0 0 2 7 a.png", ""],
     "refers to camera '7', which cameras.txt does not define"),
    ("1 PINHOLE 40 30 50 52 20 15", ["1 1 0 0 0 0 0 2 1 b.png", ""], r"b.png does not exist"),
    ("1 PINHOLE 40 30 50 52 20 15", ["1 1 0 0 0 0 0 2 1 ../a.png", ""],
     "must be a relative path inside"),
    ("1 PINHOLE 40 30 50 52 20 15", ["1 1 0 0 0 0 2", ""], "expected IMAGE_ID QW QX"),
    ("1 PINHOLE 40 30 50 52 20 15", ["1 0 0 0 0 0 0 2 1 a.png", ""],
     r"no usable image \(1 rejected, first: a.png: rotation quaternion"),
])
def test_bad_models_are_refused_naming_the_line(tmp_path, line, images, message):
    with pytest.raises(ViewError, match=message):
        read_colmap(_model(tmp_path, line, image_lines=images))


def test_a_missing_file_is_named(tmp_path):
    folder = _model(tmp_path, "1 PINHOLE 40 30 50 52 20 15")
    (folder / "images.txt").unlink()
    with pytest.raises(ViewError, match="has no images.txt"):
        load_views(folder)


def _colmap_scan(folder, rig):
    """The mug rendered through ``rig`` at 24 views, written as an OPENCV COLMAP model."""
    obj = make_object("mug")
    (folder / "images").mkdir(parents=True)
    lines = []
    for n, (theta, phi) in enumerate(ring_plan([15, 45, 75], 8)):
        camera = rig_camera(theta, phi, rig)
        image = render_image(obj.mesh.vertices, obj.mesh.faces, camera,
                             vertex_colors=obj.color_at(obj.mesh.vertices), seed=n)
        cv2.imwrite(str(folder / "images" / f"v{n:02d}.png"), image[:, :, ::-1])
        qx, qy, qz, qw = Rotation.from_matrix(np.array(camera.R)).as_quat().tolist()
        lines += [f"{n + 1} {qw!r} {qx!r} {qy!r} {qz!r} " + " ".join(map(repr, camera.t.tolist()))
                  + f" 1 v{n:02d}.png", ""]
    K = rig.K.tolist()
    values = [K[0][0], K[1][1], K[0][2] + 0.5, K[1][2] + 0.5, *rig.distortion[:4]]
    (folder / "cameras.txt").write_text(f"1 OPENCV {rig.width} {rig.height} "
                                        + " ".join(map(repr, values)) + "\n")
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    return load_views(folder), obj


def test_a_distorted_scan_reconstructs_as_well_as_an_undistorted_one(tmp_path):
    # The NeRF input's test scene (test_nerf.py), through COLMAP's OPENCV model.
    lens = (-0.3, 0.1, 0.001, -0.001, 0.0)
    rig = RigCalibration(width=320, height=240, projection="pinhole", fx=300.0, fy=300.0,
                         camera_distance_m=0.22, aim_point_m=(0.0, 0.0, 0.045))
    params = ReconstructionParams(resolution=72,
                                  bounds_m=carving_box(make_object("mug")).tolist())
    results, obj = {}, None
    for name, d in [("ideal", rig.distortion), ("lens", lens)]:
        views, obj = _colmap_scan(tmp_path / name, replace(rig, distortion=d))
        assert math.isclose(views.views[0].camera.distortion[0], d[0])
        results[name] = reconstruct(views, params)
    score = {name: score_against_truth(obj, r.vertices, r.faces, r.grid)["volume_iou"]
             for name, r in results.items()}
    grid = results["ideal"].grid
    agree = volume_iou(mesh_occupancy(results["lens"].vertices, results["lens"].faces, grid),
                       mesh_occupancy(results["ideal"].vertices, results["ideal"].faces, grid))
    # As through the NeRF input: the same hull up to the resampled silhouettes' edge pixels.
    assert score["lens"] == pytest.approx(score["ideal"], abs=0.01)
    assert agree > 0.99
