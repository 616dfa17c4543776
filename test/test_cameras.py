"""Camera sources on real files: images written with OpenCV, a real MJPG video, real renders."""

import cv2
import numpy as np
import pytest

from sfs_ros.core.calibration import detect_board
from sfs_ros.core.geometry.lens import ideal_camera
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.render import render_image
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.hardware.cameras import FolderSource, FrameUnavailable, OpenCVSource, RenderedSource
from sfs_ros.hardware.mock_world import mock_scene, world_rig

H, W = 24, 32
#: Uniform BGR frames of the video, all channels distinct.
VIDEO_BGR = [(250, 10, 10), (10, 250, 10), (10, 10, 250), (40, 120, 200), (200, 60, 90)]
# MJPG is lossy, but a uniform frame is one flat colour per 8x8 block: only its DC
# coefficient survives, quantised, plus the YCrCb round trip and clipping; measured
# error <= 1 grey level, so 6 is a generous bound far below the >= 40 between colours.
JPEG_TOL = 6
RIG = RigCalibration(width=80, height=60, projection="pinhole", fx=300.0, fy=300.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))


def _bgr_pattern(k: int) -> np.ndarray:
    """(H, W, 3) uint8 BGR with distinct channels: B = 10 + k, G = 100 + k, R = 200 + k."""
    image = np.empty((H, W, 3), np.uint8)
    image[:] = (10 + k, 100 + k, 200 + k)
    image[0, 0] = (0, 0, 0)            # one black corner: a flipped or transposed read shows
    return image


@pytest.fixture()
def folder(tmp_path):
    """b.png, a.jpg and c.png (name order a, b, c), a text file and a sub-folder (ignored)."""
    cv2.imwrite(str(tmp_path / "b.png"), _bgr_pattern(1))
    cv2.imwrite(str(tmp_path / "a.jpg"), _bgr_pattern(0), [cv2.IMWRITE_JPEG_QUALITY, 100])
    cv2.imwrite(str(tmp_path / "c.png"), _bgr_pattern(2))
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / "sub.png").mkdir()
    return tmp_path


def test_folder_source_returns_the_images_in_name_order_as_rgb(folder):
    source = FolderSource(folder)
    assert [p.name for p in source.paths] == ["a.jpg", "b.png", "c.png"]
    for k in range(3):
        image = source.grab()
        assert image.shape == (H, W, 3) and image.dtype == np.uint8
        expected_rgb = _bgr_pattern(k)[:, :, ::-1]
        if k == 0:   # JPEG at quality 100, away from the black corner's 16x16 block (chroma
            #          is subsampled over 16x16): within JPEG_TOL of the original
            assert np.abs(image[16:, 16:].astype(int) - expected_rgb[16:, 16:]).max() <= JPEG_TOL
            np.testing.assert_allclose(image[20, 20].astype(int), (200, 100, 10), atol=JPEG_TOL)
        else:        # PNG: lossless
            np.testing.assert_array_equal(image, expected_rgb)
            assert tuple(image[10, 10]) == (200 + k, 100 + k, 10 + k)     # red first
    assert source.taken == 3
    with pytest.raises(FrameUnavailable, match=r"all 3 images of .* were taken"):
        source.grab()
    with pytest.raises(FrameUnavailable):      # and stays at the end
        source.grab()
    source.close()


def test_folder_source_loops(folder):
    source = FolderSource(folder, loop=True)
    firsts = [int(source.grab()[20, 20, 0]) for _ in range(7)]
    np.testing.assert_allclose(firsts, [200, 201, 202] * 2 + [200], atol=JPEG_TOL)


def test_corrupt_file_raises_naming_it_and_the_next_grab_moves_on(folder):
    (folder / "b.png").write_bytes(b"\x89PNG\r\n\x1a\n but then garbage")
    source = FolderSource(folder)
    source.grab()
    with pytest.raises(FrameUnavailable, match="b.png"):
        source.grab()
    np.testing.assert_array_equal(source.grab(), _bgr_pattern(2)[:, :, ::-1])


def test_missing_or_empty_folder_is_refused(tmp_path):
    with pytest.raises(ValueError, match="nowhere"):
        FolderSource(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("no images here")
    with pytest.raises(ValueError, match=r"empty.*holds no image"):
        FolderSource(tmp_path / "empty")


@pytest.fixture()
def video(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (W, H))
    assert writer.isOpened()
    for bgr in VIDEO_BGR:
        writer.write(np.full((H, W, 3), bgr, np.uint8))
    writer.release()
    return path


def _assert_colour(image, bgr):
    assert image.shape == (H, W, 3) and image.dtype == np.uint8
    assert np.abs(image.astype(int) - np.array(bgr[::-1])).max() <= JPEG_TOL, image[0, 0]


def test_opencv_source_reads_a_video_in_order_as_rgb(video):
    source = OpenCVSource(str(video))
    for bgr in VIDEO_BGR:
        _assert_colour(source.grab(), bgr)
    with pytest.raises(FrameUnavailable, match="clip.avi.*gave no frame"):
        source.grab()
    source.close()


def test_opencv_source_flushes_frames_before_each_grab(video):
    source = OpenCVSource(str(video), flush_frames=1)
    _assert_colour(source.grab(), VIDEO_BGR[1])        # frame 0 discarded
    _assert_colour(source.grab(), VIDEO_BGR[3])        # frame 2 discarded
    with pytest.raises(FrameUnavailable):              # frame 4 discarded, then the end
        source.grab()
    source.close()


def test_opencv_source_refuses_a_device_that_does_not_exist(tmp_path):
    missing = str(tmp_path / "video99")
    with pytest.raises(ValueError, match="video99"):
        OpenCVSource(missing)


class Angles:
    """The angles a turntable and carriage would report; settable by the test."""

    def __init__(self, theta_rad, phi_rad):
        self.value = (theta_rad, phi_rad)

    def __call__(self):
        return self.value


@pytest.fixture(scope="module")
def mug():
    return make_object("mug")


def _render(mug, theta_rad, phi_rad, seed):
    return render_image(mug.mesh.vertices, mug.mesh.faces, rig_camera(theta_rad, phi_rad, RIG),
                        vertex_colors=mug.color_at(mug.mesh.vertices), noise_sigma=2.0,
                        seed=seed)


def test_rendered_source_is_render_image_at_the_true_angles(mug):
    angles = Angles(0.3, 0.5)
    source = RenderedSource(mug, RIG, angles, seed=7, noise_sigma=2.0)
    # Built independently, as simulate_scan does: frame k's noise seed is the k-th draw
    # of a generator seeded with the source's seed.
    seeds = np.random.default_rng(7)
    first = source.grab()
    assert first.shape == (RIG.height, RIG.width, 3) and first.dtype == np.uint8
    np.testing.assert_array_equal(first, _render(mug, 0.3, 0.5, int(seeds.integers(2**31))))
    # The mug is in view (the backdrop is white, the mug's colours stay below 200).
    silhouette = (first < 200).any(axis=2)
    assert 0.05 * silhouette.size < silhouette.sum() < 0.8 * silhouette.size

    angles.value = (1.8, 0.5)                              # the turntable turned
    turned = source.grab()
    np.testing.assert_array_equal(turned, _render(mug, 1.8, 0.5, int(seeds.integers(2**31))))
    # The handle moved: well over a hundred pixels change side (measured ~170).
    assert ((turned < 200).any(axis=2) != silhouette).sum() > 100


def test_rendered_source_injected_failures(mug):
    source = RenderedSource(mug, RIG, Angles(0.0, 0.4), seed=1)
    source.grab()
    with pytest.raises(ValueError):
        source.fail_next(-1)
    source.fail_next(2)
    for _ in range(2):
        with pytest.raises(FrameUnavailable, match=r"frame missing: .*injected fault"):
            source.grab()
    assert source.grab().shape == (RIG.height, RIG.width, 3)


def test_rendered_source_shows_the_board_through_the_worlds_lens():
    # The mock's board in the wrong world: its corners are found where the world's camera,
    # lens included, puts them (the corner detector's sub-pixel error on a noisy render).
    nominal = RigCalibration(width=640, height=480, projection="pinhole", fx=1400.0,
                             fy=1400.0, camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
    world = world_rig(nominal, "wrong")
    scene = mock_scene("board")
    angles = Angles(0.3, 0.35)
    image = RenderedSource(scene, world, angles, seed=2).grab()
    found, reason = detect_board(image, scene.board)
    assert found is not None, reason
    camera = rig_camera(*angles(), world)
    expected = camera.project_distorted(scene.pose.to_object(scene.board.object_points[found.ids]))
    rms = np.sqrt(np.mean(np.sum((found.pixels - expected) ** 2, axis=1)))
    assert len(found.ids) >= 12 and rms < 0.2
    # Through an ideal lens they would be off (measured 0.55 px RMS on this central part).
    ideal = ideal_camera(camera).project(scene.pose.to_object(scene.board.object_points[found.ids]))
    assert np.sqrt(np.mean(np.sum((found.pixels - ideal) ** 2, axis=1))) > 2 * rms
