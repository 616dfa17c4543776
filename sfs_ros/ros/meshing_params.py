"""The meshing node's parameters (:data:`PARAMS`), as ``doc/reference.md`` lists them."""

from __future__ import annotations

from sfs_ros.core.settings import COLOUR
from sfs_ros.ros.params import Param

__all__ = ["PARAMS"]

#: The meshing node's parameters: its output folder, the products a request leaves to it,
#: the display mesh, the images held and the wait for the carved scan.
PARAMS: list[Param] = [
    Param("output_dir", "", "Folder for the meshes, reports and pictures (created if needed); "
          "every file the node writes stays inside it.", read_only=True,
          constraints="required, non-empty"),
    Param.of(COLOUR, read_only=True, constraints="a request's colour left empty"),
    Param("texture", False, "Also make a textured model (<mesh stem>.textured.glb) from the "
          "captured images, after the answer, which names it (a request's texture left "
          "empty).", read_only=True),
    Param("refine", False, "Also make the mesh refined below the hull from the views' "
          "colours (<mesh stem>.refined<suffix>), after the answer, which names it; then "
          "published in the hull's place (a request's refine left empty).", read_only=True),
    Param("display_triangles", 10000, "Most triangles of the mesh marker (a simplified "
          "copy by vertex clustering, 40 bytes a corner with its colour: 10 000 make 1.2 MB); "
          "the file and mesh_shape keep the full mesh.", bounds=(100, 10_000_000),
          constraints="used from the next reconstruction"),
    Param("held_images_mb", 1024, "Most memory, MiB, for the colour images of the scan being "
          "received, held so that the carved scan need not carry them (the oldest are given "
          "up first; 0: none held, the carved scan carries them all).",
          bounds=(0, 1 << 20), read_only=True),
    Param("carve_timeout_s", 120.0, "How long a reconstruction waits for the carving node's "
          "carved scan, s.", bounds=(0.1, 86400.0), read_only=True),
    Param("rehearse", True, "At start, reconstruct a small simulated scan (in a folder in "
          "output_dir, removed after) so that the first real mesh finds its code loaded.",
          read_only=True),
]

