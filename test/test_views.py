"""Reading images, the view data types, and recognising the input format."""

import cv2
import numpy as np
import pytest

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.views import (
    View,
    ViewError,
    ViewSet,
    image_size,
    nearest_rotation,
    read_image,
)
from sfs_ros.core.geometry.camera import Camera

from tolerances import ROUND_OFF


def write(path, image):
    assert cv2.imwrite(str(path), image)
    return path


def test_colour_image_is_rgb(tmp_path):
    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 0] = 200  # blue in OpenCV's order
    rgb = read_image(write(tmp_path / "a.png", bgr), expected_size=(6, 4))
    assert rgb.shape == (4, 6, 3) and rgb.dtype == np.uint8
    assert np.all(rgb[..., 2] == 200) and np.all(rgb[..., :2] == 0)


def test_grey_image_becomes_three_channels(tmp_path):
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    rgb = read_image(write(tmp_path / "g.png", grey))
    assert rgb.shape == (3, 4, 3)
    assert np.array_equal(rgb[..., 0], grey) and np.array_equal(rgb[..., 2], grey)


def test_sixteen_bit_image_is_scaled_to_eight_bits(tmp_path):
    deep = np.zeros((2, 2, 3), np.uint16)
    deep[0, 0] = 65535
    deep[0, 1] = 32768
    rgb = read_image(write(tmp_path / "d.png", deep))
    assert rgb.dtype == np.uint8
    assert rgb[0, 0, 0] == 255 and rgb[0, 1, 0] == 128 and rgb[1, 1, 0] == 0  # value / 256


def test_alpha_channel_is_dropped(tmp_path):
    bgra = np.zeros((2, 3, 4), np.uint8)
    bgra[..., 1] = 90
    bgra[0, 0, 3] = 0  # transparent: its colour is kept as stored
    rgb = read_image(write(tmp_path / "t.png", bgra))
    assert rgb.shape == (2, 3, 3) and np.all(rgb[..., 1] == 90)


def test_non_ascii_path(tmp_path):
    path = write(tmp_path / "x.png", np.full((2, 2, 3), 7, np.uint8)).rename(tmp_path / "vue_é.png")
    assert read_image(path)[0, 0, 0] == 7
    assert image_size(path) == (2, 2)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(ViewError, match=r"nowhere\.png does not exist"):
        read_image(tmp_path / "nowhere.png")


@pytest.mark.parametrize("content", [b"", b"not a png at all"])
def test_corrupt_file_is_a_clear_error(tmp_path, content):
    path = tmp_path / "bad.png"
    path.write_bytes(content)
    with pytest.raises(ViewError, match="bad.png is not a readable image"):
        read_image(path)


def test_directory_is_not_an_image(tmp_path):
    with pytest.raises(ViewError, match="is not a file"):
        read_image(tmp_path)


def test_wrong_size_names_found_and_expected(tmp_path):
    path = write(tmp_path / "s.png", np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ViewError) as err:
        read_image(path, expected_size=(640, 480))
    message = str(err.value)
    assert "s.png" in message and "10x10" in message and "640x480" in message
    assert "\n" not in message


def test_view_error_is_a_value_error():
    assert issubclass(ViewError, ValueError)


def test_view_set_checks_source_and_bounds(tmp_path):
    camera = Camera(np.eye(3), np.eye(3), np.zeros(3), 4, 4)
    views = [View("a", tmp_path / "a.png", camera)]
    assert ViewSet(views, "session", bounds_m=[[0, 0, 0], [1, 1, 1]]).bounds_m.shape == (2, 3)
    assert ViewSet(views, "photogrammetry").source == "photogrammetry"   # any format's name
    for nameless in ("", None):
        with pytest.raises(ValueError, match="source"):
            ViewSet(views, nameless)
    with pytest.raises(ValueError, match="min < max"):
        ViewSet(views, "nerf", bounds_m=[[0, 0, 0], [1, -1, 1]])


def test_nearest_rotation_repairs_rounding_and_refuses_the_rest():
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    fixed = nearest_rotation(np.round(R, 5), what="test")
    assert np.allclose(fixed @ fixed.T, np.eye(3), atol=ROUND_OFF)
    assert np.allclose(fixed, R, atol=1e-5)  # rounding to 5 decimals moves entries <= 5e-6
    with pytest.raises(ViewError, match="not a rotation"):
        nearest_rotation(2 * R, what="test")
    with pytest.raises(ViewError, match="not a rotation"):
        nearest_rotation(np.diag([1.0, 1.0, -1.0]), what="test")  # a reflection


def test_unrecognised_input_lists_what_is_accepted(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    for path in (tmp_path, tmp_path / "notes.txt"):
        with pytest.raises(ViewError) as err:
            load_views(path)
        assert "session" in str(err.value) and "_par.txt" in str(err.value)
        assert "transforms" in str(err.value)


def test_missing_input_is_one_line(tmp_path):
    with pytest.raises(ViewError, match="does not exist") as err:
        load_views(tmp_path / "nowhere")
    assert "\n" not in str(err.value)
