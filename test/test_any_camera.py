"""A scan through any camera driver: frames streamed on ``image_raw``, no shutter call.

The mock cell (:mod:`mock_cell`, separate processes) with its mock camera
streaming at :data:`STREAM_HZ` (``rate_hz``), as a third-party driver
(``usb_cam``, ``v4l2_camera``, a GenICam driver) streams: each frame renders
the mug at the angles the simulated controller has when the frame is stamped.
One cell takes the same plan twice: through our camera node's ``capture``
(``camera_trigger`` shutter, the default), then, with the trigger switched at
run time, through the stream (the first frame stamped after the axes settled
plus an exposure delay). The two meshes agree with each other and with the
truth.

No fault is made here, so the cell's own fault deadlines (a frame, a move, a receipt, a
service answer) are set to bound a hang only (:data:`mock_cell.NO_FAULT`): two runs of
this test at once beside a CPU burner on 2 cores (doc/testing.md) saw the shutter's answer
take longer than :mod:`mock_cell`'s 3 s twice in a row, and the scan paused.
"""

from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray

from sfs_ros.cell_logic.message_fields import status_namespace
from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.geometry.grid import VoxelGrid
from sfs_ros.core.metrics import mesh_occupancy, volume_iou
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth

from mock_cell import PLAN, RESOLUTION, SCAN_TIMEOUT_S, no_fault, running_cell
from ros_harness import NAMESPACE, RosProbe, set_node_parameters
from tolerances import MUG_IOU_SPARSE_MIN

pytestmark = pytest.mark.cell

#: Frames per second of the streaming camera: a view waits at most one period after settling.
STREAM_HZ = 10.0
#: The stream's exposure delay after settling, s.
EXPOSURE_DELAY_S = 0.05
#: Volume IoU of the two scans' meshes on the 64^3 grid. Same views, same object: they
#: differ only by the encoders' noise (0.01 deg) in each view's tag and the image noise
#: (2 grey levels), which move a silhouette edge by well under a pixel, so only a few
#: boundary voxels flip (0.9999 measured); a view taken on the way (a frame exposed before
#: the axes settled) would cut whole voxel layers away.
MESHES_AGREE_MIN = 0.99
#: :data:`mock_cell.NO_FAULT`'s deadlines, the streaming camera, and the encoder reading
#: that tags a frame up to 5 s from it: a frame is taken only after readings settled on the
#: viewpoint, and the next move waits for it, so the reading nearest the frame is a settled
#: one however late the readings come.
SETTINGS = no_fault({"scan.yaml": {"encoder_max_gap_s": 5.0},
                     "camera.yaml": {"rate_hz": STREAM_HZ}})


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    with running_cell(tmp_path_factory.mktemp("any_camera"), "any_camera_client",
                      SETTINGS) as up:
        yield up


def _scan_and_reconstruct(client) -> tuple[str, dict]:
    """One scan to the end, then its mesh: (how the scan took its frames, from the scan
    node's diagnostics; the summary)."""
    probe = RosProbe("any_camera_diagnostics")
    triggers = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            # /diagnostics is shared with any other run that drew the same domain id.
            if status_namespace(status.name) == NAMESPACE and status.name.endswith(": scan"):
                values = {kv.key: kv.value for kv in status.values}
                triggers[values.get("scan")] = values.get("trigger")

    probe.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 50)
    try:
        scan = client.start_scan()
        client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
        probe.spin_until(lambda: str(scan) in triggers, what=f"the diagnostics of scan {scan}")
    finally:
        probe.close()
    summary = client.reconstruct()
    assert summary["views_received"] == summary["views_used"] == len(PLAN)
    return triggers[str(scan)], summary


def test_a_scan_through_a_streaming_camera_reaches_the_mesh_of_our_camera_node(cell):
    client = cell["client"]
    shutter_trigger, shutter = _scan_and_reconstruct(client)
    assert shutter_trigger == "shutter"

    set_node_parameters("scan", camera_trigger="stream", exposure_delay_s=EXPOSURE_DELAY_S)
    stream_trigger, stream = _scan_and_reconstruct(client)
    assert stream_trigger == "stream"          # this scan took the streamed frames

    mug = make_object("mug")
    grid = VoxelGrid.cube(*carving_box(mug), RESOLUTION)
    occupancy = {}
    for name, summary in (("shutter", shutter), ("stream", stream)):
        vertices, faces = load_mesh(Path(summary["path"]))
        occupancy[name] = mesh_occupancy(vertices, faces, grid)
        assert score_against_truth(mug, vertices, faces, grid)["volume_iou"] >= \
            MUG_IOU_SPARSE_MIN, name
    agreement = volume_iou(occupancy["shutter"], occupancy["stream"])
    assert agreement >= MESHES_AGREE_MIN, agreement
