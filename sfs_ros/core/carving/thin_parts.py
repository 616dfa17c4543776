"""How much of the silhouettes lies in parts too thin for a coarser voxel.

A part of a silhouette narrower than a few voxels' footprints is lost by the grid: a
voxel grid holds what is several of its voxels wide. The thin parts of a mask are the
pixels an opening with a disk of ``width_px`` removes: those in no disk of that
diameter that lies inside the mask (legs, wires, an antenna; and a few pixels at each
sharp corner).
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from ..mask_box import foreground_box

__all__ = ["thin_share"]


def _thin_pixels(mask: np.ndarray, disk: np.ndarray) -> tuple[int, int]:
    """Pixels of ``mask`` (H, W) bool in parts narrower than ``disk`` (d, d) uint8, and
    all its foreground pixels."""
    box = foreground_box(mask)
    if box is None:
        return 0, 0
    pad = disk.shape[0]
    crop = np.pad(mask[box].view(np.uint8), pad)  # the frame's edge does not keep a part
    opened = cv2.morphologyEx(crop, cv2.MORPH_OPEN, disk)
    foreground = int(np.count_nonzero(crop))
    return foreground - int(np.count_nonzero(opened)), foreground


def thin_share(masks: Sequence[np.ndarray], width_px: int) -> float:
    """Share of the foreground of ``masks`` ((H, W) bool each) in parts narrower than
    ``width_px`` pixels (odd, >= 3), over all of them together, in [0, 1]; 0 when they are
    all empty."""
    if width_px < 3 or width_px % 2 == 0:
        raise ValueError(f"width_px must be odd and >= 3, got {width_px}")
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (width_px, width_px))
    counts = np.array([_thin_pixels(np.ascontiguousarray(m, dtype=bool), disk) for m in masks],
                      dtype=np.int64).reshape(-1, 2)
    total = int(counts[:, 1].sum())
    return float(counts[:, 0].sum()) / total if total else 0.0
