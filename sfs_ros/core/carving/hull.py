"""Clean-up of a carved visual hull."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["drop_specks"]


def drop_specks(occupancy: np.ndarray, *, min_fraction: float = 0.01) -> tuple[np.ndarray, int]:
    """Remove connected parts smaller than ``min_fraction`` of the largest.

    A visual hull can hold small phantom pieces where the viewing cones of a
    few views happen to overlap away from the object; a real second object on
    the turntable is large and is kept.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
    min_fraction : float
        Parts with fewer voxels than this fraction of the largest part go.

    Returns
    -------
    (nx, ny, nz) bool, int
        The cleaned occupancy and the number of parts removed.
    """
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction must be in [0, 1], got {min_fraction}")
    labels, n = ndimage.label(occupancy, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return occupancy, 0
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    keep = sizes >= min_fraction * sizes.max()
    keep[0] = False
    return keep[labels], int(n - keep[1:].sum())
