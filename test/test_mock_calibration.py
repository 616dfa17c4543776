"""Calibration in the mock hardware's wrong world, and the accuracy it wins back.

The mock hardware as ``sfs-mock-hardware`` builds it from the repository's
``config/rig.yaml``, ``mock_hardware.yaml`` and ``mock_wrong_world.yaml``: the
simulated GRBL controller on its pseudo-terminal, driven by the motor driver
(:class:`GrblClient`, as the motor node drives it), and the mock camera
(:class:`RenderedSource`) rendering at the controller's true angles through the
world's rig. Each view is tagged with the encoders' read-back after the move, as
the scan node tags it. In-process, without ROS: the ROS cell adds transport, not
geometry, and 3 x 49 + 28 views through it would take minutes.

1. The ChArUco board on the plate, scanned with ``config/calibration_plan.yaml``
   into a session, calibrated by ``sfs-calibrate``: each parameter against the
   world that rendered it (in the solver's gauge, :func:`canonical`).
2. The mug scanned with ``config/scan_plan.yaml`` in the wrong world and
   reconstructed with the nominal ``rig.yaml`` and with the calibrated one, and
   scanned in a perfect world (the rig as given, no encoder offsets): volume IoU
   against the true mug. ``-s`` prints the figures (doc/calibration.md).
"""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from sfs_ros.cell_logic.scan_plan import load_plan
from sfs_ros.cli import calibrate as cli
from sfs_ros.core.calibration import canonical
from sfs_ros.core.exchange.session import read_session, write_session
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import carving_box, score_against_truth
from sfs_ros.hardware.cameras import RenderedSource
from sfs_ros.hardware.driver import GrblClient
from sfs_ros.hardware.mock_world import mock_scene, world_rig
from sfs_ros.hardware.simulator import SimulatedGrbl
from sfs_ros.ros.rig_params import rig_calibration

from tolerances import HANG_S

pytestmark = pytest.mark.slow

CONFIG = Path(__file__).resolve().parent.parent / "config"
DEG = math.pi / 180

# The acceptance bar of the calibration (what carving needs), with what this world gives
# (error; the fit's own standard uncertainty). The principal point is the weak parameter:
# through a 26 degree lens a camera turned on its carriage looks almost like a shifted
# principal point, which only the image's corners tell apart.
INTRINSICS_REL = 0.005     # 0.5 %: fx, fy ~0.01 %; cx -0.16 % to +0.15 % over ten noise
#                            draws (fit: 0.1 %), cy -0.14 % to +0.24 % (0.09 %)
#                            (doc/calibration.md)
K1_ABS = 0.01              # k1: ~0.001 (0.0014)
AXIS_POINT_M = 0.5e-3      # ~0.01 mm (0.006 mm)
ANGLE_RAD = 0.1 * DEG      # tilt and encoder zeros: ~0.002 degree (0.0007)
# A calibrated scan carves as well as a scan of a perfect world: the same views of the
# same mug, through a lens that resamples the silhouettes (edge pixels) and read-backs
# with the same 0.01 degree of noise.
WIN_IOU = 0.01
RESOLUTION = 128


def _params(*names: str) -> dict:
    values = {}
    for name in names:
        values.update(yaml.safe_load((CONFIG / name).read_text())["/**"]["ros__parameters"])
    return values


@pytest.fixture(scope="module")
def cell():
    """The nominal rig (what the cell believes), and the wrong world's settings."""
    mock = _params("mock_hardware.yaml", "mock_wrong_world.yaml")
    nominal = rig_calibration(_params("rig.yaml"))
    assert mock["world"] == "wrong"
    return {"nominal": nominal, "mock": mock, "world": world_rig(nominal, mock["world"])}


def _scan(scene_name: str, world, mock: dict, plan_file: str, *, offsets_deg, seed: int):
    """``(images, readings)``: ``scene_name`` seen through ``world`` at every view of the
    plan, the controller's read-back off by ``offsets_deg``; readings in radians."""
    simulator = SimulatedGrbl(max_speed_deg_s=(3600.0, 3600.0), accel_deg_s2=(1e5, 1e5),
                              encoder_offset_deg=offsets_deg,
                              encoder_noise_deg=mock["encoder_noise_deg"], start_locked=False,
                              seed=seed).start()
    scene = mock_scene(scene_name, background_rgb=mock["background_rgb"])
    camera = RenderedSource(scene, world, simulator.true_position_rad,
                            background_rgb=mock["background_rgb"],
                            noise_sigma=mock["image_noise"], seed=seed)
    images, readings = [], []
    try:
        with GrblClient(simulator.port, timeout_s=HANG_S, poll_interval_s=0.01) as motors:
            for n, (theta, phi) in enumerate(load_plan(CONFIG / plan_file).views):
                motors.move_to(theta, phi, timeout_s=HANG_S)
                images.append((f"view_{n:03d}.png", camera.grab()))
                status = motors.status()
                readings.append((status.theta_rad, status.phi_rad))
    finally:
        simulator.close()
    return images, readings


@pytest.fixture(scope="module")
def calibrated(cell, tmp_path_factory):
    """``sfs-calibrate`` on the board scanned in the wrong world; the truth to compare with."""
    mock = cell["mock"]
    images, readings = _scan("board", cell["world"], mock, "calibration_plan.yaml",
                             offsets_deg=mock["encoder_offset_deg"], seed=3)
    folder = write_session(tmp_path_factory.mktemp("board") / "session", images, readings,
                           cell["nominal"])
    out = tmp_path_factory.mktemp("calibration")
    assert cli.main([str(folder), "-o", str(out), "--board", "9x7"]) == 0
    values = yaml.safe_load((out / "rig.yaml").read_text())["/**"]["ros__parameters"]
    zeros = np.radians(mock["encoder_offset_deg"])
    true_rig = replace(cell["world"], theta_zero_rad=cell["world"].theta_zero_rad + zeros[0],
                       phi_zero_rad=cell["world"].phi_zero_rad + zeros[1])
    truth = canonical(true_rig, mock_scene("board").pose)[0]
    return {"rig": rig_calibration(values), "truth": truth, "file": out / "rig.yaml",
            "report": yaml.safe_load((out / "calibration_report.yaml").read_text())}


def test_the_wrong_world_is_wrong(cell):
    world, nominal = cell["world"], cell["nominal"]
    assert any(world.distortion) and not world.is_ideal
    assert world.fx != nominal.fx and nominal.is_ideal and not any(nominal.distortion)
    assert abs(world.theta_zero_rad - nominal.theta_zero_rad) > 1 * DEG
    assert abs(world.phi_zero_rad - nominal.phi_zero_rad) > 1 * DEG


def test_calibration_recovers_the_intrinsics(calibrated):
    rig, truth = calibrated["rig"], calibrated["truth"]
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(rig, name) == pytest.approx(getattr(truth, name), rel=INTRINSICS_REL)
    assert rig.distortion[0] == pytest.approx(truth.distortion[0], abs=K1_ABS)


def test_calibration_recovers_the_axis_and_the_encoder_zeros(calibrated):
    rig, truth = calibrated["rig"], calibrated["truth"]
    np.testing.assert_allclose(rig.axis_point_m, truth.axis_point_m, atol=AXIS_POINT_M)
    assert rig.axis_tilt_y_rad == pytest.approx(truth.axis_tilt_y_rad, abs=ANGLE_RAD)
    assert rig.theta_zero_rad == pytest.approx(truth.theta_zero_rad, abs=ANGLE_RAD)
    assert rig.phi_zero_rad == pytest.approx(truth.phi_zero_rad, abs=ANGLE_RAD)


def test_only_views_without_the_board_are_rejected(calibrated):
    # At 75 degrees of turntable and carriage the board is seen too obliquely for its
    # markers to be read: those views are named, every other is used.
    report = calibrated["report"]
    assert len(report["view_rms_px"]) + len(report["rejected"]) == 66
    assert len(report["rejected"]) <= 6
    for name, reason in report["rejected"].items():
        assert reason.startswith(("no marker", "only ")), (name, reason)


@pytest.fixture(scope="module")
def win(cell, calibrated, tmp_path_factory):
    """Volume IoU against the true mug: wrong world with the nominal and the calibrated rig,
    and a perfect world."""
    mock, obj = cell["mock"], make_object("mug")
    params = ReconstructionParams(resolution=RESOLUTION)

    def iou(images, readings, rig, name):
        folder = write_session(tmp_path_factory.mktemp(name) / "session", images, readings,
                               rig, bounds_m=carving_box(obj))
        result = reconstruct(read_session(folder), params)
        return score_against_truth(obj, result.vertices, result.faces, result.grid)["volume_iou"]

    wrong = _scan("mug", cell["world"], mock, "scan_plan.yaml",
                  offsets_deg=mock["encoder_offset_deg"], seed=5)
    perfect = _scan("mug", cell["nominal"], mock, "scan_plan.yaml", offsets_deg=(0.0, 0.0),
                    seed=5)
    figures = {"nominal": iou(*wrong, cell["nominal"], "nominal"),
               "calibrated": iou(*wrong, calibrated["rig"], "calibrated"),
               "perfect": iou(*perfect, cell["nominal"], "perfect")}
    print(f"\nvolume IoU against the true mug at {RESOLUTION}^3, {len(wrong[0])} views: wrong "
          f"world with the nominal rig.yaml {figures['nominal']:.4f}, with the calibrated "
          f"rig.yaml {figures['calibrated']:.4f}; perfect world {figures['perfect']:.4f}")
    return figures


def test_the_calibrated_rig_scans_as_well_as_a_perfect_world(win):
    assert win["calibrated"] == pytest.approx(win["perfect"], abs=WIN_IOU)


def test_the_nominal_rig_loses_accuracy_in_the_wrong_world(win):
    # What calibration wins back: several times the calibrated scan's gap.
    assert win["nominal"] < win["calibrated"] - 3 * WIN_IOU
