"""Camera sources of the cell (no ROS): a real camera, a folder of images, a rendered mock.

Every source is a :class:`CameraSource`: :meth:`~CameraSource.grab` takes one
frame now and returns it as (H, W, 3) uint8 **RGB**, or raises
:class:`FrameUnavailable` saying what could not be taken and why; the source
stays usable after that (the next grab tries again). :meth:`~CameraSource.close`
releases the device.

* :class:`OpenCVSource` -- ``cv2.VideoCapture``: a camera by index or path, a
  video file or a stream URL;
* :class:`FolderSource` -- the image files of a folder, in name order (replays
  a recorded scan, or stands in for a camera in tests);
* :class:`RenderedSource` -- the mock camera: a known object (or the
  calibration board) rendered at the true angles of the simulated turntable
  and carriage, through the world's lens, with injectable missing frames.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from sfs_ros.core.exchange.errors import ViewError
from sfs_ros.core.exchange.limits import image_header
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.render import render_image
from sfs_ros.core.simulation.calibration_scene import BoardPicture
from sfs_ros.core.simulation.objects import SyntheticObject

__all__ = ["FrameUnavailable", "CameraSource", "OpenCVSource", "FolderSource", "RenderedSource",
           "IMAGE_SUFFIXES"]

#: File name suffixes :class:`FolderSource` reads (any case).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class FrameUnavailable(RuntimeError):
    """A frame could not be taken; the message says what and why."""


class CameraSource(ABC):
    """A camera: :meth:`grab` one RGB frame at a time, :meth:`close` at the end.

    Attributes
    ----------
    name : str
        What the source is, for logs and diagnostics (e.g. ``camera '/dev/video0'``).
    """

    name: str = "camera"

    @abstractmethod
    def grab(self) -> np.ndarray:
        """Take a frame now: (H, W, 3) uint8 RGB; raises :class:`FrameUnavailable`."""

    def close(self) -> None:  # noqa: B027 - optional: sources that hold nothing keep it
        """Release the device (nothing to release by default)."""


def _to_rgb(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an OpenCV frame: BGR, BGRA or grey, 8-bit."""
    if frame.ndim == 2 or frame.shape[2] == 1:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB)
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)


class OpenCVSource(CameraSource):
    """A camera, video file or stream through ``cv2.VideoCapture``.

    device : str
        An integer string (``"0"``) is the camera index; anything else a path
        (``/dev/video0``, a video file) or a URL.
    width, height : int
        Frame size to request from the driver, pixels (0 = the driver's
        default). The driver may deliver another size: callers check it.
    flush_frames : int >= 0
        Frames discarded before each grab, so that a grab returns a frame
        taken after the call rather than one buffered by the driver.

    Raises ``ValueError`` when the device cannot be opened.
    """

    def __init__(self, device: str, *, width: int = 0, height: int = 0, flush_frames: int = 0):
        device = str(device).strip()
        if int(flush_frames) < 0 or int(width) < 0 or int(height) < 0:
            raise ValueError(f"width, height and flush_frames must be >= 0, got {width}, "
                             f"{height}, {flush_frames}")
        self.device = device
        self.flush_frames = int(flush_frames)
        self.name = f"camera {device!r}"
        # OpenCV logs its own warning for a device it cannot open: the ValueError says it.
        # (OpenCV 4.6's wheels, Ubuntu 24.04's version, have no cv2.utils.logging but
        # cv2.getLogLevel/setLogLevel; 2 = LOG_LEVEL_ERROR in both.)
        log = getattr(cv2.utils, "logging", cv2)
        level = log.getLogLevel()
        log.setLogLevel(2)
        try:
            self._capture = cv2.VideoCapture(int(device) if device.isdigit() else device)
        finally:
            log.setLogLevel(level)
        if not self._capture.isOpened():
            self._capture.release()
            raise ValueError(f"cannot open camera {device!r}: expected a camera index ('0'), "
                             "a device path (/dev/video0), a video file or a stream URL")
        if width > 0:
            self._capture.set(cv2.CAP_PROP_FRAME_WIDTH, int(width))
        if height > 0:
            self._capture.set(cv2.CAP_PROP_FRAME_HEIGHT, int(height))

    def grab(self) -> np.ndarray:
        """Discard ``flush_frames`` frames, then read one: (H, W, 3) uint8 RGB."""
        try:
            ok = all(self._capture.grab() for _ in range(self.flush_frames))
            frame = self._capture.read()[1] if ok else None
        except cv2.error as exc:
            raise FrameUnavailable(f"camera {self.device!r} failed to deliver a frame: "
                                   f"{exc}") from None
        if frame is None or frame.size == 0:
            raise FrameUnavailable(f"camera {self.device!r} gave no frame (unplugged, or the "
                                   "end of a video file)")
        return _to_rgb(frame)

    def close(self) -> None:
        self._capture.release()


class FolderSource(CameraSource):
    """The images of a folder, one per grab, in name order.

    folder : path
        Files with a suffix in :data:`IMAGE_SUFFIXES` (sub-folders are not read).
    loop : bool
        Start again from the first image after the last (else the end of the
        folder raises :class:`FrameUnavailable`).

    Attributes
    ----------
    paths : list of Path, the images in the order they are returned.
    taken : int, grabs so far that consumed a file (an unreadable file counts).

    Raises ``ValueError`` when the folder is missing or holds no image. A file is
    decoded only once its header is within the readers' limits
    (:func:`sfs_ros.core.exchange.limits.image_header`); one that is not raises
    :class:`FrameUnavailable` naming it and the limit.
    """

    def __init__(self, folder, *, loop: bool = False):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise ValueError(f"image folder '{self.folder}' does not exist or is not a folder")
        self.paths = sorted((p for p in self.folder.iterdir()
                             if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                            key=lambda p: p.name)
        if not self.paths:
            raise ValueError(f"image folder '{self.folder}' holds no image; expected files "
                             f"ending in {', '.join(IMAGE_SUFFIXES)}")
        self.loop = bool(loop)
        self.taken = 0
        self.name = f"folder '{self.folder}'"

    def grab(self) -> np.ndarray:
        """The next image: (H, W, 3) uint8 RGB (an unreadable file is skipped after it raised)."""
        n = len(self.paths)
        if self.taken >= n and not self.loop:
            raise FrameUnavailable(f"no more frames: all {n} images of '{self.folder}' were "
                                   "taken (loop is off)")
        path = self.paths[self.taken % n]
        self.taken += 1
        try:
            image_header(path)     # the readers' limits, from the header, before decoding
        except ViewError as exc:
            raise FrameUnavailable(str(exc)) from None
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise FrameUnavailable(f"image file '{path}' cannot be read (missing, corrupt or "
                                   "not an image)")
        return _to_rgb(image)


class RenderedSource(CameraSource):
    """The mock camera: ``obj`` rendered at the turntable and carriage's true angles.

    obj : SyntheticObject or BoardPicture
        A known object, or the calibration board standing on the plate.
    calibration : RigCalibration
        The world's camera model, axes and lens (:func:`rig_camera` at the true
        angles), and the image size.
    angles_rad : callable () -> (theta_rad, phi_rad)
        The true angles at the shutter (the simulated controller's
        ``true_position_rad``), called once per grab.
    background_rgb : 3 values in [0, 255]
    noise_sigma : float >= 0, grey levels
    seed : int, optional
        Seeds the generator that draws each frame's noise seed.

    Each grab is ``render_image`` as in :func:`sfs_ros.core.simulation.synthetic.simulate_scan`
    (the board: :meth:`BoardPicture.render`), through the calibration's lens.
    :meth:`fail_next` makes grabs fail as a camera that drops frames; it and
    :meth:`grab` may be called from different threads.
    """

    def __init__(self, obj: SyntheticObject | BoardPicture, calibration: RigCalibration,
                 angles_rad: Callable[[], tuple[float, float]], *,
                 background_rgb=(255, 255, 255), noise_sigma: float = 2.0, seed=None):
        self.calibration = calibration
        self.angles_rad = angles_rad
        self.background_rgb = tuple(background_rgb)
        self.noise_sigma = float(noise_sigma)
        self._rng = np.random.default_rng(seed)
        self._failures = 0
        self._lock = threading.Lock()
        self.set_scene(obj)

    def set_scene(self, obj: SyntheticObject | BoardPicture) -> None:
        """Put ``obj`` on the plate instead, from the next grab (any thread)."""
        if isinstance(obj, BoardPicture):
            scene = (obj, None)
        else:
            vertices = np.asarray(obj.mesh.vertices, dtype=np.float64)
            scene = (None, (vertices, np.asarray(obj.mesh.faces), obj.color_at(vertices)))
        with self._lock:
            self._scene, self.name = scene, f"rendered {obj.name}"

    def fail_next(self, n: int) -> None:
        """Make the next ``n`` grabs raise :class:`FrameUnavailable` (0 cancels)."""
        if int(n) < 0:
            raise ValueError(f"number of failing grabs must be >= 0, got {n}")
        with self._lock:
            self._failures = int(n)

    def grab(self) -> np.ndarray:
        """Render at the current true angles: (height, width, 3) uint8 RGB."""
        with self._lock:
            fail = self._failures > 0
            if fail:
                self._failures -= 1
            else:
                noise_seed = int(self._rng.integers(2**31))
            board, mesh = self._scene
        if fail:
            raise FrameUnavailable(f"frame missing: {self.name} dropped this frame "
                                   "(injected fault)")
        theta, phi = self.angles_rad()
        camera = rig_camera(float(theta), float(phi), self.calibration)
        if board is not None:
            return board.render(camera, noise=self.noise_sigma, seed=noise_seed)
        vertices, faces, colors = mesh
        return render_image(vertices, faces, camera, vertex_colors=colors,
                            background_rgb=self.background_rgb, noise_sigma=self.noise_sigma,
                            seed=noise_seed)
