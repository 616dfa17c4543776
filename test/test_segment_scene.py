"""The default segmentation and reconstruction (no options) scored against exact
silhouettes, and RGBA input.

The hostile cell (:mod:`sfs_ros.core.simulation.hostile`) renders the object
with a turntable plate reaching the frame, its cast shadow, a dark cloth,
specular highlights, near-black dashes on the object and, in every fourth
view, part of the object out of frame; its ``object_mask`` is exact.
"""

import json

import cv2
import numpy as np
import pytest
from written_scan import exact_ious, reconstruct_written

from sfs_ros.cli.reconstruct import _segmentation, build_parser
from sfs_ros.core.exchange.nerf import read_transforms
from sfs_ros.core.exchange.views import read_image
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.segmentation.segment import SegmentationParams, segment
from sfs_ros.core.simulation.hostile import BACKDROPS, simulate_hostile_scan
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan

#: 480 x 360 pinhole at 0.6 m: the mug is ~250 px tall, so one pixel of error
#: along its outline costs ~0.01 of IoU.
RIG = RigCalibration(width=480, height=360, projection="pinhole", fx=1500.0, fy=1500.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))
PLAN = ring_plan([20.0, 45.0, 70.0], 4)  # 12 views, views 3, 7, 11 partly out of frame

#: Mean per-view IoU of the views' first masks (each view alone) against the exact
#: silhouettes, per backdrop. Measured with this plan: 0.874 (black) and 0.807 (white).
#: What is lost: the cast shadow on the plate, joined to the object, in the views from
#: 70 degrees (IoU ~0.73-0.77), and the views where the object covers ~10 % of the
#: frame's border and its colours join the backdrop model (IoU 0.53-0.84). The other
#: views score 0.95-0.96. The reconstruction recovers these views by re-segmenting
#: them with the hull as a prior (below). The bars sit 0.025 under the measurement
#: (k-means and GrabCut are deterministic here, so this is margin for library
#: versions, not for chance) and far above the threshold method, the old default
#: (0.474 black, 0.436 white: the plate becomes the backdrop colour and the real
#: backdrop the object).
MEAN_IOU_MIN = {"black": 0.85, "white": 0.78}


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


@pytest.fixture(scope="module")
def mug():
    return make_object("mug")


@pytest.fixture(scope="module", params=sorted(BACKDROPS))
def scene(request, mug):
    return request.param, simulate_hostile_scan(mug, RIG, PLAN, backdrop=request.param, seed=3)


def test_scene_ground_truth_is_the_object_alone(scene, mug):
    backdrop, captures = scene
    for n, capture in enumerate(captures):
        # Views from above: nothing hides the object, so its mask is its own silhouette.
        truth = rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces, capture.camera)
        np.testing.assert_array_equal(capture.object_mask, truth)
        out_of_frame = n % 4 == 3
        assert bool(truth[:, -1].any()) == out_of_frame
        # The clutter is really there: a quarter or more of what is not the object
        # differs from the plain backdrop by more than 40 grey levels (plate, cloth, shadow).
        rest = capture.image[~truth].astype(np.int16)
        differs = np.abs(rest - np.asarray(BACKDROPS[backdrop], np.int16)).max(axis=1) > 40
        assert differs.mean() > 0.25


def test_dark_sector_darkens_only_the_object_facing_it(mug):
    plan = PLAN[4:8]
    plain = simulate_hostile_scan(mug, RIG, plan, backdrop="black", seed=3)
    dark = simulate_hostile_scan(mug, RIG, plan, backdrop="black", dark_rgb=(20, 18, 22), seed=3)
    darker = 0
    for a, b in zip(plain, dark):
        np.testing.assert_array_equal(a.object_mask, b.object_mask)
        # Same scene, same noise: only the object's own pixels can differ, never brighter.
        np.testing.assert_array_equal(a.image[~a.object_mask], b.image[~b.object_mask])
        assert np.all(b.image[b.object_mask] <= a.image[a.object_mask])
        darker += np.count_nonzero(np.abs(a.image.astype(np.int16) - b.image).max(axis=2) > 40)
    # Four views around the object: together they see the dark third.
    assert darker > 0.1 * sum(np.count_nonzero(c.object_mask) for c in dark)
    for bad in ((300, 0, 0), (20, 20), ("a", "b", "c"), (np.nan, 0, 0)):
        with pytest.raises(ValueError, match="dark_rgb"):
            simulate_hostile_scan(mug, RIG, plan, dark_rgb=bad)


def test_default_segmentation_on_the_hostile_scene(scene):
    backdrop, captures = scene
    ious = [iou(segment(c.image).mask, c.object_mask) for c in captures]
    print(f"{backdrop}: mean IoU {np.mean(ious):.4f}, per view "
          + " ".join(f"{v:.3f}" for v in ious))
    assert np.mean(ious) >= MEAN_IOU_MIN[backdrop]


# --- The whole reconstruction with no options ----------------------------------------

#: The mesh of the default reconstruction, rasterised into every view, against the
#: exact silhouettes: the issue asks for 0.97. Measured 0.984 (black; worst view 0.977)
#: and 0.983 (white; worst 0.969). What is left is the visual hull's own limit (the
#: handle's hole, seen through by few views, stays filled) and a pixel of edge; the
#: views touching the frame score like the others. Everything here is deterministic
#: (a seeded scene, seeded k-means and GrabCut), so the 0.014 of margin is for library
#: versions, and a tenth of what the views' own first masks lose (MEAN_IOU_MIN).
MESH_IOU_MIN = 0.97
#: The masks the reconstruction carved with (after the re-segmentation with the hull
#: as a prior), against the exact silhouettes: measured 0.977 (black), 0.972 (white).
CONSENSUS_MASK_IOU_MIN = 0.96


@pytest.fixture(scope="module")
def reconstructed(scene, tmp_path_factory):
    """The hostile scene written as images with their cameras and reconstructed with
    the default parameters (the box estimated from the views)."""
    backdrop, captures = scene
    folder = tmp_path_factory.mktemp(f"hostile_{backdrop}")
    return backdrop, captures, reconstruct_written(captures, folder)


def test_default_reconstruction_of_the_hostile_scene(reconstructed):
    backdrop, captures, result = reconstructed
    mesh = exact_ious(result, captures)
    masks = [iou(result.masks[c.name], c.object_mask) for c in captures]
    print(f"{backdrop}: mesh IoU {mesh.mean():.4f} per view " + " ".join(f"{v:.3f}" for v in mesh)
          + f"; masks carved with {np.mean(masks):.4f} per view "
          + " ".join(f"{v:.3f}" for v in masks))
    assert result.report["views"]["rejected"] == []
    assert mesh.mean() >= MESH_IOU_MIN
    assert np.mean(masks) >= CONSENSUS_MASK_IOU_MIN


# --- RGBA input -------------------------------------------------------------------------

H, W = 120, 160


def rgba_image():
    """(H, W, 4) RGBA: a disc of alpha 255 (its soft edge at 128 +- 1 around radius 40)
    over black, plus a bright square under fully transparent pixels."""
    yy, xx = np.mgrid[0:H, 0:W]
    radius = np.hypot(xx - 70, yy - 60)
    alpha = np.clip(128 + 40 * (40 - radius), 0, 255).astype(np.uint8)
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[alpha > 0] = (200, 150, 90)
    rgb[10:30, 120:150] = 255           # colour the alpha hides
    return np.dstack([rgb, alpha])


def test_alpha_is_the_mask():
    image = rgba_image()
    result = segment(image)
    np.testing.assert_array_equal(result.mask, image[:, :, 3] > 127)
    assert not result.empty and not result.touches_border
    # Ignoring alpha segments the colours: the hidden square shows up.
    colours = segment(image, SegmentationParams(ignore_alpha=True, min_blob_fraction=0.0))
    assert colours.mask[10:30, 120:150].all()
    # A fully transparent image is an empty view.
    transparent = image.copy()
    transparent[:, :, 3] = 0
    assert segment(transparent).empty


def test_read_image_keeps_alpha_on_request(tmp_path):
    image = rgba_image()
    path = tmp_path / "rgba.png"
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA))
    np.testing.assert_array_equal(read_image(path, keep_alpha=True), image)
    np.testing.assert_array_equal(read_image(path), image[:, :, :3])  # colour still gets RGB


def test_ignore_alpha_option():
    parser = build_parser()
    assert _segmentation(parser.parse_args(["in.json", "-o", "o.ply"]), None) is None
    params = _segmentation(parser.parse_args(["in.json", "-o", "o.ply", "--ignore-alpha"]), None)
    assert params.ignore_alpha
    threshold = _segmentation(parser.parse_args(["in.json", "-o", "o.ply", "--threshold", "0.2"]),
                              None)
    assert threshold.method == "threshold" and threshold.threshold == 0.2


def write_rgba_nerf(folder, mug, n_views=8):
    """NeRF-synthetic-style set: suffix-less ``file_path``, RGBA PNGs whose alpha is the
    exact silhouette and whose colour is black behind the object."""
    from sfs_ros.core.geometry.rig import rig_camera
    from sfs_ros.core.render import render_image

    rig = RigCalibration(width=160, height=120, projection="pinhole", fx=350.0, fy=350.0,
                         camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))
    (folder / "train").mkdir()
    frames, alphas = [], {}
    for n, (theta, phi) in enumerate(ring_plan([30.0], n_views)):
        camera = rig_camera(theta, phi, rig)
        silhouette = rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces, camera)
        rgb = render_image(mug.mesh.vertices, mug.mesh.faces, camera, background_rgb=(0, 0, 0),
                           noise_sigma=0.0)
        alpha = np.where(silhouette, 255, 0).astype(np.uint8)
        cv2.imwrite(str(folder / "train" / f"r_{n}.png"),
                    cv2.cvtColor(np.dstack([rgb, alpha]), cv2.COLOR_RGBA2BGRA))
        alphas[f"train/r_{n}.png"] = silhouette
        pose = np.eye(4)
        pose[:3, :3] = camera.R.T @ np.diag([1.0, -1.0, -1.0])  # OpenCV -> OpenGL axes
        pose[:3, 3] = camera.center
        frames.append({"file_path": f"./train/r_{n}", "transform_matrix": pose.tolist()})
    data = {"fl_x": 350.0, "fl_y": 350.0, "w": 160, "h": 120, "frames": frames,
            "bounds_m": [[-0.06, -0.05, 0.0], [0.07, 0.05, 0.1]]}
    (folder / "transforms.json").write_text(json.dumps(data))
    return folder / "transforms.json", alphas


def test_pipeline_takes_alpha_from_suffixless_nerf_files(tmp_path, mug):
    path, alphas = write_rgba_nerf(tmp_path, mug)
    views = read_transforms(path)
    assert [v.name for v in views.views] == sorted(alphas, key=lambda s: int(s[8:-4]))
    result = reconstruct(views, ReconstructionParams(resolution=32))
    for name, silhouette in alphas.items():
        np.testing.assert_array_equal(result.masks[name], silhouette)
