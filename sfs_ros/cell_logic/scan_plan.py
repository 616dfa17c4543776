"""The prescribed viewpoints of a scan, from a YAML file or from parameters.

Plan file (YAML mapping; unknown keys are an error). Either explicit views::

    views:                 # [theta_deg, phi_deg] per view
      - [0, 20]
      - [90, 20]
      - [0, 90]
    reorder: true          # optional (default true): reorder to shorten the motion
    allow_duplicates: false  # optional (default false): refuse repeated viewpoints

or rings of views (:func:`sfs_ros.core.simulation.plan.ring_plan`)::

    rings:
      phi_deg: [5, 35, 65]   # carriage elevations, degrees
      per_ring: 16           # turntable stops per ring, evenly spaced
      top_view: true         # optional (default false): one view from straight above
      stagger: true          # optional (default true): offset every other ring by half a step
    reorder: true

``theta_deg`` is the turntable angle (any finite value, taken modulo 360 into
[0, 360)), ``phi_deg`` the carriage elevation in [-90, 90]. Two views are
duplicates when they have the same elevation and turntable angle (to 1e-6
degree), or both look straight up or down (|phi| = 90: the turntable angle
then only rotates the image, the silhouette is the same).

Ordering (``reorder``): views are grouped by elevation into rings, rings taken
from the lowest elevation up, and each ring swept in the turntable direction
whose first stop is nearest to where the previous ring ended, so successive
rings alternate direction; a view straight up or down is taken at the
turntable angle of the view before it (there the turntable angle only rotates
the image). Turntable angles stay in [0, 360) (no unbounded
rotation is assumed), so the naive order (every ring from its lowest angle
upward) spends almost a full turn going back between rings; alternating
directions replaces that with one step. :func:`travel_deg` measures it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..core.simulation.plan import ring_plan

__all__ = ["ScanPlan", "load_plan", "travel_deg"]

_TOP_KEYS = ("views", "rings", "reorder", "allow_duplicates")
_RING_KEYS = ("phi_deg", "per_ring", "top_view", "stagger")

#: Angles closer than this are the same viewpoint, degrees.
_SAME_DEG = 1e-6


def _refuse_unknown_keys(mapping: dict, allowed: tuple[str, ...], where: str) -> None:
    """Raise ValueError naming the keys of ``mapping`` that are not in ``allowed``."""
    unknown = sorted(set(map(str, mapping)) - set(allowed))
    if unknown:
        raise ValueError(f"unknown keys {unknown} in {where}; expected some of {list(allowed)}")


def travel_deg(views_rad) -> tuple[float, float]:
    """Total motion of each axis visiting ``views_rad`` (n, 2) in order.

    Returns ``(turntable, carriage)`` degrees: the sums of ``|d theta|`` and
    ``|d phi|`` between consecutive views, angles taken as absolute positions
    (no wrapping).
    """
    steps = np.abs(np.diff(np.degrees(np.asarray(views_rad, dtype=np.float64).reshape(-1, 2)),
                           axis=0))
    return float(steps[:, 0].sum()), float(steps[:, 1].sum())


def _duplicates(views_deg: np.ndarray) -> list[tuple[int, int]]:
    """Index pairs (i < j) of views that are the same viewpoint."""
    pairs = []
    for j in range(1, len(views_deg)):
        theta, phi = views_deg[j]
        d_theta = np.abs(views_deg[:j, 0] - theta)
        d_theta = np.minimum(d_theta, 360.0 - d_theta)
        same = (np.abs(views_deg[:j, 1] - phi) <= _SAME_DEG) & (
            (d_theta <= _SAME_DEG) | (abs(abs(phi) - 90.0) <= _SAME_DEG))
        pairs += [(int(i), j) for i in np.flatnonzero(same)]
    return pairs


def _motion_order(views_deg: np.ndarray) -> np.ndarray:
    """Permutation visiting rings from the lowest elevation up, alternating sweep direction."""
    order = []
    position = None
    for phi in np.unique(views_deg[:, 1]):
        ring = np.flatnonzero(views_deg[:, 1] == phi)
        ring = ring[np.argsort(views_deg[ring, 0], kind="stable")]
        if position is not None and \
                abs(views_deg[ring[-1], 0] - position) < abs(views_deg[ring[0], 0] - position):
            ring = ring[::-1]
        order += ring.tolist()
        position = views_deg[ring[-1], 0]
    return np.array(order, dtype=np.int64)


def _at_turntable_position(views_deg: np.ndarray) -> np.ndarray:
    """Views straight up or down (|phi| = 90) take the turntable angle of the view before
    (the first view: after), so the turntable does not move for them."""
    out = views_deg.copy()
    for i in np.flatnonzero(np.abs(np.abs(out[:, 1]) - 90.0) <= _SAME_DEG):
        if i > 0:
            out[i, 0] = out[i - 1, 0]
        elif len(out) > 1:
            out[i, 0] = out[i + 1, 0]
    return out


@dataclass(frozen=True)
class ScanPlan:
    """Viewpoints to visit, in order.

    Attributes
    ----------
    views : (n, 2) float64
        ``(theta_rad, phi_rad)`` per view, radians; theta in [0, 2 pi),
        phi in [-pi/2, pi/2].
    names : tuple of n str
        ``view_000``, ``view_001``, ... in visiting order.
    duplicates : tuple of (int, int)
        Index pairs (into ``views``) of repeated viewpoints (empty unless allowed).
    """

    views: np.ndarray
    names: tuple
    duplicates: tuple = ()

    def __len__(self) -> int:
        return len(self.views)

    @property
    def views_deg(self) -> np.ndarray:
        """(n, 2) float64 ``(theta_deg, phi_deg)``."""
        return np.degrees(self.views)

    def travel_deg(self) -> tuple[float, float]:
        """``(turntable, carriage)`` degrees of motion visiting the views in order."""
        return travel_deg(self.views)

    @classmethod
    def from_views(cls, views_deg, *, reorder: bool = True,
                   allow_duplicates: bool = False) -> "ScanPlan":
        """Plan from ``(theta_deg, phi_deg)`` rows (n, 2), degrees.

        Raises ValueError for an empty plan, a row that is not two finite
        numbers, phi outside [-90, 90], or (unless ``allow_duplicates``)
        repeated viewpoints, naming the rows.
        """
        try:
            deg = np.array(views_deg, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("views must be a list of [theta_deg, phi_deg] pairs of numbers, "
                             f"got {views_deg!r}") from None
        if deg.ndim != 2 or deg.shape[1] != 2 or len(deg) == 0:
            raise ValueError("views must be a non-empty list of [theta_deg, phi_deg] pairs, "
                             f"got shape {deg.shape}")
        bad = np.flatnonzero(~np.all(np.isfinite(deg), axis=1))
        if len(bad):
            raise ValueError(f"view {int(bad[0])} {deg[bad[0]].tolist()} is not finite; "
                             "expected [theta_deg, phi_deg] numbers")
        bad = np.flatnonzero(np.abs(deg[:, 1]) > 90.0)
        if len(bad):
            raise ValueError(f"view {int(bad[0])} has phi {deg[bad[0], 1]} deg, outside the "
                             "carriage range [-90, 90]")
        for name, flag in (("reorder", reorder), ("allow_duplicates", allow_duplicates)):
            if not isinstance(flag, bool):
                raise ValueError(f"{name} must be true or false, got {flag!r}")
        deg[:, 0] = np.mod(deg[:, 0], 360.0)
        deg[deg[:, 0] >= 360.0, 0] = 0.0  # mod of a tiny negative number rounds to 360
        if reorder:
            deg = _at_turntable_position(deg[_motion_order(deg)])
        duplicates = _duplicates(deg)
        if duplicates and not allow_duplicates:
            shown = ", ".join(f"{i} and {j} at {deg[j].round(6).tolist()}"
                              for i, j in duplicates[:5])
            raise ValueError(f"{len(duplicates)} repeated viewpoint(s) (views {shown}); a repeat "
                             "adds nothing to the hull (set allow_duplicates to keep them)")
        names = tuple(f"view_{n:03d}" for n in range(len(deg)))
        return cls(views=np.radians(deg), names=names, duplicates=tuple(duplicates))

    @classmethod
    def from_rings(cls, phis_deg, per_ring: int, top_view: bool = False, *, stagger: bool = True,
                   reorder: bool = True) -> "ScanPlan":
        """``per_ring`` evenly spaced turntable stops per elevation of ``phis_deg`` (degrees)."""
        if isinstance(per_ring, bool) or not isinstance(per_ring, (int, np.integer)) \
                or per_ring < 1:
            raise ValueError(f"per_ring must be an integer >= 1, got {per_ring!r}")
        for name, flag in (("top_view", top_view), ("stagger", stagger)):
            if not isinstance(flag, bool):
                raise ValueError(f"{name} must be true or false, got {flag!r}")
        try:
            phis = [float(p) for p in phis_deg]
        except (TypeError, ValueError):
            raise ValueError(f"phi_deg must be a list of elevations in degrees, "
                             f"got {phis_deg!r}") from None
        if len(set(phis)) != len(phis):
            raise ValueError(f"phi_deg lists an elevation twice: {phis}")
        views_rad = ring_plan(phis, int(per_ring), top_view=top_view, stagger=stagger)
        return cls.from_views(np.degrees(views_rad), reorder=reorder)

    @classmethod
    def from_dict(cls, data) -> "ScanPlan":
        """Plan from a parsed plan file (format in the module docstring)."""
        if not isinstance(data, dict):
            raise ValueError(f"a scan plan must be a mapping with 'views' or 'rings', got "
                             f"{type(data).__name__}")
        _refuse_unknown_keys(data, _TOP_KEYS, "the scan plan")
        if ("views" in data) == ("rings" in data):
            raise ValueError("a scan plan needs exactly one of 'views' (explicit [theta_deg, "
                             "phi_deg] pairs) or 'rings'")
        reorder = data.get("reorder", True)
        if "views" in data:
            return cls.from_views(data["views"], reorder=reorder,
                                  allow_duplicates=data.get("allow_duplicates", False))
        if "allow_duplicates" in data:
            raise ValueError("allow_duplicates applies to explicit 'views' only (rings never "
                             "repeat a viewpoint)")
        rings = data["rings"]
        if not isinstance(rings, dict):
            raise ValueError(f"'rings' must be a mapping with keys {list(_RING_KEYS)}, "
                             f"got {rings!r}")
        _refuse_unknown_keys(rings, _RING_KEYS, "'rings'")
        missing = [k for k in ("phi_deg", "per_ring") if k not in rings]
        if missing:
            raise ValueError(f"'rings' needs {missing}")
        phis = rings["phi_deg"]
        if not isinstance(phis, list) or not phis:
            raise ValueError(f"rings.phi_deg must be a non-empty list of degrees, got {phis!r}")
        if not all(isinstance(p, (int, float)) and not isinstance(p, bool) and math.isfinite(p)
                   and -90.0 <= p <= 90.0 for p in phis):
            raise ValueError(f"rings.phi_deg must hold finite degrees in [-90, 90], got {phis}")
        return cls.from_rings(phis, rings["per_ring"], rings.get("top_view", False),
                              stagger=rings.get("stagger", True), reorder=reorder)


def load_plan(path) -> ScanPlan:
    """Read a plan file (YAML, format in the module docstring); ValueError naming the file."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise ValueError(f"cannot read scan plan {path}: {err.strerror}") from None
    except (yaml.YAMLError, UnicodeDecodeError):
        raise ValueError(f"scan plan {path} is not valid YAML") from None
    try:
        return ScanPlan.from_dict(data)
    except ValueError as err:
        raise ValueError(f"scan plan {path}: {err}") from None
