"""Shape from silhouette: keep the voxels whose centres project into every mask.

The pixel test: a voxel centre projects to ``(u, v)``; it lands in pixel
``(floor(u + 0.5), floor(v + 0.5))`` (the pixel whose centre is nearest) and
hits the view when that pixel is foreground. A voxel whose centre projects
outside the image (or lies behind a pinhole camera) is kept
(``outside_image="keep"``: the view knows nothing about it, so objects may be
partly out of frame) or carved (``"carve"``). With ``max_misses=k`` a voxel
survives when at most ``k`` views miss it (tolerance to a few bad masks).

Two exact algorithms compute that same test (see :mod:`.carve_kernels`):

* line path: when every view is orthographic and one grid axis ``a`` leaves
  either the image column or the image row unchanged in every view (the
  physical rig maps each vertical Z-line of voxels onto one image column, the
  paper's convention each X-line onto one image row), masks are stored as
  runs of foreground per column (row), and each voxel line keeps a list of
  surviving intervals, intersected view by view with early exit;
* block path (any camera): blocks of voxels are tested against each view
  with a summed-area table over the bounding pixel rectangle of the block's
  projection (all foreground: every voxel hits; none: every voxel misses);
  only undecided blocks are split, down to a per-voxel test.
"""

from __future__ import annotations

from collections import Counter
from typing import Sequence

import numba
import numpy as np

from ..geometry.camera import Camera
from ..geometry.grid import VoxelGrid
from ..mask_box import foreground_box
from . import carve_kernels as _k

__all__ = ["OUTSIDE_IMAGE", "PreparedMasks", "carve", "Carver", "KeptCarve", "kept_or_carved",
           "same_grid", "unpack_bits", "validate_masks", "view_coefficients", "view_key",
           "view_keys"]

OUTSIDE_IMAGE = ("keep", "carve")

#: Projection-matrix entries this small relative to their row count as zero.
_ZERO_TOL = 1e-12
#: Block path: edge of the first blocks and of the blocks tested voxel by voxel.
_TOP_BLOCK = 16
_LEAF_BLOCK = 2
#: Line path: voxel lines per parallel task.
_LINE_CHUNK = 256


def _check_options(max_misses, outside_image) -> int:
    if isinstance(max_misses, bool) or not isinstance(max_misses, (int, np.integer)) \
            or max_misses < 0:
        raise ValueError(f"max_misses must be an integer >= 0, got {max_misses!r}")
    if outside_image not in OUTSIDE_IMAGE:
        raise ValueError(f"outside_image must be one of {OUTSIDE_IMAGE}, got {outside_image!r}")
    return int(max_misses)


def _check_mask(index: int, mask, camera) -> np.ndarray:
    """(H, W) bool C-contiguous copy-free view where possible; ValueError otherwise."""
    if not isinstance(camera, Camera):
        raise ValueError(f"camera of view {index} must be a Camera, got {type(camera).__name__}")
    m = np.asarray(mask)
    expected = (camera.height, camera.width)
    if m.shape != expected:
        raise ValueError(f"mask of view {index} has shape {m.shape}, expected the camera's "
                         f"(height, width) = {expected}")
    if m.dtype != np.bool_:
        numeric = np.issubdtype(m.dtype, np.integer) or np.issubdtype(m.dtype, np.floating)
        if not numeric or not np.all((m == 0) | (m == 1)):
            raise ValueError(f"mask of view {index} must be bool or hold only 0 and 1, "
                             f"got dtype {m.dtype}")
        m = m != 0
    return np.ascontiguousarray(m)


def validate_masks(cameras, masks) -> list:
    """Masks as (H, W) bool arrays, one per camera; ValueError naming the bad view."""
    if isinstance(masks, PreparedMasks):
        masks = masks.masks
    cameras = list(cameras)
    if len(masks) != len(cameras):
        raise ValueError(f"got {len(cameras)} cameras but {len(masks)} masks; expected one mask "
                         "per camera")
    return [_check_mask(i, m, c) for i, (c, m) in enumerate(zip(cameras, masks))]


def view_coefficients(grid: VoxelGrid, cameras: Sequence[Camera]) -> np.ndarray:
    """Per view, the projection as an affine function of voxel indices.

    Returns
    -------
    (n_views, 3, 4) float64
        ``coef[v, r] = (c, a_i, a_j, a_k)``: row ``r`` of the homogeneous pixel
        of voxel ``(i, j, k)`` is ``((c + i a_i) + j a_j) + k a_k``. Entries
        below ``1e-12`` times the largest of their row are set to exactly 0.
    """
    coef = np.empty((len(cameras), 3, 4))
    for v, cam in enumerate(cameras):
        P = cam.projection_matrix
        A = P[:, :3].copy()
        scale = np.abs(A).max(axis=1, keepdims=True)
        A[np.abs(A) <= _ZERO_TOL * scale] = 0.0
        coef[v, :, 0] = A @ grid.origin + P[:, 3]
        coef[v, :, 1:] = A * grid.voxel_size
    return coef


def _line_setup(coef: np.ndarray, cameras) -> tuple[int, np.ndarray] | None:
    """Grid axis whose lines each fall on one image row or column in every view.

    Returns ``(axis, by_row)`` with ``by_row[v]`` true when view ``v`` keeps the
    image row fixed along the line (runs are then taken along mask rows), or
    None when the views need the block path.
    """
    if not all(c.orthographic for c in cameras):
        return None
    if len({(c.height, c.width) for c in cameras}) != 1:
        return None
    for axis in (2, 1, 0):  # 2 first: Z-lines are contiguous in memory
        u_fixed = coef[:, 0, 1 + axis] == 0.0
        v_fixed = coef[:, 1, 1 + axis] == 0.0
        if np.all(u_fixed | v_fixed):
            return axis, ~u_fixed
    return None


def _view_order(cameras) -> np.ndarray:
    """Views ordered so that each next one looks most unlike those before
    (greedy farthest direction): lines and blocks die after fewer views."""
    d = np.array([c.forward for c in cameras])
    n = len(d)
    order = [0]
    similar = np.abs(d @ d[0])
    similar[0] = np.inf
    for _ in range(n - 1):
        nxt = int(np.argmin(similar))
        order.append(nxt)
        similar = np.maximum(similar, np.abs(d @ d[nxt]))
        similar[nxt] = np.inf
    return np.array(order, dtype=np.int64)


def _runs(masks: np.ndarray, by_row: np.ndarray):
    """Foreground runs of each mask column (or row): (offsets, run_lo, run_hi, L)."""
    n, H, W = masks.shape
    L = max(H, W)
    counts = np.empty((n, L), np.int32)
    _k.count_runs(masks, by_row, counts)
    offsets = np.zeros(n * L + 1, np.int64)
    np.cumsum(counts.ravel(), out=offsets[1:])
    run_lo = np.empty(offsets[-1], np.int32)
    run_hi = np.empty(offsets[-1], np.int32)
    _k.fill_runs(masks, by_row, offsets, run_lo, run_hi)
    return offsets, run_lo, run_hi, L


def _mask_boxes(masks) -> np.ndarray:
    """(n, 4) int64 bounding box (column, row, width, height) of each mask's foreground;
    zeros for an empty mask."""
    boxes = np.zeros((len(masks), 4), np.int64)
    for v, m in enumerate(masks):
        box = foreground_box(m)
        if box is not None:
            rows, cols = box
            boxes[v] = cols.start, rows.start, cols.stop - cols.start, rows.stop - rows.start
    return boxes


def _flat_views(cameras, masks):
    """The masks' foreground bounding boxes (a few times smaller than the images), their
    pixels flat for the block path, and their summed-area tables. One mask array given
    for several views (e.g. :func:`~.bounds.seen_by`'s full frames) is stored and tabled
    once; those views' offsets point at it."""
    heights = np.array([c.height for c in cameras], np.int64)
    widths = np.array([c.width for c in cameras], np.int64)
    slot: dict[int, int] = {}   # id of a mask array -> its place among the distinct ones
    first = np.array([slot.setdefault(id(m), v) for v, m in enumerate(masks)], np.int64)
    distinct = np.flatnonzero(first == np.arange(len(masks)))
    boxes = _mask_boxes([masks[v] for v in distinct])
    sizes = (boxes[:, 2] + 1) * (boxes[:, 3] + 1)
    moff = np.zeros(len(distinct), np.int64)
    moff[1:] = np.cumsum(boxes[:, 2] * boxes[:, 3])[:-1]
    ioff = np.zeros(len(distinct), np.int64)
    ioff[1:] = np.cumsum(sizes)[:-1]
    flat = np.concatenate([masks[v][y:y + h, x:x + w].ravel()
                           for v, (x, y, w, h) in zip(distinct, boxes)]).view(np.uint8)
    integ = np.empty(int(np.sum(sizes)), np.int32)
    _k.integral_images(flat, moff, boxes, ioff, integ)
    index = np.searchsorted(distinct, first)  # each view's mask among the distinct ones
    ortho = np.array([c.orthographic for c in cameras])
    return ortho, flat, moff[index], integ, ioff[index], boxes[index], heights, widths


class PreparedMasks:
    """Masks checked once, with the tables carving builds from them kept for the next carve.

    Carving many grids with the same views (a coarse box, a reference hull,
    the final hull) otherwise rebuilds the summed-area tables or run lists of
    every mask each time. Pass an instance as ``masks`` to :func:`carve`.

    Parameters
    ----------
    cameras : sequence of n Camera
    masks : sequence of n (H, W) bool (or 0/1)
    """

    def __init__(self, cameras: Sequence[Camera], masks):
        self.cameras = list(cameras)
        self.masks = validate_masks(self.cameras, masks)
        self._blocks = None
        self._runs = {}
        self._keys = None

    def view_keys(self) -> list[tuple]:
        """:func:`view_key` of each view, made once (a kept carve asks for them, one per
        grid it holds)."""
        if self._keys is None:
            self._keys = [view_key(c, m) for c, m in zip(self.cameras, self.masks)]
        return self._keys

    def block_tables(self):
        """The block path's flat mask boxes and summed-area tables (see ``_flat_views``)."""
        if self._blocks is None:
            self._blocks = _flat_views(self.cameras, self.masks)
        return self._blocks

    def run_lists(self, by_row: np.ndarray):
        """The line path's foreground runs per mask column (row where ``by_row``)."""
        key = by_row.tobytes()
        if key not in self._runs:
            self._runs[key] = _runs(np.stack(self.masks), by_row)
        return self._runs[key]


def carve(grid: VoxelGrid, cameras: Sequence[Camera], masks, *, max_misses: int = 0,
          outside_image: str = "keep") -> np.ndarray:
    """Visual hull of the silhouettes ``masks`` seen by ``cameras``.

    Parameters
    ----------
    grid : VoxelGrid
        Voxels to test.
    cameras : sequence of n Camera
    masks : sequence of n (H, W) bool (or 0/1) arrays, one (n, H, W) array, or PreparedMasks
        ``masks[v]`` has the shape ``(cameras[v].height, cameras[v].width)``.
    max_misses : int
        A voxel survives when at most this many views miss it.
    outside_image : {"keep", "carve"}
        What a view says about a voxel projecting outside its image.

    Returns
    -------
    (nx, ny, nz) bool
        True for the voxels that stay.
    """
    max_misses = _check_options(max_misses, outside_image)
    cameras = list(cameras)
    if isinstance(masks, PreparedMasks):
        if len(masks.cameras) != len(cameras) or any(
                a is not b for a, b in zip(masks.cameras, cameras)):
            raise ValueError("the prepared masks belong to other cameras; prepare them with "
                             "these")
        prepared = masks
    else:
        prepared = PreparedMasks(cameras, masks)
    masks = prepared.masks
    if max_misses >= len(cameras):
        return np.ones(grid.shape, dtype=bool)
    keep = outside_image == "keep"
    coef = view_coefficients(grid, cameras)
    order = _view_order(cameras)
    out = np.zeros(grid.shape, dtype=bool)
    line = _line_setup(coef, cameras)
    with numba.parallel_chunksize(1):
        if line is not None:
            axis, by_row = line
            offsets, run_lo, run_hi, L = prepared.run_lists(by_row)
            H, W = masks[0].shape
            _k.carve_lines(coef, by_row, order, offsets, run_lo, run_hi, L, H, W, axis, keep,
                           max_misses, _LINE_CHUNK,
                           _k.LINES_INTERSECT if max_misses == 0 else _k.LINES_COUNT, out,
                           np.zeros((1, 1, 1), np.uint8))
        else:
            ortho, flat, moff, integ, ioff, boxes, heights, widths = prepared.block_tables()
            _k.carve_blocks(coef, ortho, flat, moff, integ, ioff, boxes, heights, widths, order,
                            keep, max_misses, _TOP_BLOCK, _LEAF_BLOCK, out)
    return out


class Carver:
    """Incremental carving: add views one at a time while a scan runs.

    After any sequence of :meth:`add_view` calls, :attr:`occupancy` equals
    ``carve(grid, cameras_so_far, masks_so_far, ...)`` exactly.

    Parameters
    ----------
    grid : VoxelGrid
    max_misses : int
        A voxel survives when at most this many views miss it.
    outside_image : {"keep", "carve"}
        What a view says about a voxel projecting outside its image.
    """

    def __init__(self, grid: VoxelGrid, *, max_misses: int = 0, outside_image: str = "keep"):
        self.max_misses = _check_options(max_misses, outside_image)
        if self.max_misses >= np.iinfo(np.uint16).max:
            raise ValueError(f"max_misses must be below {np.iinfo(np.uint16).max}, "
                             f"got {max_misses}")
        self.grid = grid
        self.outside_image = outside_image
        dtype = np.uint8 if self.max_misses < np.iinfo(np.uint8).max else np.uint16
        # Miss count per voxel, saturating at max_misses + 1 (= carved).
        self._misses = np.zeros(grid.shape, dtype=dtype)
        n_blocks = int(np.prod([(n + _TOP_BLOCK - 1) // _TOP_BLOCK for n in grid.shape]))
        self._alive = np.ones(n_blocks, dtype=bool)
        self._n_views = 0

    @property
    def n_views(self) -> int:
        """Number of views added so far."""
        return self._n_views

    @property
    def occupancy(self) -> np.ndarray:
        """(nx, ny, nz) bool: the voxels that stay after the views added so far."""
        return self._misses <= self.max_misses

    @property
    def counts(self) -> np.ndarray:
        """(nx, ny, nz) uint8 (uint16 past 254 misses): per voxel, the views added so far
        that miss it, up to ``max_misses + 1`` (more are counted as that)."""
        return self._misses

    def tolerating(self, max_misses: int) -> np.ndarray:
        """(nx, ny, nz) bool: the voxels that at most ``max_misses`` (<= the carver's) of
        the views added so far miss, as :func:`carve` with that ``max_misses`` gives them
        (the counts are exact up to the carver's ``max_misses`` + 1)."""
        if not 0 <= max_misses <= self.max_misses:
            raise ValueError(f"max_misses must lie in [0, {self.max_misses}] (the carver's), "
                             f"got {max_misses}")
        return self._misses <= max_misses

    def add_view(self, camera: Camera, mask) -> None:
        """Carve with one more view; ``mask`` (camera.height, camera.width) bool or 0/1."""
        mask = _check_mask(self._n_views, mask, camera)
        keep = self.outside_image == "keep"
        coef = view_coefficients(self.grid, [camera])
        line = _line_setup(coef, [camera])
        with numba.parallel_chunksize(1):
            if line is not None:
                axis, by_row = line
                offsets, run_lo, run_hi, L = _runs(mask[None], by_row)
                H, W = mask.shape
                _k.carve_lines(coef, by_row, np.zeros(1, np.int64), offsets, run_lo, run_hi, L,
                               H, W, axis, keep, self.max_misses, _LINE_CHUNK,
                               _k.LINES_ADD_VIEW,
                               np.zeros((1, 1, 1), bool), self._misses)
            else:
                ortho, flat, _, integ, _, boxes, heights, widths = _flat_views([camera], [mask])
                _k.carve_blocks_one(coef, ortho, flat, integ, boxes, int(widths[0]),
                                    int(heights[0]), keep, self.max_misses + 1, _TOP_BLOCK,
                                    _LEAF_BLOCK, self._alive, self._misses)
        self._n_views += 1


def same_grid(a: VoxelGrid, b: VoxelGrid) -> bool:
    """Whether two grids have the same voxels."""
    return a.shape == b.shape and a.voxel_size == b.voxel_size \
        and bool(np.array_equal(a.bounds_min, b.bounds_min))


def view_key(camera: Camera, mask) -> tuple:
    """What decides a view's carve: its camera's numbers and its mask's bits."""
    distortion = None if camera.distortion is None else np.asarray(camera.distortion).tobytes()
    return (camera.K.tobytes(), camera.R.tobytes(), camera.t.tobytes(), camera.width,
            camera.height, bool(camera.orthographic), distortion,
            np.packbits(np.asarray(mask, dtype=bool), axis=None).tobytes())


def view_keys(cameras: Sequence[Camera], masks) -> list[tuple]:
    """:func:`view_key` of each camera and mask (``masks`` as :func:`carve` takes them):
    those :class:`PreparedMasks` made once, when they are of these very cameras."""
    cameras = list(cameras)
    if isinstance(masks, PreparedMasks):
        if len(cameras) == len(masks.cameras) \
                and all(a is b for a, b in zip(cameras, masks.cameras)):
            return masks.view_keys()
        masks = masks.masks
    return [view_key(c, m) for c, m in zip(cameras, masks, strict=True)]


class KeptCarve:
    """A carve of one grid kept up to date as views arrive, for a later :func:`carve`.

    Counts, per voxel, the views whose silhouette misses it (:class:`Carver`), a view
    at a time while the rig moves; :meth:`carved` then gives what :func:`carve` gives
    for the same grid and the same views (cameras and masks, in any order), instead of
    carving: the same voxels either way. Up to :attr:`MOST_REPLACED` views may come with
    other masks than they were counted with (the fusion repairs a mask or two): their
    counts are taken back and the new masks counted. For another grid, other views or
    more replaced masks it gives None, and the caller carves.

    Parameters
    ----------
    grid : VoxelGrid
    most_misses : int, keyword-only
        The most misses a later carve may tolerate.

    Memory: a byte per voxel and a key per view (its camera and its packed mask).
    """

    #: Views whose mask may differ from the one counted.
    MOST_REPLACED = 8

    def __init__(self, grid: VoxelGrid, *, most_misses: int = 0):
        self.grid = grid
        self.most_misses = int(most_misses)
        # Counts exact up to most_misses + MOST_REPLACED + 1: a voxel counted past that
        # stays carved at every tolerance with any MOST_REPLACED views taken back.
        self._misses = Carver(grid, max_misses=self.most_misses + self.MOST_REPLACED)
        self._views: Counter = Counter()

    def add(self, camera: Camera, mask) -> None:
        """Count one more view: ``mask`` (camera.height, camera.width) bool."""
        self._misses.add_view(camera, mask)
        self._views[view_key(camera, mask)] += 1

    def occupancy(self, max_misses: int) -> np.ndarray:
        """(nx, ny, nz) bool: the voxels of :attr:`grid` at most ``max_misses`` (at most
        :attr:`most_misses`) of the views counted miss."""
        return self._misses.tolerating(max_misses)

    def carved(self, grid: VoxelGrid, cameras: Sequence[Camera], masks,
               max_misses: int) -> np.ndarray | None:
        """(nx, ny, nz) bool, ``carve(grid, cameras, masks, max_misses=max_misses)``, if
        this store counted these views (``masks`` as :func:`carve` takes them) on this
        grid, all but at most :attr:`MOST_REPLACED` of them with these masks; else None."""
        if not same_grid(grid, self.grid) or not 0 <= max_misses <= self.most_misses:
            return None
        cameras = list(cameras)
        keys = view_keys(cameras, masks)
        if isinstance(masks, PreparedMasks):
            masks = masks.masks
        given = Counter(keys)
        counted_only, given_only = self._views - given, given - self._views
        replaced = sum(given_only.values())
        if len(cameras) != sum(self._views.values()) or replaced > self.MOST_REPLACED:
            return None
        if not replaced:
            return self._misses.tolerating(max_misses)
        camera_of = {key[:-1]: camera for camera, key in zip(cameras, keys)}
        misses = self._misses.counts.astype(np.int16)
        for key in counted_only.elements():
            camera = camera_of.get(key[:-1])
            if camera is None:
                return None   # a view counted whose camera is not among these
            misses -= ~carve(grid, [camera], [unpack_bits(key[-1], (camera.height, camera.width))])
        for key in given_only.elements():
            index = keys.index(key)
            misses += ~carve(grid, [cameras[index]], [masks[index]])
        return misses <= max_misses


def unpack_bits(packed, shape: tuple[int, ...]) -> np.ndarray:
    """``shape`` bool of the first ``prod(shape)`` bits ``np.packbits`` packed (``packed``:
    bytes or a uint8 array), its own array (the unpacked 0/1 bytes seen as bool, not
    copied)."""
    bits = np.unpackbits(np.frombuffer(packed, np.uint8), count=int(np.prod(shape)))
    return bits.reshape(shape).view(bool)


def kept_or_carved(kept: Sequence[KeptCarve], grid: VoxelGrid, cameras: Sequence[Camera],
                   masks, max_misses: int = 0) -> np.ndarray:
    """``carve(grid, cameras, masks, max_misses=max_misses)``: from the first of the
    ``kept`` carves that holds it (:meth:`KeptCarve.carved`), else carved now."""
    for store in kept:
        found = store.carved(grid, cameras, masks, max_misses)
        if found is not None:
            return found
    return carve(grid, cameras, masks, max_misses=max_misses)
