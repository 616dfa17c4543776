"""The box of a mask's foreground: the rows and columns that hold its pixels, for work
that needs to look only there."""

from __future__ import annotations

import numpy as np

__all__ = ["foreground_box"]


def foreground_box(*masks: np.ndarray, margin_px: int = 0) -> tuple[slice, slice] | None:
    """The rows and columns holding the pixels set in any of ``masks`` ((H, W) bool, one
    shape), widened by ``margin_px`` pixels on every side and clipped to the frame, as
    two slices with int bounds; None when every mask is empty."""
    rows = masks[0].any(axis=1)
    for mask in masks[1:]:
        rows |= mask.any(axis=1)
    found = np.flatnonzero(rows)
    if found.size == 0:
        return None
    cols = masks[0].any(axis=0)
    for mask in masks[1:]:
        cols |= mask.any(axis=0)
    across = np.flatnonzero(cols)
    h, w = masks[0].shape
    return (slice(max(0, int(found[0]) - margin_px), min(h, int(found[-1]) + 1 + margin_px)),
            slice(max(0, int(across[0]) - margin_px), min(w, int(across[-1]) + 1 + margin_px)))
