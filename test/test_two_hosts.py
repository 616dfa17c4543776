"""The cell on two hosts: the meshing node and recorder on one, the rest on the other.

Two network namespaces joined by a veth pair (addresses that exist only inside
them) stand for two machines on one network: ``sfs-cell --mock --only
meshing,recorder --record`` runs in one, ``sfs-cell --mock --without
meshing,recorder`` (mock hardware, motor, camera, scan, segmentation, ...)
in the other, both in the same ROS domain and namespace, discovery over the
network (``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``: Fast DDS's multicast SPDP
over the veth). A program beside the meshing node scans and reconstructs
with :class:`CellClient`; every capture crosses the link (the veth's byte
counters show it). A third namespace, joined to neither, sees none of the
cell's nodes. Each half's files stay on its host's disk.

Needs root and ``ip netns`` (iproute2); skipped otherwise, saying which.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from sfs_ros.cell_logic.bag import PARAMETERS_TOPIC, open_bag
from sfs_ros.cell_logic.scan_plan import ScanPlan
from sfs_ros.cell_logic.scan_progress import PROGRESS_FILE
from sfs_ros.cli.bringup import NodeSpec, select_nodes
from sfs_ros.core.exchange.session import read_session

from mock_cell import OVERRIDES, write_config
from ros_harness import DOMAIN_ID, NAMESPACE, SOURCE_ROOT
from tolerances import CAPTURE_TOL_RAD
from waiting import wait

#: The meshing node's host runs these; the other host the rest of the cell (the carving
#: node's carved scan crosses to it).
FAR_NODES = "meshing,recorder"
RINGS_DEG, PER_RING = [25.0, 60.0], 4
PLAN = ScanPlan.from_rings(RINGS_DEG, PER_RING, True)                  # 9 views
#: Process start-up (rclpy, numpy, OpenCV, numba imports) on a loaded 2-core machine, a
#: scan, a reconstruction: deadlines that only bound a hang.
CELL_TIMEOUT_S = 600.0
STOP_TIMEOUT_S = 120.0
#: How long the unjoined namespace looks for the cell's nodes, s (discovery, when there
#: is a way, takes a second or two).
LOOK_S = 15.0
#: Nodes of the other half that a program beside the meshing node finds.
NEAR_NODES = ("motor", "scan", "segmentation")
CLIENT = Path(__file__).resolve().parent / "two_hosts_client.py"


def _netns_missing() -> str:
    """Why this machine cannot make network namespaces ("" if it can)."""
    if os.geteuid() != 0:
        return "not root: creating network namespaces (ip netns) needs root"
    if shutil.which("ip") is None:
        return "no ip command (iproute2): needed for ip netns"
    probe = f"sfs_probe_{os.getpid()}"
    done = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True,
                          timeout=30)
    if done.returncode != 0:
        return f"ip netns unavailable: ip netns add: {done.stderr.strip()}"
    _ip("netns", "del", probe)
    return ""


def _ip(*args: str, netns: str | None = None) -> str:
    """Run ``ip ARGS`` (in ``netns``); its output, AssertionError with its error."""
    command = ["ip"] + (["-n", netns] if netns else []) + list(args)
    done = subprocess.run(command, capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, f"{' '.join(command)}: {done.stderr.strip()}"
    return done.stdout


def _netns_names() -> set[str]:
    """The network namespaces there are (``ip netns list``: a name first on each line)."""
    return {line.split()[0] for line in _ip("netns", "list").splitlines() if line.strip()}


def _stop_processes_in(netns: str) -> None:
    """SIGINT, then SIGKILL after 30 s, to each process still in ``netns`` (this test's)."""
    for sig in (signal.SIGINT, signal.SIGKILL):
        pids = [int(p) for p in _ip("netns", "pids", netns).split()]
        for pid in pids:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + 30.0
        while pids and time.monotonic() < deadline and _ip("netns", "pids", netns).split():
            time.sleep(0.2)


@contextmanager
def network_namespaces():
    """``{"near": ..., "far": ..., "alone": ...}``: the names of three network namespaces,
    ``near`` (10.213.0.1/24) and ``far`` (10.213.0.2/24) joined by a veth pair that is up,
    ``alone`` joined to nothing; each with its loopback up. Deleted on exit (any process
    left in them stopped first), checked gone."""
    reason = _netns_missing()
    if reason:
        pytest.skip(reason)
    pid = os.getpid()
    names = {role: f"sfs_{role}_{pid}" for role in ("near", "far", "alone")}
    made = []
    try:
        for netns in names.values():
            _ip("netns", "add", netns)
            made.append(netns)
            _ip("link", "set", "lo", "up", netns=netns)
        near, far = f"sfsn{pid}", f"sfsf{pid}"
        _ip("link", "add", near, "type", "veth", "peer", "name", far, "netns", names["far"],
            netns=names["near"])
        for role, device, address in (("near", near, "10.213.0.1/24"),
                                      ("far", far, "10.213.0.2/24")):
            _ip("addr", "add", address, "dev", device, netns=names[role])
            _ip("link", "set", device, "up", netns=names[role])
        # Fast DDS takes the interfaces that are up when a participant is made.
        wait(lambda: all(_operstate(names[r], d) == "UP" for r, d in (("near", near),
                                                                      ("far", far))),
             what="the veth pair up", timeout=60.0)
        yield {**names, "devices": {"near": near, "far": far}}
    finally:
        for netns in made:
            _stop_processes_in(netns)
            _ip("netns", "del", netns)
        left = _netns_names() & set(names.values())
        assert not left, f"network namespaces left: {left}"


def _operstate(netns: str, device: str) -> str:
    return json.loads(_ip("-j", "link", "show", device, netns=netns))[0]["operstate"]


def _received_bytes(netns: str, device: str) -> int:
    return json.loads(_ip("-j", "-s", "link", "show", device, netns=netns))[0]["stats64"][
        "rx"]["bytes"]


def _environment() -> dict:
    """The node processes' environment: this test run's domain, discovery over the network,
    UDP only (no shared memory between the hosts), the ``sfs_ros`` the tests import."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET",
               FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1",
               PYTHONPATH=os.pathsep.join(filter(None, [str(SOURCE_ROOT),
                                                        os.environ.get("PYTHONPATH")])))
    env.pop("ROS_STATIC_PEERS", None)
    return env


class Half:
    """``sfs-cell --mock`` in network namespace ``netns`` with ``part`` (``--only ...`` or
    ``--without ...``), its output in ``root/sfs-cell.log``, its files in ``root/out``."""

    def __init__(self, netns: str, root: Path, config: Path, part: list[str]):
        root.mkdir()
        self.output_dir = root / "out"
        self.log = root / "sfs-cell.log"
        with self.log.open("wb") as log:
            self.process = subprocess.Popen(
                ["ip", "netns", "exec", netns, sys.executable, "-m", "sfs_ros.cli.cell", "--mock",
                 "-o", str(self.output_dir), "--config", str(config), "--namespace", NAMESPACE,
                 *part], stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                env=_environment(), cwd=root)

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def stop(self) -> int:
        """SIGINT (``ip netns exec`` runs sfs-cell in its own process); its exit status."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"sfs-cell still running {STOP_TIMEOUT_S:.0f} s after SIGINT:"
                                 f"\n{self.output()[-5000:]}") from None


def _program(netns: str, root: Path, *args: str) -> tuple[subprocess.Popen, Path]:
    """``two_hosts_client.py ARGS`` in ``netns``; the process and its output file."""
    out = root / f"client_{args[0]}_{netns}.out"
    with out.open("wb") as file:
        process = subprocess.Popen(["ip", "netns", "exec", netns, sys.executable, str(CLIENT),
                                    *args], stdin=subprocess.DEVNULL, stdout=file,
                                   stderr=subprocess.STDOUT, env=_environment(), cwd=root)
    return process, out


def _documents(out: Path) -> list[dict]:
    """The JSON lines a client program printed so far."""
    return [json.loads(line) for line in out.read_text(errors="replace").splitlines()
            if line.startswith("{")]


def _capture_stamps(bag_path: Path) -> list[tuple[int, int]]:
    """The stamps of the captures' joint states in a bag (one a message, resends too)."""
    bag = open_bag(bag_path)
    topic = bag.topic("capture/joint_state")
    if topic is None:
        return []
    stamps = []
    for message in bag.messages([topic]):
        stamp = deserialize_message(message.data, JointState).header.stamp
        stamps.append((stamp.sec, stamp.nanosec))
    return stamps


def _scan_bag(output_dir: Path) -> Path | None:
    """The MCAP file of the recorder's bag of scan 1 in ``output_dir`` (None before it)."""
    found = sorted((output_dir / "bags").glob("scan_001_*/*.mcap"))
    return found[0] if found else None


@pytest.fixture(scope="module")
def two_hosts(tmp_path_factory):
    """The scan and reconstruction made by a client beside the meshing node, the other
    half of the cell on the other side of the link; the cells stopped (each exit 0) and the
    namespaces deleted before the checks."""
    root = tmp_path_factory.mktemp("two_hosts")
    config = write_config(root / "config", plan={"rings": {"phi_deg": RINGS_DEG,
                                                           "per_ring": PER_RING,
                                                           "top_view": True}})
    started = time.monotonic()
    with network_namespaces() as netns:
        far_before = _received_bytes(netns["far"], netns["devices"]["far"])
        far = Half(netns["far"], root / "far", config, ["--only", FAR_NODES, "--record"])
        near = Half(netns["near"], root / "near", config, ["--without", FAR_NODES])
        halves = {"far": far, "near": near}
        try:
            client, client_out = _program(netns["far"], root, "scan", NAMESPACE)

            def client_says(key: str):
                def said() -> bool:
                    ended = {n: h.process.returncode for n, h in halves.items()
                             if h.process.poll() is not None}
                    assert not ended, f"sfs-cell ended: {ended}"
                    return client.poll() is not None or any(
                        key in d for d in _documents(client_out))
                return said

            wait(client_says("ready"), what="the cell ready for the client",
                 timeout=CELL_TIMEOUT_S, interval_s=0.5)
            lookers = {"alone": _program(netns["alone"], root, "look", NAMESPACE, str(LOOK_S)),
                       "far": _program(netns["far"], root, "look", NAMESPACE,
                                       str(CELL_TIMEOUT_S), ",".join(NEAR_NODES))}
            wait(client_says("summary"), what="the scan and its reconstruction",
                 timeout=CELL_TIMEOUT_S, interval_s=0.5)
            assert client.wait(timeout=STOP_TIMEOUT_S) == 0, client_out.read_text()[-5000:]
            result = _documents(client_out)[-1]
            progress = json.loads((near.output_dir / "scan_progress" / PROGRESS_FILE)
                                  .read_text())
            stamps = {tuple(c["stamp"]) for c in progress["captures"]}
            wait(lambda: _scan_bag(far.output_dir) is not None
                 and stamps <= set(_capture_stamps(_scan_bag(far.output_dir))),
                 what="every capture in the recorder's bag", timeout=CELL_TIMEOUT_S)
            for looker, look_out in lookers.values():
                assert looker.wait(timeout=STOP_TIMEOUT_S) == 0, look_out.read_text()
            received = _received_bytes(netns["far"], netns["devices"]["far"]) - far_before
            near_files = sorted(p.name for p in near.output_dir.iterdir())
            codes = {name: half.stop() for name, half in (("near", near), ("far", far))}
        except BaseException:
            for name, half in halves.items():
                print(f"--- {name} half:\n{half.output()[-8000:]}")
            raise
        finally:               # after a failure: the namespaces' deletion stops the rest
            for half in halves.values():
                if half.process.poll() is None:
                    half.process.send_signal(signal.SIGINT)
    assert codes == {"near": 0, "far": 0}, {n: h.output()[-5000:] for n, h in halves.items()}
    print(f"\ntwo hosts: {len(PLAN)} views scanned and reconstructed across the link in "
          f"{time.monotonic() - started:.0f} s (namespaces made and deleted)")
    return {**result, "progress": progress, "received": received, "near_files": near_files,
            "look": {role: _documents(out)[-1]["nodes"] for role, (_, out) in lookers.items()},
            "halves": halves,
            "logs": {n: h.output() for n, h in halves.items()}}


def _plan_view(theta: float, phi: float) -> int:
    """The plan view at these encoder angles (asserting they are within a capture's
    tolerance of it)."""
    error = np.abs(PLAN.views - np.array([theta, phi]))
    best = int(np.argmin(error.max(axis=1)))
    assert np.all(error[best] <= CAPTURE_TOL_RAD), f"({theta}, {phi}) is no planned view"
    return best


@pytest.mark.cell
def test_every_view_crosses_the_link_and_is_stored_once(two_hosts):
    status, summary = two_hosts["status"], two_hosts["summary"]
    assert status["state"] == "done"
    assert int(status["total"]) == int(status["receipted"]) == len(PLAN)
    captures = two_hosts["progress"]["captures"]
    assert sorted(c["view"] for c in captures) == list(range(len(PLAN)))
    assert all(c["receipted"] for c in captures)
    session = read_session(summary["session_dir"])
    assert sorted(_plan_view(v.theta_rad, v.phi_rad) for v in session.views) == \
        list(range(len(PLAN)))                                  # each view once, none twice
    table = Path(summary["session_dir"]) / "views.csv"
    assert len(table.read_text().strip().splitlines()) == len(PLAN) + 1        # + header
    # Every captured image (for colour and the bag) and its mask came over the veth.
    rig = OVERRIDES["rig.yaml"]
    assert two_hosts["received"] > len(PLAN) * rig["width"] * rig["height"] * (3 + 1)


@pytest.mark.cell
def test_the_mesh_is_made_on_the_meshing_nodes_host(two_hosts):
    summary = two_hosts["summary"]
    far = two_hosts["halves"]["far"].output_dir.resolve()
    mesh = Path(summary["path"])
    assert mesh.is_file() and mesh.stat().st_size > 0
    assert summary["views_used"] == len(PLAN) and summary["n_faces"] > 0
    for key in ("path", "report_path", "preview_path"):
        assert Path(summary[key]).resolve().is_relative_to(far), key
    # The scan node's host keeps the scan's progress, the mock's port and the carving
    # node's session folder, no mesh.
    session = Path(summary["session_dir"])
    near = two_hosts["halves"]["near"].output_dir.resolve()
    assert session.resolve().is_relative_to(near)
    assert set(two_hosts["near_files"]) <= {"scan_progress", "ttyMOCK", session.name}
    assert not (far / "scan_progress").exists() and not (far / session.name).exists()


@pytest.mark.cell
def test_the_recorder_beside_the_meshing_node_holds_every_capture(two_hosts):
    far = two_hosts["halves"]["far"].output_dir
    bag = _scan_bag(far)
    stamps = _capture_stamps(bag.parent)                 # the closed bag
    wanted = {tuple(c["stamp"]) for c in two_hosts["progress"]["captures"]}
    assert len(wanted) == len(PLAN) and set(stamps) == wanted
    # The parameters of the nodes on the other host, asked through their services.
    bag_read = open_bag(bag.parent)
    [message] = bag_read.messages([bag_read.topic(PARAMETERS_TOPIC)])
    document = json.loads(deserialize_message(message.data, String).data)
    assert {"scan", "segmentation", "camera"} <= set(document["nodes"])
    assert document["unavailable"] == {}


@pytest.mark.cell
def test_a_host_not_joined_sees_none_of_the_cell(two_hosts):
    # The same program beside the meshing node sees the other host's nodes.
    assert set(NEAR_NODES) <= set(two_hosts["look"]["far"])
    assert two_hosts["look"]["alone"] == []


@pytest.mark.cell
def test_each_half_says_what_it_expects_elsewhere(two_hosts):
    logs = two_hosts["logs"]
    assert f"expecting {FAR_NODES.replace(',', ', ')} on another host" in logs["near"]
    assert "expecting mock_hardware, motor" in logs["far"]
    for log in logs.values():
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in log          # SUBNET: no warning


# -- choosing the part of the cell a host runs ------------------------------------------


def _specs(names: list[str]) -> list[NodeSpec]:
    return [NodeSpec(name, f"{name}_node", []) for name in names]


CELL = ["mock_hardware", "motor", "segmentation", "carving", "meshing", "recorder", "scan"]


@pytest.mark.parametrize("only, without, started", [
    (["recorder", "meshing"], [], ["meshing", "recorder"]),
    ([], ["meshing", "recorder"], ["mock_hardware", "motor", "segmentation", "carving", "scan"]),
    ([], [], CELL),
])
def test_select_nodes_keeps_the_cells_order(only, without, started):
    chosen = select_nodes(_specs(CELL), only=only, without=without)
    assert [s.name for s in chosen] == started


@pytest.mark.parametrize("only, without, error", [
    (["meshnig"], [], "no node meshnig in this cell; its nodes are "
                      "mock_hardware, motor, segmentation, carving, meshing, recorder, scan"),
    (["scan"], ["motor"], "one or the other"),
    ([], CELL, "no node left to start"),
    (["motor", "scan"], [], "mock_hardware and motor run on the same host"),
    ([], ["mock_hardware"], "mock_hardware and motor run on the same host"),
])
def test_select_nodes_refuses_a_selection_that_cannot_run(only, without, error):
    with pytest.raises(ValueError, match=error):
        select_nodes(_specs(CELL), only=only, without=without)


def test_sfs_cell_names_the_valid_nodes_for_an_unknown_one(tmp_path):
    done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.cell", "--mock", "-o",
                           str(tmp_path / "out"), "--only", "meshing,recoder"],
                          capture_output=True, text=True, env=_environment(), cwd=tmp_path,
                          timeout=120)
    assert done.returncode == 2
    [line] = done.stderr.strip().splitlines()
    assert line.startswith("sfs-cell: error: no node recoder in this cell; its nodes are ")
    assert "meshing, recorder" in line
