"""Scan session folders: writing, reading back, appending, and every malformed case."""

import dataclasses
import math

import cv2
import numpy as np
import pytest
import yaml

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import (
    append_view,
    appended_view,
    read_session,
    write_session,
)
from sfs_ros.core.exchange.views import ViewError, read_image
from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera

RIG = RigCalibration(width=32, height=24, projection="pinhole", fx=40.0, fy=40.0,
                     camera_distance_m=0.5, aim_point_m=(0.0, 0.0, 0.02), phi_zero_rad=0.05)
ANGLES = [(0.0, 0.3), (1.0, 0.6), (2.0, 0.9), (3.0, -0.2)]


def image(n):
    rng = np.random.default_rng(n)
    return rng.integers(0, 256, (RIG.height, RIG.width, 3), dtype=np.uint8)


def make_session(folder, **kwargs):
    images = [(f"view_{n:03d}.png", image(n)) for n in range(len(ANGLES))]
    return write_session(folder, images, ANGLES, RIG, **kwargs)


@pytest.fixture()
def session(tmp_path):
    return make_session(tmp_path / "s", bounds_m=[[-0.1, -0.1, 0.0], [0.1, 0.1, 0.2]],
                        segmentation={"threshold": 0.2, "threshold_range": (0.05, 0.5)})


def rewrite_table(folder, edit):
    table = folder / "views.csv"
    lines = table.read_text().splitlines()
    table.write_text("\n".join(edit(lines)) + "\n")


def test_round_trip(session):
    views = read_session(session)
    assert views.source == "session" and views.rejected == []
    assert views.calibration == RIG
    assert np.array_equal(views.bounds_m, [[-0.1, -0.1, 0.0], [0.1, 0.1, 0.2]])
    assert views.segmentation == {"threshold": 0.2, "threshold_range": [0.05, 0.5]}
    assert [v.name for v in views.views] == [f"view_{n:03d}.png" for n in range(4)]
    for n, view in enumerate(views.views):
        assert (view.theta_rad, view.phi_rad) == ANGLES[n]  # repr() round-trips floats exactly
        expected = rig_camera(*ANGLES[n], RIG)
        assert np.array_equal(view.camera.projection_matrix, expected.projection_matrix)
        assert np.array_equal(read_image(view.image_path), image(n))  # PNG is lossless, RGB kept


def test_session_yaml_is_the_documented_format(session):
    document = yaml.safe_load((session / "session.yaml").read_text())
    assert document["format"] == "sfs_ros-session" and document["version"] == 1
    assert RigCalibration.from_dict(document["rig"]) == RIG
    assert (session / "views.csv").read_text().splitlines()[0] == "image,theta_rad,phi_rad"


def test_load_views_recognises_a_session(session):
    assert load_views(session).source == "session"
    assert len(load_views(session / "session.yaml").views) == 4


def test_projection_matrix_table(tmp_path):
    folder = make_session(tmp_path / "p")
    cameras = [rig_camera(theta, phi, RIG) for theta, phi in ANGLES]
    rows = ["image," + ",".join(f"p{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3, 4))]
    for n, camera in enumerate(cameras):
        P = 3.0 * camera.projection_matrix  # any scale of P is the same camera
        rows.append(f"view_{n:03d}.png," + ",".join(repr(v) for v in P.ravel().tolist()))
    (folder / "views.csv").write_text("\n".join(rows) + "\n")
    views = read_session(folder)
    points = np.array([[0.0, 0.0, 0.0], [0.03, -0.02, 0.05]])
    for view, camera in zip(views.views, cameras):
        assert view.theta_rad is None and view.phi_rad is None
        # RQ decomposition in float64: agreement to far below a pixel.
        assert np.allclose(view.camera.project(points), camera.project(points), atol=1e-8)


def test_the_lens_round_trips_with_angles_and_with_matrices(tmp_path):
    # The session carries the rig's distortion; every view's camera has it, both tables.
    lens = (-0.2, 0.05, 0.001, -0.002, 0.01)
    rig = dataclasses.replace(RIG, distortion=lens, axis_point_m=(0.002, -0.001),
                              axis_tilt_y_rad=0.01, mount_rotation_rad=(0.01, 0.0, -0.02))
    images = [(f"view_{n:03d}.png", image(n)) for n in range(len(ANGLES))]
    angles = read_session(write_session(tmp_path / "a", images, ANGLES, rig))
    assert angles.calibration == rig
    cameras = [rig_camera(theta, phi, rig) for theta, phi in ANGLES]
    matrices = read_session(write_session(tmp_path / "m", images, None, rig, cameras=cameras))
    points = np.array([[0.0, 0.0, 0.0], [0.03, -0.02, 0.05]])
    for a, m, camera in zip(angles.views, matrices.views, cameras):
        assert a.camera.distortion.tolist() == m.camera.distortion.tolist() == list(lens)
        np.testing.assert_allclose(m.camera.project_distorted(points),
                                   camera.project_distorted(points), atol=1e-8)
    with pytest.raises(ValueError, match=r"camera of 'view_000.png' has lens distortion "
                                         r"\[-0.2, .*expected one lens per session"):
        write_session(tmp_path / "x", images, None, RIG, cameras=cameras)


def test_nan_and_out_of_range_angles_are_rejected_views(session):
    def edit(lines):
        lines[1] = "view_000.png,nan,0.3"
        lines[2] = "view_001.png,1.0,1.7"  # 1.65 rad after the 0.05 zero: beyond 90 deg
        lines[3] = "view_002.png,2.0,-1.5"  # -1.55 rad: inside
        return lines

    rewrite_table(session, edit)
    views = read_session(session)
    rejected = dict(views.rejected)
    assert set(rejected) == {"view_000.png", "view_001.png"}
    assert "not finite" in rejected["view_000.png"]
    assert "94.538 deg" in rejected["view_001.png"] and "[-90, 90]" in rejected["view_001.png"]
    assert [v.name for v in views.views] == ["view_002.png", "view_003.png"]


def test_all_views_rejected_is_an_error(session):
    rewrite_table(session, lambda lines: [lines[0]] + [
        line.split(",")[0] + ",0.0,inf" for line in lines[1:]])
    with pytest.raises(ViewError, match="no usable view; all 4 rejected"):
        read_session(session)


def test_singular_projection_matrix_is_a_rejected_view(tmp_path):
    folder = make_session(tmp_path / "p")
    header = "image," + ",".join(f"p{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3, 4))
    good = rig_camera(0.0, 0.3, RIG).projection_matrix.ravel()
    rows = [header] + [f"view_{n:03d}.png," + ",".join(repr(v) for v in good.tolist()) for n in range(4)]
    rows[2] = "view_001.png," + ",".join(["0.0"] * 12)
    (folder / "views.csv").write_text("\n".join(rows) + "\n")
    views = read_session(folder)
    assert [name for name, _ in views.rejected] == ["view_001.png"]
    assert len(views.views) == 3


@pytest.mark.parametrize("remove, message", [
    ("session.yaml", "session.yaml is missing"),
    ("views.csv", "views.csv is missing"),
])
def test_missing_files(session, remove, message):
    (session / remove).unlink()
    with pytest.raises(ViewError, match=message):
        read_session(session)


@pytest.mark.parametrize("change, message", [
    ({"format": "other"}, "format is 'other'"),
    ({"version": 2}, "version 2 is not supported"),
    ({"colour": 1}, r"unknown keys \['colour'\]"),
    ({"rig": {"focal": 3.0}}, r"rig: unknown rig calibration keys \['focal'\]"),
    ({"rig": {"fx": "wide"}}, "rig:"),
    ({"rig": None}, "'rig' must be a mapping"),
    ({"bounds_m": [[0, 0, 0], [1, 1]]}, "bounds_m must be"),
    ({"bounds_m": [[0, 0, 0], [1, 1, -1]]}, "bounds_m must be"),
    ({"segmentation": [0.2]}, "segmentation must be a mapping"),
])
def test_bad_session_yaml(session, change, message):
    path = session / "session.yaml"
    document = yaml.safe_load(path.read_text())
    document.update(change)
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(ViewError, match=message):
        read_session(session)


def test_yaml_that_does_not_parse(session):
    (session / "session.yaml").write_text("format: [unclosed\n")
    with pytest.raises(ViewError, match="is not valid YAML"):
        read_session(session)


@pytest.mark.parametrize("edit, message", [
    (lambda ls: ["name,theta,phi"] + ls[1:], "is neither 'image,theta_rad,phi_rad'"),
    (lambda ls: ls[:2] + ["view_001.png,1.0"] + ls[3:], r"views.csv line 3: 2 fields, expected 3"),
    (lambda ls: ls[:3] + ["view_002.png,2.0,0.9,7"] + ls[4:], "line 4: 4 fields, expected 3"),
    (lambda ls: ls[:2] + ["view_001.png,one,0.6"] + ls[3:], "line 3: theta_rad 'one' is not a number"),
    (lambda ls: ls + ["view_000.png,0.5,0.5"], r"line 6: image 'view_000.png' is listed twice "
                                               r"\(first on line 2\)"),
    (lambda ls: ls + ["../escape.png,0.5,0.5"], "must be a relative path inside images/"),
    (lambda ls: [], "header '' is neither"),
])
def test_malformed_table(session, edit, message):
    rewrite_table(session, edit)
    with pytest.raises(ViewError, match=message):
        read_session(session)


def test_blank_lines_and_crlf_are_accepted(session):
    table = session / "views.csv"
    table.write_bytes(table.read_bytes().replace(b"\n", b"\r\n\r\n"))
    assert len(read_session(session).views) == 4


def test_row_whose_image_is_missing(session):
    (session / "images" / "view_002.png").unlink()
    with pytest.raises(ViewError, match=r"views.csv lists 1 image\(s\) missing from images/: "
                                        r"view_002.png"):
        read_session(session)


def test_images_not_in_the_table(session):
    rewrite_table(session, lambda lines: lines[:-1])  # the last image has no row
    cv2.imwrite(str(session / "images" / "extra.jpg"), np.zeros((24, 32, 3), np.uint8))
    (session / "images" / ".hidden.png").write_bytes(b"ignored")
    (session / "images" / "notes.txt").write_text("not an image: ignored")
    with pytest.raises(ViewError) as err:
        read_session(session)
    message = str(err.value)
    assert "2 image(s) not listed in" in message and "views.csv" in message
    assert "extra.jpg" in message and "view_003.png" in message and "hidden" not in message


def test_images_in_subfolders(tmp_path):
    images = [("ring_a/v0.png", image(0)), ("ring_b/v0.png", image(1))]
    folder = write_session(tmp_path / "s", images, ANGLES[:2], RIG)
    assert [v.name for v in read_session(folder).views] == ["ring_a/v0.png", "ring_b/v0.png"]


def test_append_view_keeps_earlier_rows(session):
    before = (session / "views.csv").read_text()
    append_view(session, "view_004.png", image(4), 4.0, 0.4)
    append_view(session, "view_005.png", image(5), 5.0, math.nan)
    assert (session / "views.csv").read_text().startswith(before)
    views = read_session(session)
    assert [v.name for v in views.views][-1] == "view_004.png"
    assert views.views[-1].theta_rad == 4.0 and np.array_equal(read_image(views.views[-1].image_path),
                                                              image(4))
    assert [name for name, _ in views.rejected] == ["view_005.png"]  # NaN stored, rejected on read


def test_appended_view_is_what_reading_the_folder_again_gives(session):
    """A live scan keeps its session in memory: each view it appends must be the view (or
    the rejection) that reading the folder gives, cameras bit for bit."""
    kept = read_session(session)
    for n, (theta, phi) in enumerate([(4.0, 0.4), (5.0, math.nan), (0.1 + 0.2, 1e-17),
                                      (6.0, 3.0)], start=4):
        name = f"view_{n:03d}.png"
        append_view(session, name, image(n), theta, phi)
        kept = appended_view(kept, session, name, theta, phi)
    read = read_session(session)
    assert kept.rejected == read.rejected and len(kept.rejected) == 2   # NaN; phi off the arm
    assert len(kept.views) == len(read.views) == len(ANGLES) + 2
    for ours, theirs in zip(kept.views, read.views):
        assert (ours.name, ours.image_path, ours.theta_rad, ours.phi_rad) \
            == (theirs.name, theirs.image_path, theirs.theta_rad, theirs.phi_rad)
        for field in dataclasses.fields(ours.camera):
            assert np.array_equal(getattr(ours.camera, field.name),
                                  getattr(theirs.camera, field.name)), field.name


def test_append_after_a_table_without_final_newline(session):
    table = session / "views.csv"
    table.write_text(table.read_text().rstrip("\n"))
    append_view(session, "view_004.png", image(4), 4.0, 0.4)
    assert len(read_session(session).views) == 5


def test_append_view_refusals(session, tmp_path):
    with pytest.raises(ValueError, match="already in the session"):
        append_view(session, "view_001.png", image(1), 0.0, 0.0)
    with pytest.raises(ValueError, match=r"8x8 pixels, expected 32x24"):
        append_view(session, "view_009.png", np.zeros((8, 8, 3), np.uint8), 0.0, 0.0)
    with pytest.raises(ValueError, match="ending in '.png'"):
        append_view(session, "view_009.jpg", image(1), 0.0, 0.0)
    with pytest.raises(ViewError, match="session.yaml is missing"):
        append_view(tmp_path, "view_009.png", image(1), 0.0, 0.0)
    assert not (session / "images" / "view_009.png").exists()


def test_write_session_replaces_a_previous_session(session):
    write_session(session, [("only.png", image(7))], [(0.0, 0.2)], RIG)
    views = read_session(session)
    assert [v.name for v in views.views] == ["only.png"]
    assert views.bounds_m is None and views.segmentation is None


def test_write_session_refusals(tmp_path):
    (tmp_path / "mine.txt").write_text("keep me")
    with pytest.raises(ValueError, match="holds other files"):
        make_session(tmp_path)
    assert (tmp_path / "mine.txt").exists()
    folder = tmp_path / "s"
    with pytest.raises(ValueError, match="one per image"):
        write_session(folder, [("a.png", image(0))], ANGLES, RIG)
    with pytest.raises(ValueError, match="unique"):
        write_session(folder, [("a.png", image(0))] * 2, ANGLES[:2], RIG)
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        write_session(folder, [("a.png", image(0).astype(float))], ANGLES[:1], RIG)
    with pytest.raises(ValueError, match="bounds_m"):
        write_session(folder, [("a.png", image(0))], ANGLES[:1], RIG, bounds_m=[1, 2, 3])
    assert not folder.exists()  # everything is checked before anything is written


def test_matrix_sessions_cannot_be_appended_to(tmp_path):
    folder = make_session(tmp_path / "p")
    header = "image," + ",".join(f"p{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3, 4))
    P = Camera(np.diag([40.0, 40.0, 1.0]), np.eye(3), [0, 0, 1], 32, 24).projection_matrix
    rows = [header] + [f"view_{n:03d}.png," + ",".join(map(repr, P.ravel().tolist())) for n in range(4)]
    (folder / "views.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(ValueError, match="projection matrices"):
        append_view(folder, "view_004.png", image(4), 0.0, 0.0)


def test_table_saved_with_a_byte_order_mark(session):
    table = session / "views.csv"
    table.write_bytes(b"\xef\xbb\xbf" + table.read_bytes())
    assert len(read_session(session).views) == 4


def test_binary_table_is_a_clear_error(session):
    (session / "views.csv").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ViewError, match="views.csv is not a UTF-8 text file"):
        read_session(session)


def test_folder_without_session_yaml_says_so(session):
    (session / "session.yaml").unlink()
    with pytest.raises(ViewError, match="session.yaml is missing"):
        load_views(session)
