"""Hostile input, round three: results that were silently wrong, crashes, tracebacks and
unclear answers (issue 29, classes 8-19). One test per class, named after it; the cases
that are command lines also run through the fuzz driver (``fuzz_driver.py``) with the
other hostile cases' rules: exit 0 or 2, one line on stderr, no traceback.
"""

import io
import json
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import test_hostile_input
import yaml
from test_hostile_input import FAST, OK, REFUSED, Cases, failures
from test_supervisor import ScriptSpec

from sfs_ros.cell_logic.bag import read_bag
from sfs_ros.cli.bringup import Cell, RestartPolicy, wait_until_signal
from sfs_ros.cli.reconstruct import main as reconstruct_main
from sfs_ros.core.calibration import BoardSpec
from sfs_ros.core.exchange.colmap import read_colmap
from sfs_ros.core.exchange.pose_export import write_colmap
from sfs_ros.core.exchange.session import read_session
from sfs_ros.core.exchange.views import ViewError, as_bounds
from sfs_ros.core.pipeline import ReconstructionParams
from sfs_ros.core.settings import RESOLUTION

from test_bag import (
    PARAMETERS_TOPIC,
    document,
    mask_messages,
    parameters_message,
    sphere_views,
    write_bag,
)

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
#: The fixture: a 13-view session of a 5 cm sphere on a 96 x 72 camera.
base = test_hostile_input.base


def reconstruct(argv) -> tuple[int, list[str], dict | None]:
    """``sfs-reconstruct argv`` in this process: exit status, stderr lines, the report."""
    err = io.StringIO()
    stdout, stderr = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = io.StringIO(), err
    try:
        status = reconstruct_main([str(a) for a in argv])
    finally:
        sys.stdout, sys.stderr = stdout, stderr
    out = Path(argv[argv.index("-o") + 1])
    report = out.with_name(out.stem + ".report.json")
    return status, err.getvalue().splitlines(), \
        json.loads(report.read_text()) if status == 0 else None


def bag(folder: Path, views, edit=None) -> Path:
    """A bag of ``views`` (``sphere_views()`` items) with its recorded parameters."""
    doc = document()
    if edit is not None:
        edit(doc)
    write_bag(folder, [(PARAMETERS_TOPIC, parameters_message(doc)), *mask_messages(views)])
    return folder


def session_of(base: Path, folder: Path, names: list[str]) -> Path:
    """A copy of the session ``base`` holding only the views ``names`` (repeats allowed)."""
    shutil.copytree(base, folder)
    table = (folder / "views.csv").read_text().splitlines()
    rows = {row.split(",")[0]: row for row in table[1:]}
    for path in (folder / "images").iterdir():
        path.unlink()
    lines = [table[0]]
    for n, name in enumerate(names):
        copy = f"copy_{n:02d}_{name}"
        shutil.copy(base / "images" / name, folder / "images" / copy)
        lines.append(copy + rows[name][len(name):])
    (folder / "views.csv").write_text("\n".join(lines) + "\n")
    return folder


# ---- class 8: too little to see a shape -------------------------------------------------

def test_class_8_too_few_viewing_directions_is_an_error(base, tmp_path):
    names = [v.name for v in read_session(base).views]
    cases = {"one view": session_of(base, tmp_path / "one", names[:1]),
             "thirteen copies of one view": session_of(base, tmp_path / "copies", names[:1] * 13),
             "two views": session_of(base, tmp_path / "two", names[:2]),
             "a bag whose last scan has two views": bag(tmp_path / "bag", sphere_views()[-2:])}
    for case, folder in cases.items():
        status, lines, _ = reconstruct([folder, "-o", tmp_path / "m.ply", *FAST])
        assert status == 2 and len(lines) == 1, (case, lines)
        assert "distinct direction" in lines[0] and "at least 3" in lines[0], (case, lines)
    held = ",".join(str(n) for n in range(1, len(names)))
    status, lines, _ = reconstruct([base, "-o", tmp_path / "h.ply", "--holdout", held, *FAST])
    assert status == 2 and "1 distinct direction" in lines[0], lines
    # Three directions 120 degrees apart bound the hull: a mesh.
    three = session_of(base, tmp_path / "three", names[0:12:4])
    status, lines, report = reconstruct([three, "-o", tmp_path / "t.ply", *FAST])
    assert status == 0 and len(report["views"]["used"]) == 3, lines


# ---- class 9: calibration with the wrong board size --------------------------------------

@pytest.fixture(scope="module")
def board_scene():
    """The calibration scene: a 7 x 5 board of 30 mm squares in 28 views, and its truth."""
    from sfs_ros.core.simulation.calibration_scene import board_scene

    return board_scene()


def write_board_session(folder: Path, scene, chosen, angles=None) -> Path:
    """A session of the views ``chosen`` of ``scene``, tagged with ``angles`` (default the
    scene's)."""
    from sfs_ros.core.exchange.session import write_session
    from sfs_ros.core.simulation.calibration_scene import nominal_rig

    angles = scene.angles if angles is None else angles
    write_session(folder, [(f"view_{i:03d}.png", scene.images[i]) for i in chosen],
                  [angles[i] for i in chosen], nominal_rig())
    return folder


@pytest.fixture(scope="module")
def board_session(board_scene, tmp_path_factory) -> Path:
    """Every other view of the calibration scene."""
    return write_board_session(tmp_path_factory.mktemp("board") / "session", board_scene,
                               range(0, len(board_scene.images), 2))


def calibrate(argv) -> tuple[int, list[str]]:
    """``sfs-calibrate argv`` in this process: exit status and stderr lines."""
    from sfs_ros.cli.calibrate import main

    err = io.StringIO()
    stdout, stderr = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = io.StringIO(), err
    try:
        status = main([str(a) for a in argv])
    finally:
        sys.stdout, sys.stderr = stdout, stderr
    return status, err.getvalue().splitlines()


def test_class_9_a_board_of_the_wrong_size_is_named_with_both_radii(board_session, tmp_path,
                                                                    caplog):
    from sfs_ros.core.simulation.calibration_scene import nominal_rig

    measured = f"{nominal_rig().camera_distance_m:.4f} m"
    status, lines = calibrate([board_session, "-o", tmp_path / "twice", "--square-m", "0.06",
                               "--marker-m", "0.044"])
    assert status == 2 and len(lines) == 1, lines
    assert "radius" in lines[0] and measured in lines[0] and "square_m 0.06" in lines[0]
    assert not (tmp_path / "twice" / "rig.yaml").exists()
    # 20 % off: a warning naming both, the fit kept.
    with caplog.at_level("WARNING"):
        status, lines = calibrate([board_session, "-o", tmp_path / "fifth", "--square-m",
                                   "0.036", "--marker-m", "0.0264"])
    assert status == 0, lines
    assert any("radius" in r.message and measured in r.message for r in caplog.records)
    for value in ("nan", "-1"):
        status, lines = calibrate([board_session, "-o", tmp_path / "rms",
                                   "--max-view-rms-px", value])
        assert status == 2 and "max_view_rms_px" in lines[0], lines


# ---- class 10: one mis-tagged view -----------------------------------------------------

def test_class_10_mis_tagged_views_are_rejected_by_name_and_the_rig_recovered(board_scene,
                                                                             tmp_path):
    """Three of the 28 views tagged with theta 90 degrees off, 1e308 and NaN: the fit
    starts from the views' board poses, names exactly those three with what was wrong,
    and recovers the true rig within the bars of ``test_calibration.py``."""
    import test_calibration as bars

    from sfs_ros.core.calibration import canonical
    from sfs_ros.ros.rig_params import rig_calibration

    angles = list(board_scene.angles)
    # The principal point is what the views pin down least: the same 25 views alone give
    # cy 0.08 px from the truth (the bar: 1.18 px; 1.02 px from OpenCV's corners before
    # they were refined to their saddle points), and so must the fit without these three.
    wrong = {5: (angles[5][0] + np.pi / 2, angles[5][1]), 9: (1e308, angles[9][1]),
             16: (float("nan"), angles[16][1])}
    angles = [wrong.get(i, pair) for i, pair in enumerate(angles)]
    folder = write_board_session(tmp_path / "session", board_scene, range(len(angles)), angles)
    status, lines = calibrate([folder, "-o", tmp_path / "out"])
    assert status == 0, lines
    report = yaml.safe_load((tmp_path / "out" / "calibration_report.yaml").read_text())
    rejected = report["rejected"]
    assert set(rejected) == {f"view_{i:03d}.png" for i in wrong}, rejected
    assert "disagree with its board pose by 90.0 degrees" in rejected["view_005.png"]
    assert "theta_rad=1e+308 is beyond any reading" in rejected["view_009.png"]
    assert "not finite" in rejected["view_016.png"]
    assert len(report["view_rms_px"]) == 25 and report["rms_px"] < bars.RMS_PX
    values = yaml.safe_load((tmp_path / "out" / "rig.yaml").read_text())["/**"]["ros__parameters"]
    rig, true = rig_calibration(values), canonical(board_scene.rig, board_scene.pose)[0]
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(rig, name) == pytest.approx(getattr(true, name),
                                                   rel=bars.INTRINSICS_REL), name
    assert rig.distortion[0] == pytest.approx(true.distortion[0], abs=bars.K1_ABS)
    np.testing.assert_allclose(rig.axis_point_m, true.axis_point_m, atol=bars.AXIS_POINT_M)
    for name in ("axis_tilt_y_rad", "theta_zero_rad", "phi_zero_rad"):
        assert getattr(rig, name) == pytest.approx(getattr(true, name), abs=bars.ANGLE_RAD), name
    assert rig.camera_distance_m == pytest.approx(true.camera_distance_m, abs=bars.RADIUS_M)
    np.testing.assert_allclose(rig.mount_rotation_rad, true.mount_rotation_rad,
                               atol=bars.MOUNT_RAD)


def test_class_10_angles_that_give_no_camera_are_rejected_before_the_fit(board_scene):
    """Angles straight from a caller (not a session, which refuses them on reading): NaN
    and a carriage beyond the C-arm are rejected views, named, not an abort."""
    from sfs_ros.core.calibration import calibrate_rig, detect_board
    from sfs_ros.core.simulation.calibration_scene import nominal_rig

    detections = [(f"v{i}", *board_scene.angles[i],
                   detect_board(board_scene.images[i], board_scene.board)[0]) for i in range(6)]
    detections[0] = ("v0", float("nan"), *detections[0][2:])
    detections[1] = ("v1", detections[1][1], 3.0, detections[1][3])
    with pytest.raises(ValueError, match=r"4 usable board views, need at least 6 \(2 rejected, "
                                         r"first: v0: its tagged angles cannot be used: "
                                         r"encoder angles must be finite"):
        calibrate_rig(detections, board_scene.board, nominal_rig())


def test_class_10_an_angle_beyond_any_reading_is_a_rejected_view_named_with_its_value(
        base, tmp_path):
    """theta 1e308 (cos and sin of it are numbers, so it once made a real camera), -2e6 and
    a phi of -1e300, in a session's views.csv and in a bag's joint states: each a rejected
    view, named with the value and the accepted range; the other views make the mesh."""
    from sfs_ros.core.geometry.rig import MAX_ENCODER_RAD

    expected = f"within +-{MAX_ENCODER_RAD:g} rad"
    folder = shutil.copytree(base, tmp_path / "session")
    table = (folder / "views.csv").read_text().splitlines()
    edits = {1: ("1e308", None), 2: ("-2e6", None), 3: (None, "-1e300")}
    for row, (theta, phi) in edits.items():
        name, old_theta, old_phi = table[row].split(",")
        table[row] = ",".join([name, theta or old_theta, phi or old_phi])
    (folder / "views.csv").write_text("\n".join(table) + "\n")
    status, lines, report = reconstruct([folder, "-o", tmp_path / "m.ply", *FAST])
    assert status == 0, lines
    reasons = {r["view"]: r["reason"] for r in report["views"]["rejected"]}
    assert reasons == {
        "view_000.png": f"encoder angle theta_rad=1e+308 is beyond any reading: expected a "
                        f"finite angle {expected}",
        "view_001.png": f"encoder angle theta_rad=-2000000.0 is beyond any reading: expected a "
                        f"finite angle {expected}",
        "view_002.png": f"encoder angle phi_rad=-1e+300 is beyond any reading: expected a "
                        f"finite angle {expected}"}, reasons
    views = sphere_views()
    views[3] = (*views[3][:2], 1e308, views[3][3])
    reasons = dict(read_bag(bag(tmp_path / "bag", views)).rejected)
    assert list(reasons) == ["103_000003000"], reasons
    assert "got theta_rad=1e+308" in reasons["103_000003000"] and expected in \
        reasons["103_000003000"]


# ---- class 11: COLMAP images.txt read by structure ---------------------------------------

def colmap_model(base: Path, folder: Path) -> Path:
    """The session ``base`` exported as a COLMAP text model (with its images) in ``folder``."""
    write_colmap(read_session(base), folder)
    shutil.copytree(base / "images", folder / "images")
    return folder


def test_class_11_colmap_images_are_read_by_structure(base, tmp_path):
    reference = read_colmap(colmap_model(base, tmp_path / "reference"))
    count = len(reference.views)
    edits = {"no points lines": lambda lines: [x for x in lines if not x or x[0] == "#"
                                               or len(x.split()) >= 10],
             "a stray blank line": lambda lines: lines[:5] + [""] + lines[5:],
             "blank lines everywhere": lambda lines: [y for x in lines for y in (x, "")]}
    for case, edit in edits.items():
        folder = colmap_model(base, tmp_path / case.replace(" ", "_"))
        path = folder / "images.txt"
        path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")
        views = read_colmap(folder)
        assert [v.name for v in views.views] == [v.name for v in reference.views], case
        assert len(views.views) == count and not views.rejected, case
    # An image line cut to six numbers is not taken for points (a POINT3D_ID is whole, and
    # an image has one points line): refused, naming its line, not silently dropped.
    for cut in ([], ["1 1 0 0 0 0"]):
        folder = colmap_model(base, tmp_path / f"cut{len(cut)}")
        path = folder / "images.txt"
        lines = path.read_text().splitlines()
        first = next(n for n, line in enumerate(lines) if line and line[0] != "#")
        lines[first + 2] = cut[0] if cut else " ".join(lines[first + 2].split()[:6])
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(ViewError, match=f"images.txt line {first + 3}: expected IMAGE_ID"):
            read_colmap(folder)


# ---- class 12: implausible lenses ---------------------------------------------------------

@pytest.mark.parametrize("k1", [999.0, -999.0])
def test_class_12_a_lens_that_does_not_map_the_image_onto_itself_is_refused(base, tmp_path, k1):
    folder = colmap_model(base, tmp_path / "model")
    cameras = folder / "cameras.txt"
    lines = cameras.read_text().splitlines()
    fields = lines[-1].split()
    fx, fy, cx, cy = fields[4:8] if fields[1] == "PINHOLE" else (fields[4], fields[4],
                                                                  *fields[5:7])
    lines[-1] = " ".join([fields[0], "OPENCV", *fields[2:4], fx, fy, cx, cy, str(k1), "0", "0",
                          "0"])
    cameras.write_text("\n".join(lines) + "\n")
    with pytest.raises(ViewError, match=f"OPENCV camera {fields[0]!r}.*(folds|moves)"):
        read_colmap(folder)
    status, lines, _ = reconstruct([folder, "-o", tmp_path / "m.ply", *FAST])
    assert status == 2 and "camera" in lines[0] and "lens distortion" in lines[0], lines


# ---- class 13: reset during a scan ---------------------------------------------------------

def test_class_13_a_reset_during_a_scan_is_refused_and_no_open_marker_is_left(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger
    from test_rig_runtime import _scan_report

    from sfs_ros.cell_logic.live_reconstruction import OPEN_MARKER
    from sfs_ros.nodes.carving_node import CarvingNode
    from sfs_ros.ros.names import DIAGNOSTICS, SERVICES

    from ros_harness import NAMESPACE, RosProbe

    probe = RosProbe("round_three_probe")
    node = CarvingNode(context=probe.context, namespace=NAMESPACE, parameter_overrides=[
        Parameter("output_dir", value=str(tmp_path / "out")),
        Parameter("resolution", value=16), Parameter("hull_rate_hz", value=0.0)])
    probe.executor.add_node(node)
    try:
        reports = probe.node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        reset = probe.node.create_client(Trigger, SERVICES["reset"])

        def call_reset():
            probe.spin_until(reset.service_is_ready, what="reset service")
            future = reset.call_async(Trigger.Request())
            probe.spin_until(future.done, what="reset answer")
            return future.result()

        def report(state):
            def reported():
                reports.publish(_scan_report(state))
                return node._rig.scan_in((state,)) is not None
            probe.spin_until(reported, what=f"scan {state}")

        # A scan's first view opens its folder, marked open.
        live = node._scan.live
        node._submit("view", live.add_view, "v0",
                     np.ones((live.calibration.height, live.calibration.width), bool),
                     0.0, 0.3).result()
        folder = node._scan.live.session_dir
        assert (folder / OPEN_MARKER).exists()
        for state in ("running", "waiting", "paused"):
            report(state)
            answer = call_reset()
            assert not answer.success and f"scan 4 {state}" in answer.message, answer.message
            assert node._scan.live.session_dir == folder and node._scan.live.n_views == 1
        report("done")
        # New per-scan settings: the reset builds a new live reconstruction; the old scan's
        # folder is no longer marked open.
        assert node.set_parameters([Parameter("resolution", value=20)])[0].successful
        assert call_reset().success
        assert not (folder / OPEN_MARKER).exists()
        assert not list((tmp_path / "out").glob(f"*/{OPEN_MARKER}"))
        # Class 18 too: a box is checked when it is set, the old one kept.
        for box in ([-1e300, -1e300, 0.0, 1e300, 1e300, 1e300],
                    [0.0, 0.0, 0.0, 1e-300, 1e-300, 1e-300]):
            result = node.set_parameters([Parameter("bounds_m", value=box)])[0]
            assert not result.successful and "bounds_m" in result.reason, result.reason
        assert node.get_parameter("bounds_m").value == [-0.1, -0.1, 0.0, 0.1, 0.1, 0.2]
    finally:
        probe.executor.remove_node(node)
        node.destroy_node()
        probe.close()


# ---- class 14: a parameters file rcl cannot parse ----------------------------------------

@pytest.mark.parametrize("text", ["a: [unclosed\n  b: :\n",
                                  "/**:\n  ros__parameters:\n    fx: [1, \"a\"]\n"])
def test_class_14_a_parameters_file_rcl_cannot_parse_is_one_line_and_no_restart(tmp_path, text):
    path = tmp_path / "params.yaml"
    path.write_text(text)
    done = subprocess.run([sys.executable, "-m", "sfs_ros.nodes.motor_node", "--ros-args",
                           "--params-file", str(path)], capture_output=True, text=True,
                          env=ENV, cwd=tmp_path, timeout=120)
    lines = done.stderr.splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert ": configuration error: " in lines[0]
    assert str(path) in lines[0] and "parse.c" not in lines[0]
    # The supervisor does not start a node again that refused its configuration.
    cell = Cell([ScriptSpec("refuser", [sys.executable, "-c", "raise SystemExit(2)"])],
                log=None).start()
    log = io.StringIO()
    status = wait_until_signal(cell, policy=RestartPolicy(first_delay_s=0.01),
                               stopping=threading.Event(), log=log)
    assert status == 2 and "restarting it in" not in log.getvalue()
    assert "node refuser refused its configuration" in log.getvalue()


# ---- class 15: CellClient without a cell ---------------------------------------------------

def test_class_15_a_cell_client_closes_cleanly_without_a_cell():
    code = ("from sfs_ros.ros.cell_client import CellClient\n"
            f"with CellClient(namespace='/round_three_{os.getpid()}'):\n    pass\n"
            "print('closed')\n")
    for _ in range(3):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              env=ENV, timeout=120)
        assert done.returncode == 0 and done.stdout == "closed\n", done.stderr[-2000:]
        assert "terminate called" not in done.stderr


# ---- class 16: a bad message is a rejected view; metadata; a huge board square -----------

def test_class_16_a_corrupt_message_is_a_rejected_view_and_the_rest_is_used(tmp_path):
    messages = mask_messages(sphere_views())
    for n, corrupt in enumerate([lambda d: d[:20], lambda d: b"\x00\x01\x00\x00" + d[4:30],
                                 lambda d: b""]):
        edited = list(messages)
        edited[4] = (edited[4][0], corrupt(edited[4][1]))
        folder = tmp_path / f"bag{n}"
        write_bag(folder, [(PARAMETERS_TOPIC, parameters_message(document())), *edited])
        views = read_bag(folder)
        assert len(views.views) == len(sphere_views()) - 1
        reasons = dict(views.rejected)
        assert any(name.startswith("capture/mask at ") and "not a valid" in reason
                   for name, reason in reasons.items()), reasons
    folder = tmp_path / "bag0"
    meta = yaml.safe_load((folder / "metadata.yaml").read_text())
    meta["rosbag2_bagfile_information"]["files"] = {"a": 1}
    (folder / "metadata.yaml").write_text(yaml.safe_dump(meta))
    assert len(read_bag(folder).views) == len(sphere_views()) - 1
    # An SQLite bag is read through its metadata.yaml: damaged, the bag is refused naming
    # the bag and the field, not with the reader's KeyError.
    sqlite = tmp_path / "sqlite"
    write_bag(sqlite, [(PARAMETERS_TOPIC, parameters_message(document())), *messages],
              storage="sqlite3")
    good = (sqlite / "metadata.yaml").read_text()
    info = "rosbag2_bagfile_information"
    damages = {
        lambda i: i.pop("duration"): f"{info}.duration is missing",
        lambda i: i.update(starting_time=5): f"{info}.starting_time is 5, expected a mapping",
        lambda i: i.update(version="x"): f"{info}.version is 'x', expected a whole number 1..9",
        lambda i: i["topics_with_message_count"][0]["topic_metadata"].pop("type"):
            f"{info}.topics_with_message_count[0].topic_metadata.type is missing",
        lambda i: i.update(relative_file_paths=["other.db3"]):
            f"{info}.relative_file_paths names 'other.db3', which is not a file in the bag's "
            "folder",
        lambda i: i.update(storage_identifier=5):
            f"{info}.storage_identifier is 5, expected 'sqlite3' or 'mcap'"}
    for damage, words in damages.items():
        meta = yaml.safe_load(good)
        damage(meta[info])
        (sqlite / "metadata.yaml").write_text(yaml.safe_dump(meta))
        status, lines, _ = reconstruct([sqlite, "-o", tmp_path / "s.ply", *FAST])
        assert status == 2 and lines == [
            f"sfs-reconstruct: error: bag {sqlite}: its metadata.yaml is damaged: {words} (the "
            "storage file is read through it; ros2 bag reindex writes it again)"], lines
    for square in (1e300, float("inf"), 1e-300):
        with pytest.raises(ValueError, match="square_m"):
            BoardSpec(square_m=square, marker_m=min(square / 2, 0.01))


# ---- class 17: -r overrides a bag's resolution; one range --------------------------------

RESOLUTION_RANGE = RESOLUTION.bounds


def test_class_17_the_command_line_resolution_overrides_the_bags_within_one_range(tmp_path):
    from sfs_ros.cell_logic.mesh_options import mesh_options
    from sfs_ros.nodes.carving_node import PARAMS

    node_range = next(p.bounds for p in PARAMS if p.name == "resolution")
    assert tuple(node_range) == RESOLUTION_RANGE
    with pytest.raises(ValueError, match=f"outside \\[{RESOLUTION_RANGE[0]}, {RESOLUTION_RANGE[1]}\\]"):
        mesh_options(tmp_path, resolution=RESOLUTION_RANGE[1] + 1)
    with pytest.raises(ValueError, match=f"{RESOLUTION_RANGE[0]}..{RESOLUTION_RANGE[1]}"):
        ReconstructionParams(resolution=RESOLUTION_RANGE[1] + 1)
    high = RESOLUTION_RANGE[1]
    folder = bag(tmp_path / "bag", sphere_views(),
                 lambda d: d["reconstruction"].update(resolution=high))
    status, lines, report = reconstruct([folder, "-o", tmp_path / "m.ply", "-r", "24", "-q"])
    assert status == 0, lines
    assert max(report["grid"]["shape"]) <= 26


# ---- class 18: boxes checked when set -----------------------------------------------------

@pytest.mark.parametrize("box", [[[-1e300] * 3, [1e300] * 3], [[0.0] * 3, [1e-300] * 3],
                                 [[1e7, 0, 0], [1e7 + 1, 1, 1]]])
def test_class_18_a_box_beyond_any_grid_is_refused_when_set(box):
    with pytest.raises(ViewError, match="expected sides"):
        as_bounds(box, what="bounds_m")


def test_class_18_negative_bounds_are_numbers_and_a_box_far_too_large_is_named(base,
                                                                                tmp_path):
    """``--bounds -1e4 ...`` is six numbers, not an option (argparse once read ``-1e4`` as
    one); the box they give, far larger than the cameras see, is refused for that."""
    box = ["-6e-2", "-6e-2", "0", "6e-2", "6e-2", "1.1e-1"]
    status, lines, report = reconstruct([base, "-o", tmp_path / "m.ply", "--bounds", *box,
                                         *FAST])
    assert status == 0, lines
    assert report["grid"]["bounds_source"] == "given"
    assert report["grid"]["bounds_m"][0] == [-0.06, -0.06, 0.0]
    status, lines, _ = reconstruct([base, "-o", tmp_path / "m.ply", "--bounds", "-1e4", "-1e4",
                                    "-1e4", "1e4", "1e4", "1e4", *FAST])
    assert status == 2 and len(lines) == 1, lines
    assert "the resolution asked for (833.3 m voxels) is wider than the cameras see at the " \
        "box's centre (about 0.315 m across" in lines[0] and "expected a box around the " \
        "object" in lines[0], lines
    status, lines, _ = reconstruct([base, "-o", tmp_path / "m.ply", "--bounds", "-inf", "0",
                                    "0", "1", "1", "1", *FAST])
    assert status == 2 and "with finite min < max" in lines[0], lines


# ---- class 19: unclear answers --------------------------------------------------------------

def test_class_19_options_that_cannot_be_met_are_named(base, tmp_path):
    cases = {("--block", "100000", "-m", "advancing-front"): "block (M) 100000",
             ("--preview", tmp_path / "p.jpg"): "--preview",
             ("--contact-sheet", tmp_path / "s.jpeg"): "--contact-sheet",
             ("--html", tmp_path / "v.png"): "--html"}
    for options, words in cases.items():
        status, lines, _ = reconstruct([base, "-o", tmp_path / "m.ply", *options, *FAST])
        assert status == 2 and len(lines) == 1 and words in lines[0], (options, lines)
    assert not (tmp_path / "p.jpg").exists() and not (tmp_path / "m.ply").exists()
    # A grid over the voxel cap is refused for that, not for the memory it would fit in.
    status, lines, _ = reconstruct([base, "-o", tmp_path / "m.ply", "--voxel-size", "0.00005",
                                    "--max-memory", "900G", "-q"])
    assert status == 2 and len(lines) == 1, lines
    assert "needs 177.21 GiB and has more than the 1074 M voxels a grid may have" in lines[0]
    assert "--max-memory" not in lines[0] and "coarser resolution" in lines[0]
    # A voxel larger than the box: what was asked, the box, and the largest voxel it takes.
    for size, voxels in (("1e3", "0.000116"), ("0.05", "2.33")):
        status, lines, _ = reconstruct([base, "-o", tmp_path / "m.ply", "--voxel-size", size,
                                        "-q"])
        assert lines == [f"sfs-reconstruct: error: the voxel size asked for ({float(size):g} m) "
                         f"is too coarse for the carving box: its longest side is 0.1163 m, "
                         f"{voxels} voxel(s); expected voxels of at most 0.01453 m (at least "
                         f"{RESOLUTION_RANGE[0]} along the box's longest side)"], lines
    status, lines, _ = reconstruct([base, "-o", tmp_path / "m.ply", "--voxel-size", "inf", "-q"])
    assert lines == ["sfs-reconstruct: error: voxel size must be a finite number of metres > 0, "
                     "got inf"], lines


def test_class_19_a_message_names_the_destination_and_no_stale_report_is_left(base, tmp_path):
    """-o names a folder: the error names it (not a temporary file beside it), and the
    report of an earlier run is gone rather than describing a mesh that was not written."""
    (tmp_path / "m.ply").mkdir()
    (tmp_path / "m.report.json").write_text('{"output": "an earlier mesh"}')
    status, lines, _ = reconstruct([base, "-o", tmp_path / "m.ply", *FAST])
    assert status == 2 and len(lines) == 1, lines
    assert f"Is a directory: '{tmp_path / 'm.ply'}'" in lines[0] and ".tmp" not in lines[0]
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]


# ---- the fuzz suite: COLMAP models and bags --------------------------------------------------

def test_round_three_cases_through_the_fuzz_driver(base, board_scene, tmp_path):
    c = Cases(tmp_path / "cases", base)

    def board(case: str, edits: dict, *options, expect=OK):
        """sfs-calibrate on every other view of the board scene, ``edits`` {view: angles}."""
        angles = [edits.get(i, pair) for i, pair in enumerate(board_scene.angles)]
        folder = write_board_session(c.folder() / "board", board_scene,
                                     range(0, len(angles), 2), angles)
        c.add(case, [folder, "-o", c.root / "out" / f"calibration{len(c.cases)}", *options],
              tool="calibrate", expect=expect)

    theta, phi = board_scene.angles[4]
    board("10: calibrate, a view 90 degrees off", {4: (theta + np.pi / 2, phi)},
          expect="view_004.png")
    board("10: calibrate, a view at theta 1e308", {4: (1e308, phi)}, expect="view_004.png")
    board("10: calibrate, a view at theta nan", {4: (float("nan"), phi)}, expect="view_004.png")
    board("10: calibrate, a view at phi -1e308", {4: (theta, -1e308)}, expect="view_004.png")
    board("10: calibrate, every angle nan",
          {i: (float("nan"), float("nan")) for i in range(len(board_scene.angles))},
          expect=REFUSED)
    for value in ("nan", "-1", "inf"):
        board(f"19: calibrate --max-view-rms-px {value}", {}, "--max-view-rms-px", value,
              expect=REFUSED)
    board("16: calibrate --square-m 1e300", {}, "--square-m", "1e300", expect=REFUSED)
    names = [v.name for v in read_session(base).views]
    c.add("8: one view", [session_of(base, c.folder(), names[:1])])
    c.add("8: copies of one view", [session_of(base, c.folder(), names[:1] * 13)])
    c.add("8: bag, last scan two views", [bag(c.folder() / "bag", sphere_views()[-2:])])
    c.add("8: holdout leaving one", [c.session(), "--holdout",
                                     ",".join(str(n) for n in range(1, len(names)))])
    for case, edit in {"11: no points lines": lambda ls: [x for x in ls if len(x.split()) >= 10],
                       "11: stray blank line": lambda ls: ls[:3] + [""] + ls[3:]}.items():
        folder = colmap_model(base, c.folder())
        path = folder / "images.txt"
        path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")
        c.add(case, [folder], expect=OK)
    for k1 in ("999", "-999", "nan"):
        folder = colmap_model(base, c.folder())
        cameras = folder / "cameras.txt"
        fields = cameras.read_text().splitlines()[-1].split()
        cameras.write_text(" ".join([fields[0], "OPENCV", *fields[2:4], fields[4], fields[4],
                                     *fields[5:7], k1, "0", "0", "0"]) + "\n")
        c.add(f"12: OPENCV k1 {k1}", [folder])
    messages = mask_messages(sphere_views())
    edited = list(messages)
    edited[4] = (edited[4][0], edited[4][1][:20])
    folder = c.folder() / "bag"
    write_bag(folder, [(PARAMETERS_TOPIC, parameters_message(document())), *edited])
    c.add("16: a corrupt message", [folder], expect=OK)
    c.add("17: bag at the highest resolution, -r 24",
          [bag(c.folder() / "bag", sphere_views(),
               lambda d: d["reconstruction"].update(resolution=RESOLUTION_RANGE[1]))],
          expect=OK)
    for box in (["0", "0", "0", "1e300", "1e300", "1e300"],
                ["0", "0", "0", "1e-300", "1e-300", "1e-300"]):
        c.add(f"18: --bounds {box[3]}", [c.session(), "--bounds", *box])
    c.add("19: --block 100000", [c.session(), "--block", "100000", "-m", "advancing-front"])
    c.add("19: --preview p.jpg", [c.session(), "--preview", tmp_path / "p.jpg"])
    (tmp_path / "a_folder.ply").mkdir()
    c.add("19: -o names a folder", [c.session(), "-o", tmp_path / "a_folder.ply", *FAST])
    spec = tmp_path / "cases.json"
    inputs = sorted(str(p) for p in (tmp_path / "cases").glob("case*"))
    spec.write_text(json.dumps({"watched": [], "inputs": inputs, "cases": c.cases}))
    results = tmp_path / "results.json"
    done = subprocess.run([sys.executable, str(HERE / "fuzz_driver.py"), str(spec), str(results)],
                          cwd=ROOT, capture_output=True, text=True, env=ENV, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    found = failures(c.cases, json.loads(results.read_text())["results"])
    assert not found, "\n".join(found)
