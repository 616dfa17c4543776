"""Calibrating the mock cell as a user would: scan the board, then ``sfs-calibrate`` the bag.

The whole mock cell (:mod:`mock_cell`) with the repository's
``config/mock_wrong_world.yaml`` on the mock hardware and ``object: board``,
the camera at the repository's 640 x 480 (the board's markers need the
pixels), ``config/calibration_plan.yaml`` as the scan node's plan, and the
recorder recording the scan. ``sfs-calibrate BAG`` must recover the world the
mock rendered (the same bars as :mod:`test_mock_calibration`, which checks
every parameter in-process and measures the accuracy it wins back).
"""

import json
import math
import subprocess
import sys
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from std_srvs.srv import Trigger

from sfs_ros.core.calibration import canonical
from sfs_ros.hardware.mock_world import mock_scene, world_rig
from sfs_ros.ros.names import SERVICES
from sfs_ros.ros.rig_params import rig_calibration
from sfs_ros.ros.services import call

from mock_cell import CONFIG, SCAN_TIMEOUT_S, running_cell
from ros_harness import SOURCE_ROOT, RosProbe

DEG = math.pi / 180
INTRINSICS_REL = 0.005      # the acceptance bars (test_mock_calibration gives the figures)
K1_ABS = 0.01
AXIS_POINT_M = 0.5e-3
ANGLE_RAD = 0.1 * DEG


def _values(name: str) -> dict:
    return yaml.safe_load((CONFIG / name).read_text())["/**"]["ros__parameters"]


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    """The board scanned and recorded by the mock cell in the wrong world, calibrated."""
    root = tmp_path_factory.mktemp("calibration_cell")
    rig = {k: _values("rig.yaml")[k] for k in ("width", "height", "fx", "fy")}
    overrides = {"rig.yaml": rig,
                 "mock_hardware.yaml": {**_values("mock_wrong_world.yaml"), "object": "board"}}
    plan = yaml.safe_load((CONFIG / "calibration_plan.yaml").read_text())
    with running_cell(root, "calibration_cell_client", overrides=overrides, plan=plan) as up:
        probe = RosProbe("calibration_cell_probe")
        services = {n: probe.node.create_client(Trigger, SERVICES[f"record/{n}"])
                    for n in ("start", "stop")}
        threading.Thread(target=probe.executor.spin, daemon=True).start()
        try:
            answer = call(services["start"], Trigger.Request(), timeout_s=60.0)
            assert answer.success, answer.message
            bag = Path(json.loads(answer.message)["path"])
            client = up["client"]
            client.wait_scan_done(client.start_scan(), timeout_s=SCAN_TIMEOUT_S)
            answer = call(services["stop"], Trigger.Request(), timeout_s=60.0)
            assert answer.success, answer.message
        finally:
            probe.close()
        config = yaml.safe_load((root / "config" / "mock_hardware.yaml").read_text())
    out = root / "calibrated"
    done = subprocess.run([sys.executable, "-m", "sfs_ros.cli.calibrate", str(bag), "-o",
                           str(out), "--board", "9x7"], cwd=SOURCE_ROOT, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    nominal = rig_calibration({**_values("rig.yaml"), **rig})
    mock = config["/**"]["ros__parameters"]
    world = world_rig(nominal, mock["world"])
    zeros = np.radians(mock["encoder_offset_deg"])
    world = replace(world, theta_zero_rad=world.theta_zero_rad + zeros[0],
                    phi_zero_rad=world.phi_zero_rad + zeros[1])
    values = yaml.safe_load((out / "rig.yaml").read_text())["/**"]["ros__parameters"]
    return {"rig": rig_calibration(values), "stdout": done.stdout,
            "truth": canonical(world, mock_scene("board").pose)[0]}


def test_the_recorded_board_scan_calibrates_the_cell(calibration):
    rig, truth = calibration["rig"], calibration["truth"]
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
