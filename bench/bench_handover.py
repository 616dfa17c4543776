"""The carving node's hand-over to the meshing node: its size, and its time against the carving.

A simulated scan of the mug with the cell's camera (640 x 480, the demo's plan: three rings
of 16 views and one from above) is received as the carving node receives it
(:class:`sfs_ros.cell_logic.live_reconstruction.LiveReconstruction`, the exact silhouettes
and the images); then, for each mesher, with and without colour: the carving
(:meth:`LiveReconstruction.carve`, the baseline, measured in the same run), and the
hand-over: the carved scan made into its message, serialised, deserialised and made back
(:mod:`sfs_ros.ros.carved_scan_msg`), as it crosses between the nodes (without the transport
itself); with colour also as it crosses when the meshing node holds the images and masks
(sent as the views were stored). Ratio = carving / hand-over (above 1: the hand-over costs less than the
carving). The serialised size goes in the notes.

Run: ``python -m bench.bench_handover`` (``--quick`` for the small camera).
"""

from __future__ import annotations

import tempfile

from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message

from sfs_ros.cell_logic.live_reconstruction import LiveReconstruction
from sfs_ros.cell_logic.mesh_files import HandOver
from sfs_ros.core.geometry.rig import rig_camera
from sfs_ros.core.render import rasterize_silhouette
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan
from sfs_ros.ros.carved_scan_msg import carved_scan_from_msg, carved_scan_to_msg
from sfs_ros_interfaces.msg import CarvedScan as CarvedScanMsg

from .bench_colour import PLAN, RIGS
from .timing import best_of, main


def _round_trip(carved, held: dict, masks: dict) -> int:
    """The carved scan through its serialised message and back, without the images in
    ``held`` ({view name: image}) and the masks in ``masks`` ({view name: mask}), those the
    meshing node holds; the message's bytes."""
    wire = serialize_message(carved_scan_to_msg(carved, HandOver("scan", "/scan", 49, "t"),
                                                stamp=Time(), held=frozenset(held),
                                                masks_held=masks))
    carved_scan_from_msg(deserialize_message(wire, CarvedScanMsg), held, masks_held=masks)
    return len(wire)


def run(quick: bool = False) -> list[dict]:
    """Rows ``{name, seconds, baseline_seconds, ratio, notes}`` per mesher and colour."""
    rig_name, resolution = ("320x240", 96) if quick else ("640x480", 192)
    rig = RIGS[rig_name]
    mug = make_object("mug")
    captures = simulate_scan(mug, rig, PLAN, seed=1)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        live = LiveReconstruction(rig, carving_box(mug), output_dir=folder,
                                  resolution=resolution)
        for n, capture in enumerate(captures):
            mask = rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces,
                                        rig_camera(capture.theta_rad, capture.phi_rad, rig))
            live.add_view(n, mask, capture.theta_rad, capture.phi_rad)
            live.add_colour_image(n, capture.image)
        for mesher in ("marching-cubes", "advancing-front"):
            for colour, holding in ((False, False), (True, False), (True, True)):
                carved = live.carve(mesher=mesher, colour=colour)
                held = ({carved.views[i].name: image for i, image
                         in zip(carved.colour_views, carved.colour_images)} if holding else {})
                masks = ({view.name: mask for view, mask in zip(carved.views, carved.masks)}
                         if holding else {})
                repeats = 2 if quick else 3
                baseline = best_of(lambda: live.carve(mesher=mesher, colour=colour), repeats)
                seconds = best_of(lambda: _round_trip(carved, held, masks), repeats)
                size = _round_trip(carved, held, masks)
                what = ("colour, images and masks held by the meshing node" if holding
                        else "colour" if colour else "no colour")
                rows.append({
                    "name": f"hand-over {mesher}, {what}, "
                            f"{len(captures)} views {rig_name}, resolution {resolution}",
                    "seconds": seconds, "baseline_seconds": baseline,
                    "ratio": baseline / seconds,
                    "notes": [f"{size / 1e6:.2f} MB serialised ({len(carved.colour_views)} "
                              f"colour views, grid {list(carved.grid.shape)})"]})
    return rows


if __name__ == "__main__":
    main(__doc__, run, quick_help="the small camera, fewer repeats")
