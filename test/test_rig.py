"""The rig model: encoder angles to cameras, physical vs the paper's matrix."""

import math

import cv2
import numpy as np
import pytest

from sfs_ros.core.geometry.camera import Camera
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera, rig_rotation

from tolerances import PIXEL_ROUND_OFF_PX, ROUND_OFF

DEG = math.pi / 180


def view_axis(R):
    """Unit viewing direction in the object frame, sign-normalised (a line, not a ray)."""
    d = R[2] / np.linalg.norm(R[2])
    first = d[np.flatnonzero(np.abs(d) > 1e-9)[0]]
    return d * np.sign(first)


def test_physical_constant_phi_sweeps_a_latitude_circle():
    phi = 35 * DEG
    for theta in np.arange(0, 360, 10) * DEG:
        forward = rig_rotation(theta, phi, "physical")[2]
        # The camera looks down at elevation phi whatever the turntable does.
        assert forward[2] == pytest.approx(-math.sin(phi), abs=ROUND_OFF)


def test_paper_constant_phi_sweeps_a_great_circle_through_x():
    for phi in (10 * DEG, 35 * DEG, 80 * DEG):
        d = view_axis(rig_rotation(90 * DEG, phi, "paper"))
        np.testing.assert_allclose(np.abs(d), [1, 0, 0], atol=ROUND_OFF)
        # Closed form of the paper's viewing direction.
        theta = 20 * DEG
        expected = np.array([math.sin(theta), math.cos(theta) * math.cos(phi),
                             math.cos(theta) * math.sin(phi)])
        np.testing.assert_allclose(view_axis(rig_rotation(theta, phi, "paper")),
                                   view_axis(np.vstack([np.eye(3)[:2], expected])), atol=ROUND_OFF)


def test_paper_matrix_rows_are_printed_matrix():
    theta, phi = 0.4, 0.9
    R = rig_rotation(theta, phi, "paper")
    ct, st, cp, sp = math.cos(theta), math.sin(theta), math.cos(phi), math.sin(phi)
    np.testing.assert_allclose(R[:2], [[ct, -st * cp, -st * sp], [0, sp, -cp]], atol=1e-15)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=ROUND_OFF)


@pytest.mark.parametrize("convention, expected_distinct", [("paper", 18), ("physical", 36)])
def test_thirty_six_views_hold_distinct_silhouettes(convention, expected_distinct):
    # Orthographic silhouettes along d and -d are mirror images: count view lines.
    phi = 30 * DEG
    axes = [view_axis(rig_rotation(k * 10 * DEG, phi, convention)) for k in range(36)]
    distinct = {tuple(np.round(a, 9)) for a in axes}
    assert len(distinct) == expected_distinct


def test_paper_opposite_turntable_angles_mirror_the_image():
    calib = RigCalibration(convention="paper")
    points = np.random.default_rng(0).uniform(-0.02, 0.02, size=(50, 3))
    centre = np.array([calib.K[0, 2], calib.K[1, 2]])
    a = rig_camera(0.3, 0.6, calib).project(points) - centre
    b = rig_camera(0.3 + math.pi, 0.6, calib).project(points) - centre
    np.testing.assert_allclose(b, a * [-1, 1], atol=PIXEL_ROUND_OFF_PX)
    # The physical rig sees another side of the object at theta + pi.
    phys = RigCalibration()
    a = rig_camera(0.3, 0.6, phys).project(points) - centre
    b = rig_camera(0.3 + math.pi, 0.6, phys).project(points) - centre
    assert np.abs(b - a * [-1, 1]).max() > 10.0


@pytest.mark.parametrize("projection", ["orthographic", "pinhole"])
def test_aim_point_projects_to_principal_point(projection):
    calib = RigCalibration(projection=projection, fx=900, fy=900, camera_distance_m=0.6,
                           aim_point_m=(0.0, 0.0, 0.04), width=640, height=480)
    for theta, phi in [(0, 0), (1.0, 0.3), (4.0, 1.2), (2.0, math.pi / 2)]:
        cam = rig_camera(theta, phi, calib)
        np.testing.assert_allclose(cam.project([[0, 0, 0.04]])[0], [319.5, 239.5],
                                   atol=PIXEL_ROUND_OFF_PX)
        if projection == "pinhole":
            assert np.linalg.norm(cam.center - [0, 0, 0.04]) == pytest.approx(0.6)
            # Camera above the plate for positive elevation.
            assert cam.center[2] == pytest.approx(0.04 + 0.6 * math.sin(phi))


def test_turntable_axis_is_fixed_and_up_is_up():
    calib = RigCalibration(projection="pinhole", fx=900, fy=900, camera_distance_m=0.6)
    for theta in np.linspace(0, 2 * math.pi, 7):
        cam = rig_camera(theta, 0.5, calib)
        low, high = cam.project([[0, 0, 0.0], [0, 0, 0.05]])
        np.testing.assert_allclose(low, [255.5, 255.5], atol=PIXEL_ROUND_OFF_PX)
        assert high[0] == pytest.approx(255.5) and high[1] < low[1]  # higher z is higher in the image


def test_encoder_zero_offsets_are_removed():
    zeroed = RigCalibration(theta_zero_rad=0.2, phi_zero_rad=-0.1)
    plain = RigCalibration()
    a = rig_camera(1.0 + 0.2, 0.5 - 0.1, zeroed)
    b = rig_camera(1.0, 0.5, plain)
    np.testing.assert_allclose(a.projection_matrix, b.projection_matrix, atol=ROUND_OFF)


@pytest.mark.parametrize("theta, phi, message", [
    (math.nan, 0.2, "finite"), (0.1, math.inf, "finite"), (0.0, 1.6, "outside the C-arm range"),
])
def test_bad_angles_are_refused(theta, phi, message):
    with pytest.raises(ValueError, match=message):
        rig_camera(theta, phi, RigCalibration())


def test_calibration_round_trips_and_refuses_unknown_keys():
    calib = RigCalibration(projection="pinhole", aim_point_m=(0, 0, 0.05), cx=300.0)
    assert RigCalibration.from_dict(calib.to_dict()) == calib
    with pytest.raises(ValueError, match="unknown rig calibration keys \\['focal'\\]"):
        RigCalibration.from_dict({"focal": 3})
    with pytest.raises(ValueError, match="projection"):
        RigCalibration(projection="fisheye")


# ---------------------------------------------------------------- the real rig's chain

REAL = dict(projection="pinhole", width=640, height=480, fx=1400.0, fy=1400.0,
            aim_point_m=(0.0, 0.0, 0.08), camera_distance_m=0.6)


def test_default_rig_camera_is_bit_for_bit_the_ideal_formula():
    calib = RigCalibration(**REAL)
    for theta, phi in [(0.3, 0.4), (-2.0, 1.2), (5.0, -0.3)]:
        cam = rig_camera(theta, phi, calib)
        tilt = rig_rotation(0.0, phi)
        assert np.array_equal(cam.R, rig_rotation(theta, phi))
        assert np.array_equal(cam.t, np.array([0.0, 0.0, 0.6]) - tilt @ np.array([0, 0, 0.08]))
        assert not np.any(cam.distortion)


def test_offset_tilted_axis_is_fixed_while_the_turntable_turns():
    calib = RigCalibration(**REAL, axis_point_m=(0.003, -0.002), axis_tilt_x_rad=0.01,
                           axis_tilt_y_rad=-0.02)
    axis = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]])      # two points on the object's Z axis
    seen = [rig_camera(theta, 0.3, calib).to_camera_frame(axis) for theta in (0.0, 1.0, 2.5)]
    for other in seen[1:]:
        np.testing.assert_allclose(other, seen[0], atol=1e-15)
    # Back in the lab frame: the object origin is the axis point, in the plane z = 0, and the
    # axis direction is Rx(0.01) Ry(-0.02) e_z.
    lab_to_cam = rig_rotation(0.0, 0.3)
    origin_lab = lab_to_cam.T @ (seen[0][0] - [0.0, 0.0, 0.6]) + [0.0, 0.0, 0.08]
    np.testing.assert_allclose(origin_lab, [0.003, -0.002, 0.0], atol=1e-15)
    up = lab_to_cam.T @ (seen[0][1] - seen[0][0]) / 0.1
    np.testing.assert_allclose(up, [math.sin(-0.02), -math.sin(0.01) * math.cos(-0.02),
                                    math.cos(0.01) * math.cos(-0.02)], atol=1e-14)


def test_mount_rotation_turns_the_camera_in_place():
    calib = RigCalibration(**REAL)
    turned = RigCalibration(**REAL, mount_rotation_rad=(0.01, -0.02, 0.03))
    ideal, real = rig_camera(0.4, 0.7, calib), rig_camera(0.4, 0.7, turned)
    np.testing.assert_allclose(real.center, ideal.center, atol=1e-15)
    assert np.degrees(np.arccos(np.clip(ideal.forward @ real.forward, -1, 1))) > 1.0


def test_distortion_projects_as_opencv():
    calib = RigCalibration(**REAL, distortion=(-0.2, 0.1, 0.001, -0.002, 0.01),
                           mount_rotation_rad=(0.01, 0.0, -0.01))
    cam = rig_camera(0.2, 0.5, calib)
    points = np.random.default_rng(1).uniform(-0.1, 0.1, size=(30, 3))
    expected = cv2.projectPoints(points, cv2.Rodrigues(cam.R)[0], cam.t, cam.K,
                                 cam.distortion)[0].reshape(-1, 2)
    # Both evaluate the same polynomial in float64: rounding only.
    np.testing.assert_allclose(cam.project_distorted(points), expected, atol=1e-9)
    assert np.abs(cam.project(points) - expected).max() > 0.5   # the ideal pinhole differs


@pytest.mark.parametrize("values, message", [
    (dict(distortion=(0.1, 0.0)), "distortion must be 5 numbers"),
    (dict(axis_point_m=(0.0, 0.0, 0.0)), "axis_point_m must be 2 numbers"),
    (dict(projection="orthographic", distortion=(0.1, 0, 0, 0, 0)), "needs the pinhole"),
    (dict(convention="paper", axis_tilt_y_rad=0.01), "need the 'physical' convention"),
    (dict(mount_rotation_rad=(0.0, float("nan"), 0.0)), r"mount_rotation_rad\[1\] must be a finite"),
])
def test_real_rig_fields_are_checked(values, message):
    with pytest.raises(ValueError, match=message):
        RigCalibration(**{**REAL, **values})


def test_real_rig_fields_round_trip():
    calib = RigCalibration(**REAL, distortion=(-0.2, 0.1, 0.0, 0.0, 0.0), axis_point_m=(1e-3, 0),
                           axis_tilt_y_rad=0.01, mount_rotation_rad=(0.0, 0.01, 0.0))
    assert RigCalibration.from_dict(calib.to_dict()) == calib


def test_camera_distortion_is_checked():
    with pytest.raises(ValueError, match="5 finite values"):
        Camera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=4, height=4, distortion=(0.1, 0.2))
    with pytest.raises(ValueError, match="orthographic camera cannot carry lens distortion"):
        Camera(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=4, height=4, orthographic=True,
               distortion=(0.1, 0, 0, 0, 0))
