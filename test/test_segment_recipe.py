"""Default segmentation (no preset) of the Middlebury rings against the datasets' own masks.

The reference is the recipe of the datasets' README (``readme_mask``): the
largest of the three channels above 0.19 of full scale (0.3 for the temple,
whose dark cloth passes 0.19), dilated by 10 px (21x21 square), eroded by
7 px (15x15 square), blobs under 1 % of the largest dropped. Reads
``../shared/datasets/middlebury`` beside the repository; skipped, with the
reason, when it is absent.
"""

from pathlib import Path

import numpy as np
import pytest

from sfs_ros.core.exchange.middlebury import read_middlebury
from sfs_ros.core.exchange.middlebury import readme_mask as recipe_mask
from sfs_ros.core.exchange.views import read_image
from sfs_ros.core.segmentation.segment import segment

DATA = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "middlebury"

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"Middlebury data sets not found at {DATA}")

# (par file, recipe threshold, bar on the mean per-view IoU). Measured: dino
# 0.977 (views 0.965-0.985), temple 0.965 (0.918-0.981). The recipe masks are
# conservative (dilate 10 then erode 7 widens every outline by ~3 px) and ours
# are not, so a perfect silhouette would score ~0.97-0.98 here, not 1. The
# bars sit 0.01 (temple 0.005) under the measurement (deterministic computation; margin for
# library versions) and above the old default (dino 0.945; temple 0.815, its
# cloth segmented as object).
SETS = {
    "dino": ("dinoSparseRing/dinoSR_par.txt", 0.19, 0.967),
    "temple": ("templeSparseRing/templeSR_par.txt", 0.3, 0.960),
}


def test_recipe_mask_drops_specks_and_bridges_cracks():
    image = np.zeros((200, 200, 3), np.uint8)
    image[20:180, 20:95] = image[20:180, 105:180] = 200  # two halves, a 10 px crack between
    image[5, 5] = 255  # a speck: 7x7 px after dilate + erode, 0.2 % of the object
    image[190, 190] = 40  # below the threshold (0.16 of full scale)
    mask = recipe_mask(image, 0.19)
    # Dilate 10 then erode 7: the crack closes and the outline grows by 3 px.
    assert mask[20:180, 95:105].all() and mask[17:183, 17:183].all()
    assert mask.sum() == 166 * 166  # nothing else: the speck dropped, the dim pixel never in


@pytest.mark.parametrize("name", sorted(SETS))
def test_default_segmentation_matches_the_recipe(name):
    par, threshold, bar = SETS[name]
    ious = []
    for view in read_middlebury(DATA / par).views:
        image = read_image(view.image_path)
        ours, reference = segment(image).mask, recipe_mask(image, threshold)
        ious.append((ours & reference).sum() / (ours | reference).sum())
    print(f"{name}: mean IoU {np.mean(ious):.4f}, per view " + " ".join(f"{v:.3f}" for v in ious))
    assert np.mean(ious) >= bar
