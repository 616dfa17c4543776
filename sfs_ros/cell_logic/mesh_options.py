"""The options of one reconstruction request, checked before it is queued (no ROS).

A ``Reconstruct`` request (``sfs_ros_interfaces/srv/Reconstruct``) may set, for that one
mesh, the resolution, the carving box, the mesher, the colour, the texture and the mesh's
file name; each left empty takes the carving or meshing node's setting. :func:`mesh_options` turns the
request's fields into :class:`MeshOptions` (None = the node's setting) or a ValueError
naming the field, what it was and what was expected. The file name is confined to the
output folder: a plain name with a mesh suffix (:func:`sfs_ros.cell_logic.paths.plain_file_name`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.exchange.export import SUPPORTED_SUFFIXES
from ..core.exchange.views import as_bounds
from ..core.meshing.meshers import MESHER
from ..core.settings import RESOLUTION
from .paths import plain_file_name

__all__ = ["COLOUR_CHOICES", "MeshOptions", "mesh_options"]

#: Accepted ``colour`` values: "" (the node's setting), then yes / no.
COLOUR_CHOICES = {"": None, "yes": True, "no": False, "true": True, "false": False}


@dataclass(frozen=True)
class MeshOptions:
    """One request's choices; None = the node's setting.

    resolution : int, voxels along the box's longest side
    bounds_m : (2, 3) float64, the carving box ``[min, max]``, metres, object frame
    mesher : str, one of :data:`sfs_ros.core.meshing.meshers.MESHERS`
    colour : bool
    output_name : str, a file name in the output folder (with its suffix)
    wait_for_pictures : bool, answer once the pictures are written too
    texture : bool, make the textured model after the answer
    refine : bool, make the mesh refined below the hull after the answer
    """

    resolution: int | None = None
    bounds_m: np.ndarray | None = None
    mesher: str | None = None
    colour: bool | None = None
    output_name: str | None = None
    wait_for_pictures: bool = False
    texture: bool | None = None
    refine: bool | None = None

    def coloured(self, default: bool) -> bool:
        """Whether the mesh is coloured: this request's choice, else ``default``; never into
        an .stl, which has no colours."""
        colour = self.colour if self.colour is not None else default
        return colour and not (self.output_name
                               and Path(self.output_name).suffix.lower() == ".stl")

    def textured(self, default: bool) -> bool:
        """Whether the textured model is made: this request's choice, else ``default``."""
        return self.texture if self.texture is not None else default

    def refined(self, default: bool) -> bool:
        """Whether the refined mesh is made: this request's choice, else ``default``."""
        return self.refine if self.refine is not None else default


def mesh_options(output_dir, *, resolution: int = 0, bounds_m=(), mesher: str = "",
                 colour: str = "", output_name: str = "",
                 wait_for_pictures: bool = False, texture: str = "",
                 refine: str = "") -> MeshOptions:
    """:class:`MeshOptions` of a request's fields (0, empty = the node's setting);
    ValueError naming the field that is wrong and what was expected.

    ``bounds_m``: 6 numbers ``[xmin, ymin, zmin, xmax, ymax, zmax]``, metres.
    ``output_name``: a file name ending in a suffix of
    :data:`sfs_ros.core.exchange.export.MESH_FORMATS`, no folders, written inside
    ``output_dir``.
    ``colour``, ``texture`` and ``refine``: "yes" or "no".
    """
    low, high = RESOLUTION.bounds
    if resolution and not low <= resolution <= high:
        raise ValueError(f"resolution {resolution} is outside [{low}, {high}] (0 = the node's)")
    box = None
    if len(bounds_m):
        try:
            if len(bounds_m) != 6:
                raise ValueError(f"got {len(bounds_m)} values")
            box = as_bounds(np.reshape(np.asarray(bounds_m, dtype=np.float64), (2, 3)),
                            what="bounds_m")
        except ValueError:
            raise ValueError(f"bounds_m {list(bounds_m)} is not [xmin, ymin, zmin, xmax, ymax, "
                             "zmax] with finite min < max (empty = the node's)") from None
    if mesher and mesher not in MESHER.choices():
        raise ValueError(f"mesher {mesher!r} is not one of {', '.join(MESHER.choices())} "
                         "(empty = the node's)")
    for name, value in (("colour", colour), ("texture", texture), ("refine", refine)):
        if value.lower() not in COLOUR_CHOICES:
            raise ValueError(f"{name} {value!r} is not 'yes' or 'no' (empty = the node's)")
    if output_name:
        plain_file_name(Path(output_dir), output_name, suffixes=SUPPORTED_SUFFIXES)
    return MeshOptions(resolution=resolution or None, bounds_m=box, mesher=mesher or None,
                       colour=COLOUR_CHOICES[colour.lower()], output_name=output_name or None,
                       wait_for_pictures=bool(wait_for_pictures),
                       texture=COLOUR_CHOICES[texture.lower()],
                       refine=COLOUR_CHOICES[refine.lower()])
