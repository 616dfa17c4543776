"""Camera models against closed-form projections."""

import numpy as np
import pytest

from sfs_ros.core.geometry.camera import Camera

from tolerances import PIXEL_ROUND_OFF_PX, ROUND_OFF

K = np.array([[800.0, 0.0, 320.0], [0.0, 820.0, 240.0], [0.0, 0.0, 1.0]])


def test_pinhole_matches_closed_form():
    cam = Camera(K, np.eye(3), [0.0, 0.0, 2.0], 640, 480)
    uv = cam.project([[0.0, 0.0, 0.0], [0.1, -0.2, 0.0], [0.1, 0.0, 2.0]])
    # u = fx x / z + cx, v = fy y / z + cy with z = point z + 2.
    np.testing.assert_allclose(uv, [[320, 240], [320 + 800 * 0.05, 240 - 820 * 0.1],
                                    [320 + 800 * 0.1 / 4, 240]], atol=PIXEL_ROUND_OFF_PX)


def test_orthographic_ignores_depth():
    cam = Camera(K, np.eye(3), [0.0, 0.0, 2.0], 640, 480, orthographic=True)
    uv = cam.project([[0.1, -0.2, 0.0], [0.1, -0.2, 5.0]])
    np.testing.assert_allclose(uv, [[320 + 80, 240 - 164]] * 2, atol=PIXEL_ROUND_OFF_PX)
    assert np.allclose(cam.projection_matrix[2], [0, 0, 0, 1])


def test_points_behind_pinhole_are_nan():
    cam = Camera(K, np.eye(3), [0.0, 0.0, 1.0], 640, 480)
    uv = cam.project([[0.0, 0.0, -1.0], [0.0, 0.0, -2.0]])
    assert np.isnan(uv).all()


def test_projection_matrix_decomposes_back():
    angle = 0.7
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    cam = Camera(K, R, [0.01, -0.02, 0.6], 640, 480)
    back = Camera.from_projection_matrix(3.5 * cam.projection_matrix, 640, 480)  # P up to scale
    np.testing.assert_allclose(back.K, K, atol=PIXEL_ROUND_OFF_PX)
    np.testing.assert_allclose(back.R, R, atol=ROUND_OFF)
    np.testing.assert_allclose(back.t, cam.t, atol=ROUND_OFF)
    np.testing.assert_allclose(back.center, cam.center, atol=ROUND_OFF)


@pytest.mark.parametrize("kwargs, message", [
    (dict(R=np.diag([1.0, 1.0, -1.0])), "not a rotation"),
    (dict(R=2 * np.eye(3)), "not a rotation"),
    (dict(t=[0.0, np.nan, 1.0]), "NaN"),
    (dict(K=np.diag([0.0, 1.0, 1.0])), "focal"),
    (dict(t=[0.0, 1.0]), "t \\(3,\\)"),
])
def test_invalid_parameters_are_refused(kwargs, message):
    args = dict(K=K, R=np.eye(3), t=[0.0, 0.0, 1.0], width=640, height=480) | kwargs
    with pytest.raises(ValueError, match=message):
        Camera(**args)
