"""The cell outlives its nodes and a full disk, in the real bring-up (``Cell`` with the
supervisor of ``wait_until_signal``, mock hardware), and every view of the plan is still
delivered exactly once:

* each node is killed (SIGKILL) in turn in the middle of one scan;
* the output folder is a small tmpfs that is filled up in the middle of a scan, then
  emptied again.

Exactly once, checked against the plan: the scan node's progress lists one capture per
planned view; the carving node's session folder holds each of those captures' views once
and nothing else; the mesh is made of all of them; the bags of the scan hold each capture.
"""

import os
import re
import signal
import threading
import time
from contextlib import contextmanager

import pytest
import yaml
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from sfs_ros.cell_logic.bag import open_bag
from sfs_ros.cell_logic.message_fields import stamp_key, view_key
from sfs_ros.cli.bringup import Cell, RestartPolicy, cell_nodes, wait_until_signal
from sfs_ros.core.exchange.errors import ViewError
from sfs_ros.core.exchange.session import read_session
from sfs_ros.ros.cell_client import CellClient, ScanFailed

from mock_cell import PLAN, SCAN_TIMEOUT_S, write_config
from ros_harness import NAMESPACE, SOURCE_ROOT
from small_disk import keep_full, small_disk
from waiting import wait

pytestmark = pytest.mark.cell

#: Kill order: hardware first, the scan node last (the hard case: it resumes from disk).
#: mock_hardware is the controller and the camera: killing it is a power cut of both. The
#: captures taken while the recorder is down reach its new bag when the scan node sees it
#: subscribe again (every capture is sent again).
KILLED = ("mock_hardware", "motor", "segmentation", "recorder", "carving", "meshing", "scan")
#: The first kill after this many views are captured, then one more per view: the last
#: (the scan node) at view 8 of 17, so every node dies while views are being taken however
#: fast the scan goes (waiting for a victim's start-up between kills let a quick scan end
#: before the last ones).
FIRST_KILL_AT_VIEW = 2
#: Bounds the whole scan with seven restarts on a loaded machine (a hang bound only).
SURVIVAL_TIMEOUT_S = 900.0

#: Retries generous enough to ride through a restart (a node's start-up under load takes
#: 10-30 s): moves and shots are tried again, homing first (a restarted controller is locked
#: until homed), and receipts are awaited without giving up.
SURVIVAL_SCAN = {"home_before_retry": True, "move_retries": 20, "capture_retries": 40,
                 "max_sends": 1000}


def _config(root):
    return write_config(root / "config", {"scan.yaml": SURVIVAL_SCAN})


def _bag_stamps(bags) -> set:
    """The stamps of the captures (``capture/joint_state``) in every readable bag under
    ``bags`` (a bag opened while the disk was full may hold nothing, not even its header)."""
    stamps = set()
    for folder in sorted(p for p in bags.iterdir() if p.is_dir()):
        try:
            bag = open_bag(folder)
        except ViewError:
            continue
        topic = bag.topic("capture/joint_state")
        if topic is None:
            continue
        for message in bag.messages([topic]):
            stamps.add(stamp_key(deserialize_message(message.data, JointState).header.stamp))
    return stamps


@contextmanager
def _supervised(root, output):
    """A mock cell configured in ``root``, writing to ``output``, recording every scan,
    under the supervisor."""
    config = _config(root)
    output.mkdir(exist_ok=True)
    log_path = root / "cell.log"
    env = dict(os.environ, PYTHONPATH=str(SOURCE_ROOT))
    with open(log_path, "w") as log:
        cell = Cell(cell_nodes(config, output, mock=True, record=True), namespace=NAMESPACE,
                    log=log, env=env).start()
        stopping = threading.Event()
        result = {}
        supervisor = threading.Thread(target=lambda: result.update(status=wait_until_signal(
            cell, policy=RestartPolicy(first_delay_s=0.2), stopping=stopping, log=log)))
        supervisor.start()
        client = CellClient(NAMESPACE, name="survival_client")
        try:
            client.wait_ready(timeout_s=SCAN_TIMEOUT_S)
            yield {"cell": cell, "client": client, "output": output, "log": log_path}
        finally:
            client.close()
            stopping.set()
            supervisor.join(SURVIVAL_TIMEOUT_S)
    assert result.get("status") == 0, \
        f"the cell did not stop cleanly\n{log_path.read_text()[-5000:]}"


def _delivered_once(output, scan: int, summary: dict) -> set:
    """Checks that every planned view of ``scan`` was stored once and meshed; its stamps."""
    total = len(PLAN)
    progress = yaml.safe_load((output / "scan_progress" / "progress.json").read_text())
    assert progress["scan"] == scan and progress["state"] == "done"
    assert sorted(c["view"] for c in progress["captures"]) == list(range(total))
    stamps = {tuple(c["stamp"]) for c in progress["captures"]}
    assert len(stamps) == total

    session = read_session(summary["session_dir"])
    names = [v.name for v in session.views]
    assert len(names) == len(set(names)) == total          # no view stored twice
    assert {n.split("_", 2)[2].removesuffix(".png") for n in names} == \
        {view_key(s) for s in stamps}                       # exactly the scan's captures
    assert summary["views_received"] == summary["views_used"] == total
    assert summary["n_faces"] > 0 and os.path.isfile(summary["path"])
    return stamps


@contextmanager
def _log_on_failure(log_path):
    """A failure inside says what the cell's nodes logged (the end of the cell's log)."""
    try:
        yield
    except (AssertionError, TimeoutError, ScanFailed) as exc:
        tail = "\n".join(log_path.read_text(errors="replace").splitlines()[-150:])
        raise AssertionError(f"{type(exc).__name__}: {exc}\n--- the end of the cell's log "
                             f"---\n{tail}") from exc


def _wait_captured(client: CellClient, scan: int, views: int, deadline: float) -> None:
    """Until ``views`` views of ``scan`` are captured; ScanFailed at once if it pauses."""
    client.wait_scan(scan, lambda s: s.count("captured") >= views,
                     timeout_s=deadline - time.monotonic())


def test_every_node_killed_mid_scan_and_every_view_delivered_exactly_once(tmp_path):
    output = tmp_path / "output"
    with _supervised(tmp_path, output) as cell, _log_on_failure(cell["log"]):
        stamps = _kill_each_node_mid_scan(cell)
    assert stamps <= _bag_stamps(output / "bags")   # the bags, closed now, hold every capture


def _resent_after_the_recorder_came_back(log: str) -> bool:
    """Whether the scan node sent every capture again after the recorder's second start-up
    line (its new subscription, or a later restart, makes it do so)."""
    starts = [m.start() for m in re.finditer("recording into", log)]
    return len(starts) >= 2 and "a new receiver of captures" in log[starts[1]:]


def _kill_each_node_mid_scan(supervised) -> set:
    """Kills each node once, mid-scan; checks that every view was delivered once; the
    stamps of the scan's captures."""
    cell, client = supervised["cell"], supervised["client"]
    output, log_path = supervised["output"], supervised["log"]
    total = len(PLAN)
    scan = client.start_scan()
    deadline = time.monotonic() + SURVIVAL_TIMEOUT_S
    for n, name in enumerate(KILLED):
        _wait_captured(client, scan, FIRST_KILL_AT_VIEW + n, deadline)
        os.kill(cell.processes[name].pid, signal.SIGKILL)
    status = client.wait_scan_done(scan, timeout_s=deadline - time.monotonic())
    assert status.count("captured") == status.count("receipted") == total
    summary = client.reconstruct()
    wait(lambda: _resent_after_the_recorder_came_back(log_path.read_text()),
         what="the captures sent again to the restarted recorder",
         timeout=deadline - time.monotonic())

    log = log_path.read_text()
    for name in KILLED:
        assert f"node {name} ended by itself (exit status -9)" in log, name
    assert "took up scan 1 (running)" in log        # the scan node resumed, not restarted
    assert "took up the open scan" in log            # so did the carving node
    stamps = _delivered_once(output, scan, summary)
    # The captures sent again are still on their way when the scan node logs that it sends
    # them: stopping the cell then could close the bag before they are in. The recorder
    # writes each message through (an open bag reads up to its last one): wait for them.
    wait(lambda: stamps <= _bag_stamps(output / "bags"),
         what="every capture of the scan in the bags", timeout=deadline - time.monotonic())
    return stamps


#: Size of the small filesystem: room for a scan (captures of 320 x 240 RGB, about 0.25 MB
#: each, kept by the scan node and recorded in the bag) with a wide margin, so that only the
#: filler makes it full.
TMPFS_SIZE = "64m"


@pytest.fixture()
def disk(tmp_path):
    mount_point = tmp_path / "disk"
    mount_point.mkdir()
    with small_disk(mount_point, TMPFS_SIZE):
        yield mount_point


def _session_intact(output) -> int:
    """The open session folder reads whole (every row's image decodes); its view count."""
    opened = [p.parent for p in output.glob("scan_*/.open")]
    assert len(opened) == 1, opened
    session = read_session(opened[0])
    assert not session.rejected
    for view in session.views:
        assert view.image_path.stat().st_size > 0
    return len(session.views)


def test_a_full_disk_pauses_the_scan_which_goes_on_once_space_returns(tmp_path, disk):
    output = disk / "cell"
    with _supervised(tmp_path, output) as cell, _log_on_failure(cell["log"]):
        client = cell["client"]
        scan = client.start_scan()
        # Views stored by the reconstruction too, so its session folder exists to be
        # checked for damage (on a loaded machine it lags the captures).
        client.wait_scan(scan, lambda s: s.count("captured") >= 4 and s.count("receipted") >= 2,
                         timeout_s=SCAN_TIMEOUT_S)
        filler, release = disk / "filler", threading.Event()
        keeper = threading.Thread(target=keep_full, args=(filler, release))
        keeper.start()
        try:
            wait(lambda: client.scan.state == "waiting", what="the scan waiting for space",
                 timeout=SCAN_TIMEOUT_S)
            stalled = client.scan
            assert "cannot keep the capture in" in stalled.message
            assert str(output / "scan_progress") in stalled.message
            assert "No space left on device" in stalled.message
            assert "MB free there" in stalled.message
            stored = _session_intact(output)     # what was stored before is whole
            assert stored <= stalled.count("captured") < len(PLAN)
            # The recorder meets the full disk at its own pace: its small messages (the
            # diagnostics, once the captures stop) fill the slack of its file's last page
            # first, so the disk is held full until it reports the failed write.
            wait(lambda: "No space left on device; bag closed" in cell["log"].read_text(),
                 what="the recorder closing the bag it cannot write", timeout=SCAN_TIMEOUT_S)
            assert client.scan.state == "waiting"     # while the disk is held full
        finally:
            release.set()
            keeper.join()
        filler.unlink()
        status = client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
        assert status.count("receipted") == len(PLAN)
        summary = client.reconstruct()
        stamps = _delivered_once(output, scan, summary)
        # The recorder closed the bag it could not write and recorded on in a new one.
        assert max(stamps) in _bag_stamps(output / "bags")
    log = (tmp_path / "cell.log").read_text()
    assert "the scan goes on" in log
    assert "ended by itself" not in log                 # no node died of the full disk
