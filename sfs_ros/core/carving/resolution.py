"""The voxel size from the data: no larger than a pixel at the object, within a memory budget.

A voxel larger than the footprint of a pixel at the object throws away what the
cameras resolved; a smaller one adds no information to a visual hull (the
silhouettes are only known to a pixel). The footprint of view ``v`` at the
centre ``c`` of the carving box is ``depth_v(c) / f_v`` metres for a pinhole
camera and ``1 / f_v`` for an orthographic one (``f_v`` the smaller of the focal
lengths, pixels). The default voxel is the *finest* footprint over the views,
so every view's pixels are resolved, unless the silhouettes have next to no thin
parts: then it is :data:`COARSE_FOOTPRINTS` footprints, which loses what is narrower
than :data:`THIN_PART_PX` pixels (:mod:`.thin_parts`), bevels sharp edges a little more,
and holds the rest about as well. It is enlarged further only when the grid would not fit
the memory budget.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..geometry.camera import Camera
from ..geometry.grid import MAX_VOXELS, resolution_voxel_size
from ..settings import RESOLUTION

__all__ = ["BYTES_PER_VOXEL", "COARSE_FOOTPRINTS", "THIN_PART_PX", "THIN_SHARE_MAX",
           "refuse_unfit_grid", "ResolutionChoice", "pixel_footprints_m", "parse_memory",
           "default_memory_budget", "grid_shape", "choose_voxel_size"]

#: Peak working memory of a reconstruction per voxel of its grid, bytes: the
#: occupancy and the carving's working grids (four bool arrays), the labels of
#: the speck removal (int32) and the meshing volume (float32), with room for a
#: float32 distance field.
BYTES_PER_VOXEL = 16
#: Share of the machine's physical memory a reconstruction may use by default.
DEFAULT_MEMORY_SHARE = 0.25

#: The default voxel, in finest pixel footprints, for silhouettes with next to no thin parts.
COARSE_FOOTPRINTS = 1.5
#: Width, pixels, of the silhouette parts a grid of :data:`COARSE_FOOTPRINTS` loses.
THIN_PART_PX = 7
#: Largest share of the silhouettes' area in parts narrower than :data:`THIN_PART_PX` for
#: the coarse voxel: about the silhouette IoU the coarse voxel may lose there.
THIN_SHARE_MAX = 0.002

_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


@dataclass(frozen=True)
class ResolutionChoice:
    """How the voxel size was chosen.

    Attributes
    ----------
    voxel_size_m : float
        Voxel edge, metres.
    shape : tuple of 3 int
        Grid shape over the box.
    footprint_m : float
        Finest pixel footprint at the box centre over the views, metres.
    footprint_median_m : float
        Median over the views of the same, metres.
    source : str
        ``"footprint"`` (voxel = finest footprint, or :data:`COARSE_FOOTPRINTS` of it),
        ``"memory"`` (enlarged to fit ``max_memory_bytes``), ``"resolution"`` or
        ``"voxel-size"`` (given by the caller).
    memory_bytes : int
        Working memory the grid needs (``BYTES_PER_VOXEL`` per voxel).
    max_memory_bytes : int
        The budget it had to fit.
    thin_share : float or None
        Share of the silhouettes' area in parts narrower than :data:`THIN_PART_PX`
        pixels (None: not measured, or not needed: a size given by the caller).
    """

    voxel_size_m: float
    shape: tuple
    footprint_m: float
    footprint_median_m: float
    source: str
    memory_bytes: int
    max_memory_bytes: int
    thin_share: float | None = None

    @property
    def reason(self) -> str:
        """One sentence: why this voxel size."""
        mm = self.voxel_size_m * 1e3
        if self.source == "footprint":
            times = "the" if self.voxel_size_m == self.footprint_m else \
                f"{self.voxel_size_m / self.footprint_m:.3g} times the"
            return (f"{mm:.4g} mm: {times} finest pixel footprint at the box centre over the "
                    f"views (median {self.footprint_median_m * 1e3:.4g} mm){self._thin_parts()}")
        if self.source == "memory":
            return (f"{mm:.4g} mm: the finest pixel footprint ({self.footprint_m * 1e3:.4g} mm) "
                    f"coarsened to fit {self.max_memory_bytes / (1 << 30):.2f} GiB")
        return f"{mm:.4g} mm: from the given {self.source}"

    def _thin_parts(self) -> str:
        if self.thin_share is None:
            return ""
        share = f"{100 * self.thin_share:.2g} % of the silhouettes' area"
        if self.thin_share <= THIN_SHARE_MAX:
            return f"; parts under {THIN_PART_PX} px wide are {share}"
        return f", keeping the parts under {THIN_PART_PX} px wide ({share})"


def pixel_footprints_m(cameras: Sequence[Camera], point) -> np.ndarray:
    """(n,) float64: side of one pixel of each camera at the world ``point`` (3,), metres.

    Raises ``ValueError`` when the point lies behind a pinhole camera.
    """
    point = np.asarray(point, dtype=np.float64).reshape(1, 3)
    out = np.empty(len(cameras))
    for n, cam in enumerate(cameras):
        focal_px = min(cam.K[0, 0], cam.K[1, 1])
        if cam.orthographic:
            out[n] = 1.0 / focal_px
            continue
        depth = float(cam.depth(point)[0])
        if not depth > 0:
            raise ValueError(f"the box centre {point[0].round(4).tolist()} m lies behind camera "
                             f"{n}: cannot size the voxels from its pixels")
        out[n] = depth / focal_px
    return out


def parse_memory(text: str) -> int:
    """Bytes in a size like ``"2G"``, ``"512M"``, ``"1.5GiB"``, ``"800MB"`` or ``"1000000"``.

    Suffixes K, M, G, T are powers of 1024 (with or without ``B`` / ``iB``).
    """
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([KMGT]?)(?:I?B)?\s*", str(text).upper())
    if match is None:
        raise ValueError(f"memory size {text!r} not understood; expected a number with an "
                         "optional K, M, G or T suffix, e.g. 2G or 512M")
    value = float(match.group(1)) * _UNITS[match.group(2)]
    if value < 1 << 20:
        raise ValueError(f"memory size {text!r} is below 1 MiB; expected e.g. 2G or 512M")
    return int(value)


def default_memory_budget() -> int:
    """A quarter of the machine's physical memory, bytes."""
    return int(DEFAULT_MEMORY_SHARE * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def grid_shape(bounds_m, voxel_size_m: float) -> tuple:
    """Shape of the grid of ``voxel_size_m`` voxels over ``bounds_m`` (2, 3), as
    :class:`~..geometry.grid.VoxelGrid` makes it."""
    extent = np.asarray(bounds_m, dtype=np.float64)[1] - np.asarray(bounds_m, dtype=np.float64)[0]
    return tuple(int(n) for n in np.maximum(1, np.ceil(extent / voxel_size_m - 1e-9)))


def _fits(shape, max_memory_bytes: int) -> bool:
    voxels = int(np.prod(shape))
    return voxels <= MAX_VOXELS and voxels * BYTES_PER_VOXEL <= max_memory_bytes


def _describe(shape) -> str:
    """The grid ``shape``, its voxels and memory; the voxel cap when that is what it exceeds."""
    voxels = int(np.prod(shape))
    cap = "" if voxels <= MAX_VOXELS else \
        f" and has more than the {MAX_VOXELS / 1e6:.0f} M voxels a grid may have"
    return (f"grid {tuple(shape)} = {voxels / 1e6:.0f} M voxels needs "
            f"{voxels * BYTES_PER_VOXEL / (1 << 30):.2f} GiB{cap}")


def refuse_unfit_grid(shape, max_memory_bytes: int, what: str) -> None:
    """ValueError naming ``what``, the memory the grid ``shape`` (voxels per axis) needs and
    the budget ``max_memory_bytes`` when it does not fit (nothing is allocated)."""
    if not _fits(shape, max_memory_bytes):
        raise ValueError(f"{what} is more than this machine may hold: {_describe(shape)}, "
                         f"the budget is {max_memory_bytes / (1 << 30):.2f} GiB; choose "
                         "a coarser resolution")


def _refuse_coarse_voxel(size: float, source: str, bounds: np.ndarray, cameras,
                         footprints) -> None:
    """ValueError unless a voxel of ``size`` metres (chosen by ``source``) can show a
    shape: a given voxel size leaves as many voxels along the box's longest side as the
    coarsest resolution (:data:`~sfs_ros.core.settings.RESOLUTION`), and no voxel is wider
    than what the cameras see at the box centre (the median over the views of the image's longer side
    times the pixel footprint ``footprints`` (n,), metres): a wider voxel holds the whole
    view, so every silhouette is one voxel."""
    extent = float(np.max(bounds[1] - bounds[0]))
    what = {"memory": "voxel the memory budget allows", "voxel-size": "voxel size asked for",
            "resolution": "resolution asked for"}.get(source, "pixel footprint")
    min_side_voxels = RESOLUTION.bounds[0]
    if source == "voxel-size" and extent / size < min_side_voxels:
        raise ValueError(
            f"the {what} ({size:.4g} m) is too coarse for the carving box: its longest side "
            f"is {extent:.4g} m, {extent / size:.3g} voxel(s); expected voxels of at most "
            f"{extent / min_side_voxels:.4g} m (at least {min_side_voxels} along the box's "
            "longest side)")
    sides = np.array([max(c.width, c.height) for c in cameras], dtype=np.float64)
    field = float(np.median(sides * footprints))
    if size > field:
        raise ValueError(
            f"the {what} ({size:.4g} m voxels) is wider than the cameras see at the box's "
            f"centre (about {field:.4g} m across, the median over the views): the carving box "
            f"{bounds.round(4).tolist()} m is far larger than what the views show; expected a "
            "box around the object")


def choose_voxel_size(bounds_m, cameras: Sequence[Camera], *, max_memory_bytes: int,
                      resolution: int | None = None,
                      voxel_size_m: float | None = None,
                      thin_share: float | None = None) -> ResolutionChoice:
    """The voxel size for carving ``bounds_m`` (2, 3), metres, seen by ``cameras``.

    By default the finest pixel footprint, :data:`COARSE_FOOTPRINTS` of it when
    ``thin_share`` (the share of the silhouettes' area in parts narrower than
    :data:`THIN_PART_PX` pixels, :func:`.thin_parts.thin_share`) is at most
    :data:`THIN_SHARE_MAX`. ``voxel_size_m`` or ``resolution`` (voxels along the box's
    longest side) override the footprint; a grid they ask for that does not fit
    ``max_memory_bytes`` (or more than ``MAX_VOXELS`` voxels) is refused with a
    ``ValueError`` giving the memory it would need, before anything is
    allocated. The footprint's grid is instead coarsened until it fits. A voxel
    that cannot show a shape is refused with a ``ValueError`` saying why: a given
    size with fewer voxels along the box's longest side than the coarsest
    resolution, or any voxel wider than the cameras' view at the box centre (a
    box far larger than the object).
    """
    bounds = np.asarray(bounds_m, dtype=np.float64)
    if int(max_memory_bytes) <= 0:
        raise ValueError(f"max_memory_bytes must be > 0, got {max_memory_bytes}")
    footprints = pixel_footprints_m(cameras, bounds.mean(axis=0))
    finest, median = float(footprints.min()), float(np.median(footprints))
    if voxel_size_m is not None:
        size, source = float(voxel_size_m), "voxel-size"
    elif resolution is not None:
        size, source = resolution_voxel_size(bounds[0], bounds[1], resolution), "resolution"
    else:
        coarse = thin_share is not None and thin_share <= THIN_SHARE_MAX
        size, source = finest * (COARSE_FOOTPRINTS if coarse else 1.0), "footprint"
    shape = grid_shape(bounds, size)
    if not _fits(shape, max_memory_bytes):
        if source != "footprint":
            advice = "raise it with --max-memory, or choose a coarser resolution" \
                if int(np.prod(shape)) <= MAX_VOXELS else "choose a coarser resolution"
            raise ValueError(
                f"the {source} asked for ({size * 1e3:.4g} mm voxels) is more than this "
                f"reconstruction may use: {_describe(shape)}, the budget is "
                f"{max_memory_bytes / (1 << 30):.2f} GiB ({advice})")
        limit = min(MAX_VOXELS, max_memory_bytes // BYTES_PER_VOXEL)
        volume = float(np.prod(bounds[1] - bounds[0]))
        size = (volume / limit) ** (1.0 / 3.0)
        while not _fits(grid_shape(bounds, size), max_memory_bytes):  # whole-voxel rounding
            size *= 1.01
        shape, source = grid_shape(bounds, size), "memory"
    _refuse_coarse_voxel(size, source, bounds, cameras, footprints)
    return ResolutionChoice(voxel_size_m=size, shape=shape, footprint_m=finest,
                            footprint_median_m=median, source=source,
                            memory_bytes=int(np.prod(shape)) * BYTES_PER_VOXEL,
                            max_memory_bytes=int(max_memory_bytes),
                            thin_share=None if source in ("resolution", "voxel-size")
                            else thin_share)
