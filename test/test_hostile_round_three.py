"""Hostile input, round three (issue 29, classes 1-7): input never chooses code to run,
outputs are written atomically and read back, confinement is even, and memory and time
stay bounded however an input lies about its sizes.

Each test is named after its class. Memory is measured in a subprocess (its peak
resident set, ``ru_maxrss``), the way ``fuzz_driver.py`` measures the fuzz suite, whose
cases cover the classes too (``test_hostile_input.py``: bombs in bags, COLMAP links).
"""

import functools
import json
import os
import struct
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml

from sfs_ros.core.exchange.errors import ViewError
from sfs_ros.core.exchange.limits import MAX_BAG_RECORD_BYTES, MAX_IMAGE_PIXELS, MAX_WAITING_BYTES

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
#: Peak memory of a tool refusing a bomb, MiB: its start-up (numba, OpenCV, SciPy, rclpy)
#: takes about 300 of it, up to 750 when numba compiles kernels whose cache is cold; the
#: bomb expanded takes 3 GiB more.
MAX_REFUSAL_MIB = 1500
#: Longest a refusal may take, s (start-up included).
MAX_REFUSAL_S = 60

_MAGIC = b"\x89MCAP0\r\n"


# ---- MCAP files written record by record, so that they can lie -------------------------

def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def mcap_file(records: list[bytes]) -> bytes:
    """An MCAP file (profile ros2) of ``records``, closed without a summary."""
    header = _record(0x01, _string("ros2") + _string("test"))
    footer = _record(0x02, struct.pack("<QQI", 0, 0, 0))
    return _MAGIC + header + b"".join(records) + _record(0x0F, struct.pack("<I", 0)) \
        + footer + _MAGIC


def channel_records(msgtype: str, topic: str) -> list[bytes]:
    """Schema 1 and channel 1 of ``msgtype`` on ``topic``."""
    schema = struct.pack("<H", 1) + _string(msgtype) + _string("ros2msg") + _string("int32 a")
    channel = struct.pack("<HH", 1, 1) + _string(topic) + _string("cdr") \
        + struct.pack("<I", 0)
    return [_record(0x03, schema), _record(0x04, channel)]


def message_record(data: bytes, log_time: int = 1) -> bytes:
    return _record(0x05, struct.pack("<HIQQ", 1, 0, log_time, log_time) + data)


def chunk_record(compressed: bytes, *, declared: int, compression: str = "zstd") -> bytes:
    body = struct.pack("<QQQI", 1, 1, declared, 0) + _string(compression) \
        + struct.pack("<Q", len(compressed)) + compressed
    return _record(0x06, body)


@functools.cache
def zstd_bomb() -> tuple[bytes, int]:
    """A 98 KB zstd frame of 3 GiB of zeros, and that size."""
    if sys.version_info >= (3, 14):
        from compression import zstd
    else:
        from backports import zstd
    size, block = 3 << 30, bytes(16 << 20)
    compressor = zstd.ZstdCompressor(level=3)
    frame = b"".join([*(compressor.compress(block) for _ in range(size // len(block))),
                      compressor.flush()])
    return frame, size


def bomb_bags(folder: Path, zstd_bomb) -> dict[str, Path]:
    """Bag folders of one zstd chunk that expands to 3 GiB: declaring so, declaring a few
    bytes, and declaring just under the limit."""
    frame, size = zstd_bomb
    records = channel_records("sensor_msgs/msg/Image", "/sfs/capture/image")
    bags = {}
    for name, declared in (("declares 3 GiB", size), ("declares 4 KiB", 4096),
                           ("declares the limit", MAX_BAG_RECORD_BYTES)):
        bag = folder / name.replace(" ", "_") / "bag"
        bag.mkdir(parents=True)
        (bag / "bag.mcap").write_bytes(mcap_file([*records, chunk_record(frame,
                                                                         declared=declared)]))
        bags[name] = bag
    return bags


def run_measured(code: str, *, cwd=ROOT, timeout=MAX_REFUSAL_S) -> dict:
    """Run ``code`` in a fresh interpreter; its JSON line on stdout, with ``peak_mib``."""
    probe = code + textwrap.dedent("""
        import json as _json, resource as _resource
        print(_json.dumps({**RESULT, "peak_mib":
                           _resource.getrusage(_resource.RUSAGE_SELF).ru_maxrss / 1024}))
    """)
    done = subprocess.run([sys.executable, "-c", probe], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


# ---- class 1: a bag never chooses which module is imported -----------------------------

def test_class1_a_bags_message_types_never_choose_a_module(tmp_path):
    """``sfs-replay`` of a bag whose channels are typed ``venv/__main__/X`` (which ran
    ``python -m venv``) and ``evil/msg/X`` (a package beside the bag) imports neither:
    both topics are skipped, named, and the bag is played."""
    sentinel = tmp_path / "imported"
    evil = tmp_path / "evil" / "msg"
    evil.mkdir(parents=True)
    (tmp_path / "evil" / "__init__.py").write_text(f"open({str(sentinel)!r}, 'w').close()\n")
    (evil / "__init__.py").write_text(f"open({str(sentinel)!r}, 'w').close()\nX = 1\n")
    for n, msgtype in enumerate(["venv/__main__/X", "evil/msg/X", "os/msg/System"]):
        bag = tmp_path / f"bag{n}"
        bag.mkdir()
        (bag / "bag.mcap").write_bytes(mcap_file(
            [*channel_records(msgtype, "/sfs/capture/image"), message_record(b"\0" * 8)]))
        # ``python -m`` puts the working folder (beside the bag) first on sys.path.
        done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.replay", str(bag),
                               "--wait-s", "0", "-q"], cwd=tmp_path, capture_output=True,
                              text=True, timeout=120,
                              env=dict(os.environ, PYTHONPATH=str(ROOT)))
        assert done.returncode == 0, done.stderr
        assert "Traceback" not in done.stderr
        assert f"skipping /sfs/capture/image: message type {msgtype!r}" in done.stderr
        assert not sentinel.exists(), f"{msgtype}: the bag's type imported a module"
        assert not (bag / "pyvenv.cfg").exists() and not (tmp_path / "pyvenv.cfg").exists()


def test_class1_only_known_message_packages_resolve():
    from sfs_ros.ros.message_types import message_class

    assert message_class("sensor_msgs/msg/Image").__name__ == "Image"
    for msgtype in ("venv/__main__/X", "evil/msg/X", "os/msg/Path", "sensor_msgs/srv/Image",
                    "sensor_msgs/msg/Image/x", "sensor_msgs.msg/Image", "", "std_msgs/msg/_os"):
        with pytest.raises(ValueError, match="message type"):
            message_class(msgtype)


# ---- class 4: confinement is even -------------------------------------------------------

def _colmap_model(folder: Path, image_folder: Path) -> Path:
    """A COLMAP text model in ``folder`` of one 96 x 72 image under ``image_folder``."""
    folder.mkdir(parents=True)
    (folder / "cameras.txt").write_text("1 PINHOLE 96 72 160 160 48 36\n")
    (folder / "images.txt").write_text("1 1 0 0 0 0 0 0.5 1 view_000.png\n\n")
    image_folder.mkdir(parents=True, exist_ok=True)
    (image_folder / "view_000.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    return folder


@pytest.mark.parametrize("layout", ["model/images", "model/../images", "sparse/0/../../images"])
def test_class4_a_colmap_images_folder_may_not_lead_outside(tmp_path, layout):
    from sfs_ros.core.exchange.colmap import read_colmap

    outside = tmp_path / "outside"
    model = _colmap_model(tmp_path / "input" / "sparse" / "0", outside)
    links = {"model/images": model / "images", "model/../images": model.parent / "images",
             "sparse/0/../../images": model.parent.parent / "images"}
    os.symlink(outside, links[layout])
    with pytest.raises(ViewError, match="leads outside"):
        read_colmap(model)


def test_class4_an_image_inside_the_colmap_input_is_still_read(tmp_path):
    from sfs_ros.core.exchange.colmap import read_colmap

    model = _colmap_model(tmp_path / "input" / "sparse" / "0", tmp_path / "input" / "images")
    assert [v.name for v in read_colmap(model).views] == ["view_000.png"]


# ---- class 5: a bag's chunks are checked before they are expanded ----------------------

@pytest.mark.parametrize("case", ["declares 3 GiB", "declares 4 KiB", "declares the limit"])
def test_class5_a_zstd_bomb_in_a_bag_is_refused_in_bounded_memory(tmp_path, case):
    """98 KB of zstd expanding to 3 GiB, whatever the chunk declares: each bag reader
    (``sfs-reconstruct``, ``sfs-export``, ``sfs-calibrate``, ``sfs-replay``) refuses
    it with one line naming the bag and the limit, fast and in bounded memory."""
    bag = bomb_bags(tmp_path, zstd_bomb())[case]
    code = textwrap.dedent(f"""
        import contextlib, io, time
        from sfs_ros.cli import calibrate, export, reconstruct, replay
        RESULT = {{}}
        for name, main, argv in [
                ("reconstruct", reconstruct.main, [{str(bag)!r}, "-o", {str(tmp_path)!r} + "/m.ply"]),
                ("export", export.main, [{str(bag)!r}, "--colmap", {str(tmp_path)!r} + "/c"]),
                ("calibrate", calibrate.main, [{str(bag)!r}, "-o", {str(tmp_path)!r} + "/k"]),
                ("replay", replay.main, [{str(bag)!r}, "--wait-s", "0", "-q"])]:
            err = io.StringIO()
            start = time.monotonic()
            with contextlib.redirect_stderr(err):
                status = main(argv)
            RESULT[name] = [status, err.getvalue(), time.monotonic() - start]
    """)
    result = run_measured(code)
    for tool in ("reconstruct", "export", "calibrate", "replay"):
        status, stderr, seconds = result[tool]
        assert status == 2, f"{tool}: {stderr}"
        assert len(stderr.splitlines()) == 1 and str(bag) in stderr, f"{tool}: {stderr}"
        assert "512 MiB" in stderr or "declares" in stderr, f"{tool}: {stderr}"
        assert seconds < MAX_REFUSAL_S
    # A chunk declaring the limit is expanded up to it (the output buffer grows by copies).
    limit = MAX_REFUSAL_MIB + (2 * MAX_BAG_RECORD_BYTES >> 20 if case == "declares the limit"
                               else 0)
    print(f"{case}: peak {result['peak_mib']:.0f} MiB")
    assert result["peak_mib"] < limit


def test_class5_a_sqlite_bag_row_over_the_limit_is_refused_before_it_is_read(tmp_path):
    from sfs_ros.cell_logic.bag.bounds import RecordTooLarge, check_storage

    bag = tmp_path / "bag.db3"
    import sqlite3
    with sqlite3.connect(bag) as db:
        db.execute("CREATE TABLE messages (id INTEGER PRIMARY KEY, topic_id INTEGER, "
                   "timestamp INTEGER, data BLOB)")
        db.execute("INSERT INTO messages VALUES (1, 1, 1, zeroblob(?))",
                   (MAX_BAG_RECORD_BYTES + 1,))
    with pytest.raises(RecordTooLarge, match=r"bag.db3 holds a message of 512\.0 MiB"):
        check_storage(None, [bag])


def test_class5_a_bag_compressed_by_rosbag2_is_refused_not_expanded(tmp_path):
    from sfs_ros.cell_logic.bag import open_bag

    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag.mcap").write_bytes(mcap_file([]))
    (bag / "bag.mcap.zstd").write_bytes(b"\x28\xb5\x2f\xfd" + b"\0" * 64)
    (bag / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": {
        "version": 5, "compression_mode": "FILE", "compression_format": "zstd",
        "relative_file_paths": ["bag.mcap.zstd"], "storage_identifier": "mcap"}}))
    with pytest.raises(ViewError, match="is compressed .*decompress it first"):
        open_bag(bag)


def test_class5_bounded_decompression_gives_what_a_chunk_declares():
    from backports import zstd

    from sfs_ros.cell_logic.bag.bounds import RecordTooLarge, _bounded

    decompress = _bounded(zstd.ZstdDecompressor)
    data = bytes(range(256)) * 40
    two_frames = zstd.compress(data[:5000]) + zstd.compress(data[5000:])
    assert decompress(two_frames, len(data)) == data
    with pytest.raises(RecordTooLarge, match="expands past"):
        decompress(two_frames, len(data) - 1)


# ---- class 7: the camera's image folder uses the readers' limits ------------------------

def _png_bomb(width: int, height: int) -> bytes:
    """A PNG declaring ``width`` x ``height`` RGB pixels, its first rows black."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    rows = zlib.compress(bytes((3 * width + 1) * 64))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", rows) + chunk(b"IEND", b""))


def test_class7_the_camera_image_folder_refuses_a_decode_bomb_from_its_header(tmp_path):
    """A PNG declaring 20000 x 20000 pixels is a frame not taken, named, under a memory
    limit that its decoding would break; the next image is taken."""
    import cv2
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "a_bomb.png").write_bytes(_png_bomb(20000, 20000))
    cv2.imwrite(str(folder / "b_good.png"), np.full((72, 96, 3), 90, np.uint8))
    code = textwrap.dedent(f"""
        import resource
        from sfs_ros.hardware.cameras import FolderSource, FrameUnavailable
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
        source = FolderSource({str(folder)!r})
        try:
            source.grab()
            RESULT = {{"first": "taken"}}
        except FrameUnavailable as exc:
            RESULT = {{"first": str(exc)}}
        RESULT["second"] = list(source.grab().shape)
    """)
    result = run_measured(code)
    assert "a_bomb.png declares more pixels" in result["first"]
    assert f"{MAX_IMAGE_PIXELS / 1e6:.0f} megapixels" in result["first"]
    assert result["second"] == [72, 96, 3]


# ---- classes 2 and 3: sfs-calibrate writes atomically, through no link, what reads back --

@pytest.fixture(scope="module")
def board_session(tmp_path_factory) -> Path:
    """A board scan whose folder's name holds a control character (class 3)."""
    from sfs_ros.core.exchange.session import write_session
    from sfs_ros.core.simulation.calibration_scene import board_scene, nominal_rig

    scene = board_scene()
    folder = tmp_path_factory.mktemp("board") / "board\x01scan"
    write_session(folder, [(f"view_{i:03d}.png", image) for i, image in enumerate(scene.images)],
                  scene.angles, nominal_rig())
    return folder


def test_class2_and_3_calibrate_replaces_a_link_and_writes_files_that_read_back(
        board_session, tmp_path):
    """OUTDIR/rig.yaml a link to a file elsewhere: the link is replaced, the file it led to
    is untouched. The input folder's control character is escaped in the header: every
    file parses back as YAML, and rig.yaml as an rcl parameters file."""
    from sfs_ros.cli import calibrate
    from sfs_ros.ros.params_file import check_params_file

    elsewhere = tmp_path / "elsewhere.yaml"
    elsewhere.write_text("precious: true\n")
    out = tmp_path / "out"
    out.mkdir()
    os.symlink(elsewhere, out / "rig.yaml")
    assert calibrate.main([str(board_session), "-o", str(out)]) == 0
    assert elsewhere.read_text() == "precious: true\n"
    assert not (out / "rig.yaml").is_symlink()
    for name in ("rig.yaml", "camera_info.yaml", "calibration_report.yaml"):
        text = (out / name).read_text(encoding="utf-8")
        assert text.isprintable() or set(text) - set(text.strip()) <= {"\n"}
        assert "\x01" not in text and yaml.safe_load(text)
    assert "board\\x01scan" in (out / "rig.yaml").read_text()
    check_params_file((out / "rig.yaml").read_bytes(), "rig.yaml")


def test_class3_a_document_that_would_not_read_back_is_not_written():
    from sfs_ros.core.calibration import yaml_document
    from sfs_ros.ros.params_file import check_params_file

    text = yaml_document({"a": 1}, header="from board\x01\x1b[31m\u2028scan")
    assert yaml.safe_load(text) == {"a": 1} and b"\\x01" in text
    with pytest.raises(ValueError, match="would not read back"):
        yaml_document({"a": float("nan")})
    with pytest.raises(ValueError, match="rig.yaml would not be read by ROS"):
        check_params_file(b"/**:\n  ros__parameters:\n    a: [1, x]\n", "rig.yaml")


def test_class2_a_write_that_fails_part_way_leaves_the_old_rig_whole(tmp_path):
    """Files may grow to 300 bytes only (as a full disk): the write fails naming
    rig.yaml, and the good rig.yaml already there is as it was, not cut."""
    from sfs_ros.core.calibration import rig_yaml
    from sfs_ros.core.geometry.rig import RigCalibration

    out = tmp_path / "out"
    out.mkdir()
    good = rig_yaml(RigCalibration(), header="the good one")
    (out / "rig.yaml").write_bytes(good)
    code = textwrap.dedent(f"""
        import resource
        from pathlib import Path
        from sfs_ros.cli import calibrate
        calibrate.check_params_file = lambda data, what: None   # its copy would hit the limit
        from sfs_ros.core.calibration import rig_yaml
        from sfs_ros.core.geometry.rig import RigCalibration
        data = rig_yaml(RigCalibration(fx=999.0), header="the new one")
        resource.setrlimit(resource.RLIMIT_FSIZE, (300, 300))
        try:
            calibrate._write(Path({str(out)!r}), {{"rig.yaml": data}})
            RESULT = {{"error": ""}}
        except OSError as exc:
            RESULT = {{"error": str(exc)}}
    """)
    result = run_measured(code)
    assert "File too large" in result["error"] and str(out / "rig.yaml") in result["error"]
    assert (out / "rig.yaml").read_bytes() == good
    assert sorted(p.name for p in out.iterdir()) == ["rig.yaml"]      # no temporary left


# ---- class 6: what waits for its partner is bounded in count and bytes ------------------

def test_class6_a_pairing_buffer_is_bounded_in_bytes_and_refuses_what_cannot_fit():
    from sfs_ros.ros.pairing import StampPairer

    given_up = []
    pairer = StampPairer(40, max_bytes=100 << 20,
                         on_evict=lambda *args: given_up.append((args[1], args[3])))
    for n in range(40):                                   # 40 oversized masks, 34 MB each
        pairer.add_a((n, 0), f"mask {n}", 34 << 20)
    assert pairer.pending("a") == 2 and pairer.pending_bytes("a") == 68 << 20
    assert given_up[:2] == [((0, 0), "evicted"), ((1, 0), "evicted")]
    pairer.add_b((5, 0), "too big", 101 << 20)            # never stored
    assert given_up[-1] == ((5, 0), "too large") and pairer.pending("b") == 0
    assert pairer.add_b((39, 0), "joints", 100) == ("mask 39", "joints")
    assert pairer.pending_bytes("a") == 34 << 20


def test_class6_a_mask_or_image_not_of_the_rigs_size_is_refused_before_it_is_kept():
    from sensor_msgs.msg import Image

    from sfs_ros.cell_logic.message_fields import mask_from_msg

    msg = Image(width=8000, height=6000, encoding="mono8", step=8000)   # no pixels needed
    with pytest.raises(ValueError, match="mask is 8000x6000 pixels, expected the rig's 96x72"):
        mask_from_msg(msg, (96, 72))


@pytest.mark.ros
def test_class6_the_segmentation_node_refuses_a_capture_not_of_the_rigs_size(start_node,
                                                                             tmp_path):
    """An 8000 x 6000 capture (48 MB of pixels) at a node configured with the rig's 320 x 240:
    refused from its header, named with both sizes, before it is kept or segmented (no mask
    for it, nothing left waiting); the capture after it is segmented."""
    from sensor_msgs.msg import Image
    from test_segmentation_node import NODE_PARAMS, RIG, Cell

    from sfs_ros.ros.convert import image_to_msg, joint_state

    params = tmp_path / "segmentation.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": NODE_PARAMS}}))
    cell = start_node(Cell, params)
    huge = Image(width=8000, height=6000, encoding="mono8", step=8000,
                 data=np.full(8000 * 6000, 200, np.uint8).tobytes())
    huge.header.stamp.sec = 300
    cell.image_pub.publish(huge)
    cell.joints_pub.publish(joint_state(0.0, 0.5, stamp=(300, 0)))
    good = np.full((RIG.height, RIG.width, 3), 250, np.uint8)
    good[80:160, 120:200] = 40                                       # a dark box on white
    cell.image_pub.publish(image_to_msg(good, stamp=(301, 0), frame_id="c"))
    cell.joints_pub.publish(joint_state(0.0, 0.5, stamp=(301, 0)))
    cell.receive(1)
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in cell.masks] == [(301, 0)]
    assert ("malformed image at stamp 300.000000000 dropped with its capture: image is "
            "8000x6000 pixels, expected the rig's 320x240 (width x height)"
            in cell.process.output())
    last = {kv.key: kv.value for kv in cell.diagnostics[-1].status[0].values}
    assert last["malformed"] == "1" and last["masks"] == "1"
    assert last["waiting_images"] == "0" and last["waiting_joint_states"] == "0"


def test_class6_colour_images_without_their_view_are_bounded(tmp_path):
    """3,000 captured images whose masks never come: the node's live reconstruction keeps
    at most MAX_WAITING_BYTES of them (peak memory measured), and an image whose view
    has come is kept whatever comes after it."""
    code = textwrap.dedent(f"""
        import numpy as np
        from sfs_ros.cell_logic.live_reconstruction import LiveReconstruction
        from sfs_ros.core.exchange.limits import MAX_WAITING_BYTES
        from sfs_ros.core.geometry.rig import RigCalibration
        rig = RigCalibration(width=640, height=480)
        live = LiveReconstruction(rig, [[-0.1, -0.1, 0], [0.1, 0.1, 0.2]],
                                  output_dir={str(tmp_path)!r}, resolution=16)
        mask = np.zeros((480, 640), bool)
        mask[200:280, 280:360] = True
        live.add_colour_image("kept", np.full((480, 640, 3), 7, np.uint8))
        live.add_view("kept", mask, 0.0, 0.5)
        for n in range(3000):
            live.add_colour_image(f"orphan{{n}}", np.full((480, 640, 3), n % 251, np.uint8))
        RESULT = {{"kept": "kept" in live._colour_images,
                   "orphans": len(live._colour_images) - 1,
                   "most": MAX_WAITING_BYTES // (480 * 640 * 3)}}
    """)
    result = run_measured(code, timeout=120)
    assert result["kept"] and result["orphans"] == result["most"]
    print(f"peak {result['peak_mib']:.0f} MiB")
    assert result["peak_mib"] < MAX_REFUSAL_MIB + (MAX_WAITING_BYTES >> 20)
