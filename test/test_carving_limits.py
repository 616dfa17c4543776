"""The carving node at the machine's limits (a separate process, as in the cell): a
resolution it cannot hold is refused before allocating, with the memory it would need, and
the node stays up; a view that a full disk refuses is kept, without a receipt, and stored
and receipted once space returns, the views stored before left whole."""

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Header

from sfs_ros.core.carving.resolution import BYTES_PER_VOXEL, grid_shape
from sfs_ros.core.exchange.session import read_session
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import image_to_msg, joint_state
from sfs_ros.ros.names import DIAGNOSTICS, TYPED_SERVICES
from sfs_ros_interfaces.srv import CarveScan

from ros_harness import NodeUnderTest, keep_ours
from small_disk import fill, small_disk

MODULE = "sfs_ros.nodes.carving_node"
BOX = [-0.05, -0.05, 0.0, 0.05, 0.05, 0.1]
RESOLUTION = 2048
#: The grid of 2048 voxels a side is 8.6 G voxels, 128 GiB at 16 bytes a voxel: far over
#: this budget and over any test machine's memory.
BUDGET = "256M"
#: The node's whole resident memory stays far below the grid's (imports take some 300 MB):
#: nothing of the grid was allocated.
MAX_RSS_BYTES = 1 << 30


class CarvingNode(NodeUnderTest):
    """The node with the probe's mask publishers, receipts, diagnostics and carve_scan."""

    def __init__(self, params_file):
        super().__init__(MODULE, params_file=params_file)
        node, qos = self.probe.node, capture_qos(100)
        self.diagnostics, self.receipts = [], []
        self.mask_pub = node.create_publisher(Image, "capture/mask", qos)
        self.joints_pub = node.create_publisher(JointState, "capture/mask_joint_state", qos)
        subs = [node.create_subscription(DiagnosticArray, DIAGNOSTICS,
                                         keep_ours(self.diagnostics), 10),
                node.create_subscription(Header, "capture/stored", self.receipts.append, qos)]
        self.client = node.create_client(CarveScan, TYPED_SERVICES["carve_scan"])
        self.probe.wait_connected([self.mask_pub, self.joints_pub], subs, process=self.process)
        self.probe.spin_until(self.client.service_is_ready, what="carve_scan",
                              process=self.process)

    def send(self, n: int) -> None:
        """View ``n``: a disc mask at ``theta = n`` rad, stamped ``(100 + n, 0)``."""
        yy, xx = np.mgrid[:240, :320]
        mask = ((xx - 160) ** 2 + (yy - 120) ** 2 < 60 ** 2).astype(np.uint8) * 255
        self.mask_pub.publish(image_to_msg(mask, stamp=(100 + n, 0), frame_id="camera"))
        self.joints_pub.publish(joint_state(float(n), 0.5, stamp=(100 + n, 0)))

    @property
    def statuses(self):
        return [s for array in self.diagnostics for s in array.status]

    def receipted(self) -> list[int]:
        return [r.stamp.sec - 100 for r in self.receipts]


def _params(folder, output, **values):
    params = {"width": 320, "height": 240, "fx": 700.0, "fy": 700.0, "bounds_m": BOX,
              "output_dir": str(output), "resolution": 32, **values}
    path = folder / "carving.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    return path


@pytest.fixture()
def params_file(tmp_path):
    return _params(tmp_path, tmp_path / "out", resolution=RESOLUTION, max_memory=BUDGET)


def test_a_resolution_too_large_is_refused_with_the_memory_it_needs_and_the_node_stays_up(
        start_node, params_file):
    node = start_node(CarvingNode, params_file)
    shape = grid_shape(np.reshape(BOX, (2, 3)), 0.1 / RESOLUTION)     # the box is 0.1 m a side
    needed_gib = int(np.prod(shape)) * BYTES_PER_VOXEL / (1 << 30)
    node.probe.spin_until(lambda: node.statuses, what="diagnostics", process=node.process)
    status = node.statuses[-1]
    assert status.level == DiagnosticStatus.ERROR
    assert f"resolution {RESOLUTION} is more than this machine may hold" in status.message
    assert f"needs {needed_gib:.2f} GiB" in status.message and "budget is 0.25 GiB" in \
        status.message
    future = node.client.call_async(CarveScan.Request())
    node.probe.spin_until(future.done, what="the carve_scan answer", process=node.process)
    answer = future.result()
    assert not answer.success and f"needs {needed_gib:.2f} GiB" in answer.message
    assert node.process.alive()
    rss_kib = int(re.search(r"VmRSS:\s+(\d+)", Path(
        f"/proc/{node.process.process.pid}/status").read_text()).group(1))
    assert rss_kib * 1024 < MAX_RSS_BYTES


def test_a_view_refused_by_a_full_disk_is_stored_and_receipted_once_space_returns(
        start_node, tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    with small_disk(disk, "2m"):
        # No rehearsal: its scan, refused by the small disk, would free its space again
        # whenever its clean-up runs, maybe after the disk is filled below.
        node = start_node(CarvingNode, _params(tmp_path, disk / "out", rehearse=False))
        node.send(0)
        node.probe.spin_until(lambda: node.receipted() == [0], what="view 0's receipt",
                              process=node.process)
        fill(disk / "filler")
        node.send(1)

        def refused():
            return any("not stored in" in s.message and "No space left on device" in s.message
                       for s in node.statuses)
        node.probe.spin_until(refused, what="the ERROR of view 1", process=node.process)
        message = next(s.message for s in node.statuses if "not stored in" in s.message)
        assert str(disk / "out" / "scan_001") in message and "MB free" in message
        assert node.receipted() == [0]                  # no receipt for what is not stored
        session = read_session(disk / "out" / "scan_001")
        assert [v.name for v in session.views] == ["view_000_100_000000000.png"]
        (disk / "filler").unlink()
        node.probe.spin_until(lambda: node.receipted() == [0, 1], what="view 1's receipt",
                              process=node.process)
        session = read_session(disk / "out" / "scan_001")
        assert [v.name for v in session.views] == ["view_000_100_000000000.png",
                                                   "view_001_101_000000000.png"]
        assert node.process.alive()
