"""Middlebury ``*_par.txt`` reader: small files written here, then the real data sets."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.middlebury import read_middlebury
from sfs_ros.core.exchange.views import ViewError

from tolerances import PIXEL_ROUND_OFF_PX

WIDTH, HEIGHT = 40, 30
K = np.array([[50.0, 0.0, 19.5], [0.0, 52.0, 14.5], [0.0, 0.0, 1.0]])


def rotation_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


CAMERAS = [(f"img{n:02d}.png", rotation_z(0.4 * n), np.array([0.01 * n, -0.02, 0.5 + 0.1 * n]))
           for n in range(3)]


def par_line(name, K, R, t):
    return " ".join([name] + [f"{v:.17g}" for v in np.concatenate([K.ravel(), R.ravel(), t])])


def write_dataset(folder, cameras=CAMERAS, count=None, sizes=None):
    folder.mkdir(exist_ok=True)
    for n, (name, _, _) in enumerate(cameras):
        w, h = (sizes or {}).get(name, (WIDTH, HEIGHT))
        cv2.imwrite(str(folder / name), np.full((h, w, 3), 40 * n, np.uint8))
    lines = [str(len(cameras) if count is None else count)]
    lines += [par_line(name, K, R, t) for name, R, t in cameras]
    path = folder / "toy_par.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_cameras_are_k_r_t(tmp_path):
    views = read_middlebury(write_dataset(tmp_path))
    assert views.source == "middlebury" and views.bounds_m is None and views.calibration is None
    assert [v.name for v in views.views] == [name for name, _, _ in CAMERAS]
    points = np.array([[0.0, 0.0, 0.0], [0.05, -0.03, 0.1]])
    for view, (name, R, t) in zip(views.views, CAMERAS):
        assert view.image_path == tmp_path / name
        assert (view.camera.width, view.camera.height) == (WIDTH, HEIGHT)
        assert view.theta_rad is None and view.phi_rad is None
        h = (K @ (points @ R.T + t).T).T
        # Same arithmetic up to float64 rounding.
        assert np.allclose(view.camera.project(points), h[:, :2] / h[:, 2:],
                           atol=PIXEL_ROUND_OFF_PX)


def test_load_views_takes_the_file_or_its_folder(tmp_path):
    path = write_dataset(tmp_path)
    assert len(load_views(path).views) == 3
    assert len(load_views(tmp_path).views) == 3
    (tmp_path / "other_par.txt").write_text("0\n")
    with pytest.raises(ViewError, match="several \\*_par.txt files"):
        load_views(tmp_path)


def test_count_mismatch(tmp_path):
    with pytest.raises(ViewError, match="declares 4 views but has 3 view lines"):
        read_middlebury(write_dataset(tmp_path, count=4))


@pytest.mark.parametrize("edit, message", [
    (lambda ls: ["sixteen"] + ls[1:], "line 1: expected the number of views"),
    (lambda ls: ls[:2] + [ls[2].rsplit(" ", 1)[0]] + ls[3:], "line 3: 21 fields, expected 22"),
    (lambda ls: ls[:3] + [ls[3].replace(" 1 ", " one ", 1)] + ls[4:], "line 4: 'one' is not a number"),
    (lambda ls: ls[:3] + [ls[1]], r"line 4: image 'img00.png' is listed twice \(first on line 2\)"),
    (lambda ls: ls[:2] + [ls[2].replace("img01", "gone")] + ls[3:],
     r"line 3: image .*gone.png does not exist"),
    (lambda ls: ls[:2] + [ls[2] + "x"] + ls[3:], "line 3: '0.5[0-9]*x' is not a number"),
    (lambda ls: ls[:1] + [ls[1].replace(" 1 ", " nan ", 1)] + ls[2:],
     "line 2: camera parameters contain NaN"),
    (lambda ls: [], "is empty"),
])
def test_malformed_par_file(tmp_path, edit, message):
    path = write_dataset(tmp_path)
    path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")
    with pytest.raises(ViewError, match=message):
        read_middlebury(path)


def test_not_a_rotation(tmp_path):
    bad = [CAMERAS[0], ("img01.png", 1.1 * np.eye(3), np.zeros(3))]
    with pytest.raises(ViewError, match="line 3: not a rotation"):
        read_middlebury(write_dataset(tmp_path, bad))


def test_images_of_different_sizes(tmp_path):
    path = write_dataset(tmp_path, sizes={"img02.png": (41, 30)})
    with pytest.raises(ViewError, match=r"img02.png is 41x30 pixels, expected 40x30 like img00.png"):
        read_middlebury(path)


def test_unreadable_image(tmp_path):
    path = write_dataset(tmp_path)
    (tmp_path / "img01.png").write_bytes(b"broken")
    with pytest.raises(ViewError, match="img01.png is not a readable image"):
        read_middlebury(path)


# ---------------------------------------------------------------------------
# Real data: the Middlebury sparse-ring data sets, when they are present beside
# the repository (shared/datasets/middlebury). Skipped, with the reason, otherwise.

DATASETS = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "middlebury"
needs_data = pytest.mark.skipif(not DATASETS.is_dir(), reason=f"Middlebury data not found at {DATASETS}")

#: The tight bounding boxes printed in each data set's README, metres.
README_BOXES = {
    "dinoSparseRing/dinoSR_par.txt":
        ((-0.061897, -0.018874, -0.057845), (0.010897, 0.068227, 0.015495)),
    "templeSparseRing/templeSR_par.txt":
        ((-0.073568, 0.021728, -0.012445), (0.028855, 0.181892, 0.062736)),
}


@needs_data
@pytest.mark.parametrize("par", sorted(README_BOXES))
def test_real_data_sets_have_sane_cameras(par):
    views = load_views(DATASETS / par)
    assert len(views.views) == 16
    box = np.array(README_BOXES[par])
    corners = np.array([[box[i, 0], box[j, 1], box[k, 2]]
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    centre = box.mean(axis=0)
    for view in views.views:
        camera = view.camera
        assert (camera.width, camera.height) == (640, 480)
        assert np.all(camera.depth(corners) > 0)  # the whole box is in front of every camera
        u, v = camera.project(centre[None])[0]
        assert 0 <= u <= camera.width - 1 and 0 <= v <= camera.height - 1
        # A ring: every camera is about as far from the object (dino and temple: ~0.5-0.7 m).
        assert 0.4 < np.linalg.norm(camera.center - centre) < 0.8
