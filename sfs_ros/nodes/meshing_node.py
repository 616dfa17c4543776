"""Meshing node: the carving node's carved scan in, the mesh out, on request.

The meshing half of the cell's reconstruction (:mod:`sfs_ros.nodes.carving_node` keeps the
scan): ``~/reconstruct_mesh`` asks the carving node for the carved scan, meshes it in a
worker thread (:func:`sfs_ros.cell_logic.mesh_files.write_mesh`), answers, then publishes the
mesh and makes the products that follow the answer (:mod:`sfs_ros.cell_logic.after_answer`).
What it does, in full: ``doc/nodes.md``; its parameters: ``doc/reference.md`` (generated
from :data:`PARAMS`); its topics and services: ``doc/cell.md``.
"""

from __future__ import annotations

import json
import traceback
from functools import partial

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.after_answer import make_product, products_after, without_colour
from sfs_ros.cell_logic.held_images import HeldImages
from sfs_ros.cell_logic.mesh_files import write_mesh
from sfs_ros.cell_logic.mesh_options import MeshOptions, mesh_options
from sfs_ros.cell_logic.meshing_status import MeshingStatus
from sfs_ros.cell_logic.repeated_requests import RepeatedRequests, request_key
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos
from sfs_ros.ros.carved_scan_msg import (
    carried_images,
    carve_scan_request,
    carved_scan_from_msg,
    view_image_from_msg,
    view_mask_from_msg,
)
from sfs_ros.ros.frames import FRAME_PARAMS, frame_names
from sfs_ros.ros.meshing_outputs import MeshingOutputs
from sfs_ros.ros.meshing_params import PARAMS
from sfs_ros.ros.names import (
    TYPED_SERVICES,
    VIEW_IMAGE_DEPTH,
    VIEW_IMAGES,
    VIEW_MASKS,
    private,
)
from sfs_ros.ros.params import declare, output_folder
from sfs_ros.ros.rehearsal import Rehearsal
from sfs_ros.ros.services import ServiceError, call
from sfs_ros.ros.typed import fill_reconstruct_response
from sfs_ros.ros.worker import JobsOnHold, Worker, internal_error
from sfs_ros_interfaces.msg import ViewImage
from sfs_ros_interfaces.srv import CarveScan, Reconstruct

__all__ = ["MeshingNode", "PARAMS", "main"]

NODE_NAME = "meshing"

#: Period (s) of the timer that releases the jobs after a ``reconstruct`` answer (it runs
#: once per answer, as soon as the answer is sent).
ANSWER_CHECK_S = 0.001


class MeshingNode(Node):
    """Meshes the carving node's carved scan on request.

    Raises :class:`ParameterError` at construction for invalid parameters.
    ``destroy_node`` finishes the queued work and stops the worker thread.
    """

    def __init__(self, **kwargs):
        self._worker = None  # started last; a node refused at start-up has none to stop
        self._rehearsal = None
        super().__init__(NODE_NAME, **kwargs)
        values = declare(self, PARAMS)
        self._frame_id = frame_names(declare(self, FRAME_PARAMS)).turntable_frame
        self._output_dir = output_folder(values["output_dir"], "the meshes")
        self._values = values
        self._status = MeshingStatus()

        services = MutuallyExclusiveCallbackGroup()   # one request at a time
        self._carve_client = self.create_client(CarveScan, TYPED_SERVICES["carve_scan"],
                                                callback_group=ReentrantCallbackGroup())
        self._held = HeldImages(values["held_images_mb"] << 20)
        self._repeats = RepeatedRequests()
        if self._held.max_bytes:
            held_group = MutuallyExclusiveCallbackGroup()
            self.create_subscription(ViewImage, VIEW_IMAGES, self._on_view_image,
                                     capture_qos(VIEW_IMAGE_DEPTH), callback_group=held_group)
            self.create_subscription(ViewImage, VIEW_MASKS, self._on_view_mask,
                                     capture_qos(VIEW_IMAGE_DEPTH), callback_group=held_group)
        self._out = MeshingOutputs(self, self._frame_id)
        self.create_service(Trigger, private("reconstruct"), self._on_reconstruct,
                            callback_group=services)
        self.create_service(Reconstruct, private("reconstruct_mesh"), self._on_reconstruct_mesh,
                            callback_group=services)
        self.create_timer(1.0, self._publish_diagnostics,
                          callback_group=MutuallyExclusiveCallbackGroup())
        # The jobs after a reconstruction (pictures, mesh messages) wait on a hold until
        # its answer is sent: released by this timer, armed by the service callback. In the
        # services group it runs only once that callback is done, and rclpy sends the
        # answer before that.
        self._answered = self.create_timer(ANSWER_CHECK_S, self._release_after_answer,
                                           callback_group=services)
        self._answered.cancel()
        self._after_answer: JobsOnHold | None = None
        self._worker = Worker("meshing", on_error=self._job_failed)
        self._publish_status()
        self.get_logger().info(f"meshing into {self._output_dir}, carved scans from "
                               f"{self._carve_client.srv_name}")
        if values["rehearse"]:
            self._rehearsal = Rehearsal(self, self._output_dir)

    def destroy_node(self) -> None:
        """Finish the queued work, stop the worker thread and the rehearsal, then destroy
        the node."""
        if self._worker is not None:
            if self._after_answer is not None:   # the answer's timer will not run now
                self._after_answer.release()
            self._worker.stop()
            self._worker.join()
        if self._rehearsal is not None:
            self._rehearsal.join()
        super().destroy_node()

    def _on_view_image(self, msg) -> None:
        """A view's colour image as the carving node stored it: held for the carved scan."""
        try:
            self._held.add(*view_image_from_msg(msg))
        except ValueError as exc:   # the carved scan will carry that image instead
            self.get_logger().warning(f"{exc}: not held")

    def _on_view_mask(self, msg) -> None:
        """A view's silhouette as the carving node stored it: held with its image."""
        try:
            self._held.add_mask(*view_mask_from_msg(msg))
        except ValueError as exc:   # the carved scan will carry that silhouette instead
            self.get_logger().warning(f"{exc}: not held")

    # -- requests (services group) -------------------------------------------------------------

    def _on_reconstruct(self, _request, response):
        response.success, response.message, _ = self._answer(MeshOptions())
        return response

    def _on_reconstruct_mesh(self, request, response):
        """The typed ``reconstruct_mesh``: options checked here (refused at once with the
        reason), the carved scan asked for, the mesh made in the worker."""
        try:
            options = mesh_options(
                self._output_dir, resolution=request.resolution,
                bounds_m=list(request.bounds_m), mesher=request.mesher,
                colour=request.colour, output_name=request.output_name,
                wait_for_pictures=request.wait_for_pictures, texture=request.texture,
                refine=request.refine)
        except ValueError as exc:
            response.success, response.message = False, f"request refused: {exc}"
            return response
        response.success, response.message, summary = self._answer(options)
        if summary is not None:
            fill_reconstruct_response(response, summary, frame_id=self._frame_id)
        return response

    def _answer(self, options: MeshOptions) -> tuple[bool, str, dict | None]:
        """Ask for the carved scan, mesh it in the worker: ``(success, JSON summary or the
        reason, summary or None)``; the jobs after it are held until the answer is out."""
        # The previous answer is out (this group ran one callback at a time): should its
        # timer not have run yet, the jobs held for it must not hold this one up.
        self._release_after_answer()
        held_session, held, with_masks = self._held.snapshot()
        carved = self._carved_scan(options, held_session, with_masks)
        if isinstance(carved, str):
            return self._failed(carved)
        # A request sent again (its first copy or answer lost): the answer made, not the
        # mesh again, when the carving is of the same views.
        key = request_key(options, carved.session_dir, carved.views_received)
        repeated = self._repeats.recall(key)
        if repeated is not None:
            self.get_logger().info("the same request again: answered as before")
            return repeated
        try:
            answer = self._worker.submit(lambda: self._mesh(carved, options, held_session,
                                                            held, with_masks),
                                         name="mesh").result()
        except Exception as exc:  # noqa: BLE001 -- the worker reported it; the caller gets it
            answer = False, internal_error("mesh", exc), None
        if answer[0]:
            self._repeats.remember(key, answer)
        if self._after_answer is not None:
            self._answered.reset()
        return answer

    def _carved_scan(self, options: MeshOptions, held_session: str, held: list):
        """The carving node's carved scan for ``options`` (a message), or why there is none;
        without the images and silhouettes of the views ``held`` of the scan
        ``held_session``."""
        # The texture needs the images the carving node sends to colour the mesh, the
        # refinement those of every view used: those not held here come in the carved scan.
        values = self._values
        colour = options.coloured(values["colour"]) or options.textured(values["texture"])
        request = carve_scan_request(options, colour, held_session, held,
                                     every_image=options.refined(values["refine"]))
        try:
            answer = call(self._carve_client, request,
                          timeout_s=self._values["carve_timeout_s"])
        except ServiceError as exc:
            return f"reconstruction failed: no carved scan: {exc}"
        if not answer.success:
            return f"reconstruction failed: {answer.message}"
        return answer.scan

    def _release_after_answer(self) -> None:
        """Timer (services group), once the ``reconstruct`` answer is sent: the worker may
        start the jobs that follow it."""
        self._answered.cancel()
        hold, self._after_answer = self._after_answer, None
        if hold is not None:
            hold.release()

    # -- worker thread ---------------------------------------------------------------------------

    def _mesh(self, msg, options: MeshOptions, held_session: str, held: dict,
              with_masks: list) -> tuple[bool, str, dict | None]:
        """Mesh a carved scan message (``held``: the images of the scan ``held_session``,
        those it leaves out among them; ``with_masks``: the views whose silhouettes it may
        leave out) and write the files; the messages, the pictures and the products (the
        textured model, the refined mesh) are queued to follow the answer."""
        try:
            carved, hand_over = carved_scan_from_msg(
                msg, held, self._held.thumbnails(held_session),
                self._held.masks(held_session, with_masks))
            # The refinement's images: every view's, held or carried.
            images = carried_images(msg, held) if options.refined(self._values["refine"]) \
                else {}
            # Images asked for the texture alone do not colour the mesh.
            meshed = carved if options.coloured(self._values["colour"]) \
                else without_colour(carved)
            made = write_mesh(meshed, hand_over, self._output_dir, options.output_name,
                              pictures=options.wait_for_pictures)
        except (ValueError, OSError) as exc:
            return self._failed(f"reconstruction failed: {exc}")
        summary = made.summary
        n_held = sum(view.image_held for view in msg.views)
        n_carried = sum(len(view.image_rgb) > 0 for view in msg.views)
        products = self._products(carved, meshed, made, options, images)
        for key in ("textured_path", "refined_mesh_path"):
            summary[key] = next((str(p.path) for p in products if p.key == key), "")
        self._status.meshed(summary["path"], summary["session"], n_held, n_carried)
        self.get_logger().info(f"mesh written to {summary['path']} ({summary['views_used']} "
                               f"views, {summary['n_faces']} faces, "
                               f"{summary['seconds']:.1f} s)")
        self._publish_diagnostics()
        self._publish_status()
        self._after_answer = self._worker.hold()
        result = made.result
        self._worker.submit(partial(self._publish_marker, result.vertices, result.faces,
                                    result.vertex_colors), name="publish the display mesh")
        if made.pictures_due is not None:
            self._worker.submit(partial(self._write_pictures, made.pictures_due,
                                        summary["path"]), name="pictures")
        self._worker.submit(partial(self._out.shape, result.vertices, result.faces),
                            name="publish the mesh")
        for product in products:
            self._worker.submit(partial(self._make_product, product, summary["report_path"]),
                                name=product.key)
        return True, json.dumps(summary), summary

    def _products(self, carved, meshed, made, options: MeshOptions, held: dict) -> list:
        """The products to make after the answer (:func:`products_after`); one that cannot
        be made is reported and left out."""
        products, notes = products_after(
            carved, meshed, made, self._output_dir, held,
            texture=options.textured(self._values["texture"]),
            refine=options.refined(self._values["refine"]), on_mesh=self._publish_refined)
        for level, text in notes:
            if level == "error":
                self._report_problem(text)
            else:
                self.get_logger().warning(text)
        return products

    def _publish_refined(self, vertices, faces, colours) -> None:
        """The refined mesh on ``mesh`` and ``mesh_shape``, in the hull's place."""
        self._publish_marker(vertices, faces, colours)
        self._out.shape(vertices, faces)

    def _make_product(self, product, report_path: str) -> None:
        try:
            make_product(product, report_path, self._output_dir)
        except (ValueError, OSError) as exc:
            self._report_problem(f"{product.path} not written (the mesh and its report "
                                 f"are): {exc}")
            return
        self.get_logger().info(f"{product.path.name} written after the answer")

    def _write_pictures(self, pictures_due, mesh_path: str) -> None:
        try:
            pictures_due()
        except (ValueError, OSError) as exc:
            self._report_problem(f"pictures of {mesh_path} not written (the mesh and its "
                                 f"report are): {exc}")

    def _publish_marker(self, vertices, faces, colours) -> None:
        """``mesh``: the display copy, within ``display_triangles``."""
        self._out.display_mesh(vertices, faces, colours,
                               self.get_parameter("display_triangles").value)

    def _job_failed(self, name: str, exc: Exception) -> None:
        text = internal_error(name, exc)
        self.get_logger().error(f"{text}\n{''.join(traceback.format_exception(exc))}")
        self._report_problem(text)

    # -- status (any thread) ---------------------------------------------------------------------

    def _failed(self, text: str) -> tuple[bool, str, None]:
        self._status.failed()
        self._report_problem(text)
        return False, text, None

    def _report_problem(self, text: str) -> None:
        self._status.report(text)
        self.get_logger().error(text)
        self._publish_diagnostics()
        self._publish_status()

    def _publish_status(self) -> None:
        self._out.status(self._status)

    def _publish_diagnostics(self) -> None:
        self._out.diagnostics(self._status)


def main(args=None) -> None:
    """Entry point ``sfs-meshing``
    (``--ros-args --params-file config/meshing.yaml``, with ``output_dir`` set); the
    process keeps the memory it frees, as the carving node's."""
    configure_process(keep_freed_memory=True)
    run_node("sfs-meshing", MeshingNode, args, threads=3)


if __name__ == "__main__":
    main()
