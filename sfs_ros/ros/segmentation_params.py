"""The segmentation parameters as node parameters, shared by the nodes that need them.

The segmentation node declares them (with a preset's values as defaults) and
segments with them; the recorder turns the values it fetched from that node
into the ``segmentation`` section of a bag's parameters document.
"""

from __future__ import annotations

from sfs_ros.core.segmentation.segment import SegmentationParams
from sfs_ros.ros.params import Param, ParameterError

__all__ = ["segmentation_param_list", "segmentation_params"]


def segmentation_param_list(defaults: SegmentationParams) -> list[Param]:
    """The segmentation parameters with ``defaults`` as their default values."""
    d = defaults
    bg = d.background if isinstance(d.background, str) else ",".join(map(str, d.background))
    return [
        Param("method", d.method, "graph-cut (backdrop model from the image border + GrabCut, "
              "needs no preset) or threshold (the parameters below).",
              choices=("graph-cut", "threshold")),
        Param("background", bg, "Background colour: auto (most common border colour), white, "
              "black (most common bright / dark border colour) or 'r,g,b' (0..255, used as given).",
              constraints="auto, white, black or three integers 0..255 'r,g,b'"),
        Param("background_model", d.background_model, "constant, or smooth (a quadratic field "
              "fitted to the background: gradients, vignetting).", choices=("constant", "smooth")),
        Param("threshold", 0.0 if d.threshold is None else float(d.threshold),
              "Sure-object threshold on the colour distance, fraction of full scale.",
              bounds=(0.0, 1.0), constraints="0 = automatic (Otsu); else below 1"),
        Param("threshold_range", [float(v) for v in d.threshold_range],
              "Bounds [low, high] of the automatic threshold.", bounds=(0.0, 1.0),
              constraints="0 < low <= high < 1"),
        Param("weak_ratio", float(d.weak_ratio), "Hysteresis: pixels above weak_ratio * threshold "
              "are object when connected to sure pixels (1 disables hysteresis).",
              bounds=(0.0, 1.0), constraints="above 0"),
        Param("grow_px", -1 if d.grow_px is None else int(d.grow_px),
              "How far (pixels) weak pixels may extend from sure ones.", bounds=(-1, 100000),
              constraints="-1 = unlimited"),
        Param("chroma_weight", float(d.chroma_weight), "Weight of the chromatic part of the "
              "colour difference (1 = RMS of channel differences, 0 = brightness only).",
              bounds=(0.0, 100.0)),
        Param("open_px", int(d.open_px), "Radius (pixels) of the morphological opening.",
              bounds=(0, 1000)),
        Param("close_px", int(d.close_px), "Radius (pixels) of the morphological closing.",
              bounds=(0, 1000)),
        Param("min_blob_fraction", float(d.min_blob_fraction), "Components smaller than this "
              "fraction of the largest are removed.", bounds=(0.0, 1.0)),
        Param("keep_largest_only", bool(d.keep_largest_only), "Keep only the largest component."),
        Param("fill_holes_max_fraction", float(d.fill_holes_max_fraction), "Interior holes "
              "smaller than this fraction of the object area are filled.", bounds=(0.0, 1.0)),
        Param("dilate_px", int(d.dilate_px), "Final dilation radius (pixels), for conservative "
              "silhouettes.", bounds=(0, 1000)),
        Param("min_area_fraction", float(d.min_area_fraction), "A largest component below this "
              "fraction of the image means an empty view.", bounds=(0.0, 1.0),
              constraints="below 1"),
        Param("border_fraction", float(d.border_fraction), "Width of the border band used to "
              "estimate the background, fraction of the smaller image side.",
              bounds=(0.0, 0.25), constraints="above 0"),
    ]


def segmentation_params(values: dict) -> SegmentationParams:
    """:class:`SegmentationParams` from the node's parameter values (ROS encodings decoded).

    Raises :class:`ParameterError` naming the parameter the core rejects.
    """
    names = {p.name for p in segmentation_param_list(SegmentationParams())}
    fields = {k: v for k, v in values.items() if k in names}
    bg = fields["background"]
    if bg not in ("auto", "white", "black"):
        try:
            fields["background"] = tuple(int(c) for c in bg.split(","))
        except ValueError:
            raise ParameterError("background", f"got {bg!r}, expected auto, white, black or "
                                 "'r,g,b' with integers 0..255") from None
    fields["threshold"] = None if fields["threshold"] == 0.0 else fields["threshold"]
    fields["threshold_range"] = tuple(fields["threshold_range"])
    fields["grow_px"] = None if fields["grow_px"] == -1 else fields["grow_px"]
    try:
        return SegmentationParams(**fields)
    except ValueError as exc:
        message = str(exc)
        name = next((n for n in sorted(names, key=len, reverse=True) if message.startswith(n)),
                    "segmentation")
        raise ParameterError(name, message) from None
