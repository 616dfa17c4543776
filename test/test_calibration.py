"""Calibrating the cell from a ChArUco board: recovered rig against the rig that made the images.

The synthetic world (:mod:`sfs_ros.core.simulation.calibration_scene`) renders the
board through a rig with a tilted, off-centre turntable axis, encoder zero
offsets, lens distortion and a turned camera; the calibration starts from the
ideal hand-measured rig. The truth compared against is that world in the
solver's gauge (:func:`canonical`: the axis tilt about lab X folded into the
carriage zero, which images cannot tell apart).
"""

import math

import cv2
import numpy as np
import pytest
import yaml

from sfs_ros.cli import calibrate as cli
from sfs_ros.core.calibration import BoardSpec, calibrate_rig, camera_info, canonical, detect_board
from sfs_ros.core.calibration.board import refine_saddle_points
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.simulation.calibration_scene import board_scene, nominal_rig
from sfs_ros.ros.rig_params import RIG_PARAMS, rig_calibration

DEG = math.pi / 180

# Tolerances: the acceptance bar of the calibration against the truth (what a carving
# needs), with what this scene gives (error; the fit's own standard uncertainty).
INTRINSICS_REL = 0.005        # 0.5 %; fx, fy 0.01 % (0.07 px), cx 0.07 % (0.19 px),
#                               cy 0.05 % (0.14 px): the principal point is the weakest
K1_ABS = 0.01                 # k1: 0.0004 (0.0011)
AXIS_POINT_M = 0.5e-3         # axis position: 0.003 mm (0.009 mm)
ANGLE_RAD = 0.1 * DEG         # axis tilt and encoder zeros: under 0.001 degree (0.002)
RADIUS_M = 1e-3               # C-arm radius: 0.02 mm (0.03 mm)
MOUNT_RAD = 0.2 * DEG         # camera mounting: 0.015 degree (0.014); it trades with cx, cy
# Corners are found to ~0.03 px in the noisy, anti-aliased renders; a fit of the right
# model leaves about that, a wrong model (or a bad view kept) several pixels.
RMS_PX = 0.2

WRONG_VIEW = 5                # its turntable reading is recorded 3 degrees off
BLURRED_VIEW = 12             # its image is blurred until no marker can be read


@pytest.fixture(scope="module")
def scene():
    return board_scene()


def _session(folder, scene, *, indices=None, images=None, angles=None):
    indices = range(len(scene.images)) if indices is None else indices
    images = images or {}
    angles = angles or {}
    write_session(folder, [(f"view_{i:03d}.png", images.get(i, scene.images[i])) for i in indices],
                  [angles.get(i, scene.angles[i]) for i in indices], nominal_rig())
    return folder


@pytest.fixture(scope="module")
def calibrated(scene, tmp_path_factory):
    """sfs-calibrate run on the whole scene with one view mis-tagged and one blurred."""
    theta, phi = scene.angles[WRONG_VIEW]
    blurred = cv2.GaussianBlur(scene.images[BLURRED_VIEW], (0, 0), 9.0)
    folder = _session(tmp_path_factory.mktemp("board") / "session", scene,
                      images={BLURRED_VIEW: blurred}, angles={WRONG_VIEW: (theta + 3 * DEG, phi)})
    out = tmp_path_factory.mktemp("out")
    assert cli.main([str(folder), "-o", str(out)]) == 0
    values = yaml.safe_load((out / "rig.yaml").read_text())["/**"]["ros__parameters"]
    return {"values": values, "rig": rig_calibration(values),
            "report": yaml.safe_load((out / "calibration_report.yaml").read_text()),
            "info": yaml.safe_load((out / "camera_info.yaml").read_text())}


@pytest.fixture(scope="module")
def truth(scene):
    return canonical(scene.rig, scene.pose)


def test_axis_tilt_about_x_is_the_carriage_zero(scene, truth):
    # The gauge the solver reports in gives the very same pixels as the true world.
    rig, pose = truth
    assert scene.rig.axis_tilt_x_rad != 0 and rig.axis_tilt_x_rad == 0
    points = scene.board.object_points
    for theta, phi in scene.angles[::4]:
        expected = rig_camera(theta, phi, scene.rig).project_distorted(scene.pose.to_object(points))
        got = rig_camera(theta, phi, rig).project_distorted(pose.to_object(points))
        np.testing.assert_allclose(got, expected, atol=1e-9)


def test_intrinsics_are_recovered(calibrated, truth):
    rig, true = calibrated["rig"], truth[0]
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(rig, name) == pytest.approx(getattr(true, name), rel=INTRINSICS_REL), name
    assert rig.distortion[0] == pytest.approx(true.distortion[0], abs=K1_ABS)


def test_turntable_axis_and_encoder_zeros_are_recovered(calibrated, truth):
    rig, true = calibrated["rig"], truth[0]
    np.testing.assert_allclose(rig.axis_point_m, true.axis_point_m, atol=AXIS_POINT_M)
    assert rig.axis_tilt_y_rad == pytest.approx(true.axis_tilt_y_rad, abs=ANGLE_RAD)
    assert rig.axis_tilt_x_rad == 0.0                       # the gauge: held, not estimated
    assert rig.theta_zero_rad == pytest.approx(true.theta_zero_rad, abs=ANGLE_RAD)
    assert rig.phi_zero_rad == pytest.approx(true.phi_zero_rad, abs=ANGLE_RAD)
    assert rig.camera_distance_m == pytest.approx(true.camera_distance_m, abs=RADIUS_M)
    np.testing.assert_allclose(rig.mount_rotation_rad, true.mount_rotation_rad, atol=MOUNT_RAD)
    assert rig.aim_point_m == nominal_rig().aim_point_m      # the lab frame's anchor


def test_fit_reports_residuals_uncertainties_and_what_it_fixed(calibrated, truth):
    report = calibrated["report"]
    assert report["rms_px"] < RMS_PX
    assert all(rms < RMS_PX * 2 for rms in report["view_rms_px"].values())
    assert len(report["view_rms_px"]) == 28 - 2
    assert {"axis_tilt_x_rad", "k3", "aim_point_m"} <= set(report["fixed"])
    sigma = report["uncertainty"]
    assert set(sigma) >= {"fx", "k1", "axis_x_m", "theta_zero_rad", "board_z_m"}
    assert "k3" not in sigma and all(s > 0 for s in sigma.values())
    # The stated uncertainties are honest: the truth lies within 4 of them.
    rig, true = calibrated["rig"], truth[0]
    for name, got, want in [("fx", rig.fx, true.fx), ("k1", rig.distortion[0], true.distortion[0]),
                            ("axis_x_m", rig.axis_point_m[0], true.axis_point_m[0]),
                            ("axis_y_m", rig.axis_point_m[1], true.axis_point_m[1]),
                            ("theta_zero_rad", rig.theta_zero_rad, true.theta_zero_rad),
                            ("phi_zero_rad", rig.phi_zero_rad, true.phi_zero_rad)]:
        assert abs(got - want) < 4 * sigma[name], name


def test_bad_views_are_named_not_absorbed(calibrated):
    rejected = calibrated["report"]["rejected"]
    assert set(rejected) == {f"view_{WRONG_VIEW:03d}.png", f"view_{BLURRED_VIEW:03d}.png"}
    assert "reprojection error" in rejected[f"view_{WRONG_VIEW:03d}.png"]
    assert "no marker" in rejected[f"view_{BLURRED_VIEW:03d}.png"]


def test_rig_yaml_is_the_cells_parameter_file(calibrated):
    assert set(calibrated["values"]) == {p.name for p in RIG_PARAMS}


def test_camera_info_reads_back(calibrated):
    info, rig = calibrated["info"], calibrated["rig"]
    assert (info["image_width"], info["image_height"]) == (640, 480)
    assert info["distortion_model"] == "plumb_bob"
    np.testing.assert_array_equal(np.reshape(info["camera_matrix"]["data"], (3, 3)), rig.K)
    assert info["distortion_coefficients"] == {"rows": 1, "cols": 5,
                                               "data": list(rig.distortion)}
    np.testing.assert_array_equal(np.reshape(info["rectification_matrix"]["data"], (3, 3)),
                                  np.eye(3))
    P = np.reshape(info["projection_matrix"]["data"], (3, 4))
    assert info["projection_matrix"]["rows"] == 3 and not np.any(P[:, 3])
    # P is the camera of the undistorted image: same scale as K within the barrel's shrink.
    assert P[0, 0] == pytest.approx(rig.fx, rel=0.1)
    assert info == camera_info(rig)


def test_blank_images_are_a_clear_error(tmp_path, capsys):
    blank = np.full((480, 640, 3), 128, np.uint8)
    folder = tmp_path / "blank"
    write_session(folder, [(f"v{i}.png", blank) for i in range(8)],
                  [(i * 0.3, 0.2) for i in range(8)], nominal_rig())
    assert cli.main([str(folder), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "board (7x5 squares, DICT_5X5_100) was found in none of the 8 images" in err
    assert not (tmp_path / "out").exists()


def _junction(centre, angles_deg, size=41, supersample=16):
    """(size, size) uint8: two straight edges through ``centre`` (u, v), pixels, at
    ``angles_deg`` from the u axis, opposite sectors alike (a chessboard corner under some
    perspective); each pixel the mean of supersample^2 samples over its area."""
    u = (np.arange(size * supersample) + 0.5) / supersample - 0.5
    x, y = np.meshgrid(u - centre[0], u - centre[1])
    a, b = np.radians(angles_deg)
    sides = (np.cos(a) * y - np.sin(a) * x) * (np.cos(b) * y - np.sin(b) * x)
    image = np.where(sides > 0, 230.0, 25.0)
    return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA).round().astype(np.uint8)


def test_a_corner_is_refined_to_where_its_edges_cross():
    # Anywhere on the pixel grid, edges meeting at 40 to 140 degrees, the start up to half
    # a pixel off: measured 0.006 px RMS and 0.024 px at most over these 200 (the grey
    # levels' rounding included), where cv2.cornerSubPix (window 5) leaves 0.034 px RMS.
    rng = np.random.default_rng(0)
    errors = []
    for _ in range(200):
        centre = 20.0 + rng.uniform(-0.5, 0.5, 2)
        first = rng.uniform(0.0, 180.0)
        image = _junction(centre, (first, first + rng.uniform(40.0, 140.0)))
        start = centre + rng.uniform(-0.5, 0.5, 2)
        errors.append(refine_saddle_points(image, start[None])[0] - centre)
    errors = np.array(errors)
    assert np.sqrt(np.mean(errors ** 2)) < 0.01 and np.abs(errors).max() < 0.05


def test_corners_are_found_where_the_true_camera_puts_them(scene):
    # Every view's corners (noisy renders through the true lens) against the true rig's
    # projection: no offset between the renderer's and the detector's pixel centres, and
    # the sub-pixel error small (measured: means under 0.001 px, 0.030 px RMS; OpenCV's
    # own corners, before the saddle-point refinement, 0.108 px RMS, which the principal
    # point multiplies about 14 times, doc/calibration.md).
    errors = []
    for image, angles in zip(scene.images, scene.angles):
        found, reason = detect_board(image, scene.board)
        assert found is not None, reason
        camera = rig_camera(*angles, scene.rig)
        true = camera.project_distorted(scene.pose.to_object(scene.board.object_points[found.ids]))
        errors.append(found.pixels - true)
    errors = np.concatenate(errors)
    assert np.all(np.abs(errors.mean(axis=0)) < 0.01)
    assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) < 0.05


def test_a_blurred_board_is_rejected_with_its_reason(scene):
    blurred = cv2.GaussianBlur(scene.images[0], (0, 0), 9.0)
    found, reason = detect_board(blurred, scene.board)
    assert found is None and "no marker" in reason
    # A mild blur still gives corners: the rejection is about blur that destroys the board.
    found, reason = detect_board(cv2.GaussianBlur(scene.images[0], (0, 0), 0.8), scene.board)
    assert found is not None and len(found.ids) >= 20


def test_too_few_views_are_a_clear_error(scene, tmp_path, capsys):
    folder = _session(tmp_path / "few", scene, indices=[3, 10, 17, 4])
    assert cli.main([str(folder), "-o", str(tmp_path / "out")]) == 2
    assert "4 usable board views, need at least 6" in capsys.readouterr().err


def test_too_few_views_after_rejection_name_the_rejected(scene):
    detections = []
    for i in range(6):
        found, _ = detect_board(scene.images[i], scene.board)
        detections.append((f"v{i}", *scene.angles[i], found))
    with pytest.raises(ValueError, match=r"5 usable board views, need at least 6 \(1 rejected, "
                                         r"first: x: no marker"):
        calibrate_rig(detections[:5], scene.board, nominal_rig(), rejected=[("x", "no marker")])


@pytest.mark.parametrize("spec, message", [
    (dict(squares_x=2), "at least 3x3"),
    (dict(marker_m=0.04), "marker_m < square_m"),
    (dict(dictionary="DICT_NOPE"), "unknown ArUco dictionary"),
    (dict(squares_x=20, squares_y=20, dictionary="DICT_4X4_50"), "needs 200 markers"),
])
def test_bad_board_definitions_are_refused(spec, message):
    with pytest.raises(ValueError, match=message):
        BoardSpec(**spec)


def test_views_at_one_turntable_angle_cannot_place_the_axis():
    # Without turning the table, moving the axis is moving the board: a rank-deficient fit
    # must say so instead of returning a wandering axis.
    scene = board_scene(thetas_deg=(0,), phis_deg=(0, 10, 20, 30, 40, 50, 60))
    detections = [(f"v{i}", *angles, detect_board(image, scene.board)[0])
                  for i, (image, angles) in enumerate(zip(scene.images, scene.angles))]
    with pytest.raises(ValueError, match="cannot tell .*axis_.*: spread the turntable"):
        calibrate_rig(detections, scene.board, nominal_rig())


def test_three_radial_terms_fit_k3_and_report_it(scene):
    # Half the views (phi 0 and 40 degrees) keep this second fit short.
    views = [i for i, (_, phi) in enumerate(scene.angles)
             if round((phi - scene.rig.phi_zero_rad) / DEG) in (0, 40)]
    detections = [(f"v{i}", *scene.angles[i], detect_board(scene.images[i], scene.board)[0])
                  for i in views]
    fit = calibrate_rig(detections, scene.board, nominal_rig(), radial_terms=3)
    assert "k3" in fit.uncertainty and "k3" not in fit.fixed
    assert fit.rms_px < RMS_PX and not fit.rejected
    assert fit.rig.fx == pytest.approx(canonical(scene.rig, scene.pose)[0].fx,
                                       rel=INTRINSICS_REL)
    # The true lens has k3 = 0; a free k3 must find it within its stated uncertainty.
    assert abs(fit.rig.distortion[4]) < 4 * fit.uncertainty["k3"]
