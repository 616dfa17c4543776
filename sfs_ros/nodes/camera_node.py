"""Camera node: the cell's shutter; one frame per ``capture`` call, or a stream.

| kind | name | type | notes |
|---|---|---|---|
| pub | ``image_raw`` | sensor_msgs/Image | rgb8, the rig's width x height |
| pub | ``camera_info`` | sensor_msgs/CameraInfo | the rig's intrinsics, same header as its image |
| pub | ``/diagnostics`` | diagnostic_msgs/DiagnosticArray | 1 Hz and on every failure |
| srv | ``~/capture`` | std_srvs/Trigger | take one frame now; message: JSON stamp, size, count |

``image_raw`` and ``camera_info``: reliable, volatile, depth 10
(:func:`sfs_ros.ros.capture_qos`): a triggered frame must not be dropped, and
best-effort viewers still match a reliable publisher.

A managed (lifecycle) node (:mod:`sfs_ros.ros.lifecycle`): ``configure`` opens
the camera (it fails, the node staying unconfigured, when it cannot be opened),
``activate`` serves ``capture`` and starts the ``rate_hz`` stream,
``deactivate`` stops them (a caller of ``capture`` waits for the service as for
a node not started yet), ``cleanup`` closes the camera, ``shutdown`` does all
from any state. With
``autostart`` (the default) the node brings itself up at start-up, and a camera
that cannot be opened then stops it with one line (exit status 2).

``capture`` reads the node clock, grabs a frame (:mod:`sfs_ros.hardware.cameras`)
and publishes it on ``image_raw`` with that stamp and the camera frame, together
with its ``camera_info`` under the same header, then answers ``success`` and
``{"stamp": [sec, nanosec], "width": W, "height": H, "frame": n}`` (n = frames
published so far). With ``rate_hz`` > 0 a timer also takes frames at that rate.
Grabs run one at a time (the service and the timer share a mutually exclusive
callback group); diagnostics run beside them.

A frame that cannot be taken (camera unplugged, end of the folder, unreadable
file) or whose size is not the rig's publishes nothing: ``capture`` answers
``success=False`` with the reason, the failure is logged and counted, and the
diagnostics stay ERROR until the next good frame; the node carries on.

Parameters: :data:`PARAMS` (all read-only), the rig calibration
:data:`sfs_ros.ros.rig_params.WRITABLE_RIG_PARAMS` (``config/rig.yaml``), whose
``width`` x ``height`` every frame must have and whose intrinsics fill
``camera_info`` (settable between scans, not the size, checked as one rig by
:class:`sfs_ros.ros.rig_params.RigParameters`: the next frame's ``camera_info``
carries it), and the frames :data:`sfs_ros.ros.frames.FRAME_PARAMS`
(``config/frames.yaml``): the images' ``frame_id`` is the prefixed camera
frame. ``backend`` "mock" is served by ``sfs-mock-hardware``, which runs
this node in its own process with a
:class:`~sfs_ros.hardware.cameras.RenderedSource` (it renders at the
simulated controller's angles); started alone with "mock", the node refuses.
"""

from __future__ import annotations

import json
import threading

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.lifecycle import LifecycleNode
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.hardware.cameras import CameraSource, FolderSource, FrameUnavailable, OpenCVSource
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos
from sfs_ros.ros.convert import camera_info, diagnostic_array, image_to_msg
from sfs_ros.ros.frames import FRAME_PARAMS, frame_names
from sfs_ros.ros.lifecycle import AUTOSTART, FAILURE, SUCCESS, bring_up
from sfs_ros.ros.names import DIAGNOSTICS, private, status_name
from sfs_ros.ros.pairing import stamp_key
from sfs_ros.ros.params import Param, ParameterError, declare
from sfs_ros.ros.rig_params import WRITABLE_RIG_PARAMS, RigParameters

__all__ = ["CameraNode", "PARAMS", "main"]

NODE_NAME = "camera"

#: The node's own parameters (all read-only); the rig calibration from WRITABLE_RIG_PARAMS.
PARAMS: list[Param] = [
    Param("backend", "opencv", "Frame source: opencv (a camera, video file or stream), folder "
          "(the images of a folder in name order) or mock (served by sfs-mock-hardware).",
          choices=("opencv", "folder", "mock"), read_only=True),
    Param("device", "0", "opencv: camera index ('0'), device path (/dev/video0), video file or "
          "stream URL.", read_only=True),
    Param("folder", "", "folder: the folder of images (png, jpg, jpeg, bmp, tif, tiff).",
          read_only=True, constraints="required for backend folder"),
    Param("loop", False, "folder: start again at the first image after the last.",
          read_only=True),
    Param("flush_frames", 0, "opencv: frames discarded before each grab, so that a capture "
          "returns a fresh frame rather than one buffered by the driver.", bounds=(0, 100),
          read_only=True),
    Param("rate_hz", 0.0, "Frames per second streamed without capture calls.",
          bounds=(0.0, 120.0), read_only=True, constraints="0 = frames on capture only"),
    AUTOSTART,
]


def _check_source(values: dict) -> None:
    """:class:`ParameterError` for parameters that name no source the node can open."""
    if values["backend"] == "mock":
        raise ParameterError("backend", "'mock' is served by sfs-mock-hardware (it renders at "
                             "the simulated controller's angles); expected opencv or folder")
    if values["backend"] == "folder" and not values["folder"].strip():
        raise ParameterError("folder", "is required for backend 'folder': the folder of "
                             "images to serve")


def _open_source(values: dict) -> CameraSource:
    """The source the parameters name; :class:`ParameterError` if it cannot be opened."""
    if values["backend"] == "folder":
        try:
            return FolderSource(values["folder"], loop=values["loop"])
        except ValueError as exc:
            raise ParameterError("folder", str(exc)) from None
    try:
        return OpenCVSource(values["device"], width=values["width"], height=values["height"],
                            flush_frames=values["flush_frames"])
    except ValueError as exc:
        raise ParameterError("device", str(exc)) from None


class CameraNode(LifecycleNode):
    """Publishes frames of a :class:`CameraSource` on ``capture`` calls and at ``rate_hz``.

    source : CameraSource, optional
        Used instead of the one the parameters name, whatever ``backend`` says
        (the mock hardware injects its rendered camera); the node closes it in
        :meth:`destroy_node`, or at once if the parameters are refused.

    Raises :class:`ParameterError` at construction for invalid parameters, and with
    ``autostart`` for a camera that cannot be opened.
    """

    def __init__(self, source: CameraSource | None = None, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            values = declare(self, [*PARAMS, *WRITABLE_RIG_PARAMS, *FRAME_PARAMS])
            self._rig = RigParameters(self, on_change=self._new_rig)
            calibration = self._rig.calibration
            self._frame_id = frame_names(values).camera_frame
            if source is None:
                _check_source(values)
        except ParameterError:
            if source is not None:
                source.close()
            super().destroy_node()         # no source of ours to release
            raise
        self._values = values
        self._injected = source
        self._source: CameraSource | None = source
        self._lifecycle = "unconfigured"
        self._stream = None                # the rate_hz timer, while active
        self._capture = None               # the capture service, while active
        self._size = (calibration.width, calibration.height)
        self._camera = rig_camera(0.0, 0.0, calibration)   # only its intrinsics are published

        self._lock = threading.Lock()      # counts and problem: grabs and diagnostics
        self._counts = {"frames": 0, "failures": 0}
        self._problem = ""                 # the current failure, "" after a good frame
        self._last_problem = ""            # the last failure, kept after good frames

        qos = capture_qos(10)
        self._image_pub = self.create_publisher(Image, "image_raw", qos)
        self._info_pub = self.create_publisher(CameraInfo, "camera_info", qos)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self._grabs = MutuallyExclusiveCallbackGroup()
        self.create_timer(1.0, self._publish_diagnostics)
        self._opening_error: ParameterError | None = None
        if values["autostart"] and not bring_up(self):
            self.destroy_node()
            raise self._opening_error or ParameterError("autostart", "the camera node did not "
                                                        "become active")
        rate = f"streaming at {values['rate_hz']} Hz" if values["rate_hz"] > 0 \
            else "frames on capture"
        self.get_logger().info(f"{self._name()}, {self._size[0]}x{self._size[1]} rgb8, "
                               f"{rate} when active")

    # -- lifecycle -----------------------------------------------------------------------------

    def on_configure(self, _state):
        if self._source is None:
            try:
                self._source = _open_source(self._values)
            except ParameterError as exc:
                self._opening_error = exc
                if not self._values["autostart"]:      # autostart: the start-up says why
                    self.get_logger().warning(f"configure failed: {exc}")
                return FAILURE
        return self._now("inactive")

    def on_activate(self, _state):
        self._capture = self.create_service(Trigger, private("capture"), self._on_capture,
                                            callback_group=self._grabs)
        rate_hz = self._values["rate_hz"]
        if rate_hz > 0:
            self._stream = self.create_timer(1.0 / rate_hz, self._grab_and_publish,
                                             callback_group=self._grabs)
        return self._now("active")

    def on_deactivate(self, _state):
        self._stop_stream()
        return self._now("inactive")

    def on_cleanup(self, _state):
        self._close_own()
        return self._now("unconfigured")

    def on_shutdown(self, _state):
        self._stop_stream()
        self._close_own()
        return self._now("finalized")

    def _now(self, state: str):
        """Enter lifecycle ``state`` (logged, in the diagnostics); SUCCESS."""
        self._lifecycle = state
        self.get_logger().info(f"camera node {state}")
        self._publish_diagnostics()
        return SUCCESS

    def _stop_stream(self) -> None:
        """Take the stream and the ``capture`` service away."""
        if self._stream is not None:
            self.destroy_timer(self._stream)
            self._stream = None
        if self._capture is not None:
            self.destroy_service(self._capture)
            self._capture = None

    def _close_own(self) -> None:
        """Close the source the node opened (an injected one stays open for the next
        configure: its owner closes it through :meth:`destroy_node`)."""
        if self._source is not None and self._source is not self._injected:
            self._source.close()
            self._source = None

    def _name(self) -> str:
        return self._source.name if self._source is not None else "no camera open"

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the frames, pixels: the rig's."""
        return self._size

    def destroy_node(self) -> None:
        self._stop_stream()
        self._close_own()
        if self._injected is not None:
            self._injected.close()
        super().destroy_node()

    def _new_rig(self, rig) -> None:
        """A new rig was set: the next frames' ``camera_info`` carries its intrinsics."""
        self._camera = rig_camera(0.0, 0.0, rig)
        self.get_logger().info(f"new rig: camera_info from the next frame on, f = "
                               f"({rig.fx:.2f}, {rig.fy:.2f}) px, distortion "
                               f"{list(rig.distortion)}")

    def _on_capture(self, _request, response):
        response.success, response.message = self._grab_and_publish()
        return response

    def _grab_and_publish(self) -> tuple[bool, str]:
        """Grab, check and publish one frame; (success, JSON summary or the reason)."""
        stamp = self.get_clock().now().to_msg()
        width, height = self._size
        try:
            frame = self._source.grab()
        except FrameUnavailable as exc:
            return self._failed(str(exc))
        if frame.shape != (height, width, 3) or frame.dtype != np.uint8:
            return self._failed(f"{self._source.name} gave a {frame.shape[1]}x{frame.shape[0]} "
                                f"frame (shape {frame.shape}, {frame.dtype}), expected the "
                                f"rig's {width}x{height} (width x height) 8-bit RGB")
        image = image_to_msg(frame, stamp=stamp, frame_id=self._frame_id)
        self._image_pub.publish(image)
        self._info_pub.publish(camera_info(self._camera, stamp=stamp, frame_id=self._frame_id))
        with self._lock:
            self._counts["frames"] += 1
            n = self._counts["frames"]
            recovered, self._problem = bool(self._problem), ""
        if recovered:
            self._publish_diagnostics()
        return True, json.dumps({"stamp": list(stamp_key(stamp)), "width": width,
                                 "height": height, "frame": n})

    def _failed(self, reason: str) -> tuple[bool, str]:
        with self._lock:
            self._counts["failures"] += 1
            repeated, self._problem = reason == self._problem, reason
            self._last_problem = reason
        if not repeated:                   # a stream failing at every tick logs once
            self.get_logger().error(reason)
        self._publish_diagnostics()
        return False, reason

    def _publish_diagnostics(self) -> None:
        with self._lock:
            values, problem = dict(self._counts), self._problem
            values["last_problem"] = self._last_problem
        level, message = ((DiagnosticStatus.ERROR, problem) if problem
                          else (DiagnosticStatus.OK, f"{values['frames']} frames"))
        if self._lifecycle != "active":
            level, message = DiagnosticStatus.WARN, f"{self._lifecycle}: activate it"
        values.update(lifecycle=self._lifecycle, source=self._name(),
                      size=f"{self._size[0]}x{self._size[1]}")
        self._diag_pub.publish(diagnostic_array(
            status_name(self, "camera"), level, message, values,
            stamp=self.get_clock().now().to_msg(), hardware_id=self._name()))


def main(args=None) -> None:
    """Entry point ``sfs-camera``.

    ``sfs-camera --ros-args --params-file config/rig.yaml --params-file config/camera.yaml``
    """
    configure_process()
    run_node("sfs-camera", CameraNode, args, threads=2)


if __name__ == "__main__":
    main()
