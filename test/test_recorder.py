"""The recorder node as a separate OS process: starting, stopping, and what survives a crash.

A carving node runs beside it (the recorder stores its parameters,
and the offline reader needs them to place the cameras); the probe publishes
exact sphere silhouettes with their joint states as the segmentation node
would. A bag closed by SIGINT, SIGTERM or ``recorder/stop`` opens with rosbags; a bag
whose recorder was killed outright (SIGKILL) reads up to its last whole
message, and every view in it is one the probe sent, in order, with no gap.
"""

import json
import logging
import signal
import sqlite3
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.bag import open_bag, read_bag
from sfs_ros.core.exchange.views import ViewError
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import image_to_msg, joint_state
from sfs_ros.ros.names import DIAGNOSTICS, SERVICES

from analytic_masks import sphere_mask
from conftest import TEST_RIG
from ros_harness import NAMESPACE, NodeProcess, NodeUnderTest, RosProbe

RECORDER = "sfs_ros.nodes.recorder_node"
PLAN = ring_plan([20.0, 55.0], 8, top_view=True)                 # 17 views
RESEND_S = 5.0          # no answer to a first call this long: the request goes again
BOUNDS = [-0.05, -0.05, 0.0, 0.05, 0.05, 0.09]
MASKS = f"{NAMESPACE}/capture/mask"
JOINTS = f"{NAMESPACE}/capture/mask_joint_state"
#: Seconds for a message to cross from the probe to the recorder and into the bag on a
#: loaded 2-core machine (typically milliseconds).
DELIVERY_S = 30.0
STORE = get_typestore(Stores.ROS2_KILTED)


@pytest.fixture(scope="module")
def views():
    """(stamp, mask (H, W) bool, theta_rad, phi_rad) of each view of PLAN."""
    return [((300 + n, 7 * n), sphere_mask(rig_camera(theta, phi, TEST_RIG), (0.0, 0.0, 0.04),
                                            0.03), theta, phi)
            for n, (theta, phi) in enumerate(PLAN)]


@pytest.fixture(scope="module")
def probe(tmp_path_factory, start_node_for_module):
    """The probe, with a carving node running (whose parameters every bag stores)."""
    params = {"projection": TEST_RIG.projection, "width": TEST_RIG.width,
              "height": TEST_RIG.height, "fx": TEST_RIG.fx, "fy": TEST_RIG.fy,
              "camera_distance_m": TEST_RIG.camera_distance_m,
              "aim_point_m": list(TEST_RIG.aim_point_m), "bounds_m": BOUNDS, "resolution": 40,
              "output_dir": str(tmp_path_factory.mktemp("carving")), "hull_rate_hz": 0.0}
    path = tmp_path_factory.mktemp("params") / "carving.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    reconstruction = start_node_for_module(NodeUnderTest, "sfs_ros.nodes.carving_node",
                                           params_file=path, probe_name="recorder_probe")
    probe = reconstruction.probe
    qos = capture_qos(100)
    probe.masks = probe.node.create_publisher(Image, "capture/mask", qos)
    probe.joints = probe.node.create_publisher(JointState, "capture/mask_joint_state", qos)
    probe.diagnostics = probe.node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
    probe.wait_connected([probe.masks, probe.joints], process=reconstruction.process)
    return probe


class Recorder:
    """A recorder node process and the probe's clients of its services."""

    def __init__(self, probe: RosProbe, output_dir, **parameters):
        self.probe = probe
        self.output_dir = output_dir
        self.process = NodeProcess(RECORDER, parameters={
            "output_dir": str(output_dir), "parameter_nodes": ["carving"],
            "parameter_timeout_s": 10.0, **parameters})
        self.clients = {n: probe.node.create_client(Trigger, SERVICES[f"record/{n}"])
                        for n in ("start", "stop")}
        # up when its services answer and it has matched both capture topics (the
        # reconstruction node is the other subscriber)
        probe.spin_until(lambda: all(c.service_is_ready() for c in self.clients.values())
                         and probe.masks.get_subscription_count() >= 2
                         and probe.joints.get_subscription_count() >= 2,
                         what="the recorder", process=self.process)
        # Fast DDS drops a response while the server has not matched a just-made client's
        # reply reader (a refused stop's answer was lost so in one CI run): a stop, refused
        # by a recorder not recording yet, goes until it is answered, and then the stop
        # client's answers reach it. The start client's first call resends (start()).
        refused = probe.call_resending(self.clients["stop"], Trigger.Request(),
                                       resend_after_s=RESEND_S, attempts=3, process=self.process)
        assert not refused.success, refused.message

    def call(self, what: str) -> Trigger.Response:
        future = self.clients[what].call_async(Trigger.Request())
        self.probe.spin_until(future.done, what=f"record/{what} answer", process=self.process)
        return future.result()

    def start(self) -> str:
        """Start recording; the bag's path. The request goes again after ``RESEND_S``
        without an answer (``RosProbe.call_resending``): this fresh recorder then answers
        that it records to the bag the first request opened."""
        answer = self.probe.call_resending(self.clients["start"], Trigger.Request(),
                                           resend_after_s=RESEND_S, attempts=3,
                                           process=self.process)
        if answer.success:
            return json.loads(answer.message)["path"]
        recording_to = "already recording to "
        assert answer.message.startswith(recording_to), answer.message
        return answer.message.removeprefix(recording_to).split(";")[0]

    def close(self) -> None:
        for client in self.clients.values():
            self.probe.node.destroy_client(client)
        self.process.cleanup()


@pytest.fixture()
def recorder_factory(probe, tmp_path):
    made = []

    def make(**parameters) -> Recorder:
        made.append(Recorder(probe, tmp_path / f"out_{len(made)}", **parameters))
        return made[-1]

    yield make
    for recorder in made:
        recorder.close()


def publish(probe: RosProbe, views) -> None:
    for stamp, mask, theta, phi in views:
        probe.masks.publish(image_to_msg(mask, stamp=stamp, frame_id="camera_optical"))
        probe.joints.publish(joint_state(theta, phi, stamp=stamp))


def wait_views_in_bag(probe: RosProbe, folder, n: int) -> None:
    """Spin until the bag being written holds ``n`` masks and joint states, and the
    parameters (it reads while open): a recorder that stops cannot write what it has not
    received yet."""
    def written() -> int:
        try:
            counts = open_bag(folder).counts
        except ViewError:                                     # created, nothing flushed yet
            return 0
        if not counts.get(f"{NAMESPACE}/sfs/parameters"):
            return 0
        return min(counts.get(MASKS, 0), counts.get(JOINTS, 0))

    logging.getLogger("sfs_ros.cell_logic.bag").setLevel(logging.ERROR)   # "not closed", known
    try:
        probe.spin_until(lambda: written() >= n, timeout=DELIVERY_S,
                         what=f"{n} views in the bag")
    finally:
        logging.getLogger("sfs_ros.cell_logic.bag").setLevel(logging.NOTSET)


def _values_of(diagnostics: list, path) -> dict:
    """The values of the last recorder status received that reports the bag at ``path``."""
    for array in reversed(diagnostics):
        for status in array.status:
            values = {kv.key: kv.value for kv in status.values}
            if values.get("path") == str(path):
                return values
    return {}


def _stamps(view_set) -> list[tuple[int, int]]:
    return [tuple(int(x) for x in v.name.removesuffix(".png").split("_")[-2:])
            for v in view_set.views]


@pytest.mark.parametrize("stop_signal", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_closes_the_bag_with_every_view_and_the_parameters(
        recorder_factory, probe, views, stop_signal):
    recorder = recorder_factory()
    path = recorder.start()
    publish(probe, views)
    wait_views_in_bag(probe, path, len(views))
    recorder.process.process.send_signal(stop_signal)     # Ctrl-C; a service manager's stop
    assert recorder.process.wait_exit() == 0
    assert "Traceback" not in recorder.process.output()
    assert (recorder.output_dir / "bags").is_dir()
    with Reader(path) as reader:                              # closed: metadata.yaml written
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts[MASKS] == counts[JOINTS] == len(views)
    assert counts[f"{NAMESPACE}/sfs/parameters"] == 1
    view_set = read_bag(path)
    assert _stamps(view_set) == [stamp for stamp, *_ in views]
    assert view_set.calibration == TEST_RIG
    assert [(v.theta_rad, v.phi_rad) for v in view_set.views] == [(t, p) for _, _, t, p in views]



def test_a_stop_while_a_node_does_not_answer_for_the_parameters_closes_the_bag_at_once(
        recorder_factory, probe, views):
    """A node of ``parameter_nodes`` that never answers (one restarting, or gone) holds the
    parameters' fetch until its deadline; a stop meanwhile gives it up: the recorder ends
    cleanly long before that deadline (a cell's stop waits 10 s before SIGTERM), the bag
    closed with every view and the parameters that came."""
    deadline_s = 300.0
    recorder = recorder_factory(parameter_nodes=["carving", "no_such_node"],
                                parameter_timeout_s=deadline_s)
    diagnostics: list = []
    probe.node.create_subscription(DiagnosticArray, DIAGNOSTICS, diagnostics.append, 10)
    path = recorder.start()
    publish(probe, views)

    def views_written() -> int:
        try:
            counts = open_bag(path).counts
        except ViewError:                                     # created, nothing flushed yet
            return 0
        return min(counts.get(MASKS, 0), counts.get(JOINTS, 0))
    logging.getLogger("sfs_ros.cell_logic.bag").setLevel(logging.ERROR)   # "not closed", known
    try:
        probe.spin_until(lambda: views_written() >= len(views), timeout=DELIVERY_S,
                         what="the views (masks and joint states) in the bag")
    finally:
        logging.getLogger("sfs_ros.cell_logic.bag").setLevel(logging.NOTSET)
    probe.spin_until(lambda: "carving" in _values_of(diagnostics, path).get("parameters_from", ""),
                     timeout=DELIVERY_S, what="the carving node's parameters at the recorder",
                     process=recorder.process)
    recorder.process.process.send_signal(signal.SIGINT)
    assert recorder.process.wait_exit(timeout=deadline_s / 2) == 0
    output = recorder.process.output()
    assert "Traceback" not in output and "no_such_node" in output, output
    with Reader(path) as reader:                              # closed: metadata.yaml written
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts[MASKS] == len(views) and counts[f"{NAMESPACE}/sfs/parameters"] == 1
    assert read_bag(path).calibration == TEST_RIG             # the carving node's came


def test_sqlite3_storage_on_request(recorder_factory, probe, views):
    recorder = recorder_factory(storage="sqlite3")
    path = recorder.start()
    database = Path(path) / f"{Path(path).name}.db3"
    publish(probe, views)

    def written(topic: str) -> int:      # sqlite3 reads beside its writer (the bag's commits)
        with sqlite3.connect(f"file:{database}?mode=ro", uri=True, timeout=10.0) as db:
            return db.execute("SELECT COUNT(*) FROM messages JOIN topics ON topic_id = topics.id "
                              "WHERE topics.name = ?", (topic,)).fetchone()[0]

    probe.spin_until(lambda: min(written(MASKS), written(JOINTS)) >= len(views),
                     timeout=DELIVERY_S, what="every view in the database")
    answer = recorder.call("stop")
    assert answer.success and json.loads(answer.message)["path"] == path
    with Reader(path) as reader:
        assert {c.topic: c.msgcount for c in reader.connections}[MASKS] == len(views)
    assert len(read_bag(path).views) == len(views)


def test_start_twice_and_stop_without_recording_are_refused(recorder_factory):
    recorder = recorder_factory(bag_name="mine")
    refused = recorder.call("stop")
    assert not refused.success and refused.message == "not recording: call recorder/start first"
    path = recorder.start()
    assert path.endswith("/bags/mine")
    again = recorder.call("start")
    assert not again.success and again.message == f"already recording to {path}; call " \
                                                  "recorder/stop first"
    assert recorder.call("stop").success
    taken = recorder.call("start")                            # bag_name is taken now
    assert not taken.success and "exists" in taken.message and "bag_name" in taken.message


def _scan_starting(scan: int) -> DiagnosticArray:
    status = DiagnosticStatus(level=DiagnosticStatus.OK, name=f"{NAMESPACE}/scan: scan",
                              message="starting", values=[KeyValue(key="scan", value=str(scan)),
                                                          KeyValue(key="state",
                                                                   value="starting")])
    return DiagnosticArray(status=[status])


def test_with_scan_a_bag_opens_at_each_new_scan(recorder_factory, probe, views):
    recorder = recorder_factory(with_scan=True)
    bags = recorder.output_dir / "bags"
    probe.spin_until(lambda: probe.diagnostics.get_subscription_count() >= 1,
                     what="the recorder's diagnostics subscription")
    for scan, part in ((1, views[:5]), (2, views[5:])):
        for _ in range(3):                                    # "starting" comes at 1 Hz
            probe.diagnostics.publish(_scan_starting(scan))
        probe.spin_until(lambda: len(list(bags.glob(f"scan_{scan:03d}_*"))) == 1,
                         what=f"the bag of scan {scan}", process=recorder.process)
        publish(probe, part)
        wait_views_in_bag(probe, next(bags.glob(f"scan_{scan:03d}_*")), len(part))
    first = next(bags.glob("scan_001_*"))
    assert (first / "metadata.yaml").is_file()                # closed when scan 2 started
    assert len(read_bag(first).views) == 5
    assert recorder.call("stop").success
    assert len(read_bag(next(bags.glob("scan_002_*"))).views) == len(views) - 5
    # Each bag names its scan once, as data: the number, when first reported in the bag.
    for scan in (1, 2):
        bag = open_bag(next(bags.glob(f"scan_{scan:03d}_*")))
        records = list(bag.messages([bag.topic("sfs/scan")]))
        assert [STORE.deserialize_cdr(m.data, m.msgtype).data for m in records] == [scan]


def test_missing_output_dir_exits_with_one_line():
    process = NodeProcess(RECORDER)
    code, lines = process.exit_lines()
    assert code == 2
    assert lines == ["sfs-recorder: invalid parameter 'output_dir': is required: the folder "
                     "for the bags"]


def test_the_bag_is_its_data_plus_a_small_index(recorder_factory, probe, views):
    """Bag size against the bytes recorded (figures printed with -s)."""
    recorder = recorder_factory()
    path = recorder.start()
    started = time.monotonic()
    publish(probe, views)
    wait_views_in_bag(probe, path, len(views))
    stopped = json.loads(recorder.call("stop").message)
    size = sum(p.stat().st_size for p in open_bag(path).path.iterdir())
    print(f"\n{stopped['messages']} messages, {stopped['bytes'] / 1e6:.2f} MB of data, bag "
          f"{size / 1e6:.2f} MB, {time.monotonic() - started:.2f} s from first publish")
    assert size < 1.05 * stopped["bytes"] + 200_000          # index and schemas: small


def test_a_killed_recorder_leaves_every_whole_message(recorder_factory, probe, views,
                                                      monkeypatch, caplog):
    # UDP only: a process killed outright leaves no Fast DDS shared memory behind
    monkeypatch.setenv("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")
    recorder = recorder_factory()
    path = recorder.start()
    publish(probe, views[:8])
    wait_views_in_bag(probe, path, 8)
    publish(probe, views[8:])                                 # still arriving when killed
    recorder.process.process.kill()
    assert recorder.process.wait_exit() == -9
    with caplog.at_level(logging.WARNING):
        bag = open_bag(path)
    assert not (bag.storage_file.parent / "metadata.yaml").exists()
    assert "was not closed (recorder killed?)" in caplog.text and bag.problem
    masks = list(bag.messages([MASKS]))
    assert len(masks) >= 8
    view_set = read_bag(path)
    stamps = _stamps(view_set)
    # the views read are the first ones sent, without a gap (a mask whose joint state did
    # not make it is a rejected view, not a missing one)
    assert stamps == [stamp for stamp, *_ in views][:len(stamps)] and len(stamps) >= 8
    assert len(stamps) + len(view_set.rejected) == len(masks)
    sent = {stamp: mask for stamp, mask, *_ in views}
    for message in masks:                                     # each whole, as sent
        msg = STORE.deserialize_cdr(message.data, "sensor_msgs/msg/Image")
        mask = sent[(msg.header.stamp.sec, msg.header.stamp.nanosec)]
        np.testing.assert_array_equal(msg.data.reshape(mask.shape), mask * np.uint8(255))
    # Discovery forgets the killed process only when its lease runs out (Fast DDS: 20 s);
    # until then its services look ready. Wait, so that no later test calls a ghost.
    probe.spin_until(lambda: not recorder.clients["start"].service_is_ready(), timeout=90.0,
                     what="discovery to forget the killed recorder")
