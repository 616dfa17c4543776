"""A quiet, honest cell: ``sfs-cell --mock --record`` started, a short scan started the moment
the cell is ready, a reconstruction, Ctrl-C (SIGINT); the cell's whole output holds no
ERROR, no traceback and none of rclpy's shutdown complaints, the hardware was brought up in
order through its lifecycle services with no retry warning, and the recorded bag holds
every capture and every mask of the scan.
"""

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from sfs_ros.cell_logic.bag import open_bag
from sfs_ros.ros.cell_client import CellClient

from mock_cell import NO_FAULT, SCAN_TIMEOUT_S, write_config
from ros_harness import NAMESPACE, SOURCE_ROOT
from waiting import wait

pytestmark = pytest.mark.cell

#: Lines that must not appear in a normal start, scan, reconstruct and Ctrl-C.
NOISE = ("[ERROR]", "Traceback", "was never retrieved", "Failed to publish log message")
#: Seconds sfs-cell may take to stop its nodes after SIGINT (bounds a hang only).
STOP_TIMEOUT_S = 120.0
THETA_RAD = [0.0, 1.6, 3.2, 4.8]
PHI_RAD = [0.4, 0.4, 0.9, 0.9]
CAPTURE_TOPICS = ("capture/image", "capture/joint_state", "capture/mask",
                  "capture/mask_joint_state")


def _sfs_cell(root: Path, namespace: str) -> tuple[subprocess.Popen, Path, Path]:
    """``sfs-cell --mock --record`` on the small config, its output in a file."""
    # The scan's deadlines bound a hang only, so that a retry, which this test looks for,
    # is never one the machine's load caused (receipts may take long while the first views
    # compile the carving kernels, too).
    config = write_config(root / "config", NO_FAULT)
    output = root / "output"
    log_path = root / "sfs-cell.log"
    env = dict(os.environ, PYTHONPATH=str(SOURCE_ROOT))
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "sfs_ros.cli.cell", "--mock", "--record", "-o", str(output),
             "--config", str(config), "--namespace", namespace],
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=root)
    return process, output, log_path


def test_a_normal_session_logs_no_error_and_the_bag_holds_the_whole_scan(tmp_path):
    namespace = f"{NAMESPACE}_quiet"
    process, output, log_path = _sfs_cell(tmp_path, namespace)
    try:
        with CellClient(namespace, name="quiet_client") as client:
            client.wait_ready(timeout_s=SCAN_TIMEOUT_S)
            result = client.scan_goal(theta_rad=THETA_RAD, phi_rad=PHI_RAD, scan_name="quiet",
                                      timeout_s=SCAN_TIMEOUT_S)
            assert result.success, result.message
            summary = client.reconstruct()
            assert summary["views_used"] == len(THETA_RAD), summary
        [bag] = (output / "bags").iterdir()
        mcap = next(bag.glob("*.mcap"))
        wanted = {f"{namespace}/{topic}" for topic in CAPTURE_TOPICS}
        counts = {}

        def whole() -> bool:
            counts.update(open_bag(mcap).counts)
            return all(counts.get(topic, 0) >= len(THETA_RAD) for topic in wanted)

        try:
            wait(whole, what="every capture and mask in the bag")
        except AssertionError as exc:
            raise AssertionError(f"{exc}: {counts}") from None
    finally:
        process.send_signal(signal.SIGINT)
        code = process.wait(timeout=STOP_TIMEOUT_S)
    log = log_path.read_text(errors="replace")
    assert code == 0, log[-5000:]
    noisy = [line for line in log.splitlines() if any(n in line for n in NOISE)]
    assert not noisy, "\n".join(noisy)
    # In order, through the lifecycle services: no retry, no refused transition.
    assert "retrying" not in log and "refused" not in log, log
    # The mock (its port), then its camera, then the motor: "[node] [INFO] [time] [ns.node]: ..."
    order = [log.index(text) for text in (
        "[mock_hardware] ", "lifecycle_manager]: camera is active",
        "lifecycle_manager]: motor is active")]
    assert order == sorted(order), log
