"""Exports for other tools: each format read back (ours, or parsed here by its spec) gives
the same cameras: the same pixel for every point."""

import json
from dataclasses import replace

import numpy as np
import pytest

from sfs_ros.core.exchange.colmap import read_colmap
from sfs_ros.core.exchange.nerf import read_transforms
from sfs_ros.core.exchange.pose_export import export_session, write_colmap, write_nerf_transforms
from sfs_ros.core.exchange.session import read_session, write_session
from sfs_ros.core.exchange.views import View, ViewSet, read_image
from sfs_ros.core.geometry.camera import Camera

# Points around the mug (metres, object frame), seen by every view.
POINTS = np.random.default_rng(0).uniform([-0.04, -0.04, 0.0], [0.04, 0.04, 0.09], (200, 3))
# Exported numbers are repr() of float64: a round trip is exact up to the RQ decomposition
# and quaternion conversions, ~1e-12 relative; 1e-6 px is far below anything visible.
PIXEL_TOL = 1e-6


def _same_projection(a: Camera, b: Camera) -> None:
    assert (a.width, a.height) == (b.width, b.height)
    np.testing.assert_allclose(a.project(POINTS), b.project(POINTS), atol=PIXEL_TOL)


def test_nerf_transforms_read_back_to_the_same_cameras(mug_session):
    mug_views = read_session(mug_session)
    path = write_nerf_transforms(mug_views, mug_session / "transforms.json")
    data = json.loads(path.read_text())
    assert len(data["frames"]) == len(mug_views.views)
    # OpenGL camera axes: the camera's -z (third column negated) looks at the object.
    frame = data["frames"][0]
    c2w = np.array(frame["transform_matrix"])
    to_object = -c2w[:3, 3] / np.linalg.norm(c2w[:3, 3])
    assert np.dot(-c2w[:3, 2], to_object) > 0.9
    back = read_transforms(path)
    assert [v.image_path.resolve() for v in back.views] == \
        [v.image_path.resolve() for v in mug_views.views]
    for ours, theirs in zip(mug_views.views, back.views):
        _same_projection(ours.camera, theirs.camera)
    np.testing.assert_allclose(back.bounds_m, mug_views.bounds_m)


def _quaternion_matrix(qw, qx, qy, qz) -> np.ndarray:
    """Rotation of a unit quaternion, written out (COLMAP's Hamilton convention)."""
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])


def _read_colmap(folder):
    """cameras.txt and images.txt parsed as COLMAP's documentation describes them."""
    cameras = {}
    for line in (folder / "cameras.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            cid, model, w, h, fx, fy, cx, cy = line.split()
            assert model == "PINHOLE"
            cameras[cid] = (int(w), int(h), *map(float, (fx, fy, cx, cy)))
    lines = [ln for ln in (folder / "images.txt").read_text().split("\n")
             if not ln.startswith("#")]
    images = {}
    for pose, points in zip(lines[0::2], lines[1::2]):   # a pose line, then its 2-D points
        fields = pose.split()
        assert points == ""
        qw, qx, qy, qz, tx, ty, tz = map(float, fields[1:8])
        images[fields[9]] = (_quaternion_matrix(qw, qx, qy, qz), np.array([tx, ty, tz]),
                             cameras[fields[8]])
    return images


def test_colmap_text_model_projects_like_our_cameras(mug_views, tmp_path):
    folder = write_colmap(mug_views, tmp_path / "colmap", points=POINTS[:5])
    images = _read_colmap(folder)
    assert list(images) == [v.name for v in mug_views.views]
    assert len((folder / "cameras.txt").read_text().splitlines()) == 2   # one shared camera
    for view in mug_views.views:
        R, t, (w, h, fx, fy, cx, cy) = images[view.name]
        xc = POINTS @ R.T + t
        # COLMAP: the top-left pixel's centre is (0.5, 0.5); ours is (0, 0).
        uv = np.stack([fx * xc[:, 0] / xc[:, 2] + cx, fy * xc[:, 1] / xc[:, 2] + cy], axis=1)
        np.testing.assert_allclose(uv - 0.5, view.camera.project(POINTS), atol=PIXEL_TOL)
        assert (w, h) == (view.camera.width, view.camera.height)
    rows = (folder / "points3D.txt").read_text().splitlines()[1:]
    assert len(rows) == 5
    np.testing.assert_allclose([list(map(float, r.split()[1:4])) for r in rows], POINTS[:5])


def test_a_lens_survives_export_to_colmap_and_nerf(mug_views, tmp_path):
    # A session through a distorted lens: both pose formats carry the lens, and the readers
    # give back the same cameras, lens included.
    lens = (-0.2, 0.05, 0.001, -0.002, 0.0)
    rig = replace(mug_views.calibration, distortion=lens)
    images = [(v.name, read_image(v.image_path)) for v in mug_views.views[:4]]
    views = read_session(write_session(tmp_path / "s", images,
                                       [(v.theta_rad, v.phi_rad) for v in mug_views.views[:4]],
                                       rig))
    colmap = write_colmap(views, tmp_path / "s" / "sparse")
    assert " OPENCV " in (colmap / "cameras.txt").read_text()
    nerf = read_transforms(write_nerf_transforms(views, tmp_path / "s" / "transforms.json"))
    for back in (read_colmap(colmap), nerf):
        for ours, theirs in zip(views.views, back.views):
            np.testing.assert_allclose(theirs.camera.distortion, lens)
            np.testing.assert_allclose(theirs.camera.project_distorted(POINTS),
                                       ours.camera.project_distorted(POINTS), atol=PIXEL_TOL)
    with pytest.raises(ValueError, match="k3 = 0.01 is not a COLMAP OPENCV camera"):
        write_colmap(replace(views, views=[replace(v, camera=replace(
            v.camera, distortion=(*lens[:4], 0.01))) for v in views.views]), tmp_path / "x")


def test_session_export_keeps_angles_and_calibration(mug_views, tmp_path):
    folder = export_session(mug_views, tmp_path / "plain")
    back = read_session(folder)
    assert back.calibration == mug_views.calibration
    assert [(v.theta_rad, v.phi_rad) for v in back.views] == \
        [(v.theta_rad, v.phi_rad) for v in mug_views.views]
    assert "theta_rad" in (folder / "views.csv").read_text().splitlines()[0]


def test_session_export_without_angles_writes_projection_matrices(mug_views, tmp_path):
    # As a NeRF or Middlebury input gives them: cameras only, no encoder angles.
    cameras_only = ViewSet(views=[View(v.name, v.image_path, v.camera) for v in mug_views.views],
                           source="nerf", bounds_m=mug_views.bounds_m)
    back = read_session(export_session(cameras_only, tmp_path / "plain"))
    assert back.calibration is not None and back.views[0].theta_rad is None
    for ours, theirs in zip(cameras_only.views, back.views):
        _same_projection(ours.camera, theirs.camera)


def test_orthographic_views_are_refused(mug_views, tmp_path):
    view = mug_views.views[0]
    ortho = Camera(K=[[2000.0, 0, 160], [0, 2000.0, 120], [0, 0, 1]], R=np.eye(3),
                   t=[0, 0, 1.0], width=320, height=240, orthographic=True)
    views = ViewSet(views=[View(view.name, view.image_path, ortho)], source="nerf")
    for write in (write_colmap, write_nerf_transforms):
        with pytest.raises(ValueError, match="orthographic view"):
            write(views, tmp_path / "x.json")


def test_sfs_export_writes_all_three_and_refuses_bad_input(mug_session, tmp_path, capsys):
    from sfs_ros.cli.export import main

    out = tmp_path / "out"
    assert main([str(mug_session), "--session", str(out / "plain"), "--colmap",
                 str(out / "colmap"), "--nerf", str(out / "transforms.json")]) == 0
    assert "49 views exported" in capsys.readouterr().out
    back = read_transforms(out / "transforms.json")
    assert all(v.image_path.resolve().is_relative_to((out / "plain").resolve())
               for v in back.views)
    assert set(_read_colmap(out / "colmap")) == {v.name for v in read_session(out / "plain").views}
    assert main([str(tmp_path / "missing"), "--nerf", str(out / "t.json")]) == 2
    assert main([str(mug_session)]) == 2
    assert "nothing to do" in capsys.readouterr().err
