"""The meshing node's publishers: the mesh (a display marker and the full shape), its
status and diagnostics.

:class:`MeshingOutputs` publishes the meshes the node makes and what
:class:`sfs_ros.cell_logic.meshing_status.MeshingStatus` holds, each in the turntable frame
``frame_id``; every method may be called from any thread.
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from shape_msgs.msg import Mesh
from visualization_msgs.msg import Marker

from sfs_ros.cell_logic.meshing_status import MeshingStatus
from sfs_ros.core.meshing.decimate import decimate
from sfs_ros.ros import result_qos
from sfs_ros.ros.convert import diagnostic_array, health, mesh_to_marker, mesh_to_shape
from sfs_ros.ros.names import DIAGNOSTICS, MESHING_STATUS, status_name
from sfs_ros_interfaces.msg import ReconstructionStatus

__all__ = ["MeshingOutputs"]


class MeshingOutputs:
    """The publishers of ``node``: ``mesh`` and ``mesh_shape`` (results QoS), ``~/status``
    and ``/diagnostics``."""

    def __init__(self, node: Node, frame_id: str):
        self._node = node
        self._frame_id = frame_id
        self._marker = node.create_publisher(Marker, "mesh", result_qos())
        self._shape = node.create_publisher(Mesh, "mesh_shape", result_qos())
        self._diagnostics = node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self._status = node.create_publisher(
            ReconstructionStatus, "~/" + MESHING_STATUS.split("/", 1)[1], result_qos())

    def _now(self):
        return self._node.get_clock().now().to_msg()

    def display_mesh(self, vertices, faces, colours, max_triangles: int) -> None:
        """``mesh``: a marker of the (V, 3) metres ``vertices``, (F, 3) ``faces`` and
        per-vertex ``colours`` (or None), simplified to at most ``max_triangles``."""
        vertices, faces, colours = decimate(vertices, faces, max_triangles, colours)
        self._publish_quietly(self._marker, lambda: mesh_to_marker(
            vertices, faces, stamp=self._now(), frame_id=self._frame_id,
            vertex_colors=colours))

    def shape(self, vertices, faces) -> None:
        """``mesh_shape``: the full mesh (in the turntable frame, as ``mesh``)."""
        self._publish_quietly(self._shape, lambda: mesh_to_shape(vertices, faces))

    def _publish_quietly(self, publisher, build) -> None:
        """Publish ``build()``; nothing once the node is stopping (the mesh is in its file)."""
        try:
            publisher.publish(build())
        except Exception:  # noqa: BLE001 -- rclpy's RCLError, once the node is stopping
            if self._node.context.ok():
                raise

    def status(self, status: MeshingStatus) -> None:
        """``~/status``: the reconstructions made, the last mesh and its session folder,
        the problem."""
        msg = ReconstructionStatus(**status.status())
        msg.header.stamp = self._now()
        msg.header.frame_id = self._frame_id
        self._status.publish(msg)

    def diagnostics(self, status: MeshingStatus) -> None:
        """``/diagnostics``: the counts and the problem."""
        values, problem = status.diagnostics()
        level, message = health(problem, "", f"{values['reconstructions']} meshes made")
        self._diagnostics.publish(diagnostic_array(
            status_name(self._node, "meshing"), level, message, values, stamp=self._now()))
