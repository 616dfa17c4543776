"""The default reconstruction (no options) of a harder hostile cell, scored against exact
silhouettes: 48 views of 640 x 480 on four rings up to 75 degrees.

The cell of :mod:`sfs_ros.core.simulation.hostile` (turntable plate, cast shadow, dark
cloth, highlights, dark dashes, a quarter of the views partly out of frame), seen as a
hemisphere scan sees it: from 15 degrees the whole plate fits in the frame, from 75 the
mug's dark side lies next to its cast shadow on the plate. The figures move with the
segmentation's every choice, and a whole ring can be wrong the same way (the fusion
cannot outvote twelve views), so this set guards them: a change that scored the same
on the smaller scene of ``test_segment_scene.py`` took this mesh on black from 0.969 to
0.914.
"""

import pytest
from written_scan import exact_ious, reconstruct_written

from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.simulation.hostile import simulate_hostile_scan
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan

#: Pinhole at 0.6 m, aimed 45 mm above the plate: the mug is ~200 px tall.
RIG = RigCalibration(width=640, height=480, projection="pinhole", fx=1300.0, fy=1300.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.045))
PLAN = ring_plan([15.0, 35.0, 55.0, 75.0], 12)

#: Mean IoU of the mesh against the exact silhouettes, measured: 0.985 on black (worst
#: view 0.973) and 0.984 on white (worst 0.973). Everything is deterministic (a seeded
#: scene, seeded k-means and GrabCut), so the bars sit 0.014 under the measurements, as
#: in ``test_segment_scene.py``, for library versions. Before each view's backdrop was
#: made to agree with the whole scan's (the plate, wholly in the frame of the lowest
#: ring, taken for object there), 0.975 (worst 0.929) and 0.972 (0.936); before the
#: consensus cut the views not settled with a prior that tolerates misses by a tenth of
#: the views, white scored 0.890 (worst 0.800): from 75 degrees the mug's dark side went
#: with its cast shadow in most views of the ring, the strict prior lost it, and the
#: views from 55 degrees were cut to match.
MESH_IOU_MIN = {"black": 0.971, "white": 0.969}


@pytest.fixture(scope="module", params=["black", "white"])
def scan(request, tmp_path_factory):
    """The scene's views written as images with their cameras, reconstructed with the
    default parameters (box estimated from the views)."""
    backdrop = request.param
    captures = simulate_hostile_scan(make_object("mug"), RIG, PLAN, backdrop=backdrop, seed=3)
    folder = tmp_path_factory.mktemp(f"hemisphere_{backdrop}")
    return backdrop, captures, reconstruct_written(captures, folder)


def test_default_reconstruction_of_the_hostile_hemisphere(scan):
    backdrop, captures, result = scan
    ious = exact_ious(result, captures)
    print(f"{backdrop}: mesh IoU {ious.mean():.4f} (worst {ious.min():.3f})")
    assert result.report["views"]["rejected"] == []
    # The lowest ring sees the whole plate in the frame: each of its views is segmented
    # with the scan's backdrop, which holds the plate's grey.
    assert {c.name for c in captures[:12]} <= set(result.report["backdrop"]["views"])
    assert ious.mean() >= MESH_IOU_MIN[backdrop]
