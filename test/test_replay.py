"""``sfs-replay`` publishes a bag back onto its topics: same messages, same bytes, its pace.

The bag is written with :class:`BagWriter` under a namespace of its own
(``/recorded``) and played into the test run's namespace with
``--namespace``; a probe subscribes to the serialized bytes, as a node
re-running on the recording would receive them.
"""

import re
import subprocess
import sys

import numpy as np
import pytest
from sensor_msgs.msg import Image, JointState

from sfs_ros.cell_logic.bag import TOPICS, BagWriter
from sfs_ros.ros import capture_qos

from ros_harness import NAMESPACE, SOURCE_ROOT, RosProbe
from test_bag import image_bytes, joints_bytes, scan_bytes

N_VIEWS = 12
SPACING_NS = 100_000_000                                 # recorded 0.1 s apart
RATE = 4.0


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """A bag of N_VIEWS captures (64 x 48 rgb8 images and joint states) and a diagnostics
    message, recorded under /recorded; its [(relative topic, bytes)] in order."""
    folder = tmp_path_factory.mktemp("replay") / "bag"
    writer = BagWriter(folder)
    for name, (msgtype, kind) in TOPICS.items():
        writer.add_topic(f"/recorded/{name}", msgtype, kind=kind)
    rng = np.random.default_rng(5)
    messages = [("diagnostics", scan_bytes(1))]
    for n in range(N_VIEWS):
        stamp = (500 + n, 11 * n)
        messages += [("capture/image", image_bytes(rng.integers(0, 256, (48, 64, 3)), stamp,
                                                   "rgb8")),
                     ("capture/joint_state", joints_bytes(0.1 * n, 0.5, stamp))]
    for n, (name, data) in enumerate(messages):
        writer.write(f"/recorded/{name}", 1_700_000_000_000_000_000 + n * SPACING_NS, data)
    writer.close()
    return folder, messages


def _replay(*args, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sfs_ros.cli.replay", *map(str, args)],
                          capture_output=True, text=True, cwd=SOURCE_ROOT, timeout=timeout)


def test_replay_publishes_every_capture_with_its_bytes_at_the_chosen_rate(bag):
    folder, messages = bag
    probe = RosProbe("replay_probe")
    received = {"capture/image": [], "capture/joint_state": []}
    try:
        qos = capture_qos(100)
        probe.node.create_subscription(Image, "capture/image", received["capture/image"].append,
                                       qos, raw=True)
        probe.node.create_subscription(JointState, "capture/joint_state",
                                       received["capture/joint_state"].append, qos, raw=True)
        process = subprocess.Popen(
            [sys.executable, "-m", "sfs_ros.cli.replay", str(folder), "--rate", str(RATE),
             "--namespace", NAMESPACE, "--topics", "capture/image", "capture/joint_state",
             "--wait-s", "30"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            cwd=SOURCE_ROOT)
        probe.spin_until(lambda: all(len(v) >= N_VIEWS for v in received.values()),
                         timeout=120.0, what="the replayed captures")
        probe.spin_for(0.5)                                   # nothing more comes
        out, err = process.communicate(timeout=60)
    finally:
        probe.close()
    assert process.returncode == 0, err
    for name, got in received.items():
        assert got == [data for topic, data in messages if topic == name], name
    # The captures span (2 N - 1) spacings of the recording; at RATE x they take at least
    # that / RATE (a loaded machine can only be slower).
    seconds = float(re.search(r"published (\d+) messages on 2 topics in ([\d.]+) s", out)
                    .group(2))
    assert seconds >= 0.95 * (2 * N_VIEWS - 2) * SPACING_NS / 1e9 / RATE
    assert f"published {2 * N_VIEWS} messages" in out


def test_replay_refuses_bad_arguments_with_one_line(bag, tmp_path):
    folder, _ = bag
    for args, says in (((folder, "--topics", "capture/nothing"), "capture/nothing not in the bag"),
                       ((folder, "--rate", "0"), "--rate must be > 0"),
                       ((tmp_path / "none",), "does not exist")):
        done = _replay(*args, "--wait-s", "0")
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and says in lines[0], done.stderr
