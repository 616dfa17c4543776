"""Calibrating the mock cell as ``doc/calibration.md`` tells a user to, then applying it.

The ``sh`` blocks of the doc's section "A calibration scan in the cell" run as they
stand, in a temporary folder holding a copy of the repository's ``config`` and the venv
(``.venv``, its ``bin`` also on ``PATH``): the first brings the mock cell up in the wrong
world with the board on the plate and the recorder recording (its ``sfs-cell`` line in
the background); the board's scan (object ``board``: on ``calibration/*``, which
``sfs-calibrate BAG`` reads) is a Scan goal through :class:`CellClient`, as the doc says; the
second block calibrates from the recorded bag and applies the result to the running cell
(``--apply``).

Checked: ``sfs-calibrate`` recovers the world the mock rendered (the bars of
:mod:`test_mock_calibration`, which checks every parameter in-process and measures the
accuracy it wins back); every node that holds the rig now has the calibrated file's
values; the rig is kept in ``out/calib/calibration/rig.yaml``; a carving node
stopped and started again by ``sfs-cell`` comes back with it; applying logs no ERROR,
and the cell stops cleanly.
"""

import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from sfs_ros.core.calibration import canonical
from sfs_ros.hardware.mock_world import mock_scene, world_rig
from sfs_ros.ros.cell_client import CellClient
from sfs_ros.ros.rig_params import RIG_PARAMS, rig_calibration

from ros_harness import SOURCE_ROOT, STARTUP_TIMEOUT_S
from waiting import wait

pytestmark = pytest.mark.cell

REPO = Path(__file__).resolve().parent.parent
DOC = REPO / "doc" / "calibration.md"
SECTION = "## A calibration scan in the cell"
DEG = math.pi / 180
INTRINSICS_REL = 0.005      # the acceptance bars (test_mock_calibration gives the figures)
K1_ABS = 0.01
AXIS_POINT_M = 0.5e-3
ANGLE_RAD = 0.1 * DEG
#: Deadlines that only bound a hang: 66 views at the repository's axis speeds on a loaded
#: 2-core machine, the calibration, a node's start-up.
SCAN_TIMEOUT_S = 900.0
COMMAND_TIMEOUT_S = 600.0
NAMESPACE = "/sfs"          # the doc's sfs-cell line: the default namespace
ANSWER_S = 5.0              # a parameter request not answered this long is sent again


def doc_blocks() -> list[list[str]]:
    """The lines of each ``sh`` block of the doc's calibration-scan section (up to its
    first sub-heading)."""
    section = DOC.read_text().split(SECTION, 1)[1]
    section = re.split(r"\n#{2,3} ", section, maxsplit=1)[0]
    return [block.strip().splitlines()
            for block in re.findall(r"```sh\n(.*?)```", section, flags=re.S)]


def _values(path: Path) -> dict:
    return yaml.safe_load(path.read_text())["/**"]["ros__parameters"]


def _rig_of(client: CellClient, node: str) -> dict:
    """The rig parameters of ``node`` (a name in the cell), asked until it answers."""
    parameters = AsyncParameterClient(client.node, f"{NAMESPACE}/{node}")
    names = [p.name for p in RIG_PARAMS]
    answers = []

    def answered() -> bool:
        """Ask once; an answer not come within ANSWER_S is asked for again (Fast DDS may
        drop the answer to a client it has just matched)."""
        if not parameters.services_are_ready():
            return False
        future = parameters.get_parameters(names)
        deadline = time.monotonic() + ANSWER_S
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.02)
        if future.done():
            answers.append(future.result())
        return bool(answers)

    wait(answered, what=f"the parameter services of {node}", timeout=STARTUP_TIMEOUT_S)
    values = [parameter_value_to_python(v) for v in answers[0].values]
    return {n: list(v) if isinstance(v, (list, tuple)) or hasattr(v, "tolist") else v
            for n, v in zip(names, values)}


def _pids(*patterns: str) -> set[int]:
    """Processes whose command line (arguments joined by spaces) holds every pattern."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            args = (entry / "cmdline").read_bytes().decode(errors="replace").replace("\0", " ")
        except OSError:                                      # ended meanwhile
            continue
        if all(pattern in args for pattern in patterns):
            found.add(int(entry.name))
    return found


def _restart_carving(client: CellClient, output: Path) -> dict:
    """Stop this cell's carving node (SIGTERM): ``sfs-cell`` starts it again. The
    rig of the new process."""
    ours = (f"sfs_ros.nodes.carving_node --ros-args -r __ns:={NAMESPACE}",
            f"output_dir:={output}")
    running = _pids(*ours)
    assert len(running) == 1, running
    os.kill(next(iter(running)), signal.SIGTERM)
    wait(lambda: _pids(*ours) - running, what="the carving node started again",
         timeout=STARTUP_TIMEOUT_S)
    return _rig_of(client, "carving")


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    """The doc's commands run through: the calibration, the rigs the nodes hold after it,
    and the cell's log."""
    root = tmp_path_factory.mktemp("calibration_cell")
    (root / ".venv").symlink_to(Path(sys.prefix))
    shutil.copytree(REPO / "config", root / "config")
    env = dict(os.environ, PATH=os.pathsep.join([str(Path(sys.prefix) / "bin"),
                                                 os.environ.get("PATH", "")]),
               PYTHONPATH=str(SOURCE_ROOT))
    bring_up, calibrate = doc_blocks()
    assert "sfs-cell" in bring_up[-1]
    subprocess.run(["bash", "-ec", "\n".join(bring_up[:-1])], cwd=root, env=env, check=True,
                   timeout=60)
    log_path = root / "cell.log"
    output = root / "out" / "calib"
    with open(log_path, "w") as log:
        cell = subprocess.Popen(["bash", "-c", f"exec {bring_up[-1]}"], cwd=root, env=env,
                                stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    result = {"log": log_path}
    try:
        with CellClient(NAMESPACE, name="calibration_cell_client") as client:
            client.wait_ready(timeout_s=STARTUP_TIMEOUT_S)
            client.scan_goal(object="board", timeout_s=SCAN_TIMEOUT_S)   # the doc's
            scanned = len(log_path.read_text())
            done = subprocess.run(["bash", "-ec", "\n".join(calibrate)], cwd=root, env=env,
                                  capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
            assert done.returncode == 0, done.stderr + log_path.read_text()[-5000:]
            result["stdout"] = done.stdout
            result["held"] = {node: _rig_of(client, node)
                              for node in ("carving", "camera")}
            result["apply_log"] = log_path.read_text()[scanned:]
            result["restarted"] = _restart_carving(client, output.resolve())
    finally:
        cell.send_signal(signal.SIGINT)
        result["exit"] = cell.wait(timeout=120)
    mock = _values(root / "calib_config" / "mock_hardware.yaml")
    world = world_rig(rig_calibration(mock["world_rig"]), mock["world"])
    zeros = np.radians(mock["encoder_offset_deg"])
    world = replace(world, theta_zero_rad=world.theta_zero_rad + zeros[0],
                    phi_zero_rad=world.phi_zero_rad + zeros[1])
    result.update(file=_values(root / "calibration" / "rig.yaml"),
                  kept=_values(output / "calibration" / "rig.yaml"),
                  truth=canonical(world, mock_scene("board").pose)[0])
    return result


def test_the_recorded_board_scan_calibrates_the_cell(calibration):
    rig, truth = rig_calibration(calibration["file"]), calibration["truth"]
    # 66 views planned; the few where the board is too oblique to read are named.
    used = int(calibration["stdout"].split(" views,")[0])
    assert 60 <= used <= 66 and calibration["stdout"].count("rejected ") == 66 - used
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(rig, name) == pytest.approx(getattr(truth, name), rel=INTRINSICS_REL)
    assert rig.distortion[0] == pytest.approx(truth.distortion[0], abs=K1_ABS)
    np.testing.assert_allclose(rig.axis_point_m, truth.axis_point_m, atol=AXIS_POINT_M)
    assert rig.axis_tilt_y_rad == pytest.approx(truth.axis_tilt_y_rad, abs=ANGLE_RAD)
    assert rig.theta_zero_rad == pytest.approx(truth.theta_zero_rad, abs=ANGLE_RAD)
    assert rig.phi_zero_rad == pytest.approx(truth.phi_zero_rad, abs=ANGLE_RAD)


def test_the_calibration_is_applied_to_the_running_cell_and_kept(calibration):
    applied = calibration["stdout"].split("applied to ", 1)[1].splitlines()[0]
    assert f"{NAMESPACE}/carving" in applied and f"{NAMESPACE}/camera" in applied
    for node, held in calibration["held"].items():
        assert held == calibration["file"], node
    assert calibration["kept"] == calibration["file"]


def test_a_node_started_again_keeps_the_applied_rig(calibration):
    assert calibration["restarted"] == calibration["file"]
    assert "sfs-cell: carving starts with the rig applied last" \
        in calibration["log"].read_text()


def test_applying_logs_no_error_and_the_cell_stops_cleanly(calibration):
    errors = [line for line in calibration["apply_log"].splitlines() if "[ERROR]" in line]
    assert not errors, errors
    assert calibration["exit"] == 0, calibration["log"].read_text()[-5000:]
