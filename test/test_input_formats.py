"""One simulated scan written in every input format reconstructs the same object.

The writers here are independent of the readers: Middlebury's ``K R t`` per
line, NeRF's camera-to-world poses in OpenGL axes with the principal point in
pixel-corner convention, and the session folder with per-view 3x4 matrices.
A convention error in any reader (axes, transposes, half-pixel offsets) would
carve a different hull.
"""

import json

import cv2
import numpy as np
import pytest

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.metrics import volume_iou
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.simulation.synthetic import carving_box


def _write_images(folder, captures):
    folder.mkdir(parents=True, exist_ok=True)
    for c in captures:
        cv2.imwrite(str(folder / c.name), cv2.cvtColor(c.image, cv2.COLOR_RGB2BGR))


def write_middlebury(folder, captures, cameras):
    _write_images(folder, captures)
    lines = [str(len(captures))]
    for c, cam in zip(captures, cameras):
        values = [*cam.K.ravel(), *cam.R.ravel(), *cam.t]
        lines.append(c.name + " " + " ".join(f"{v:.17g}" for v in values))
    (folder / "scan_par.txt").write_text("\n".join(lines) + "\n")
    return folder / "scan_par.txt"


def write_nerf(folder, captures, cameras, bounds):
    _write_images(folder / "images", captures)
    cam = cameras[0]
    frames = []
    for c, camera in zip(captures, cameras):
        cam_to_world = np.eye(4)
        cam_to_world[:3, :3] = camera.R.T @ np.diag([1.0, -1.0, -1.0])  # OpenCV -> OpenGL axes
        cam_to_world[:3, 3] = camera.center
        frames.append({"file_path": "images/" + c.name.removesuffix(".png"),
                       "transform_matrix": cam_to_world.tolist()})
    data = {"fl_x": cam.K[0, 0], "fl_y": cam.K[1, 1], "w": cam.width, "h": cam.height,
            "cx": cam.K[0, 2] + 0.5, "cy": cam.K[1, 2] + 0.5,  # pixel-corner convention
            "bounds_m": bounds.tolist(), "frames": frames}
    (folder / "transforms.json").write_text(json.dumps(data))
    return folder / "transforms.json"


def write_matrix_session(folder, captures, cameras, bounds, rig):
    _write_images(folder / "images", captures)
    rows = ["image," + ",".join(f"p{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3, 4))]
    for capture, cam in zip(captures, cameras):
        rows.append(capture.name + "," + ",".join(f"{v:.17g}" for v in cam.projection_matrix.ravel()))
    (folder / "views.csv").write_text("\n".join(rows) + "\n")
    (folder / "session.yaml").write_text(
        "format: sfs_ros-session\nversion: 1\n"
        f"rig: {{width: {rig.width}, height: {rig.height}}}\n"
        f"bounds_m: {bounds.tolist()}\n")
    return folder


@pytest.fixture(scope="module")
def angle_session_result(mug, mug_views):
    # The box given, as for the other formats (an input's box would be refined).
    return reconstruct(mug_views, ReconstructionParams(
        resolution=64, check_consistency=False, bounds_m=tuple(map(tuple, carving_box(mug)))))


@pytest.mark.parametrize("form", ["middlebury", "nerf", "matrix-session"])
def test_every_format_carves_the_same_hull(tmp_path, mug, mug_captures, mug_views,
                                           angle_session_result, form):
    cameras = [v.camera for v in mug_views.views]
    bounds = carving_box(mug)
    if form == "middlebury":
        path = write_middlebury(tmp_path, mug_captures, cameras)
    elif form == "nerf":
        path = write_nerf(tmp_path, mug_captures, cameras, bounds)
    else:
        path = write_matrix_session(tmp_path, mug_captures, cameras, bounds,
                                    mug_views.calibration)
    views = load_views(path)
    assert len(views.views) == len(mug_captures) and not views.rejected
    params = ReconstructionParams(resolution=64, check_consistency=False,
                                  bounds_m=tuple(map(tuple, bounds)))
    result = reconstruct(views, params)
    reference = angle_session_result
    assert result.grid.shape == reference.grid.shape
    # Same images, same cameras up to float rounding of the written numbers: the
    # hulls may differ only where a voxel centre projects onto a pixel border.
    assert volume_iou(result.occupancy, reference.occupancy) >= 0.999
    assert result.report["silhouette_iou"]["mean_used"] >= 0.95
