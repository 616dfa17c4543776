"""Acceptance on real photographs: the Middlebury dino and temple sparse rings.

Reads ``../shared/datasets/middlebury`` beside the repository; skipped, with
the reason printed, where the data sets are absent.
"""

import json
from pathlib import Path

import pytest

from sfs_ros.cli.reconstruct import main

DATA = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "middlebury"

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"Middlebury data sets not found at {DATA}")

# Acceptance bars on the mean silhouette IoU of the mesh reprojected into every
# view of the set (rejected views count too, so dropping views cannot help).
CASES = [("dinoSparseRing/dinoSR_par.txt", "middlebury-dino", 0.95),
         ("templeSparseRing/templeSR_par.txt", "middlebury-temple", 0.92)]


@pytest.mark.parametrize("par, preset, bar", CASES, ids=["dino", "temple"])
def test_reprojected_mesh_matches_the_silhouettes(tmp_path, capsys, par, preset, bar):
    out = tmp_path / "mesh.ply"
    assert main([str(DATA / par), "-o", str(out), "--preset", preset, "-r", "160", "-q"]) == 0
    report = json.loads((tmp_path / "mesh.report.json").read_text())
    per_view = report["silhouette_iou"]["per_view"]
    assert len(per_view) == 16
    mean = sum(v["silhouette_iou"] for v in per_view) / len(per_view)
    print(f"{preset}: mean silhouette IoU {mean:.4f} over {len(per_view)} views, "
          f"min {min(v['silhouette_iou'] for v in per_view):.4f}")
    assert mean >= bar
    assert report["mesh"]["watertight"] and report["mesh"]["outward"]


def test_temple_texture_and_vertex_colours_in_held_out_views(tmp_path, capsys):
    """Three of the temple's 16 photographs held out, the mesh textured and coloured from
    the others: PSNR of each in the held-out photographs, inside their silhouettes."""
    out = tmp_path / "temple.glb"
    assert main([str(DATA / "templeSparseRing/templeSR_par.txt"), "-o", str(out), "--preset",
                 "middlebury-temple", "-r", "160", "--texture", "--colour", "--holdout",
                 "2,7,12", "-q"]) == 0
    colour = json.loads((tmp_path / "temple.report.json").read_text())["held_out_colour_psnr"]
    assert colour["views"] == ["templeSR0003.png", "templeSR0008.png", "templeSR0013.png"]
    print(f"temple, held out: texture {colour['texture_db']:.2f} dB, vertex colours "
          f"{colour['vertex_colours_db']:.2f} dB")
    # Measured 18.83 dB against 18.76. The mesh is not the temple (its columns and steps
    # are concave), so a view 22.5 degrees away sees the views' detail a few pixels off:
    # there the views, left out one by one, predict one another best blurred, and the
    # texture blurs its blend as far (unblurred, it was 18.25 dB).
    assert colour["texture_db"] > colour["vertex_colours_db"]
    assert colour["texture_db"] > 15.0
