"""A mock scan recorded by the recorder node, then replayed offline into the live mesh.

The mock cell is brought up as in test_cell.py (:mod:`mock_cell`: small
camera, fast axes, 64^3, a 17-view plan), the recorder among its nodes. The scan
runs through :class:`CellClient` while ``recorder/start`` .. ``recorder/stop``
records it; ``sfs-reconstruct BAG`` must then give the mesh the
carving node wrote: the bag holds the masks and joint states the node
carved and the parameters it ran with, and the offline reader feeds them to
the same code in the same order.
"""

import json
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.bag import PARAMETERS_TOPIC, TOPICS, open_bag
from sfs_ros.core.exchange.export import load_mesh
from sfs_ros.core.exchange.nerf import read_transforms
from sfs_ros.core.exchange.session import read_session
from sfs_ros.core.exchange.views import read_image
from sfs_ros.ros.names import SERVICES
from sfs_ros.ros.services import call

from mock_cell import NO_FAULT, RESOLUTION, SCAN_TIMEOUT_S, running_cell
from ros_harness import NAMESPACE, SOURCE_ROOT, RosProbe, wait

pytestmark = pytest.mark.cell

STORE = get_typestore(Stores.ROS2_KILTED)
CAPTURE_TOPICS = ("capture/image", "capture/joint_state", "capture/mask",
                  "capture/mask_joint_state", "capture/stored")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    with running_cell(tmp_path_factory.mktemp("recorded_cell"), "recorded_cell_client",
                      NO_FAULT) as up:
        probe = RosProbe("recorded_cell_probe")
        services = {n: probe.node.create_client(Trigger, SERVICES[f"record/{n}"]) for n in ("start", "stop")}
        threading.Thread(target=probe.executor.spin, daemon=True).start()
        try:
            yield {**up, "services": services}
        finally:
            probe.close()


def _record(cell, what: str) -> Trigger.Response:
    return call(cell["services"][what], Trigger.Request(), timeout_s=60.0)


@pytest.fixture(scope="module")
def recorded(cell):
    """One scan recorded from recorder/start to recorder/stop: the bag, the live summary, figures."""
    client = cell["client"]
    answer = _record(cell, "start")
    assert answer.success, answer.message
    bag_path = Path(json.loads(answer.message)["path"])
    assert bag_path.parent == (cell["output"] / "bags").resolve()
    started = time.monotonic()
    scan = client.start_scan()
    client.wait_scan_done(scan, timeout_s=SCAN_TIMEOUT_S)
    summary = client.reconstruct()
    scan_s = time.monotonic() - started
    # The mesh is published after reconstruct answers, and a capture the reconstruction
    # stored can still be on its way to the recorder (a reliable topic resends what a busy
    # reader missed, up to a heartbeat later). The open bag already reads (without its
    # summary) up to its last message: wait until the mesh and every view are in it.
    mcap = bag_path / f"{bag_path.name}.mcap"
    views = summary["views_used"]

    wanted = {f"{NAMESPACE}/mesh_shape": 1, **{f"{NAMESPACE}/{name}": views
                                                for name in CAPTURE_TOPICS}}
    counts = {}

    def complete() -> bool:
        counts.update(open_bag(mcap).counts)
        return all(counts.get(topic, 0) >= n for topic, n in wanted.items())

    try:
        wait(complete, what="the mesh and every view in the bag")
    except AssertionError as exc:     # say which topic fell short
        short = {t: f"{counts.get(t, 0)} of {n}" for t, n in wanted.items()
                 if counts.get(t, 0) < n}
        raise AssertionError(f"{exc}; short in the bag: {short}") from None
    answer = _record(cell, "stop")
    assert answer.success, answer.message
    stopped = json.loads(answer.message)
    return {"bag": bag_path, "summary": summary, "stop": stopped, "scan_s": scan_s}


def test_the_recorded_scan_replays_offline_into_the_live_mesh(recorded, tmp_path):
    out = tmp_path / "offline.ply"
    done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.reconstruct", str(recorded["bag"]),
                           "-o", str(out), "-q"], capture_output=True, text=True, cwd=SOURCE_ROOT,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    live_vertices, live_faces = load_mesh(recorded["summary"]["path"])
    vertices, faces = load_mesh(out)
    # Same views, cameras, box, grid and code: the same mesh. Both files are written by
    # export_mesh from float64 vertices; float32 storage leaves no more than its rounding
    # (7.5e-9 m at 0.1 m), far below a voxel (1.8 mm).
    np.testing.assert_array_equal(faces, live_faces)
    np.testing.assert_allclose(vertices, live_vertices, rtol=0, atol=1e-7)
    report = json.loads(out.with_name("offline.report.json").read_text())
    assert len(report["views"]["used"]) == recorded["summary"]["views_used"] == 17
    assert max(report["grid"]["shape"]) == RESOLUTION              # the recorded resolution
    size = sum(p.stat().st_size for p in recorded["bag"].iterdir())
    stop = recorded["stop"]
    print(f"\nbag {size / 1e6:.2f} MB, {stop['messages']} messages ({stop['bytes'] / 1e6:.2f} MB "
          f"of data), written in {stop['write_s']:.3f} s; scan + reconstruct "
          f"{recorded['scan_s']:.1f} s, recording {stop['seconds']:.1f} s")


def _records(data: bytes):
    """Top-level MCAP records ``(opcode, body)`` after the magic (the summary included)."""
    offset = 8
    while offset + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, offset)
        yield op, data[offset + 9:offset + 9 + length]
        offset += 9 + length


def _string(body: bytes, at: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", body, at)
    return body[at + 4:at + 4 + n].decode(), at + 4 + n


def test_the_bag_is_a_ros2_mcap_that_rosbags_opens(recorded):
    with Reader(recorded["bag"]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        types = {c.topic: c.msgtype for c in reader.connections}
        parameters = [data for c, _, data in reader.messages()
                      if c.topic == f"{NAMESPACE}/{PARAMETERS_TOPIC}"]
    for name in CAPTURE_TOPICS:
        assert counts[f"{NAMESPACE}/{name}"] >= 17, name           # resends may add some
    for name in ("joint_states", "diagnostics", "camera_info", "mesh", "mesh_shape", "hull"):
        assert counts[f"{NAMESPACE}/{name}"] >= 1, name
    assert all(types[f"{NAMESPACE}/{n}"] == t for n, (t, _) in TOPICS.items())
    assert len(parameters) == 1
    document = json.loads(STORE.deserialize_cdr(parameters[0], "std_msgs/msg/String").data)
    assert set(document["nodes"]) == {"carving", "meshing", "segmentation", "scan", "camera"}
    assert document["unavailable"] == {}
    assert document["reconstruction"]["resolution"] == RESOLUTION
    data = (recorded["bag"] / f"{recorded['bag'].name}.mcap").read_bytes()
    assert data[:8] == b"\x89MCAP0\r\n" and data[-8:] == b"\x89MCAP0\r\n"
    records = list(_records(data))
    assert records[0][0] == 0x01 and _string(records[0][1], 0)[0] == "ros2"   # header profile
    schemas = [r for op, r in records if op == 0x03]                  # summary section
    channels = [r for op, r in records if op == 0x04]
    assert len(schemas) == len(set(t for t, _ in TOPICS.values()))
    assert {_string(body, _string(body, 2)[1])[0] for body in schemas} == {"ros2msg"}
    assert len(channels) == len(TOPICS)
    assert {_string(body, _string(body, 4)[1])[0] for body in channels} == {"cdr"}


def test_the_bag_exports_its_captures_for_other_tools(recorded, tmp_path):
    out = tmp_path / "export"
    done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.export", str(recorded["bag"]),
                           "--session", str(out / "plain"), "--nerf",
                           str(out / "transforms.json")], capture_output=True, text=True,
                          cwd=SOURCE_ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    plain = read_session(out / "plain")
    assert len(plain.views) == 17
    # The captured images (the mug in colour on a white backdrop), not the 0/255 masks.
    image = read_image(plain.views[0].image_path)
    assert len(np.unique(image)) > 16 and np.any(image[..., 0] != image[..., 2])
    # Tagged with the encoder angles the carving node stored for the same captures.
    live = read_session(recorded["summary"]["session_dir"])
    assert sorted((v.theta_rad, v.phi_rad) for v in plain.views) == \
        sorted((v.theta_rad, v.phi_rad) for v in live.views)
    assert len(read_transforms(out / "transforms.json").views) == 17


def test_the_bag_replays_offline_into_a_coloured_mesh(recorded, tmp_path):
    out = tmp_path / "coloured.glb"
    done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.reconstruct", str(recorded["bag"]),
                           "-o", str(out), "--colour", "-q"], capture_output=True, text=True,
                          cwd=SOURCE_ROOT, timeout=600)
    assert done.returncode == 0, done.stderr
    vertices, faces, colours = load_mesh(out, with_colors=True)
    live_vertices, live_faces = load_mesh(recorded["summary"]["path"])
    np.testing.assert_array_equal(faces, live_faces)              # the live mesh, coloured
    assert colours is not None and len(np.unique(colours[:, :3], axis=0)) > 100
