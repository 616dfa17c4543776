"""Carving node: silhouettes in, the live hull out; the carved scan on request.

| kind | name | type | notes |
|---|---|---|---|
| sub | ``capture/mask`` | sensor_msgs/Image | mono8, 0 / 255 (or 0 / 1), the rig's size |
| sub | ``capture/mask_joint_state`` | sensor_msgs/JointState | same stamp as its mask |
| sub | ``capture/image`` | sensor_msgs/Image | the captured images, to colour the mesh (``colour``) |
| pub | ``capture/stored`` | std_msgs/Header | a view's stamp once stored (or rejected): its receipt |
| pub | ``hull`` | sensor_msgs/PointCloud2 | surface voxels of the live hull, turntable frame |
| pub | ``camera_poses`` | geometry_msgs/PoseArray | the cameras of this scan's views, turntable frame |
| pub | ``~/view_image`` | sfs_ros_interfaces/ViewImage | each stored view's colour image, for meshing |
| pub | ``/diagnostics`` | diagnostic_msgs/DiagnosticArray | per event and at 1 Hz |
| pub | ``~/status`` | sfs_ros_interfaces/ReconstructionStatus | the scan's fields; transient local |
| srv | ``~/carve_scan`` | sfs_ros_interfaces/CarveScan | the carved scan, for the meshing node |
| srv | ``~/new_scan`` | sfs_ros_interfaces/NewScan | start a new scan, optionally naming it |
| srv | ``~/reset`` | std_srvs/Trigger | alias of ``new_scan`` with the ``scan_name`` parameter |

The carving half of the cell's reconstruction (the meshing node,
:mod:`sfs_ros.nodes.meshing_node`, is the other): it keeps the scan. Each view is stored
in a session folder under ``output_dir`` and carved into the live hull as it arrives
(:class:`sfs_ros.cell.live.LiveReconstruction`); ``carve_scan`` answers with the views'
carving at the final grid (:meth:`LiveReconstruction.carve`, a
``sfs_ros_interfaces/CarvedScan``: the hull, the mesher's input, the views' masks and
the images that colour the mesh), as often as it is asked: a meshing node restarted or
swapped asks again. Its options (``resolution``, ``bounds_m``, ``mesher``, ``colour``)
are those of the ``Reconstruct`` request; each left empty is the node's parameter; a bad
one, or a grid that does not fit ``max_memory``, is refused at once with the reason.
``~/status`` (reliable, transient local, depth 1) gives this scan's session folder, views
stored and views rejected (``view at stamp S (theta T rad, phi P rad): reason``) and
the problem, on every change; its ``reconstructions`` and ``mesh_path`` are the meshing
node's (``meshing/status``).

Mask, joint state and receipt topics: reliable, volatile, depth ``queue_depth``
(:func:`sfs_ros.ros.capture_qos`); masks and joint states are paired by
exactly equal stamps (either order). Once a view is stored (or rejected as unusable)
its header goes out on ``capture/stored``: the scan node resends a capture that has no
receipt in time, and a view that comes again is not carved twice (``repeats``, receipted
again); a late copy of a view of an earlier scan is not stored in the new one
(``stale``, receipted again). ``hull`` and ``camera_poses``: reliable, transient local,
depth 1 (:func:`sfs_ros.ros.result_qos`).

Threads: the executor only decodes and pairs messages and answers services; one worker
thread owns the ``LiveReconstruction`` and takes, in arrival order, views, carvings and
resets: a carving uses exactly the views that arrived before the request. With
``colour`` the node keeps each view's captured image (in memory, paired with its view by
stamp, whichever comes first); the carved scan carries those of the views that colour
the mesh. Each view's image goes out on ``~/view_image`` (reliable, volatile) once both
have come, so that the meshing node holds the images before the scan ends:
``carve_scan`` leaves out those its request names as held (``images_held``).

A malformed message or an unusable view is logged, counted in the diagnostics (ERROR
until the next good view) and dropped; the node carries on. An all-zero mask is stored
but carves nothing (WARN). A node started again takes up the scan being received
(:meth:`LiveReconstruction.reopen`). A view the disk refuses is an ERROR naming the
folder and the free space; it is kept in memory without a receipt and stored as soon as
a write succeeds. A ``resolution`` whose grid does not fit ``max_memory`` is refused
before anything is allocated: the node stays up with an ERROR giving the memory it
would need and receipts no view.

Per-scan settings (``bounds_m``, ``resolution``, ``mesher``, ``scan_name``) and the rig
(:data:`sfs_ros.ros.rig_params.WRITABLE_RIG_PARAMS`) can be set at run time, between
scans: checked when set, used from the next ``reset``. A ``reset`` (or ``new_scan``) is
refused with the reason while the scan node reports its scan ``running``, ``waiting`` or
``paused``.

Parameters: see :data:`PARAMS`; ``output_dir`` is required and every file the node
writes stays inside it. The frames (:data:`sfs_ros.ros.frames.FRAME_PARAMS`) name the
turntable frame ``hull``, ``camera_poses`` and the carved scan are in.
"""

from __future__ import annotations

import os
import threading
import time
import traceback
from dataclasses import replace
from functools import partial

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState, PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from sfs_ros.cell.live import DuplicateViewError, LiveReconstruction, check_scan_name
from sfs_ros.cell.mesh_options import MeshOptions, mesh_options
from sfs_ros.cell.messages import check_image_size
from sfs_ros.core.carving.resolution import (
    default_memory_budget,
    grid_shape,
    parse_memory,
    refuse_unfit_grid,
)
from sfs_ros.core.exchange.views import as_bounds
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.meshing.meshers import MESHER
from sfs_ros.core.resident_memory import prefault
from sfs_ros.core.settings import BOUNDS_M, COLOUR, MAX_MEMORY, RESOLUTION
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.carved_scan_msg import carved_scan_to_msg, view_image_msg
from sfs_ros.ros.convert import (
    angles_from_joint_state,
    camera_poses,
    diagnostic_array,
    header,
    health,
    msg_to_image,
    points_to_cloud,
)
from sfs_ros.ros.frames import FRAME_PARAMS, frame_names
from sfs_ros.ros.names import (
    DIAGNOSTICS,
    RECONSTRUCTION_STATUS,
    VIEW_IMAGE_DEPTH,
    VIEW_IMAGES,
    private,
    status_name,
)
from sfs_ros.ros.paired_input import PairedInput, Stream
from sfs_ros.ros.pairing import format_stamp, stamp_key, view_key
from sfs_ros.ros.params import Param, ParameterError, declare, read, validating_callback
from sfs_ros.ros.rehearsal import Rehearsal
from sfs_ros.ros.rig_params import (
    CAPTURING_STATES,
    WRITABLE_RIG_PARAMS,
    RigParameters,
    rig_calibration,
)
from sfs_ros.ros.worker import Worker, internal_error
from sfs_ros_interfaces.msg import CarvedScan as CarvedScanMsg
from sfs_ros_interfaces.msg import ReconstructionStatus, ViewImage
from sfs_ros_interfaces.srv import CarveScan, NewScan

__all__ = ["CarvingNode", "PARAMS", "main"]

NODE_NAME = "carving"

#: The node's parameters: the rig calibration, then the scan's own (the per-scan settings
#: settable at run time, see the module's description).
PARAMS: list[Param] = [
    *WRITABLE_RIG_PARAMS,
    Param.of(BOUNDS_M, constraints="six values, min < max on each axis; from the next reset"),
    Param.of(RESOLUTION, constraints="the live hull's and the final reconstruction's; from "
             "the next reset"),
    Param.of(MESHER, constraints="from the next reset"),
    Param("scan_name", "", "Name of the next scan's folder in output_dir and of its mesh "
          "(<name>.ply); empty = scan_NNN, the next free number.",
          constraints="from the next reset; 1-100 letters, digits, '_', '-', '.', a folder "
          "not yet in output_dir"),
    Param("output_dir", "", "Folder for scan session folders, meshes and reports (created if "
          "needed); every file the node writes stays inside it.", read_only=True,
          constraints="required, non-empty"),
    Param("hull_rate_hz", 2.0, "Most hull clouds per second; the latest is always published "
          "once the views received so far are carved.", bounds=(0.0, 1000.0), read_only=True,
          constraints="0 = after every view"),
    Param("max_hull_points", 100000, "Most points of a hull cloud (an evenly spaced subset "
          "of the surface voxels beyond that).", bounds=(1, 100_000_000), read_only=True),
    Param("queue_depth", 100, "Depth of the reliable mask topics and of the buffer of unpaired "
          "halves per topic; at least the number of views of a scan.", bounds=(1, 100000),
          read_only=True),
    Param.of(COLOUR, read_only=True, constraints="the captured images on capture/image"),
    Param.of(MAX_MEMORY, read_only=True, constraints=f"empty = {MAX_MEMORY.default_text}"),
    Param("rehearse", True, "At start, receive and reconstruct a small simulated scan (in a "
          "folder in output_dir, removed after) so that the first real reconstruction finds "
          "its code loaded (about 0.2 s less from the last view to the mesh).", read_only=True),
]
#: How often views that could not be stored (a full disk) are tried again, s.
STORE_RETRY_S = 1.0
#: Views of earlier scans remembered by their keys, so that a late copy of one (a resend
#: that crossed its receipt) is not stored into the next scan; the most recent are kept.
EARLIER_VIEWS_KEPT = 10_000


def _decode_mask(msg: Image, size: tuple[int, int]) -> tuple[np.ndarray, str]:
    """A mono8 mask (a copy) and its frame id; ValueError for another size than ``size``
    (the rig's width, height), another encoding or a bad layout."""
    check_image_size(msg, size, "mask")
    if msg.encoding != "mono8":
        raise ValueError(f"mask encoding is {msg.encoding!r}, expected 'mono8'")
    return msg_to_image(msg).copy(), msg.header.frame_id


def _store_problem(stamp, live: LiveReconstruction, exc: OSError, waiting: int) -> str:
    """The ERROR of a view the disk refused: where, why, the free space, what happens next."""
    folder = live.session_dir or live.output_dir
    try:
        stat = os.statvfs(live.output_dir)
        free = f"{stat.f_bavail * stat.f_frsize / 1e6:.1f} MB free"
    except OSError:
        free = "free space unknown"
    return (f"view at stamp {format_stamp(stamp)} not stored in {folder}: "
            f"{exc.strerror or exc} ({free}; a view's image takes at most "
            f"{live.calibration.width * live.calibration.height * 3 / 1e6:.2f} MB); {waiting} "
            f"view(s) kept in memory without a receipt, stored as soon as a write succeeds")


def _scan_settings(values: dict) -> tuple:
    """The settings that need a new :class:`LiveReconstruction` when they change (the
    rig among them)."""
    return (tuple(values["bounds_m"]), values["resolution"], values["mesher"],
            rig_calibration(values))


def _bounds(values: dict) -> np.ndarray:
    box = values["bounds_m"]
    try:
        if len(box) != 6:
            raise ValueError(f"got {len(box)} values")
        return as_bounds(np.reshape(box, (2, 3)), what="bounds_m")
    except ValueError:
        raise ParameterError("bounds_m", f"got {box!r}, expected [xmin, ymin, zmin, xmax, ymax, "
                             "zmax] with finite min < max") from None



class CarvingNode(Node):
    """Carves paired masks into a live hull; hands the carved scan over on request.

    Raises :class:`ParameterError` at construction for invalid parameters.
    ``destroy_node`` finishes the queued work and stops the worker thread.
    """

    def __init__(self, *, memory_kept: bool = False, **kwargs):
        self._worker = None  # started last; a node refused at start-up has none to stop
        self._rehearsal = None
        super().__init__(NODE_NAME, **kwargs)
        self._memory_kept = memory_kept    # malloc keeps freed memory: prefault helps
        values = declare(self, PARAMS)
        # Frame of the hull, camera poses and carved scan: the object frame on the turntable.
        self._frame_id = frame_names(declare(self, FRAME_PARAMS)).turntable_frame
        if not values["output_dir"].strip():
            raise ParameterError("output_dir", "is required: the folder for the scans")
        calibration = rig_calibration(values)
        bounds = _bounds(values)
        try:
            budget = parse_memory(values["max_memory"]) if values["max_memory"].strip() \
                else default_memory_budget()
        except ValueError as exc:
            raise ParameterError("max_memory", str(exc)) from None
        self._budget = budget
        self._live = None
        # Why no reconstruction can be held (the node stays up; a reset with a resolution
        # that fits ends it).
        self._refusal = self._grid_refusal(values)
        if not self._refusal:
            try:
                # scan_name is for the next reset: a respawned node must not be refused
                # because the scan it was named for is on disk already.
                self._live = LiveReconstruction(calibration, bounds,
                                                output_dir=values["output_dir"],
                                                resolution=values["resolution"],
                                                mesher=values["mesher"])
            except (ValueError, OSError) as exc:
                raise ParameterError("output_dir" if isinstance(exc, OSError)
                                     else "resolution", str(exc)) from None
        self._scan_settings = _scan_settings(values)
        self.add_on_set_parameters_callback(validating_callback(self, PARAMS,
                                                                self._check_scan_settings))
        self._rig = RigParameters(self, on_change=self._new_rig)
        self._hull_period = 0.0 if values["hull_rate_hz"] == 0 else 1.0 / values["hull_rate_hz"]
        self._max_hull_points = values["max_hull_points"]
        depth = values["queue_depth"]

        self._stats_lock = threading.Lock()
        self._counts = {"views_received": 0, "carved": 0, "empty": 0, "rejected": 0,
                        "malformed": 0, "repeats": 0, "stale": 0, "unpaired_dropped": 0,
                        "carvings": 0, "carving_failures": 0, "scan_views": 0}
        self._carve_s = 0.0     # storing and carving this scan's views, for the benchmark
        self._unstored: dict = {}   # view key -> _add_view's arguments (worker thread)
        self._earlier: dict = {}    # keys of views stored in earlier scans (worker thread)
        self._problem = self._refusal
        self._warning = ""
        self._rejected: list[str] = []   # this scan's rejected views, named

        inputs = MutuallyExclusiveCallbackGroup()     # pairer, timers
        services = MutuallyExclusiveCallbackGroup()   # one request at a time, waits on the worker
        qos = capture_qos(depth)
        self._stored_pub = self.create_publisher(Header, "capture/stored", qos)
        self._hull_pub = self.create_publisher(PointCloud2, "hull", result_qos())
        self._poses_pub = self.create_publisher(PoseArray, "camera_poses", result_qos())
        self._view_image_pub = self.create_publisher(
            ViewImage, "~/" + VIEW_IMAGES.split("/", 1)[1], capture_qos(VIEW_IMAGE_DEPTH))
        self._cameras: list = []   # of this scan's views, for camera_poses (worker thread)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self._status_pub = self.create_publisher(ReconstructionStatus,
                                                 "~/" + RECONSTRUCTION_STATUS.split("/", 1)[1],
                                                 result_qos())
        # The image size is fixed while the node runs (RigParameters): anything else is
        # refused before it is kept.
        self._size = (calibration.width, calibration.height)
        self._input = PairedInput(
            self, Stream(Image, "capture/mask", "mask",
                         lambda msg: _decode_mask(msg, self._size)),
            Stream(JointState, "capture/mask_joint_state", "joint state",
                   angles_from_joint_state),
            depth, qos, unit="view", on_pair=self._on_view, on_problem=self._dropped,
            callback_group=inputs)
        if values["colour"]:
            self.create_subscription(Image, "capture/image", self._on_image, qos,
                                     callback_group=inputs)
        self.create_service(CarveScan, private("carve_scan"), self._on_carve_scan,
                            callback_group=services)
        self.create_service(Trigger, private("reset"), self._on_reset, callback_group=services)
        self.create_service(NewScan, private("new_scan"), self._on_new_scan,
                            callback_group=services)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=inputs)
        self.create_timer(STORE_RETRY_S, self._retry_unstored, callback_group=inputs)
        self._last_hull = -float("inf")   # worker thread: when the hull was last published
        self._hull_dirty = False           # worker thread: carved since then
        self._worker = Worker("carving", on_error=self._job_failed)
        self._publish_status()
        if self._refusal:
            self.get_logger().error(f"{self._refusal}; the node receipts no view and "
                                    "carves nothing until started with another one")
            return
        self.get_logger().info(
            f"carving into {self._live.output_dir} (box {self._live.bounds_m.tolist()}, "
            f"resolution {values['resolution']}, {values['mesher']}, queue depth {depth})")
        self._submit("reopen", self._reopen)
        # Before the rehearsal thread allocates, so that it finds the pages touched too.
        self._prefault()
        if values["rehearse"]:
            # Beside the worker, not on it: with kernels still to compile (a fresh install)
            # it takes minutes, and views and resets must not wait for it.
            self._rehearsal = Rehearsal(self, self._live.output_dir)

    def destroy_node(self) -> None:
        """Finish the queued work, stop the worker thread and the rehearsal
        (:meth:`Rehearsal.join`), then destroy the node."""
        if self._worker is not None:
            self._worker.stop()
            self._worker.join()
        if self._rehearsal is not None:
            self._rehearsal.join()
        super().destroy_node()

    # -- inputs (executor threads) -----------------------------------------------------------

    def _on_image(self, msg: Image) -> None:
        """A captured image, kept to colour the mesh (its view may come before or after)."""
        try:
            stamp = stamp_key(msg.header.stamp)
            check_image_size(msg, self._size, "captured image")
            image = msg_to_image(msg)
            if image.ndim != 3 or image.dtype != np.uint8:
                raise ValueError(f"encoding {msg.encoding!r}, expected rgb8 or bgr8")
        except ValueError as exc:
            self._count("malformed")
            self._report_problem(f"captured image not kept for colour: {exc}")
            return
        self._submit("image", self._add_colour_image, stamp, image.copy())

    def _on_view(self, stamp, mask_and_frame: tuple[np.ndarray, str],
                 angles: tuple[float, float]) -> None:
        (mask, frame_id), (theta, phi) = mask_and_frame, angles
        self._count("views_received")
        self._submit("view", self._add_view, stamp, frame_id, mask, theta, phi)

    def _dropped(self, kind: str, text: str) -> None:
        """A message of a view was dropped: ``kind`` is its counter."""
        self._count(kind)
        self._report_problem(text)

    def _on_carve_scan(self, request, response):
        """``carve_scan``: options checked here (refused at once with the reason), the
        carving made in the worker."""
        try:
            options = mesh_options(
                self.get_parameter("output_dir").value, resolution=request.resolution,
                bounds_m=list(request.bounds_m), mesher=request.mesher, colour=request.colour)
        except ValueError as exc:
            response.success, response.message = False, f"request refused: {exc}"
            return response
        grid = dict(read(self, PARAMS))
        if options.resolution is not None:
            grid["resolution"] = options.resolution
        if options.bounds_m is not None:
            grid["bounds_m"] = options.bounds_m.ravel().tolist()
        refusal = self._grid_refusal(grid) if grid != read(self, PARAMS) else ""
        if refusal:
            response.success, response.message = False, f"request {refusal}"
            return response
        try:
            held = frozenset(request.images_held)
            response.success, response.message, scan = self._submit(
                "carve", self._carve, options, request.images_session, held).result()
        except Exception as exc:  # noqa: BLE001 -- the worker reported it; the caller gets it
            response.success, response.message, scan = False, internal_error("carve", exc), None
        if scan is not None:
            response.scan = scan
        return response

    def _on_reset(self, _request, response):
        return self._request("reset", self._reset, response)

    def _on_new_scan(self, request, response):
        return self._request("reset", partial(self._reset, request.scan_name), response)

    def _capturing(self) -> str:
        """Why no new scan may start now (the scan node is taking views: a new scan would
        split its views over two session folders), or ""."""
        scan = self._rig.scan_in(CAPTURING_STATES)
        if scan is None:
            return ""
        return (f"reset refused: the scan node reports scan {scan[0]} {scan[1]}; its views go "
                "to the scan open now (cancel it first: scan/cancel, then reset)")

    def _request(self, name: str, job, response):
        """Run ``job`` (which answers ``(success, message)``) in the worker and answer with it."""
        try:
            response.success, response.message = self._submit(name, job).result()
        except Exception as exc:  # noqa: BLE001 -- the worker reported it; the caller gets it
            response.success, response.message = False, internal_error(name, exc)
        return response

    def _submit(self, name: str, job, *args):
        """Queue ``job(*args)`` for the worker, followed by the hull's publication when it is
        due; its future."""
        return self._worker.submit(partial(self._then_hull, job, *args), name=name)

    # -- worker thread -----------------------------------------------------------------------

    def _then_hull(self, job, *args):
        """Run ``job``; then publish the hull if a job changed it and no job waits or the
        period is over. ``job``'s answer."""
        answer = job(*args)
        now = time.monotonic()
        if self._hull_dirty and (self._worker.pending() == 0
                                 or now - self._last_hull >= self._hull_period):
            self._publish_hull()
            self._last_hull, self._hull_dirty = now, False
        return answer

    def _job_failed(self, name: str, exc: Exception) -> None:
        text = internal_error(name, exc)
        self.get_logger().error(f"{text}\n{''.join(traceback.format_exception(exc))}")
        self._report_problem(text)

    def _reopen(self) -> None:
        """Take up the scan that was open when the node last stopped (a restart)."""
        self.get_logger().info(self._live.reopen())
        self._cameras = [rig_camera(theta, phi, self._live.calibration)
                         for _, _, theta, phi in self._live.views()]
        with self._stats_lock:
            self._counts["scan_views"] = self._live.n_views
        if self._cameras:
            self._publish_poses()
            self._hull_dirty = True
        self._publish_status()

    def _prefault(self) -> None:
        """Touch the heap a reconstruction will need, once, before the first one (see
        :mod:`sfs_ros.core.resident_memory`); no more than the memory budget."""
        reserve = 0 if self._live is None else min(self._live.working_memory_bytes,
                                                    self._budget)
        if prefault(reserve, memory_kept=self._memory_kept):
            self.get_logger().info(f"{reserve >> 20} MiB of working memory made resident")

    def _retry_unstored(self) -> None:
        """Timer: store again the views a full disk refused (in the worker)."""
        if self._unstored:
            self._submit("store again", self._store_again)

    def _store_again(self) -> None:
        for args in list(self._unstored.values()):
            self._add_view(*args)
            if view_key(args[0]) in self._unstored:
                return                      # still refused: the rest waits too

    def _add_colour_image(self, stamp, image) -> None:
        """Keep a captured image to colour the mesh."""
        if self._live is None:
            return
        try:
            self._live.add_colour_image(view_key(stamp), image)
        except ValueError as exc:
            self._report_problem(f"captured image at stamp {format_stamp(stamp)} not kept for "
                                 f"colour: {exc}")
            return
        self._send_view_image(stamp)

    def _send_view_image(self, stamp) -> None:
        """``~/view_image``: the view's colour image, once both the view and its image
        are in."""
        found = self._live.colour_image(view_key(stamp))
        if found is not None:
            self._view_image_pub.publish(view_image_msg(
                str(self._live.session_dir), *found,
                header=header(stamp=stamp, frame_id=self._frame_id)))

    def _grid_refusal(self, values: dict) -> str:
        """Why the voxel grid of ``values`` cannot be held within the memory budget ("" if it
        can), with the memory it would need; nothing is allocated."""
        bounds = _bounds(values)
        voxel_m = float(np.max(bounds[1] - bounds[0])) / values["resolution"]
        try:
            refuse_unfit_grid(grid_shape(bounds, voxel_m), self._budget,
                              f"resolution {values['resolution']}")
        except ValueError as exc:
            return f"refused: {exc}"
        return ""

    def _check_scan_settings(self, values: dict) -> None:
        """ParameterError for per-scan settings that cannot make a scan."""
        _bounds(values)
        refusal = self._grid_refusal(values)
        if refusal:
            raise ParameterError("resolution", refusal)
        if values["scan_name"]:
            try:
                check_scan_name(values["output_dir"], values["scan_name"])
            except ValueError as exc:
                raise ParameterError("scan_name", str(exc)) from None

    def _reset(self, scan_name: str = "") -> tuple[bool, str]:
        """Start a new scan with the per-scan settings as they are now, named ``scan_name``
        ("" = the ``scan_name`` parameter); publishes an empty hull. (False, the reason) if
        the scan name is taken or the grid does not fit in memory: nothing changes."""
        values = read(self, PARAMS)
        settings, name = _scan_settings(values), scan_name or values["scan_name"] or None
        refusal = self._capturing() or self._grid_refusal(values)
        if refusal:
            self.get_logger().error(refusal)
            return False, refusal
        earlier = [] if self._live is None else self._live.view_keys()
        try:
            if self._live is None or settings != self._scan_settings:
                if self._live is not None:
                    self._live.close()
                self._live = LiveReconstruction(
                    rig_calibration(values), _bounds(values), output_dir=values["output_dir"],
                    resolution=values["resolution"], mesher=values["mesher"], scan_name=name)
                self._scan_settings, self._refusal = settings, ""
                self._prefault()
                self.get_logger().info(f"new scan settings: box {values['bounds_m']}, "
                                       f"resolution {values['resolution']}, {values['mesher']}, "
                                       f"rig f = ({values['fx']}, {values['fy']}) px")
            else:
                self._live.reset(name)
        except ValueError as exc:
            text = f"reset refused: {exc}"
            self.get_logger().error(text)
            return False, text
        self._unstored.clear()
        self._remember_earlier(earlier)
        self._cameras = []
        self._publish_poses()
        with self._stats_lock:
            self._counts["scan_views"] = 0
            self._carve_s = 0.0
            self._problem = self._warning = ""
            self._rejected = []
        self.get_logger().info("reset: the next view starts a new scan")
        self._publish_status()
        self._hull_dirty = True
        return True, "new scan: no views yet"

    def _new_rig(self, rig) -> None:
        """A new rig was set (a parameter thread): the next reset uses it."""
        self.get_logger().info(f"new rig (f = ({rig.fx:.2f}, {rig.fy:.2f}) px, distortion "
                               f"{list(rig.distortion)}): the next scan (reset) uses it")

    def _remember_earlier(self, keys: list) -> None:
        """Remember the keys of a finished scan's views (at most :data:`EARLIER_VIEWS_KEPT`)."""
        self._earlier.update(dict.fromkeys(keys))
        for key in list(self._earlier)[:max(0, len(self._earlier) - EARLIER_VIEWS_KEPT)]:
            del self._earlier[key]

    def _add_view(self, stamp, frame_id: str, mask, theta: float, phi: float) -> None:
        """Give one view to the live reconstruction and send its receipt."""
        if self._live is None:
            self._report_problem(f"view at stamp {format_stamp(stamp)} not received: "
                                 f"{self._refusal}")
            return
        receipt = header(stamp=stamp, frame_id=frame_id)
        start = time.perf_counter()
        key = view_key(stamp)
        if key in self._earlier:
            self._count("stale")
            self.get_logger().info(f"view at stamp {format_stamp(stamp)} came again after its "
                                   "scan ended: not stored in this scan, receipt sent again")
            self._stored_pub.publish(receipt)
            return
        self._unstored.pop(key, None)
        try:
            added = self._live.add_view(key, mask, theta, phi)
        except OSError as exc:
            self._unstored[key] = (stamp, frame_id, mask, theta, phi)
            self._report_problem(_store_problem(stamp, self._live, exc, len(self._unstored)))
            return
        except DuplicateViewError:
            self._count("repeats")
            self.get_logger().info(f"view at stamp {format_stamp(stamp)} came again: already "
                                   "stored, receipt sent again")
            self._stored_pub.publish(receipt)
            return
        except ValueError as exc:
            self._count("rejected")
            with self._stats_lock:
                self._rejected.append(f"view at stamp {format_stamp(stamp)} (theta {theta:.6g} "
                                      f"rad, phi {phi:.6g} rad): {exc}")
            self._stored_pub.publish(receipt)      # resending cannot make it usable
            self._report_problem(f"view at stamp {format_stamp(stamp)} rejected: {exc}")
            return
        self._hull_dirty |= added.carved
        self._stored_pub.publish(receipt)
        self._cameras.append(rig_camera(theta, phi, self._live.calibration))
        self._publish_poses()
        with self._stats_lock:
            self._carve_s += time.perf_counter() - start
            self._counts["scan_views"] = added.n_views
            self._counts["carved" if added.carved else "empty"] += 1
            self._problem = ""
            self._warning = ("" if added.carved
                             else f"view at stamp {format_stamp(stamp)}: {added.reason}")
        if self._warning:
            self.get_logger().warning(self._warning)
        self._publish_diagnostics()
        self._publish_status()
        self._send_view_image(stamp)

    def _carve(self, options: MeshOptions, images_session: str,
               held: frozenset) -> tuple[bool, str, CarvedScanMsg | None]:
        """The carved scan of the views received, with ``options``: ``(success, summary or
        the reason, the message or None)``; without the images of the views in ``held`` if
        the caller holds them of this scan (``images_session``)."""
        if self._live is None:
            return False, self._refusal, None
        start = time.perf_counter()
        try:
            carved = self._live.carve(resolution=options.resolution, bounds_m=options.bounds_m,
                                      mesher=options.mesher, colour=options.colour)
            hand_over = replace(self._live.hand_over(), frame_id=self._frame_id)
            msg = carved_scan_to_msg(
                carved, hand_over, stamp=self.get_clock().now().to_msg(),
                held=held if images_session == hand_over.session_dir else frozenset())
        except ValueError as exc:
            self._count("carving_failures")
            reason = str(exc)
            if self._live.n_views == 0:
                reason += ": publish masks with their joint states first"
            text = f"carving failed: {reason}"
            self.get_logger().error(text)
            self._publish_diagnostics()
            return False, text, None
        self._count("carvings")
        text = (f"carved {sum(v.role == 'used' for v in carved.views)} of "
                f"{self._live.n_views} views on a grid of {list(carved.grid.shape)} voxels "
                f"({carved.mesher}, {len(carved.colour_views)} views to colour from) in "
                f"{time.perf_counter() - start:.2f} s")
        self.get_logger().info(text)
        self._publish_diagnostics()
        return True, text, msg

    def _publish_poses(self) -> None:
        self._poses_pub.publish(camera_poses(self._cameras, stamp=self.get_clock().now().to_msg(),
                                             frame_id=self._frame_id))

    def _publish_hull(self) -> None:
        if self._live is None:
            return
        points = self._live.hull_points(self._max_hull_points)
        stamp = self.get_clock().now().to_msg()
        self._hull_pub.publish(points_to_cloud(points, stamp=stamp, frame_id=self._frame_id))

    # -- diagnostics (any thread) ------------------------------------------------------------

    def _count(self, name: str) -> None:
        with self._stats_lock:
            self._counts[name] += 1

    def _report_problem(self, text: str) -> None:
        with self._stats_lock:
            self._problem = text
        self.get_logger().error(text)
        self._publish_diagnostics()
        self._publish_status()

    def _publish_status(self) -> None:
        """``~/status``: this scan's session folder, views stored and rejected, the problem
        (any thread)."""
        live = self._live
        with self._stats_lock:
            msg = ReconstructionStatus(
                session_dir=str(live.session_dir or "") if live is not None else "",
                views_stored=live.n_views if live is not None else 0,
                views_rejected=list(self._rejected),
                problem=self._problem)
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self._frame_id
        self._status_pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        with self._stats_lock:
            values = dict(self._counts, carve_s=round(self._carve_s, 4))
            problem, warning = self._problem, self._warning
        level, message = health(problem, warning, f"{values['scan_views']} views in this scan")
        values.update(waiting_masks=self._input.pending("first"),
                      waiting_joint_states=self._input.pending("second"),
                      unstored=len(self._unstored))
        self._diag_pub.publish(diagnostic_array(
            status_name(self, "carving"), level, message, values,
            stamp=self.get_clock().now().to_msg()))


def main(args=None) -> None:
    """Entry point ``sfs-carving``
    (``--ros-args --params-file config/carving.yaml``, with ``output_dir`` set).

    The process keeps the memory it frees (:func:`~sfs_ros.process.configure_process`;
    started by ``sfs-cell`` or the launch files, malloc has the settings from the start,
    before rclpy's threads), so a reconstruction does not fault in its working memory
    anew."""
    kept = configure_process(keep_freed_memory=True)
    run_node("sfs-carving", partial(CarvingNode, memory_kept=kept), args, threads=3)


if __name__ == "__main__":
    main()
