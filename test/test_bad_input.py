"""Bad input: a clear error or a reported rejected view, never a traceback or an empty mesh."""

import json

import cv2
import numpy as np
import pytest

from sfs_ros.cli.reconstruct import main
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct

from tolerances import MUG_IOU_SPARSE_MIN

FAST = ReconstructionParams(resolution=64)


def run_cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_missing_input_is_one_clear_line(capsys, tmp_path):
    code, _, err = run_cli(capsys, tmp_path / "nowhere", "-o", tmp_path / "m.ply", "-q")
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("sfs-reconstruct: error:")
    assert "Traceback" not in err


def test_unsupported_output_suffix(capsys, mug_session, tmp_path):
    code, _, err = run_cli(capsys, mug_session, "-o", tmp_path / "m.fbx", "-q")
    assert code == 2 and ".fbx" in err and ".ply" in err


def test_cli_writes_mesh_and_report(capsys, mug_session, tmp_path):
    out = tmp_path / "mug.ply"
    code, stdout, err = run_cli(capsys, mug_session, "-o", out, "-r", "64", "--holdout", "3", "-q")
    assert code == 0, err
    report = json.loads((tmp_path / "mug.report.json").read_text())
    assert out.exists() and report["mesh"]["watertight"]
    assert set(report["timings_s"]) >= {"segmentation", "carving", "meshing"}
    assert report["views"]["held_out"] == ["view_003.png"]
    assert "silhouette IoU" in stdout


def test_corrupt_and_missing_images_are_rejected_views(mug_session):
    (mug_session / "images" / "view_002.png").write_bytes(b"not a png at all")
    cv2.imwrite(str(mug_session / "images" / "view_007.png"), np.zeros((10, 10, 3), np.uint8))
    result = reconstruct(load_views(mug_session), FAST)
    reasons = {r["view"]: r["reason"] for r in result.report["views"]["rejected"]}
    assert "view_002.png" in reasons and "view_007.png" in reasons
    assert "10x10" in reasons["view_007.png"]  # names the size found
    assert result.report["mesh"]["watertight"]


def test_empty_silhouette_is_a_rejected_view(mug_session):
    image = cv2.imread(str(mug_session / "images" / "view_004.png"))
    image[:] = image[0, 0]  # background only
    cv2.imwrite(str(mug_session / "images" / "view_004.png"), image)
    result = reconstruct(load_views(mug_session), FAST)
    reasons = {r["view"]: r["reason"] for r in result.report["views"]["rejected"]}
    assert "empty silhouette" in reasons["view_004.png"]


def test_one_bad_mask_does_not_destroy_the_object(mug_session, mug):
    from sfs_ros.core.simulation.synthetic import score_against_truth

    path = mug_session / "images" / "view_010.png"
    image = cv2.imread(str(path))
    image[:, : image.shape[1] // 2] = image[0, 0]  # the left half of the object is gone
    cv2.imwrite(str(path), image)
    result = reconstruct(load_views(mug_session), FAST)
    rejected = {r["view"] for r in result.report["views"]["rejected"]}
    assert rejected == {"view_010.png"}
    assert score_against_truth(mug, result.vertices, result.faces,
                               result.grid)["volume_iou"] > MUG_IOU_SPARSE_MIN


def test_cli_reports_an_inconsistent_view_in_its_report(capsys, mug_session, tmp_path):
    path = mug_session / "images" / "view_010.png"
    image = cv2.imread(str(path))
    image[:, : image.shape[1] // 2] = image[0, 0]  # the left half of the object is gone
    cv2.imwrite(str(path), image)
    code, _, err = run_cli(capsys, mug_session, "-o", tmp_path / "m.ply", "-r", "48")
    assert code == 0, err
    report = json.loads((tmp_path / "m.report.json").read_text())
    assert [r["view"] for r in report["views"]["rejected"]] == ["view_010.png"]
    assert [c["consistent"] for c in report["consistency"]].count(False) == 1


def test_bounding_box_missing_the_object_is_an_error(mug_session):
    params = ReconstructionParams(resolution=64, bounds_m=((0.2, 0.2, 0.0), (0.3, 0.3, 0.1)))
    with pytest.raises(ValueError, match="misses part of the object"):
        reconstruct(load_views(mug_session), params)


def test_nan_and_out_of_range_angles_are_rejected_views(mug_session):
    table = mug_session / "views.csv"
    lines = table.read_text().splitlines()
    name_a, _, _ = lines[1].split(",")
    name_b, theta_b, _ = lines[2].split(",")
    lines[1] = f"{name_a},nan,0.3"
    lines[2] = f"{name_b},{theta_b},2.5"  # 143 degrees: beyond the C-arm
    table.write_text("\n".join(lines) + "\n")
    views = load_views(mug_session)
    rejected = dict(views.rejected)
    assert set(rejected) == {name_a, name_b}
    result = reconstruct(views, FAST)
    assert {r["view"] for r in result.report["views"]["rejected"]} >= {name_a, name_b}


def test_angles_table_not_matching_images(capsys, mug_session, tmp_path):
    table = mug_session / "views.csv"
    lines = table.read_text().splitlines()
    table.write_text("\n".join(lines[:-1]) + "\n")  # one image has no row
    code, _, err = run_cli(capsys, mug_session, "-o", tmp_path / "m.ply", "-q")
    assert code == 2 and "views.csv" in err and "Traceback" not in err


def test_cli_colours_the_mesh_and_refuses_colour_in_stl(capsys, mug_session, tmp_path, mug):
    from sfs_ros.core.exchange.export import load_mesh

    code, _, err = run_cli(capsys, mug_session, "-o", tmp_path / "c.ply", "-r", "48", "--colour")
    assert code == 0, err
    vertices, _, colours = load_mesh(tmp_path / "c.ply", with_colors=True)
    assert colours is not None and len(colours) == len(vertices)
    assert json.loads((tmp_path / "c.report.json").read_text())["colour"]["views"] > 0
    code, _, err = run_cli(capsys, mug_session, "-o", tmp_path / "c.stl", "--colour")
    assert code == 2 and "STL has none" in err
