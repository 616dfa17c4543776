"""Whether the views see the object from enough directions for the visual hull to have a shape.

A silhouette bounds the object across its viewing direction, never along it:
the hull of one view (or of any number of copies of one view) reaches as far
as the carving box lets it. Two directions bound it, but every slice of the
hull through both directions is a quadrilateral whatever the object is (the
two silhouettes' edges, nothing of its outline): its depth along their bisector
is the silhouettes' width over the sine of half their angle, not the object's.
Only from three directions does each such slice carry an outline of the object,
so a reconstruction needs views along at least :data:`MIN_DIRECTIONS` lines
through the object, each pair of them at least :data:`MIN_SEPARATION_DEG` apart.
Opposite views count as one line: their silhouettes are mirror images of each
other's (exactly so for orthographic cameras). A ring of views at any carriage
angle, the horizon included, meets this; one view, a repeated view, or two
views do not.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry.camera import Camera

__all__ = ["MIN_DIRECTIONS", "MIN_SEPARATION_DEG", "check_directions", "distinct_directions",
           "viewing_directions"]

#: Viewing lines the views must span.
MIN_DIRECTIONS = 3
#: Smallest angle between two viewing lines that count as distinct, degrees.
MIN_SEPARATION_DEG = 15.0


def viewing_directions(cameras: list[Camera], centre=None) -> np.ndarray:
    """(n, 3) unit vectors: from each camera's centre to ``centre`` (metres, world frame;
    None: along its optical axis). Orthographic cameras look along their axis."""
    out = []
    for camera in cameras:
        d = camera.forward
        if centre is not None and not camera.orthographic:
            towards = np.asarray(centre, dtype=np.float64) - camera.center
            norm = float(np.linalg.norm(towards))
            if norm > 0 and math.isfinite(norm):
                d = towards / norm
        out.append(d)
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def distinct_directions(directions: np.ndarray,
                        separation_deg: float = MIN_SEPARATION_DEG) -> list[int]:
    """Indices of a largest-found set of ``directions`` pairwise at least ``separation_deg``
    apart as lines (``d`` and ``-d`` the same), grown greedily, each next the one farthest
    from those taken; at most :data:`MIN_DIRECTIONS` are sought."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if not len(d):
        return []
    limit = math.cos(math.radians(separation_deg))
    taken = [0]
    while len(taken) < MIN_DIRECTIONS:
        closeness = np.abs(d @ d[taken].T).max(axis=1)   # |cos| to the nearest line taken
        best = int(np.argmin(closeness))
        if closeness[best] > limit:
            break
        taken.append(best)
    return taken


def check_directions(cameras: list[Camera], names: list[str], centre=None) -> None:
    """ValueError naming the views unless they see the object along at least
    :data:`MIN_DIRECTIONS` distinct lines (module docstring); ``centre`` as
    :func:`viewing_directions`."""
    taken = distinct_directions(viewing_directions(cameras, centre))
    if len(taken) >= MIN_DIRECTIONS:
        return
    seen = ", ".join(names[i] for i in taken) or "none"
    raise ValueError(
        f"{len(cameras)} view(s) see the object from only {len(taken)} distinct direction(s) "
        f"({seen}): a visual hull needs views along at least {MIN_DIRECTIONS} lines through "
        f"the object, each pair at least {MIN_SEPARATION_DEG:.0f} degrees apart, to bound "
        "its shape (fewer leave its depth to the box); add views from other angles")
