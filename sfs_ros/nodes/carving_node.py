"""Carving node: silhouettes in, the live hull out; the carved scan on request.

It keeps the scan (:class:`sfs_ros.cell_logic.carving_scan.CarvingScan`): each paired mask and
joint state is stored and carved into the live hull as it arrives and receipted on
``capture/stored``; ``carve_scan`` hands the views' carving to the meshing node. What it
does, in full: ``doc/nodes.md``; its parameters: ``doc/reference.md`` (generated from
:data:`PARAMS`); its topics and services: ``doc/cell.md``.
"""

from __future__ import annotations

import time
import traceback
from functools import partial

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.carving_scan import HullSchedule, reset_refusal
from sfs_ros.cell_logic.mesh_options import MeshOptions
from sfs_ros.cell_logic.message_fields import colour_image_from_msg, mask_from_msg
from sfs_ros.core.resident_memory import prefault
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos
from sfs_ros.ros.carve_request import carved_scan_message
from sfs_ros.ros.carving_outputs import CarvingOutputs
from sfs_ros.ros.carving_params import (
    PARAMS,
    carve_options,
    check_scan_settings,
    live_reconstruction,
    open_scan,
    scan_bounds,
    scan_settings,
)
from sfs_ros.ros.convert import angles_from_joint_state
from sfs_ros.ros.frames import FRAME_PARAMS, frame_names
from sfs_ros.ros.names import private
from sfs_ros.ros.paired_input import PairedInput, Stream
from sfs_ros.ros.pairing import stamp_key, view_key
from sfs_ros.ros.params import declare, read, validating_callback
from sfs_ros.ros.rehearsal import Rehearsal
from sfs_ros.ros.rig_params import (
    CAPTURING_STATES,
    RigParameters,
    rig_calibration,
)
from sfs_ros.ros.worker import Worker, internal_error
from sfs_ros_interfaces.msg import CarvedScan as CarvedScanMsg
from sfs_ros_interfaces.srv import CarveScan, NewScan

__all__ = ["CarvingNode", "PARAMS", "main"]

NODE_NAME = "carving"

#: How often views that could not be stored (a full disk) are tried again, s.
STORE_RETRY_S = 1.0


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
        self._scan = open_scan(values)
        self.add_on_set_parameters_callback(validating_callback(
            self, PARAMS, lambda values: check_scan_settings(values, self._scan.budget)))
        self._rig = RigParameters(self, on_change=self._new_rig)
        self._hull = HullSchedule(0.0 if values["hull_rate_hz"] == 0
                                  else 1.0 / values["hull_rate_hz"])
        self._max_hull_points = values["max_hull_points"]
        calibration = rig_calibration(values)
        # The image size is fixed while the node runs (RigParameters): anything else is
        # refused before it is kept.
        self._size = (calibration.width, calibration.height)
        self._out = CarvingOutputs(self, values["queue_depth"], self._frame_id)
        self._create_inputs(values)
        self._worker = Worker("carving", on_error=self._job_failed)
        self._out.status(self._scan)
        if self._scan.refusal:
            self.get_logger().error(f"{self._scan.refusal}; the node receipts no view and "
                                    "carves nothing until started with another one")
            return
        self.get_logger().info(
            f"carving into {self._scan.live.output_dir} (box "
            f"{self._scan.live.bounds_m.tolist()}, resolution {values['resolution']}, "
            f"{values['mesher']}, queue depth {values['queue_depth']})")
        self._submit("reopen", self._reopen)
        # Before the rehearsal thread allocates, so that it finds the pages touched too.
        self._prefault()
        if values["rehearse"]:
            # Beside the worker, not on it: with kernels still to compile (a fresh install)
            # it takes minutes, and views and resets must not wait for it.
            self._rehearsal = Rehearsal(self, self._scan.live.output_dir)

    def _create_inputs(self, values: dict) -> None:
        """The mask pairing, the captured images, the services and the timers."""
        inputs = MutuallyExclusiveCallbackGroup()     # pairer, timers
        services = MutuallyExclusiveCallbackGroup()   # one request at a time, waits on the worker
        depth = values["queue_depth"]
        qos = capture_qos(depth)
        self._input = PairedInput(
            self, Stream(Image, "capture/mask", "mask",
                         lambda msg: mask_from_msg(msg, self._size)),
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
            image = colour_image_from_msg(msg, self._size)
        except ValueError as exc:
            self._scan.health.count("malformed")
            self._report_problem(f"captured image not kept for colour: {exc}")
            return
        self._submit("image", self._add_colour_image, stamp, image)

    def _on_view(self, stamp, mask_and_frame: tuple[np.ndarray, str],
                 angles: tuple[float, float]) -> None:
        (mask, frame_id), (theta, phi) = mask_and_frame, angles
        self._scan.health.count("views_received")
        self._submit("view", self._add_view, stamp, frame_id, mask, theta, phi)

    def _dropped(self, kind: str, text: str) -> None:
        """A message of a view was dropped: ``kind`` is its counter."""
        self._scan.health.count(kind)
        self._report_problem(text)

    def _on_carve_scan(self, request, response):
        """``carve_scan``: options checked here (refused at once with the reason), the
        carving made in the worker."""
        try:
            options = carve_options(request, read(self, PARAMS), self._scan.budget)
        except ValueError as exc:
            response.success, response.message = False, str(exc)
            return response
        try:
            held = frozenset(request.images_held)
            response.success, response.message, scan = self._submit(
                "carve", self._carve, options, request.images_session, held,
                request.every_image).result()
        except Exception as exc:  # noqa: BLE001 -- the worker reported it; the caller gets it
            response.success, response.message, scan = False, internal_error("carve", exc), None
        if scan is not None:
            response.scan = scan
        return response

    def _on_reset(self, _request, response):
        return self._request("reset", self._reset, response)

    def _on_new_scan(self, request, response):
        return self._request("reset", partial(self._reset, request.scan_name), response)

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
        return self._worker.submit(partial(self._run_then_publish_hull, job, *args), name=name)

    def _new_rig(self, rig) -> None:
        """A new rig was set (a parameter thread): the next reset uses it."""
        self.get_logger().info(f"new rig (f = ({rig.fx:.2f}, {rig.fy:.2f}) px, distortion "
                               f"{list(rig.distortion)}): the next scan (reset) uses it")

    # -- worker thread -----------------------------------------------------------------------

    def _run_then_publish_hull(self, job, *args):
        """Run ``job``; then publish the hull if a job changed it and no job waits or the
        period is over. ``job``'s answer."""
        answer = job(*args)
        now = time.monotonic()
        if self._hull.due(self._worker.pending(), now):
            if self._scan.live is not None:
                self._out.hull(self._scan.live.hull_points(self._max_hull_points))
            self._hull.published(now)
        return answer

    def _job_failed(self, name: str, exc: Exception) -> None:
        text = internal_error(name, exc)
        self.get_logger().error(f"{text}\n{''.join(traceback.format_exception(exc))}")
        self._report_problem(text)

    def _reopen(self) -> None:
        """Take up the scan that was open when the node last stopped (a restart)."""
        self.get_logger().info(self._scan.reopen())
        if self._scan.cameras:
            self._out.poses(self._scan.cameras)
            self._hull.changed = True
        self._out.status(self._scan)

    def _prefault(self) -> None:
        """Touch the heap a reconstruction will need, once, before the first one (see
        :mod:`sfs_ros.core.resident_memory`); no more than the memory budget."""
        reserve = self._scan.working_memory_reserve()
        if prefault(reserve, memory_kept=self._memory_kept):
            self.get_logger().info(f"{reserve >> 20} MiB of working memory made resident")

    def _retry_unstored(self) -> None:
        """Timer: store again the views a full disk refused (in the worker)."""
        if self._scan.unstored:
            self._submit("store again", self._scan.store_unstored, self._add_view)

    def _add_colour_image(self, stamp, image) -> None:
        """Keep a captured image to colour the mesh."""
        if self._scan.live is None:
            return
        problem = self._scan.add_colour_image(stamp, image)
        if problem:
            self._report_problem(problem)
            return
        self._out.view_image(self._scan, stamp, view_key(stamp))

    def _reset(self, scan_name: str = "") -> tuple[bool, str]:
        """Start a new scan with the per-scan settings as they are now, named ``scan_name``
        ("" = the ``scan_name`` parameter); publishes an empty hull. (False, the reason) if
        the scan name is taken, the grid does not fit in memory or the scan node is taking
        views (a new scan would split them over two session folders): nothing changes."""
        values = read(self, PARAMS)
        name = scan_name or values["scan_name"] or None
        refusal = reset_refusal(self._rig.scan_in(CAPTURING_STATES), scan_bounds(values),
                                values["resolution"], self._scan.budget)
        if refusal:
            self.get_logger().error(refusal)
            return False, refusal
        try:
            changed = self._scan.new_scan(name, scan_settings(values),
                                          partial(live_reconstruction, values, name))
        except ValueError as exc:
            self.get_logger().error(f"reset refused: {exc}")
            return False, f"reset refused: {exc}"
        if changed:
            self._prefault()
            self.get_logger().info(f"new scan settings: box {values['bounds_m']}, "
                                   f"resolution {values['resolution']}, {values['mesher']}, "
                                   f"rig f = ({values['fx']}, {values['fy']}) px")
        self._out.poses(self._scan.cameras)
        self.get_logger().info("reset: the next view starts a new scan")
        self._out.status(self._scan)
        self._hull.changed = True
        return True, "new scan: no views yet"

    def _add_view(self, stamp, frame_id: str, mask, theta: float, phi: float) -> None:
        """Give one view to the scan and send its receipt."""
        outcome = self._scan.add_view(stamp, frame_id, mask, theta, phi)
        if outcome.receipted:
            self._out.receipt(stamp, frame_id)
        if not outcome.stored:
            if outcome.kind in ("stale", "repeat"):
                self.get_logger().info(outcome.text)
            else:
                self._report_problem(outcome.text)
            return
        self._hull.changed |= outcome.kind == "carved"
        self._out.poses(self._scan.cameras)
        if outcome.text:
            self.get_logger().warning(outcome.text)
        self._publish_diagnostics()
        self._out.status(self._scan)
        self._out.view_image(self._scan, stamp, view_key(stamp))

    def _carve(self, options: MeshOptions, images_session: str, held: frozenset,
               every_image: bool) -> tuple[bool, str, CarvedScanMsg | None]:
        """The carved scan of the views received, with ``options``: ``(success, summary or
        the reason, the message or None)``; with every used view's image when
        ``every_image``, without the images and silhouettes of the views in ``held`` if the
        caller holds them of this scan (``images_session``)."""
        if self._scan.live is None:
            return False, self._scan.refusal, None
        success, text, msg = carved_scan_message(
            self._scan, options, frame_id=self._frame_id, clock=self.get_clock(),
            images_session=images_session, held=held, every_image=every_image)
        if success:
            self.get_logger().info(text)
        else:
            self.get_logger().error(text)
        self._publish_diagnostics()
        return success, text, msg

    # -- diagnostics (any thread) ------------------------------------------------------------

    def _report_problem(self, text: str) -> None:
        self._scan.health.report(text)
        self.get_logger().error(text)
        self._publish_diagnostics()
        self._out.status(self._scan)

    def _publish_diagnostics(self) -> None:
        self._out.diagnostics(self._scan, waiting_masks=self._input.pending("first"),
                              waiting_joint_states=self._input.pending("second"))


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
