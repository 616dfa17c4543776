"""The reconstruction node refuses a resolution the machine cannot hold, before allocating,
with the memory it would need, and stays up (a separate process, as in the cell)."""

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_srvs.srv import Trigger

from sfs_ros.core.carving.resolution import BYTES_PER_VOXEL, grid_shape

from ros_harness import NodeUnderTest

MODULE = "sfs_ros.nodes.reconstruction_node"
BOX = [-0.05, -0.05, 0.0, 0.05, 0.05, 0.1]
RESOLUTION = 2048
#: The grid of 2048 voxels a side is 8.6 G voxels, 128 GiB at 16 bytes a voxel: far over
#: this budget and over any test machine's memory.
BUDGET = "256M"
#: The node's whole resident memory stays far below the grid's (imports take some 300 MB):
#: nothing of the grid was allocated.
MAX_RSS_BYTES = 1 << 30


class RefusingNode(NodeUnderTest):
    def __init__(self, params_file):
        super().__init__(MODULE, params_file=params_file)
        node = self.probe.node
        self.statuses = []
        sub = node.create_subscription(DiagnosticArray, "diagnostics",
                                       lambda m: self.statuses.extend(m.status), 10)
        self.client = node.create_client(Trigger, "reconstruct")
        self.probe.wait_connected([], [sub], process=self.process)
        self.probe.spin_until(self.client.service_is_ready, what="reconstruct",
                              process=self.process)


@pytest.fixture()
def params_file(tmp_path):
    params = {"width": 320, "height": 240, "fx": 700.0, "fy": 700.0, "bounds_m": BOX,
              "resolution": RESOLUTION, "max_memory": BUDGET,
              "output_dir": str(tmp_path / "out")}
    path = tmp_path / "reconstruction.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    return path


def test_a_resolution_too_large_is_refused_with_the_memory_it_needs_and_the_node_stays_up(
        start_node, params_file):
    node = start_node(RefusingNode, params_file)
    shape = grid_shape(np.reshape(BOX, (2, 3)), 0.1 / RESOLUTION)     # the box is 0.1 m a side
    needed_gib = int(np.prod(shape)) * BYTES_PER_VOXEL / (1 << 30)
    node.probe.spin_until(lambda: node.statuses, what="diagnostics", process=node.process)
    status = node.statuses[-1]
    assert status.level == DiagnosticStatus.ERROR
    assert f"resolution {RESOLUTION} is more than this machine may hold" in status.message
    assert f"needs {needed_gib:.2f} GiB" in status.message and "budget is 0.25 GiB" in \
        status.message
    future = node.client.call_async(Trigger.Request())
    node.probe.spin_until(future.done, what="the reconstruct answer", process=node.process)
    answer = future.result()
    assert not answer.success and f"needs {needed_gib:.2f} GiB" in answer.message
    assert node.process.alive()
    rss_kib = int(re.search(r"VmRSS:\s+(\d+)", Path(
        f"/proc/{node.process.process.pid}/status").read_text()).group(1))
    assert rss_kib * 1024 < MAX_RSS_BYTES
