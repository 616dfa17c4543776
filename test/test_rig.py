"""The rig model: encoder angles to cameras, physical vs the paper's matrix."""

import math

import numpy as np
import pytest

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
