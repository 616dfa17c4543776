"""Bags written with :class:`BagWriter` and read back as views (no ROS: rosbags serializes).

A bag of exact sphere silhouettes must give the views a reconstruction node
would have stored (its :class:`LiveReconstruction` fed the same masks), and
so the very same mesh; a bag of captures, the mesh of a session of the same
images segmented with the recorded parameters. Faults: a file cut at any
byte keeps the whole views before the cut, with a warning; what cannot be
read is one line naming what is wrong and what was expected.
"""

import json
import logging
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from sfs_ros.cell_logic.bag import (
    PARAMETERS_TOPIC,
    SCAN_TOPIC,
    TOPICS,
    BagWriter,
    bag_folder,
    open_bag,
    parameters_message,
    read_bag,
    scan_message,
)
from sfs_ros.cell_logic.live_reconstruction import LiveReconstruction
from sfs_ros.cli.common import load_input
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.exchange.views import ViewError
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.segmentation.segment import SegmentationParams
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box

from analytic_masks import sphere_mask
from conftest import TEST_RIG
from ros_harness import SOURCE_ROOT

STORE = get_typestore(Stores.ROS2_KILTED)
T = STORE.types
NS = "/cell"
PLAN = ring_plan([20.0, 55.0], 8, top_view=True)                 # 17 views
SPHERE_CENTRE, SPHERE_RADIUS = (0.0, 0.0, 0.04), 0.03
BOUNDS = [[-0.05, -0.05, 0.0], [0.05, 0.05, 0.09]]
RESOLUTION = 40


def _cdr(msg, msgtype: str) -> bytes:
    return bytes(STORE.serialize_cdr(msg, msgtype))


def _header(stamp):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=stamp[0],
                                                                          nanosec=stamp[1]),
                                    frame_id="camera_optical")


def image_bytes(array: np.ndarray, stamp, encoding: str) -> bytes:
    array = np.ascontiguousarray(array, dtype=np.uint8)
    h, w = array.shape[:2]
    msg = T["sensor_msgs/msg/Image"](header=_header(stamp), height=h, width=w, encoding=encoding,
                                     is_bigendian=0, step=array[0].size, data=array.reshape(-1))
    return _cdr(msg, "sensor_msgs/msg/Image")


def joints_bytes(theta: float, phi: float, stamp) -> bytes:
    msg = T["sensor_msgs/msg/JointState"](header=_header(stamp), name=["turntable", "carriage"],
                                          position=np.array([theta, phi]), velocity=np.zeros(0),
                                          effort=np.zeros(0))
    return _cdr(msg, "sensor_msgs/msg/JointState")


def scan_bytes(scan: int) -> bytes:
    values = [T["diagnostic_msgs/msg/KeyValue"](key=k, value=v)
              for k, v in (("scan", str(scan)), ("state", "starting"))]
    status = T["diagnostic_msgs/msg/DiagnosticStatus"](level=0, name="/cell/scan: scan",
                                                       message="", hardware_id="",
                                                       values=values)
    msg = T["diagnostic_msgs/msg/DiagnosticArray"](header=_header((0, 0)), status=[status])
    return _cdr(msg, "diagnostic_msgs/msg/DiagnosticArray")


def document(*, resolution=RESOLUTION, bounds=BOUNDS, segmentation=None) -> dict:
    return {"namespace": NS, "nodes": {"reconstruction": {"queue_depth": 100}},
            "unavailable": {},
            "session": {"rig": TEST_RIG.to_dict(), "bounds_m": bounds,
                        "segmentation": asdict(segmentation or SegmentationParams())},
            "reconstruction": {"resolution": resolution, "mesher": "marching-cubes"}}


def sphere_views() -> list[tuple[tuple[int, int], np.ndarray, float, float]]:
    """(stamp, mask (H, W) uint8 0/255, theta_rad, phi_rad) of each view of PLAN."""
    views = []
    for n, (theta, phi) in enumerate(PLAN):
        mask = sphere_mask(rig_camera(theta, phi, TEST_RIG), SPHERE_CENTRE, SPHERE_RADIUS)
        views.append(((100 + n, 1000 * n), mask.astype(np.uint8) * 255, theta, phi))
    return views


def write_bag(folder, messages, *, storage="mcap") -> list[int]:
    """Write ``[(relative topic, bytes)]`` (1 ms apart); the file size after each message."""
    bag = BagWriter(folder, storage=storage)
    for name, (msgtype, kind) in TOPICS.items():
        bag.add_topic(f"{NS}/{name}", msgtype, kind=kind)
    sizes = []
    for n, (name, data) in enumerate(messages):
        bag.write(f"{NS}/{name}", 1_700_000_000_000_000_000 + n * 1_000_000, data)
        sizes.append(bag.storage_file.stat().st_size)
    bag.close()
    return sizes


def mask_messages(views, *, images="capture/mask", joints="capture/mask_joint_state",
                  encoding="mono8"):
    out = []
    for stamp, image, theta, phi in views:
        out += [(images, image_bytes(image, stamp, encoding)),
                (joints, joints_bytes(theta, phi, stamp))]
    return out


def live_mesh(tmp_path, views):
    """The mesh of the session a reconstruction node's LiveReconstruction stores for ``views``."""
    live = LiveReconstruction(TEST_RIG, BOUNDS, output_dir=tmp_path / "live",
                              resolution=RESOLUTION)
    for stamp, mask, theta, phi in views:
        live.add_view(f"{stamp[0]}_{stamp[1]:09d}", mask, theta, phi)
    result = reconstruct(load_views(live.session_dir), ReconstructionParams(resolution=RESOLUTION))
    return result.vertices, result.faces


def bag_mesh(view_set):
    result = reconstruct(view_set, ReconstructionParams(resolution=view_set.resolution,
                                                        mesher=view_set.mesher))
    return result.vertices, result.faces


@pytest.fixture(scope="module")
def views():
    return sphere_views()


@pytest.fixture(scope="module")
def reference(tmp_path_factory, views):
    return live_mesh(tmp_path_factory.mktemp("reference"), views)


def _scan_bag(folder, views, *, storage="mcap"):
    messages = [(PARAMETERS_TOPIC, parameters_message(document())), *mask_messages(views)]
    return write_bag(folder, messages, storage=storage), messages


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_of_masks_gives_the_live_nodes_views_and_mesh(tmp_path, views, reference, storage):
    _scan_bag(tmp_path / "bag", views, storage=storage)
    view_set = read_bag(tmp_path / "bag")
    assert len(view_set.views) == len(views) and view_set.rejected == []
    assert view_set.calibration == TEST_RIG
    np.testing.assert_array_equal(view_set.bounds_m, BOUNDS)
    assert (view_set.resolution, view_set.mesher) == (RESOLUTION, "marching-cubes")
    assert [(v.theta_rad, v.phi_rad) for v in view_set.views] == [(t, p) for _, _, t, p in views]
    vertices, faces = bag_mesh(view_set)
    # The same masks, cameras, box and grid through the same code: the very same mesh.
    np.testing.assert_array_equal(faces, reference[1])
    np.testing.assert_array_equal(vertices, reference[0])
    # The command-line tools and the core's one door recognise the folder and the storage
    # file alike.
    ending = ".mcap" if storage == "mcap" else ".db3"
    for path in (tmp_path / "bag", tmp_path / "bag" / f"bag{ending}"):
        loaded, recorded = load_input(path)
        assert len(loaded.views) == len(views)
        assert recorded == {"resolution": RESOLUTION, "mesher": "marching-cubes"}
        assert [v.name for v in load_views(path).views] == [v.name for v in loaded.views]


def test_bag_of_captures_is_segmented_with_the_recorded_parameters(tmp_path, mug,
                                                                   mug_captures):
    captures = mug_captures[::3]                                  # 17 of the 49 views
    seg = SegmentationParams(threshold=0.2)
    box = carving_box(mug).tolist()
    session = write_session(tmp_path / "session", [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], TEST_RIG,
                            bounds_m=box, segmentation=seg)
    views = [((200 + n, 0), c.image, c.theta_rad, c.phi_rad) for n, c in enumerate(captures)]
    messages = [(PARAMETERS_TOPIC, parameters_message(document(bounds=box, segmentation=seg))),
                *mask_messages(views, images="capture/image", joints="capture/joint_state",
                               encoding="rgb8")]
    write_bag(tmp_path / "bag", messages)
    # The bag's captures are segmented view by view as they are read (as the live nodes
    # do), so the session is too: no re-segmentation with the hull as a prior.
    params = ReconstructionParams(resolution=RESOLUTION, consensus=False)
    expected = reconstruct(load_views(session), params)
    got = reconstruct(read_bag(tmp_path / "bag"), params)
    np.testing.assert_array_equal(got.faces, expected.faces)
    np.testing.assert_array_equal(got.vertices, expected.vertices)


def test_a_capture_sent_again_is_stored_once(tmp_path, views, reference):
    messages = [(PARAMETERS_TOPIC, parameters_message(document())), *mask_messages(views),
                *mask_messages(views[:3])]                        # resent after no receipt
    write_bag(tmp_path / "bag", messages)
    view_set = read_bag(tmp_path / "bag")
    assert len(view_set.views) == len(views)
    np.testing.assert_array_equal(bag_mesh(view_set)[1], reference[1])


def test_the_last_of_several_scans_is_used_with_a_warning(tmp_path, views, caplog):
    messages = [(PARAMETERS_TOPIC, parameters_message(document())),
                ("diagnostics", scan_bytes(1)), *mask_messages(views[:5]),
                ("diagnostics", scan_bytes(2)), *mask_messages(views[5:])]
    write_bag(tmp_path / "bag", messages)
    with caplog.at_level(logging.WARNING):
        view_set = read_bag(tmp_path / "bag")
    assert len(view_set.views) == len(views) - 5
    assert "2 scans" in caplog.text and "5 views of the earlier" in caplog.text


def test_scans_are_told_apart_by_the_recorders_scan_records(tmp_path, views, caplog):
    # The same scan number again is no new scan; with records in the bag, the diagnostics'
    # scan numbers (9 here, mid-scan) are not looked at.
    messages = [(PARAMETERS_TOPIC, parameters_message(document())),
                (SCAN_TOPIC, scan_message(1)), *mask_messages(views[:3]),
                (SCAN_TOPIC, scan_message(1)), *mask_messages(views[3:5]),
                (SCAN_TOPIC, scan_message(2)), *mask_messages(views[5:8]),
                ("diagnostics", scan_bytes(9)), *mask_messages(views[8:])]
    write_bag(tmp_path / "bag", messages)
    with caplog.at_level(logging.WARNING):
        view_set = read_bag(tmp_path / "bag")
    assert len(view_set.views) == len(views) - 5
    assert "2 scans" in caplog.text and "5 views of the earlier" in caplog.text


@pytest.mark.parametrize("scan", [-1, 2 ** 32, 1.0, True, "3"])
def test_a_scan_record_holds_an_unsigned_32_bit_number(scan):
    with pytest.raises(ValueError, match=r"scan number must be an integer in \[0, 2\*\*32\)"):
        scan_message(scan)


def _views_cut_at(sizes, messages, cut: int) -> tuple[int, int]:
    """Fewest and most whole views (mask and joint state) a file cut at byte ``cut`` can
    hold: a message is read when its record is whole, which ends after the end of the
    previous message's write and at the latest at the end of its own (``sizes``)."""
    joints = [n for n, (name, _) in enumerate(messages) if name == "capture/mask_joint_state"]
    return (sum(sizes[n] <= cut for n in joints),
            sum(n == 0 or sizes[n - 1] < cut for n in joints))


def test_a_bag_cut_anywhere_keeps_every_whole_view_before_the_cut(tmp_path, views, caplog):
    sizes, messages = _scan_bag(tmp_path / "bag", views)
    data = (tmp_path / "bag" / "bag.mcap").read_bytes()
    rng = np.random.default_rng(3)
    # arbitrary offsets after the first view, and right after a message's write
    cuts = sorted({*rng.integers(sizes[2], sizes[-1], 12).tolist(), sizes[6], sizes[9]})
    for n, cut in enumerate(cuts):
        cut_file = tmp_path / f"cut_{n}.mcap"
        cut_file.write_bytes(data[:cut])
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            view_set = read_bag(cut_file)
        fewest, most = _views_cut_at(sizes, messages, cut)
        assert fewest <= len(view_set.views) <= most, cut
        if cut in sizes:
            assert len(view_set.views) == fewest
        assert "was not closed (recorder killed?) or was cut" in caplog.text
        # a mask whose joint state was cut off is a rejected view, named
        assert all("capture/mask_joint_state" in why for _, why in view_set.rejected)


def test_a_bag_cut_inside_its_closing_summary_reads_every_view(tmp_path, views, caplog):
    sizes, messages = _scan_bag(tmp_path / "bag", views)
    data = (tmp_path / "bag" / "bag.mcap").read_bytes()
    whole = read_bag(tmp_path / "bag")
    # Every message is on disk by sizes[-1]; what follows is the data end and the summary.
    for n, cut in enumerate(sorted({sizes[-1] + 40, (sizes[-1] + len(data)) // 2,
                                    len(data) - 9})):
        cut_file = tmp_path / f"summary_cut_{n}.mcap"
        cut_file.write_bytes(data[:cut])
        with caplog.at_level(logging.WARNING):
            view_set = read_bag(cut_file)
        assert [v.name for v in view_set.views] == [v.name for v in whole.views], cut


_KILLED_WRITER = """
import os, signal, sys
sys.path.insert(0, {test_dir!r})
from test_bag import PARAMETERS_TOPIC, document, mask_messages, parameters_message, sphere_views
from sfs_ros.cell_logic.bag import TOPICS, BagWriter
bag = BagWriter({folder!r}, storage={storage!r})
for name, (msgtype, kind) in TOPICS.items():
    bag.add_topic("/cell/" + name, msgtype, kind=kind)
messages = [(PARAMETERS_TOPIC, parameters_message(document())), *mask_messages(sphere_views()[:9])]
for n, (name, data) in enumerate(messages):
    bag.write("/cell/" + name, 1 + n, data)
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_writer_killed_outright_leaves_every_message_it_wrote(tmp_path, storage):
    code = _KILLED_WRITER.format(test_dir=str(Path(__file__).parent), folder=str(tmp_path / "bag"),
                                 storage=storage)
    done = subprocess.run([sys.executable, "-c", code], cwd=SOURCE_ROOT, timeout=120)
    assert done.returncode == -9
    assert not (tmp_path / "bag" / "metadata.yaml").exists()
    assert len(read_bag(tmp_path / "bag").views) == 9


def test_a_bag_cut_before_its_parameters_is_refused_clearly(tmp_path, views):
    sizes, _ = _scan_bag(tmp_path / "bag", views)
    cut_file = tmp_path / "cut.mcap"
    cut_file.write_bytes((tmp_path / "bag" / "bag.mcap").read_bytes()[:sizes[0] // 2])
    with pytest.raises(ViewError, match=f"no {PARAMETERS_TOPIC} message"):
        read_bag(cut_file)


def test_masks_without_their_angle_topic_are_refused_naming_it(tmp_path, views):
    messages = [(PARAMETERS_TOPIC, parameters_message(document())),
                *[m for m in mask_messages(views) if m[0] == "capture/mask"]]
    write_bag(tmp_path / "bag", messages)
    with pytest.raises(ViewError, match="none on /cell/capture/mask_joint_state: expected "
                                        "the joint states"):
        read_bag(tmp_path / "bag")


def _foreign_bag(folder, views, *, mask_type: str, extra_type: str):
    """A bag written with rosbags directly: masks recorded as ``mask_type`` and one more
    topic of ``extra_type`` (a type no typestore here knows)."""
    with Writer(folder, version=9) as writer:
        def connection(name, msgtype):
            if msgtype in STORE.types:
                return writer.add_connection(f"{NS}/{name}", msgtype, typestore=STORE)
            return writer.add_connection(f"{NS}/{name}", msgtype, msgdef="int32 x",
                                         rihs01="RIHS01_" + "0" * 64)
        topics = {name: connection(name, t) for name, t in (
            (PARAMETERS_TOPIC, "std_msgs/msg/String"), ("capture/mask", mask_type),
            ("capture/mask_joint_state", "sensor_msgs/msg/JointState"), ("vendor/x", extra_type))}
        writer.write(topics[PARAMETERS_TOPIC], 1, parameters_message(document()))
        writer.write(topics["vendor/x"], 2, b"\x00\x01\x00\x00\x07\x00\x00\x00")
        for n, (name, data) in enumerate(mask_messages(views)):
            writer.write(topics[name], 3 + n, data)


def test_an_unknown_message_type_is_skipped_with_a_warning_naming_it(tmp_path, views, caplog):
    _foreign_bag(tmp_path / "bag", views, mask_type="sensor_msgs/msg/Image",
                 extra_type="vendor_msgs/msg/Gauge")
    with caplog.at_level(logging.WARNING):
        view_set = read_bag(tmp_path / "bag")
    assert len(view_set.views) == len(views)
    assert "/cell/vendor/x has type vendor_msgs/msg/Gauge, unknown here: skipped" in caplog.text


def test_masks_of_another_type_are_refused_naming_both_types(tmp_path, views):
    _foreign_bag(tmp_path / "bag", views, mask_type="vendor_msgs/msg/Mask",
                 extra_type="vendor_msgs/msg/Gauge")
    with pytest.raises(ViewError, match="/cell/capture/mask has type vendor_msgs/msg/Mask, "
                                        "expected sensor_msgs/msg/Image"):
        read_bag(tmp_path / "bag")


def test_malformed_views_are_rejected_and_the_others_used(tmp_path, views):
    bad_stamp = views[2][0]
    messages = [(PARAMETERS_TOPIC, parameters_message(document()))]
    for stamp, mask, theta, phi in views:
        encoding = "rgb8" if stamp == bad_stamp else "mono8"
        image = np.repeat(mask[:, :, None], 3, 2) if stamp == bad_stamp else mask
        messages += [("capture/mask", image_bytes(image, stamp, encoding)),
                     ("capture/mask_joint_state", joints_bytes(theta, phi, stamp))]
    write_bag(tmp_path / "bag", messages)
    view_set = read_bag(tmp_path / "bag")
    assert len(view_set.views) == len(views) - 1
    assert view_set.rejected == [(f"{bad_stamp[0]}_{bad_stamp[1]:09d}",
                                  "malformed capture/mask: image encoding is 'rgb8', expected "
                                  "one of ['mono8']")]


def _cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sfs_ros.cli.reconstruct", *map(str, args)],
                          capture_output=True, text=True, cwd=SOURCE_ROOT, timeout=300)


def test_sfs_reconstruct_reads_a_bag_and_says_one_line_for_a_bad_one(tmp_path, views):
    _scan_bag(tmp_path / "bag", views)
    done = _cli(tmp_path / "bag", "-o", tmp_path / "mesh.ply", "-q")
    assert done.returncode == 0, done.stderr
    assert f"{len(views)} used" in done.stdout
    # the recorded resolution is used unless -r says otherwise
    report = json.loads((tmp_path / "mesh.report.json").read_text())
    assert max(report["grid"]["shape"]) == RESOLUTION
    (tmp_path / "empty.mcap").write_bytes(b"not an mcap file")
    write_bag(tmp_path / "no_views", [(PARAMETERS_TOPIC, parameters_message(document()))])
    for bad, says in ((tmp_path / "empty.mcap", "is not an MCAP file"),
                      (tmp_path / "no_views", "holds no views"),
                      (tmp_path / "missing.db3", "does not exist")):
        done = _cli(bad, "-o", tmp_path / "x.ply")
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and says in lines[0], done.stderr


def test_bag_names_stay_inside_the_output_folder(tmp_path):
    assert bag_folder(tmp_path, "scan_001") == (tmp_path / "bags" / "scan_001").resolve()
    for bad in ("../x", "a/b", ".hidden", "", "x" * 101, "-x"):
        with pytest.raises(ValueError, match="must be 1-100 letters"):
            bag_folder(tmp_path, bad)
    (tmp_path / "bags").mkdir()
    (tmp_path / "bags" / "out").symlink_to(tmp_path.parent)
    with pytest.raises(ValueError, match="leads outside"):
        bag_folder(tmp_path, "out")


def test_open_bag_finds_the_namespace_and_refuses_what_is_not_a_bag(tmp_path, views):
    _scan_bag(tmp_path / "bag", views)
    bag = open_bag(tmp_path / "bag")
    assert bag.namespace == NS and bag.relative(f"{NS}/capture/mask") == "capture/mask"
    assert bag.counts[f"{NS}/capture/mask"] == len(views)
    (tmp_path / "folder").mkdir()
    with pytest.raises(ViewError, match="holds no .mcap or .db3 file"):
        open_bag(tmp_path / "folder")
    (tmp_path / "x.bag").write_bytes(b"")
    with pytest.raises(ViewError, match="expected a folder or a file ending in .mcap or .db3"):
        open_bag(tmp_path / "x.bag")
