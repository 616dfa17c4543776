"""The rehearsal scan: a real live reconstruction of the mug, files and pictures included."""

import json
from pathlib import Path

import numpy as np
import pytest

from sfs_ros.cell_logic.rehearsal import REHEARSAL_PLAN, REHEARSAL_RIG, rehearse
from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.meshing.colour import MAX_COLOUR_VIEWS


def test_rehearsal_reconstructs_the_mug_with_its_files(tmp_path):
    summary = rehearse(tmp_path)
    assert summary["views_used"] == len(REHEARSAL_PLAN) == 25
    # More views than the colour takes: the evaluation draws the others, as in a real scan.
    assert summary["watertight"] and summary["coloured_from_views"] == MAX_COLOUR_VIEWS < 25
    vertices, faces = load_mesh(summary["path"])
    assert len(faces) == summary["n_faces"] > 1000
    assert Path(summary["path"]).resolve().is_relative_to(tmp_path.resolve())
    report = json.loads(Path(summary["report_path"]).read_text())
    # The mesh against the exact silhouettes it was made from, at 48^3 on 160 x 120
    # (drawn into the views the colour does not draw with the pictures, after the mesh):
    # 0.984 measured; a mesh far from the mug (a box, an empty scan) is below 0.9.
    assert report["silhouette_iou"]["mean_used"] >= 0.96
    for key in ("preview", "html", "contact_sheet"):      # the pictures came after the mesh
        assert Path(report[key]).is_file()


def test_rehearsal_takes_one_view_per_planned_pose(tmp_path):
    mask = np.ones((REHEARSAL_RIG.height, REHEARSAL_RIG.width), bool)
    with pytest.raises(ValueError, match="25 views, got 2"):
        rehearse(tmp_path, [(mask, np.zeros(mask.shape + (3,), np.uint8))] * 2)
