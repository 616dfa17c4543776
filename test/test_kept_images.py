"""The consensus cuts the images the segmentation kept: each photograph decoded once.

A mug rendered on white from 12 views (320 x 240, on three rings: so few views that the
tolerant hull sticks out of the object and most views are cut again), reconstructed by
:func:`~sfs_ros.core.pipeline.carve_scan` with every image read counted. The masks the
views carve with are scored against the renderer's exact silhouettes.
"""

from collections import Counter

import numpy as np
import pytest

from sfs_ros.core import stages
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.metrics import silhouette_iou
from sfs_ros.core.pipeline import ReconstructionParams, carve_scan
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import exact_silhouettes, simulate_scan

RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=700.0, fy=700.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))
PARAMS = ReconstructionParams(resolution=96)
#: Least IoU of a view's mask with its exact silhouette: the mug's silhouettes here cover
#: about 9 000 px inside an outline of about 400 px, so a tenth of a pixel all around
#: costs 0.005; on a clean render on white the cut finds the outline closer than that.
IOU_MIN = 0.995


@pytest.fixture(scope="module")
def mug_scan(tmp_path_factory):
    """The session's views and the exact silhouettes of the mug in their ideal cameras."""
    obj = make_object("mug")
    captures = simulate_scan(obj, RIG, ring_plan((10.0, 40.0, 70.0), 4), seed=3)
    session = write_session(tmp_path_factory.mktemp("kept") / "session",
                            [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], RIG)
    views = load_views(session)
    return views, exact_silhouettes(obj, [v.camera for v in views.views])


def _carve_counting_reads(views, monkeypatch) -> tuple:
    """carve_scan of ``views`` with PARAMS, and how often each image file was read."""
    reads = Counter()
    read = stages.read_image

    def counted(path, *args, **kwargs):
        reads[str(path)] += 1
        return read(path, *args, **kwargs)

    monkeypatch.setattr(stages, "read_image", counted)
    return carve_scan(views, PARAMS), reads


def _worst_iou(carved, truth) -> float:
    return float(np.min([silhouette_iou(m, t) for m, t in zip(carved.masks, truth)]))


def test_the_consensus_cuts_the_kept_images_without_reading_them_again(mug_scan,
                                                                        monkeypatch):
    views, truth = mug_scan
    carved, reads = _carve_counting_reads(views, monkeypatch)
    assert carved.report["resegmentation"]["resegmented"] > 0
    assert sorted(reads.values()) == [1] * len(views.views)
    assert _worst_iou(carved, truth) >= IOU_MIN


def test_a_scan_over_the_budget_is_read_again_for_the_same_masks(mug_scan, monkeypatch):
    views, truth = mug_scan
    monkeypatch.setattr(stages, "KEPT_IMAGES_BYTES", 3 * RIG.width * RIG.height)
    carved, reads = _carve_counting_reads(views, monkeypatch)
    again = carved.report["resegmentation"]["resegmented"]
    assert again > 0
    assert sum(reads.values()) == len(views.views) + again
    assert _worst_iou(carved, truth) >= IOU_MIN
