"""A camera driver's frames and camera_info as the scan node reads them: every encoding
drivers publish, against pixels worked out by hand; compressed frames within the readers'
limits; the driver's intrinsics against the rig's."""

import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image as PILImage
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from sfs_ros.cell_logic.intrinsics import (
    DriverIntrinsics,
    describe_differences,
    intrinsics_differences,
    largest_difference,
    rig_intrinsics,
    rig_update,
)
from sfs_ros.cell_logic.message_fields import msg_to_image
from sfs_ros.ros.convert import (
    DRIVER_ENCODINGS,
    bayer_to_rgb,
    camera_info_intrinsics,
    driver_frame,
    image_to_msg,
    yuv422_to_rgb,
)

STAMP = (12, 345)


def _raw(encoding: str, pixels: np.ndarray, width: int, *, pad: int = 0) -> Image:
    """An Image of ``encoding`` holding ``pixels`` (H, row bytes) uint8, rows padded."""
    h = pixels.shape[0]
    rows = np.zeros((h, pixels.shape[1] + pad), np.uint8)
    rows[:, :pixels.shape[1]] = pixels
    msg = Image(height=h, width=width, encoding=encoding, step=rows.shape[1])
    msg.header.stamp.sec, msg.header.stamp.nanosec = STAMP
    msg.header.frame_id = "driver_optical"
    msg.data = rows.tobytes()
    return msg


def _mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """The Bayer samples of an RGB image: each pixel keeps its tile's colour."""
    h, w, _ = rgb.shape
    tile = np.array(["rgb".index(c) for c in pattern]).reshape(2, 2)
    channel = np.tile(tile, (h // 2, w // 2))
    return np.take_along_axis(rgb, channel[..., None], axis=2)[..., 0]


@pytest.mark.parametrize("encoding, pattern", [("bayer_rggb8", "rggb"), ("bayer_bggr8", "bggr"),
                                               ("bayer_gbrg8", "gbrg"), ("bayer_grbg8", "grbg")])
def test_a_bayer_mosaic_of_a_uniform_colour_comes_back_as_that_colour(encoding, pattern):
    rgb = np.empty((6, 8, 3), np.uint8)
    rgb[:] = (200, 120, 40)
    out = msg_to_image(driver_frame(_raw(encoding, _mosaic(rgb, pattern), 8, pad=3)))
    assert out.shape == (6, 8, 3)
    assert np.array_equal(out, rgb)


def test_bayer_demosaicing_is_bilinear():
    # A red sample of 100 at an R site, the rest 0: the B site diagonal to it gets a quarter
    # of the way from its four diagonal R neighbours (one of them 100) -> 25; the G site
    # beside it, half (two R neighbours) -> 50. The R site keeps its sample.
    raw = np.zeros((6, 6), np.uint8)
    raw[2, 2] = 100                               # an R site of rggb
    out = bayer_to_rgb(raw, "rggb")
    assert out[2, 2, 0] == 100
    assert out[3, 3, 0] == 25                     # B site
    assert out[2, 3, 0] == 50 and out[3, 2, 0] == 50   # G sites
    assert out[..., 1].max() == 0 and out[..., 2].max() == 0


@pytest.mark.parametrize("encoding, order", [("yuv422", (0, 1, 2, 3)), ("uyvy", (0, 1, 2, 3)),
                                             ("yuyv", (1, 0, 3, 2)),
                                             ("yuv422_yuy2", (1, 0, 3, 2))])
def test_yuv422_pixels_are_bt601_video_range(encoding, order):
    # (U, Y0, V, Y1) groups: white and black (U = V = 128, Y = 235 / 16), then pure red:
    # Y = 81, U = 90, V = 240 (BT.601: R = 1.164 (81 - 16) + 1.596 (240 - 128) = 254.4).
    groups = np.array([[128, 235, 128, 16], [90, 81, 240, 81]], np.uint8)
    data = groups[:, list(order)].reshape(1, 8)
    out = msg_to_image(driver_frame(_raw(encoding, data, 4)))
    assert out.tolist() == [[[255, 255, 255], [0, 0, 0], [254, 0, 0], [254, 0, 0]]]


def test_yuv422_of_an_odd_width_is_refused():
    with pytest.raises(ValueError, match="even width"):
        driver_frame(_raw("yuyv", np.zeros((2, 6), np.uint8), 3))
    with pytest.raises(ValueError, match=r"\(H, 2 W\)"):
        yuv422_to_rgb(np.zeros((2, 6), np.uint8), "yuyv")


@pytest.mark.parametrize("encoding, rgba", [("rgba8", (10, 20, 30, 99)),
                                            ("bgra8", (30, 20, 10, 99))])
def test_alpha_is_dropped_and_the_channels_ordered(encoding, rgba):
    data = np.tile(np.array(rgba, np.uint8), (2, 3))
    out = msg_to_image(driver_frame(_raw(encoding, data, 3, pad=4)))
    assert out.shape == (2, 3, 3) and (out == (10, 20, 30)).all()


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "mono8", "mono16"])
def test_the_cells_own_encodings_pass_unchanged(encoding):
    shape = (4, 5, 3) if encoding in ("rgb8", "bgr8") else (4, 5)
    dtype = np.uint16 if encoding == "mono16" else np.uint8
    msg = image_to_msg(np.ones(shape, dtype), stamp=STAMP, frame_id="c", encoding=encoding)
    assert driver_frame(msg) is msg


def test_the_header_is_kept_and_bad_frames_are_named():
    out = driver_frame(_raw("bayer_rggb8", np.zeros((4, 4), np.uint8), 4))
    assert (out.header.stamp.sec, out.header.stamp.nanosec) == STAMP
    assert out.header.frame_id == "driver_optical" and out.encoding == "rgb8"
    with pytest.raises(ValueError, match="unsupported image encoding 'nv12'.*bayer_rggb8"):
        driver_frame(_raw("nv12", np.zeros((4, 4), np.uint8), 4))
    short = _raw("bayer_rggb8", np.zeros((4, 4), np.uint8), 4)
    short.data = bytes(10)
    with pytest.raises(ValueError, match="10 bytes, expected height"):
        driver_frame(short)
    assert set(DRIVER_ENCODINGS) >= {"rgba8", "bgra8", "yuv422", "uyvy", "yuyv", "yuv422_yuy2"}


def _compressed(fmt: str, pixels: np.ndarray) -> CompressedImage:
    buffer = io.BytesIO()
    PILImage.fromarray(pixels).save(buffer, format=fmt)
    msg = CompressedImage(format=fmt.lower())
    msg.header.stamp.sec, msg.header.stamp.nanosec = STAMP
    msg.data = buffer.getvalue()
    return msg


def test_compressed_frames_png_exactly_and_jpeg_closely():
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    assert np.array_equal(msg_to_image(driver_frame(_compressed("PNG", rgb))), rgb)
    grey = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    assert np.array_equal(msg_to_image(driver_frame(_compressed("PNG", grey))), grey)
    flat = np.full((16, 16, 3), (200, 60, 30), np.uint8)
    out = driver_frame(_compressed("JPEG", flat))
    assert out.encoding == "rgb8" and (out.header.stamp.sec, out.header.stamp.nanosec) == STAMP
    assert np.abs(msg_to_image(out).astype(int) - flat).max() <= 3


def test_a_compressed_bomb_or_garbage_is_refused_before_decoding():
    # A PNG of a few dozen bytes whose header declares 12000 x 9000 pixels (108 MP).
    small = bytes(_compressed("PNG", np.zeros((1, 1), np.uint8)).data)
    ihdr = b"IHDR" + struct.pack(">II", 12000, 9000) + small[24:29]
    bomb = CompressedImage(format="png", data=small[:12] + ihdr
                           + struct.pack(">I", zlib.crc32(ihdr)) + small[33:])
    with pytest.raises(ValueError, match="declares 12000x9000 pixels; at most 100 megapixels"):
        driver_frame(bomb)
    with pytest.raises(ValueError, match="at most 1 megapixels"):
        driver_frame(_compressed("PNG", np.zeros((1000, 1001), np.uint8)), max_pixels=1_000_000)
    with pytest.raises(ValueError, match="not a readable image .*expected JPEG or PNG"):
        driver_frame(CompressedImage(format="jpeg", data=b"\xff\xd8 not a jpeg"))


def _info(k, d=(0.1, -0.2, 0.001, 0.002, 0.0), model="plumb_bob", size=(320, 240)):
    return CameraInfo(width=size[0], height=size[1], k=[float(v) for v in k],
                      d=[float(v) for v in d], distortion_model=model)


def test_camera_info_gives_the_driver_intrinsics_or_names_what_is_wrong():
    info = camera_info_intrinsics(_info([714, 0, 161, 0, 713, 121, 0, 0, 1]))
    assert info == DriverIntrinsics(320, 240, 714.0, 713.0, 161.0, 121.0,
                                    (0.1, -0.2, 0.001, 0.002, 0.0))
    rational = _info([700, 0, 160, 0, 700, 120, 0, 0, 1], (0.1, 0, 0, 0, 0, 0, 0, 0),
                     "rational_polynomial")
    assert camera_info_intrinsics(rational).distortion == (0.1, 0.0, 0.0, 0.0, 0.0)
    assert camera_info_intrinsics(_info([700, 0, 160, 0, 700, 120, 0, 0, 1], ())).distortion \
        == (0.0,) * 5
    with pytest.raises(ValueError, match="focal lengths must be > 0.*uncalibrated"):
        camera_info_intrinsics(_info([0] * 8 + [1]))
    with pytest.raises(ValueError, match="K must be"):
        camera_info_intrinsics(_info([700, 0, 160, 0, 700, 120, 0, 0, 0]))
    with pytest.raises(ValueError, match="'equidistant' with 4 coefficients"):
        camera_info_intrinsics(_info([700, 0, 160, 0, 700, 120, 0, 0, 1], (0, 0, 0, 0),
                                     "equidistant"))


def test_a_two_percent_difference_is_named_with_its_size():
    rig = rig_intrinsics({"width": 320, "height": 240, "fx": 700.0, "fy": 700.0, "cx": -1.0,
                          "cy": -1.0, "distortion": [0.0] * 5})
    assert (rig.cx, rig.cy) == (159.5, 119.5)
    driver = DriverIntrinsics(320, 240, 714.0, 686.0, 159.5, 119.5, (0.05, 0, 0, 0, 0))
    differences = intrinsics_differences(rig, driver)
    assert differences["fx"] == pytest.approx(0.02) and differences["fy"] == pytest.approx(-0.02)
    assert largest_difference(differences) == pytest.approx(0.02)
    assert describe_differences(differences, 0.005) == "fx +2.00 %, fy -2.00 %, k1 +0.0500"
    assert describe_differences(intrinsics_differences(rig, rig), 0.005) == ""
    other_size = DriverIntrinsics(640, 480, 700.0, 700.0, 159.5, 119.5)
    assert describe_differences(intrinsics_differences(rig, other_size), 0.5) \
        == "width +320 px, height +240 px"
    assert rig_update(driver) == {"fx": 714.0, "fy": 686.0, "cx": 159.5, "cy": 119.5,
                                  "distortion": [0.05, 0.0, 0.0, 0.0, 0.0]}
