"""The reconstruction's settings, each defined once: its meaning, its range and its defaults.

``sfs-reconstruct``'s options, the carving and meshing nodes' parameters
(``sfs_ros.ros.params.Param.of``), :class:`sfs_ros.core.pipeline.ReconstructionParams`'
checks and the generated tables of ``doc/reference.md`` all read a :class:`Setting`
from here; a mesher's own options are settings too, kept with the mesher
(:data:`sfs_ros.core.meshing.meshers.MESHERS`), and so is the mesher's name
(:data:`sfs_ros.core.meshing.meshers.MESHER`).

A setting has two defaults: ``default`` is the offline reconstruction's
(``sfs-reconstruct``, :func:`sfs_ros.core.pipeline.reconstruct`), which may come from
the input (``default_text`` says how); ``cell_default`` is the nodes', which must be a
value before the first view arrives (the live scan carves as the views come).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["BOUNDS_M", "COLOUR", "MAX_COLOUR_VIEWS", "MAX_MEMORY", "RESOLUTION", "Setting"]


@dataclass(frozen=True)
class Setting:
    """One reconstruction setting.

    name : str
        The node parameter's name; also the option's name in the report.
    description : str
        What it means, one sentence.
    kind : type
        int, float, str or bool: the type of a value (of each element, with ``length``).
    flag : str
        The ``sfs-reconstruct`` option.
    bounds : (low, high), optional
        Inclusive range of a number, or of each element; ``high`` None: no upper bound.
    choices : callable, optional
        () -> tuple of str: the allowed values, read when asked (a registry's names).
    default : optional
        The offline reconstruction's value; None when it comes from the input
        (``default_text``).
    default_text : str
        The offline default in words, when it is not a plain value.
    recorded : bool
        An input may record it (a bag: the carving node's), and the recorded value is
        the offline default.
    cell_default : optional
        The carving and meshing nodes' value; None: not a node parameter.
    unit : str
        Of a number (``"voxels"``, ``"m"``).
    length : int
        Number of values (a list) or 0 (one value).
    metavar : str
        The value's name on the command line.
    """

    name: str
    description: str
    kind: type
    flag: str
    bounds: tuple | None = None
    choices: Callable[[], tuple[str, ...]] | None = None
    default: Any = None
    default_text: str = ""
    recorded: bool = False
    cell_default: Any = None
    unit: str = ""
    length: int = 0
    metavar: str | None = None

    def allowed(self) -> str:
        """The valid values in words: ``"8..2048 voxels"``, ``">= 1"``, ``"one of a, b"``."""
        if self.choices is not None:
            return "one of " + ", ".join(self.choices())
        if self.bounds is None:
            return ""
        low, high = self.bounds
        text = f">= {low}" if high is None else f"{low}..{high}"
        return f"{text} {self.unit}".strip()

    def default_words(self) -> str:
        """The offline default in words."""
        if self.default_text:
            words = self.default_text
        elif self.kind is bool:
            words = "on" if self.default else "off"
        else:
            words = f"{self.default} {self.unit}".strip()
        return f"a bag's recorded one, else {words}" if self.recorded else words

    def check(self, value) -> None:
        """ValueError naming the setting unless ``value`` is in its range or choices."""
        if self.choices is not None and value not in self.choices():
            raise ValueError(f"{self.name} must be {self.allowed()}, got {value!r}")
        if self.bounds is not None:
            low, high = self.bounds
            values = list(value) if self.length else [value]
            if not all(low <= v and (high is None or v <= high) for v in values):
                raise ValueError(f"{self.name} must be {self.allowed()}, got {value!r}")

    def help(self, default: str | None = None) -> str:
        """The command-line help: meaning, valid values, the default (``default``: other
        words for it)."""
        allowed = self.allowed()
        return (f"{self.description[0].lower()}{self.description[1:].rstrip('.')}"
                + (f", {allowed}" if allowed and self.choices is None else "")
                + f" (default: {self.default_words() if default is None else default})")


RESOLUTION = Setting(
    "resolution", "Voxels along the longest side of the carving box.", int, "--resolution",
    bounds=(8, 2048), unit="voxels", cell_default=192, recorded=True,
    default_text="the finest pixel footprint at the object (1.5 of it when next to none of "
                 "the silhouettes lies in parts under 7 px wide), within the memory budget")
BOUNDS_M = Setting(
    "bounds_m", "Carving box [xmin, ymin, zmin, xmax, ymax, zmax], metres, object frame.",
    float, "--bounds", length=6, unit="m",
    cell_default=[-0.1, -0.1, 0.0, 0.1, 0.1, 0.2],
    default_text="the input's, else estimated from the silhouettes")
COLOUR = Setting(
    "colour", "Colour the mesh's vertices from the captured images of the views it uses.",
    bool, "--colour", default=False, cell_default=True)
MAX_MEMORY = Setting(
    "max_memory", "Working memory the voxel grid may take, e.g. 2G or 512M; a resolution "
    "that needs more is refused, a grid from the pixel footprint is coarsened to fit.",
    str, "--max-memory", metavar="SIZE", cell_default="",
    default_text="a quarter of the machine's memory")
#: Most views a mesh is coloured or textured from (spread over the directions:
#: :func:`sfs_ros.core.meshing.colour.spread_views`). A vertex takes colour from the views
#: within 78 degrees of its normal; 24 views spread over a hemisphere, some 30 degrees
#: apart, leave about eight of them to each vertex, which the view-angle weights blend:
#: more views cost a z-buffer each and change the blend little.
MAX_COLOUR_VIEWS = 24
