"""A ``carve_scan`` request answered: the scan's views carved and made into the message.

:func:`carved_scan_message` carves the views a
:class:`~sfs_ros.cell_logic.carving_scan.CarvingScan` holds with a request's options and
packs the carving with its hand-over as a ``sfs_ros_interfaces/CarvedScan`` message
(:func:`~sfs_ros.ros.carved_scan_msg.carved_scan_to_msg`), counting the carving or its
failure in the scan's health.
"""

from __future__ import annotations

import time
from dataclasses import replace

from sfs_ros.cell_logic.carving_scan import CarvingScan
from sfs_ros.cell_logic.mesh_options import MeshOptions
from sfs_ros.ros.carved_scan_msg import carved_scan_to_msg
from sfs_ros_interfaces.msg import CarvedScan as CarvedScanMsg

__all__ = ["carved_scan_message"]


def carved_scan_message(scan: CarvingScan, options: MeshOptions, *, frame_id: str, clock,
                        images_session: str, held: frozenset,
                        every_image: bool = False) -> tuple[bool, str, CarvedScanMsg | None]:
    """The carved scan of the views ``scan`` received, with ``options``: ``(success, summary
    or the reason, the message or None)``. The message is in the turntable frame
    ``frame_id``, stamped by ``clock`` (an rclpy clock) once carved, carries the image of
    every view used when ``every_image`` (else those that colour the mesh), and leaves out
    the images and silhouettes of the views in ``held`` if the caller holds them of this
    scan (``images_session``, its session folder; a silhouette only where the one sent is
    the carving's). ``scan`` must have a live reconstruction."""
    live = scan.live
    start = time.perf_counter()
    try:
        carved = live.carve(resolution=options.resolution, bounds_m=options.bounds_m,
                            mesher=options.mesher, colour=options.colour)
        hand_over = replace(live.hand_over(), frame_id=frame_id)
        held = held if images_session == hand_over.session_dir else frozenset()
        used = [view.name for view in carved.views if view.role == "used"]
        msg = carved_scan_to_msg(carved, hand_over, stamp=clock.now().to_msg(), held=held,
                                 masks_held=live.view_masks(held),
                                 images=live.colour_images(used) if every_image else None)
    except ValueError as exc:
        return False, scan.carving_failed(exc), None
    return True, scan.carved(carved, time.perf_counter() - start), msg
