"""The carving node's publishers: receipts, the live hull, camera poses, the views' images,
its status and diagnostics.

:class:`CarvingOutputs` publishes what :class:`sfs_ros.cell_logic.carving_scan.CarvingScan`
holds, each in the turntable frame ``frame_id``; every method may be called from any
thread.
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from sfs_ros.cell_logic.carving_scan import CarvingScan
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.carved_scan_msg import view_image_msg, view_mask_msg
from sfs_ros.ros.convert import camera_poses, diagnostic_array, header, health, points_to_cloud
from sfs_ros.ros.names import (
    DIAGNOSTICS,
    RECONSTRUCTION_STATUS,
    VIEW_IMAGE_DEPTH,
    VIEW_IMAGES,
    VIEW_MASKS,
    status_name,
)
from sfs_ros_interfaces.msg import ReconstructionStatus, ViewImage

__all__ = ["CarvingOutputs"]


class CarvingOutputs:
    """The publishers of ``node``: ``capture/stored`` (captures QoS, ``depth``), ``hull``
    and ``camera_poses`` (results QoS), ``~/view_image``, ``~/view_mask``, ``~/status`` and
    ``/diagnostics``."""

    def __init__(self, node: Node, depth: int, frame_id: str):
        self._node = node
        self._frame_id = frame_id
        self._stored = node.create_publisher(Header, "capture/stored", capture_qos(depth))
        self._hull = node.create_publisher(PointCloud2, "hull", result_qos())
        self._poses = node.create_publisher(PoseArray, "camera_poses", result_qos())
        self._view_image = node.create_publisher(
            ViewImage, "~/" + VIEW_IMAGES.split("/", 1)[1], capture_qos(VIEW_IMAGE_DEPTH))
        self._view_mask = node.create_publisher(
            ViewImage, "~/" + VIEW_MASKS.split("/", 1)[1], capture_qos(VIEW_IMAGE_DEPTH))
        self._diagnostics = node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self._status = node.create_publisher(ReconstructionStatus,
                                             "~/" + RECONSTRUCTION_STATUS.split("/", 1)[1],
                                             result_qos())

    def _now(self):
        return self._node.get_clock().now().to_msg()

    def receipt(self, stamp, frame_id: str) -> None:
        """``capture/stored``: the view at ``stamp`` (its mask's ``frame_id``) is done with."""
        self._stored.publish(header(stamp=stamp, frame_id=frame_id))

    def poses(self, cameras: list) -> None:
        """``camera_poses``: the cameras of this scan's views."""
        self._poses.publish(camera_poses(cameras, stamp=self._now(), frame_id=self._frame_id))

    def hull(self, points) -> None:
        """``hull``: the (n, 3) surface voxels of the live hull, metres."""
        self._hull.publish(points_to_cloud(points, stamp=self._now(), frame_id=self._frame_id))

    def view_image(self, scan: CarvingScan, stamp, key: str) -> None:
        """``~/view_image`` and ``~/view_mask``: the view's colour image and its silhouette,
        once both the view and its image are in."""
        found = scan.live.colour_image(key)
        if found is None:
            return
        session = str(scan.live.session_dir)
        stamped = header(stamp=stamp, frame_id=self._frame_id)
        self._view_image.publish(view_image_msg(session, *found, header=stamped))
        mask = scan.live.view_mask(key)
        if mask is not None:
            self._view_mask.publish(view_mask_msg(session, *mask, header=stamped))

    def status(self, scan: CarvingScan) -> None:
        """``~/status``: this scan's session folder, views stored and rejected, the problem."""
        live = scan.live
        _, problem, _, rejected = scan.health.snapshot()
        msg = ReconstructionStatus(
            session_dir=str(live.session_dir or "") if live is not None else "",
            views_stored=live.n_views if live is not None else 0,
            views_rejected=rejected, problem=problem)
        msg.header.stamp = self._now()
        msg.header.frame_id = self._frame_id
        self._status.publish(msg)

    def diagnostics(self, scan: CarvingScan, **waiting: int) -> None:
        """``/diagnostics``: the counts, the problem or warning, and the ``waiting`` counts
        given (messages not yet paired)."""
        values, problem, warning, _ = scan.health.snapshot()
        level, message = health(problem, warning, f"{values['scan_views']} views in this scan")
        values.update(waiting, unstored=len(scan.unstored))
        self._diagnostics.publish(diagnostic_array(
            status_name(self._node, "carving"), level, message, values, stamp=self._now()))
