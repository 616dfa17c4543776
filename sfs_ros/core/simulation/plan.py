"""Scan plans: the prescribed (theta, phi) viewpoints on the upper hemisphere."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ring_plan"]


def ring_plan(phis_deg, n_theta: int, *, top_view: bool = False,
              stagger: bool = True) -> np.ndarray:
    """Viewpoints on latitude rings: ``n_theta`` turntable stops per carriage angle.

    Parameters
    ----------
    phis_deg : sequence of float
        Carriage elevations, degrees, each in [-90, 90].
    n_theta : int
        Turntable stops per ring, evenly spaced over 360 degrees.
    top_view : bool
        Append one view straight down (phi = 90 deg).
    stagger : bool
        Offset every other ring by half a step so rings do not share meridians.

    Returns
    -------
    (n, 2) float64
        ``(theta_rad, phi_rad)`` per view, ring by ring.
    """
    phis = [float(p) for p in phis_deg]
    if n_theta < 1:
        raise ValueError(f"n_theta must be >= 1, got {n_theta}")
    if not phis or not all(math.isfinite(p) and -90.0 <= p <= 90.0 for p in phis):
        raise ValueError(f"ring elevations must be finite degrees in [-90, 90], got {phis}")
    step = 2 * math.pi / n_theta
    rows = []
    for ring, phi in enumerate(phis):
        offset = 0.5 * step if (stagger and ring % 2) else 0.0
        rows += [(offset + k * step, math.radians(phi)) for k in range(n_theta)]
    if top_view:
        rows.append((0.0, math.pi / 2))
    return np.array(rows, dtype=np.float64)
