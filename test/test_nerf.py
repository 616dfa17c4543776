"""NeRF / instant-ngp transforms.json reader, on files written here with known cameras."""

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.nerf import read_transforms
from sfs_ros.core.exchange.views import ViewError
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.metrics import mesh_occupancy, volume_iou
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.render import render_image
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth

from tolerances import PIXEL_ROUND_OFF_PX, ROUND_OFF

WIDTH, HEIGHT = 40, 30
ANGLE_X = 0.7  # radians, horizontal field of view
#: Camera positions (world units), all looking at the origin with world +Z up.
POSITIONS = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 1.0], [-1.5, -1.5, 0.2], [0.3, -1.0, 2.5]])


def look_at_origin(position):
    """Camera-to-world 4x4 in the OpenGL / Blender convention (x right, y up, z backwards)."""
    back = position / np.linalg.norm(position)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, up, back])
    pose[:3, 3] = position
    return pose


def write_scene(folder, extra=None, frames_extra=None, name="transforms.json", extension=""):
    (folder / "train").mkdir(parents=True, exist_ok=True)
    frames = []
    for n, position in enumerate(POSITIONS):
        cv2.imwrite(str(folder / "train" / f"r_{n}.png"), np.full((HEIGHT, WIDTH, 3), n, np.uint8))
        frame = {"file_path": f"./train/r_{n}{extension}",
                 "transform_matrix": look_at_origin(position).tolist()}
        frame.update((frames_extra or {}).get(n, {}))
        frames.append(frame)
    document = {"camera_angle_x": ANGLE_X, "frames": frames, **(extra or {})}
    path = folder / name
    path.write_text(json.dumps(document))
    return path


def test_nerf_synthetic_style(tmp_path):
    views = read_transforms(write_scene(tmp_path))
    assert views.source == "nerf" and views.bounds_m is None and len(views.views) == 4
    fx = 0.5 * WIDTH / math.tan(0.5 * ANGLE_X)
    for n, (view, position) in enumerate(zip(views.views, POSITIONS)):
        camera = view.camera
        assert view.name == f"train/r_{n}.png"  # extension found on disk
        assert view.image_path == tmp_path / "train" / f"r_{n}.png"
        assert (camera.width, camera.height) == (WIDTH, HEIGHT)  # read from the first image
        assert np.allclose(camera.K, [[fx, 0, 19.5], [0, fx, 14.5], [0, 0, 1]])
        assert np.allclose(camera.center, position, atol=ROUND_OFF)
        # The origin is on the optical axis: the image centre (pixel-centre coordinates).
        assert np.allclose(camera.project(np.zeros((1, 3))), [[19.5, 14.5]],
                           atol=PIXEL_ROUND_OFF_PX)
        # A point h above the origin, seen from distance d at elevation e, sits
        # fy * h cos(e) / (d - h sin(e)) pixels above the centre, on the same column.
        h, d = 0.3, np.linalg.norm(position)
        e = math.asin(position[2] / d)
        u, v = camera.project(np.array([[0.0, 0.0, h]]))[0]
        assert abs(u - 19.5) < PIXEL_ROUND_OFF_PX
        assert v == pytest.approx(14.5 - fx * h * math.cos(e) / (d - h * math.sin(e)),
                                  abs=PIXEL_ROUND_OFF_PX)
        assert v < 14.5
        assert camera.depth(np.zeros((1, 3)))[0] == pytest.approx(np.linalg.norm(position))


def test_explicit_intrinsics_per_frame_win(tmp_path):
    extra = {"fl_x": 30.0, "fl_y": 33.0, "cx": 20.0, "cy": 15.0, "w": WIDTH, "h": HEIGHT}
    per_frame = {1: {"fl_x": 60.0, "cx": 25.0}, 2: {"camera_angle_y": 1.0}}
    views = read_transforms(write_scene(tmp_path, extra, per_frame, extension=".png"))
    K = [v.camera.K for v in views.views]
    # File convention: image centre at w / 2 (pixel corners); ours: (w - 1) / 2.
    assert np.allclose(K[0], [[30, 0, 19.5], [0, 33, 14.5], [0, 0, 1]])
    assert np.allclose(K[1], [[60, 0, 24.5], [0, 33, 14.5], [0, 0, 1]])
    assert K[2][1, 1] == pytest.approx(0.5 * HEIGHT / math.tan(0.5))  # frame angle beats top fl_y
    assert np.allclose(views.views[1].camera.project(np.zeros((1, 3))), [[24.5, 14.5]])


@pytest.mark.parametrize("extra, expected", [
    ({"aabb": [[-1, -1, -1], [1, 1, 1]]}, [[-1, -1, -1], [1, 1, 1]]),
    ({"aabb": [[-1, -1, -1], [1, 1, 1]], "bounds_m": [[0, 0, 0], [0.5, 0.5, 0.5]]},
     [[0, 0, 0], [0.5, 0.5, 0.5]]),
    ({"aabb_scale": 16}, None),
])
def test_bounds(tmp_path, extra, expected):
    bounds = read_transforms(write_scene(tmp_path, extra)).bounds_m
    assert (bounds is None) if expected is None else np.array_equal(bounds, expected)


def test_load_views_finds_the_json(tmp_path):
    write_scene(tmp_path, name="transforms_train.json")
    assert load_views(tmp_path / "transforms_train.json").source == "nerf"
    assert load_views(tmp_path).source == "nerf"  # the only transforms*.json
    write_scene(tmp_path, name="transforms_test.json")
    with pytest.raises(ViewError, match="transforms_test.json, transforms_train.json"):
        load_views(tmp_path)
    write_scene(tmp_path, {"fl_x": 99.0})  # transforms.json is preferred
    assert load_views(tmp_path).views[0].camera.K[0, 0] == 99.0


def bad_pose():
    pose = look_at_origin(POSITIONS[0])
    pose[:3, :3] *= 2.0  # scaled, not rigid
    return pose.tolist()


@pytest.mark.parametrize("extra, per_frame, message", [
    ({"camera_angle_x": None}, {}, "camera_angle_x must be a finite number"),
    ({"camera_angle_x": 4.0}, {}, r"camera_angle_x must be in \(0, pi\)"),
    ({}, {2: {"file_path": "./train/missing"}}, r"frame 2: image .*missing does not exist"),
    ({}, {1: {"file_path": "./train/r_0"}}, r"frame 1: image 'train/r_0.png' is listed twice"),
    ({"k4": 0.01}, {}, "frame 0: lens distortion k4 is not supported"),
    ({"k1": "strong"}, {}, "frame 0: k1 must be a finite number"),
    ({}, {0: {"is_fisheye": True}}, "fisheye"),
    ({}, {3: {"transform_matrix": bad_pose()}}, "frame 3: transform_matrix: not a rotation"),
    ({}, {0: {"transform_matrix": [[1, 0, 0], [0, 1, 0]]}}, "must be a finite 4x4"),
    ({"aabb": [0, 1]}, {}, r"aabb must be \[\[xmin"),
    ({"frames": []}, {}, "non-empty 'frames' list"),
])
def test_bad_transforms(tmp_path, extra, per_frame, message):
    with pytest.raises(ViewError, match=message):
        read_transforms(write_scene(tmp_path, extra, per_frame))


def test_no_focal_length(tmp_path):
    path = write_scene(tmp_path)
    document = json.loads(path.read_text())
    del document["camera_angle_x"]
    path.write_text(json.dumps(document))
    with pytest.raises(ViewError, match="no focal length; expected camera_angle_x or fl_x"):
        read_transforms(path)


def test_zero_distortion_is_accepted(tmp_path):
    views = read_transforms(write_scene(tmp_path, {"k1": 0.0, "p1": 0, "is_fisheye": False}))
    assert len(views.views) == 4


def test_invalid_json(tmp_path):
    path = tmp_path / "transforms.json"
    path.write_text('{"frames": [')
    with pytest.raises(ViewError, match="is not valid JSON"):
        read_transforms(path)


def test_distortion_is_read_as_plumb_bob(tmp_path):
    views = read_transforms(write_scene(tmp_path, {"k1": -0.2, "p2": 0.001},
                                        {1: {"k2": 0.05, "p1": -0.002, "k3": 0.01}}))
    np.testing.assert_array_equal(views.views[0].camera.distortion, [-0.2, 0, 0, 0.001, 0])
    np.testing.assert_array_equal(views.views[1].camera.distortion,
                                  [-0.2, 0.05, -0.002, 0.001, 0.01])


def _nerf_scan(folder, rig, *, write_lens=True):
    """The mug rendered through ``rig`` at 24 views, as a transforms.json (OpenGL poses)."""
    obj = make_object("mug")
    folder.mkdir()
    frames = []
    for n, (theta, phi) in enumerate(ring_plan([15, 45, 75], 8)):
        camera = rig_camera(theta, phi, rig)
        image = render_image(obj.mesh.vertices, obj.mesh.faces, camera,
                             vertex_colors=obj.color_at(obj.mesh.vertices), seed=n)
        cv2.imwrite(str(folder / f"v{n:02d}.png"), image[:, :, ::-1])
        pose = np.eye(4)
        pose[:3, :3] = camera.R.T @ np.diag([1.0, -1.0, -1.0])     # OpenCV -> OpenGL axes
        pose[:3, 3] = camera.center
        frames.append({"file_path": f"v{n:02d}.png", "transform_matrix": pose.tolist()})
    K = rig.K
    lens = dict(zip(("k1", "k2", "p1", "p2", "k3"), rig.distortion)) if write_lens else {}
    document = {"fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2] + 0.5, "cy": K[1, 2] + 0.5,
                "w": rig.width, "h": rig.height, "bounds_m": carving_box(obj).tolist(),
                **lens, "frames": frames}
    (folder / "transforms.json").write_text(json.dumps(document))
    return read_transforms(folder / "transforms.json"), obj


def test_a_distorted_scan_reconstructs_as_well_as_an_undistorted_one(tmp_path):
    # A wide-angle lens (3 to 5 px of barrel where the mug's rim is) close to the mug.
    lens = (-0.3, 0.1, 0.001, -0.001, 0.0)
    rig = RigCalibration(width=320, height=240, projection="pinhole", fx=300.0, fy=300.0,
                         camera_distance_m=0.22, aim_point_m=(0.0, 0.0, 0.045))
    params = ReconstructionParams(resolution=72)
    runs = {name: _nerf_scan(tmp_path / name, replace(rig, distortion=d), write_lens=w)
            for name, d, w in [("ideal", rig.distortion, True), ("lens", lens, True),
                               ("ignored", lens, False)]}
    results = {name: reconstruct(views, params) for name, (views, _) in runs.items()}
    obj = runs["ideal"][1]
    score = {name: score_against_truth(obj, r.vertices, r.faces, r.grid)["volume_iou"]
             for name, r in results.items()}
    grid = results["ideal"].grid
    occupancy = {name: mesh_occupancy(r.vertices, r.faces, grid) for name, r in results.items()}
    # Through the lens, with its coefficients, the scan reconstructs as well as through an
    # ideal lens (measured: volume IoU 0.9737 against 0.9770; the resampled silhouettes'
    # edge pixels) and the same hull (0.9942 agreement). Carving the same images as if the
    # lens were ideal makes another hull (0.9897 agreement: barrel shrinks the silhouettes,
    # which here even happens to score 0.9776 against the truth).
    assert score["lens"] == pytest.approx(score["ideal"], abs=0.01)
    agree_lens = volume_iou(occupancy["lens"], occupancy["ideal"])
    assert agree_lens > 0.99
    assert volume_iou(occupancy["ignored"], occupancy["ideal"]) < agree_lens - 0.003
