"""The hull's signed distance near its surface, kept as the views arrive.

:func:`.marching.hull_band_distance` evaluates the views' silhouette distances
(:class:`.hull_distance.HullDistance`) at the voxels within a band of the carved
surface: after the last view of a scan, the most of a reconstruction's carving time.
A point's value is the ``rank``-th largest of its views' values (above a floor), which
does not depend on the order the views come in: :class:`KeptBand` keeps those largest
values at the band's voxels of the hull carved so far, adding each view as it arrives
(while the rig moves) and evaluating every view so far at the voxels the band reaches
only then. After the last view, the band of the final hull is mostly kept already: its
voxels kept are read, the others evaluated. The values are the same either way, bit for
bit: every view's value at a voxel is the same number whichever
:class:`~.hull_distance.HullDistance` holds the view.

It keeps the hull's zeros along the grid edges its band's level crosses as well
(:class:`.marching.BandEdges`, found each time it follows the hull) with where they were
stepped to (:class:`~.hull_distance.ZeroTrace`): a view that comes later and gives no
value above the distance at those points leaves the zero as it is, the others have it
found again when the band follows the hull next or after the last view. After the last
view, an edge's zero is read where the edge is kept with the same end values and no
view since raised it, the others are found.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from ..carving.carve import same_grid, unpack_bits, view_key
from ..geometry.grid import VoxelGrid
from .hull_distance import DistanceImages, HullDistance, ZeroTrace, point_groups
from .marching import (
    CROSSING_ITERATIONS,
    BandEdges,
    band_values,
    band_voxel_indices,
    hull_band_floor_m,
    padded_crop,
)

__all__ = ["KeptBand"]


class KeptBand:
    """The ``rank`` largest view values (:meth:`.hull_distance.HullDistance.add_largest`)
    at the voxels near a hull's surface on ``grid``, kept as views arrive, for
    :func:`.marching.hull_band_distance` of the same views.

    Parameters
    ----------
    grid : VoxelGrid
    max_misses : int, keyword-only
        The misses the hull tolerates (``rank = max_misses + 1``).
    known : DistanceImages, keyword-only
        The views' distance images (each view's added before it is given here).
    band_voxels : int, keyword-only
        The band of :func:`.marching.hull_band_distance`.

    Memory: per voxel of the band of the hull followed, its index and place (16 bytes),
    centre (24 bytes) and ``rank`` values (8 bytes each); per edge its level crosses (about
    as many), its key, end values and zero (32 bytes) and trace
    (:data:`~.marching.CROSSING_ITERATIONS` points and values, 32 bytes each, and a
    count); per view, its packed mask.
    """

    def __init__(self, grid: VoxelGrid, *, max_misses: int, known: DistanceImages,
                 band_voxels: int = 1):
        self.grid, self.rank, self.band_voxels = grid, int(max_misses) + 1, int(band_voxels)
        self.floor_m = hull_band_floor_m(grid, self.band_voxels)
        self._known = known
        self._views: Counter = Counter()
        self._cameras: list = []
        self._packed: list[tuple[np.ndarray, tuple]] = []   # (packed mask, its shape)
        # The voxels kept, in the groups the views are evaluated in (point_groups): their
        # centres, values and group starts; and their linear indices, ascending, with
        # where each lies in the groups.
        self._points = np.empty((0, 3))
        self._top = np.empty((0, self.rank))
        self._starts = np.zeros(1, np.int64)
        self._sorted = np.empty(0, np.int64)
        self._place = np.empty(0, np.int64)
        self._edges = _KeptZeros.none()

    def add(self, camera, mask: np.ndarray) -> None:
        """One more view: ``camera`` and ``mask`` (H, W) bool on it, its values added at
        the voxels kept."""
        if len(self._points) or len(self._edges):
            view = HullDistance([camera], [mask], known=self._known)
            view.add_largest(self._points, self._top, floor_m=self.floor_m,
                             starts=self._starts)
            self._edges.raised_by(view)
        self._cameras.append(camera)
        self._packed.append((np.packbits(mask, axis=None), mask.shape))
        self._views[view_key(camera, mask)] += 1

    def follow(self, occupancy: np.ndarray) -> None:
        """Keep the values at the band of ``occupancy`` (the grid's shape, bool; the hull
        carved so far) from now on: every view's values evaluated where they were not
        kept (the hull decides where the values are kept, not what they are)."""
        crop, corner, in_crop = self._band(occupancy)
        voxels = in_crop + corner
        linear = self._linear(voxels)
        points = self.grid.index_to_world(voxels)
        top, missing = self._kept_at(linear)
        hull = HullDistance(self._cameras,
                            [unpack_bits(packed, shape) for packed, shape in self._packed],
                            max_misses=self.rank - 1, known=self._known,
                            bounds_m=(self.grid.bounds_min, self.grid.bounds_max)) \
            if self._cameras else None
        if missing.any():
            fresh = np.full((int(missing.sum()), self.rank), self.floor_m)
            hull.add_largest(points[missing], fresh, floor_m=self.floor_m)
            top[missing] = fresh
        if len(voxels):
            values = band_values(hull.floored(points, top, floor_m=self.floor_m), self.grid,
                                 self.band_voxels)
            self._edges = self._edges.followed(
                hull, BandEdges.of(crop, corner, in_crop, values, self.grid, self.band_voxels),
                self._linear)
        order, self._starts = point_groups(points, self.floor_m)
        self._points, self._top = points[order], top[order]
        self._sorted = linear          # (ascending: the band's voxels come in C order)
        self._place = np.empty_like(order)
        self._place[order] = np.arange(len(order))

    def holds(self, grid: VoxelGrid, keys: list, max_misses: int) -> bool:
        """Whether these values are of the views of ``keys``
        (:func:`~sfs_ros.core.carving.carve.view_key`, in any order) on ``grid``, for
        ``max_misses``."""
        return same_grid(grid, self.grid) and self.rank == int(max_misses) + 1 \
            and Counter(keys) == self._views

    def distance(self, hull: HullDistance, voxels: np.ndarray) -> np.ndarray:
        """(n,) float64 metres: ``hull(points, floor_m=...)`` at the centres of ``voxels``
        (n, 3) int64 indices, ``hull`` of the views this store holds (:meth:`holds`): the
        values kept where they are, the others evaluated."""
        points = self.grid.index_to_world(voxels)
        top, missing = self._kept_at(self._linear(voxels))
        if missing.any():
            fresh = np.full((int(missing.sum()), self.rank), self.floor_m)
            hull.add_largest(points[missing], fresh, floor_m=self.floor_m)
            top[missing] = fresh
        return hull.floored(points, top, floor_m=self.floor_m)

    def crossings(self, hull: HullDistance, edges: BandEdges) -> np.ndarray:
        """(m,) float64: ``edges.zeros(hull)``, ``hull`` of the views this store holds
        (:meth:`holds`): the zeros kept where they hold, the others found."""
        return self._edges.zeros(hull, edges, self._linear)

    def _band(self, occupancy: np.ndarray) -> tuple:
        """``(crop, corner, voxels)``: :func:`.marching.padded_crop` of ``occupancy`` and
        the band's voxels in it ((n, 3) int64 indices of the crop, in C order; none for
        an empty occupancy)."""
        if not occupancy.any():
            return None, np.zeros(3, np.int64), np.empty((0, 3), np.int64)
        crop, corner = padded_crop(occupancy, self.band_voxels)
        return crop, corner, band_voxel_indices(crop, self.band_voxels)

    def _linear(self, voxels: np.ndarray) -> np.ndarray:
        """(n,) int64 indices of ``voxels`` (n, 3) in the grid grown by the band's padding
        on every side (a band voxel may lie beyond the grid), in the same order."""
        pad = self.band_voxels + 1
        size = np.array(self.grid.shape, np.int64) + 2 * pad
        shifted = voxels + pad
        return (shifted[:, 0] * size[1] + shifted[:, 1]) * size[2] + shifted[:, 2]

    def _kept_at(self, linear: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(top (n, rank) float64, missing (n,) bool)``: the values kept at the voxels
        ``linear`` (:meth:`_linear`), and where none are (their rows undefined)."""
        top = np.empty((len(linear), self.rank))
        if not len(self._sorted):
            return top, np.ones(len(linear), bool)
        slot = np.minimum(np.searchsorted(self._sorted, linear), len(self._sorted) - 1)
        found = self._sorted[slot] == linear
        top[found] = self._top[self._place[slot[found]]]
        return top, ~found


class _KeptZeros:
    """The zeros of the hull's distance along band edges (:class:`.marching.BandEdges`) kept
    with their traces, by edge: ``keys`` (ascending: the lower end's padded linear index
    times 3 plus the axis), the ends' values, the zeros (``fractions``, as
    :meth:`.marching.BandEdges.zeros` gives them), the :class:`ZeroTrace` rows, and
    ``valid``: no view added since raised the distance at the trace's points."""

    def __init__(self, keys, f_lower, f_upper, fractions, trace: ZeroTrace, valid):
        self.keys, self.f_lower, self.f_upper = keys, f_lower, f_upper
        self.fractions, self.trace, self.valid = fractions, trace, valid

    @classmethod
    def none(cls) -> "_KeptZeros":
        empty = np.empty(0)
        return cls(np.empty(0, np.int64), empty, empty, empty,
                   ZeroTrace.empty(0, CROSSING_ITERATIONS),
                   np.empty(0, bool))

    def __len__(self) -> int:
        return len(self.keys)

    def raised_by(self, view: HullDistance) -> None:
        """One more view (a :class:`HullDistance` of it alone): the zeros it may move are
        no longer valid."""
        if len(self):
            self.valid &= ~view.raises(self.trace)

    def _found(self, linear, edges: BandEdges) -> tuple[np.ndarray, np.ndarray]:
        """``(keys (m,) int64 of the edges, rows (m,) of this store holding each edge's
        zero, -1 where none holds)``: kept, valid, and of the same end values."""
        axis = np.argmax(edges.upper - edges.lower, axis=1)
        keys = linear(edges.lower) * 3 + axis
        rows = np.full(len(keys), -1, np.int64)
        if len(self.keys):
            slot = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
            same = (self.keys[slot] == keys) & self.valid[slot] \
                & (self.f_lower[slot] == edges.f_lower) & (self.f_upper[slot] == edges.f_upper)
            rows[same] = slot[same]
        return keys, rows

    def zeros(self, hull: HullDistance, edges: BandEdges, linear) -> np.ndarray:
        """(m,) float64: ``edges.zeros(hull)``, read where held (:meth:`_found`)."""
        _, rows = self._found(linear, edges)
        out = np.empty(len(edges))
        held = rows >= 0
        out[held] = self.fractions[rows[held]]
        if not held.all():
            out[~held] = edges.zeros(hull, ~held)
        return out

    def followed(self, hull: HullDistance, edges: BandEdges, linear) -> "_KeptZeros":
        """The store of the edges ``edges`` (of the band followed now) for ``hull`` (every
        view so far): their zeros read where held, the others found with their traces."""
        keys, rows = self._found(linear, edges)
        held = rows >= 0
        n = len(edges)
        zeros = np.empty(n)
        trace = ZeroTrace.empty(n, CROSSING_ITERATIONS)
        zeros[held] = self.fractions[rows[held]]
        _set_rows(trace, held, self.trace[rows[held]])
        zeros[~held], found = edges.zeros(hull, ~held, traced=True)
        _set_rows(trace, ~held, found)
        order = np.argsort(keys)
        return _KeptZeros(keys[order], edges.f_lower[order], edges.f_upper[order],
                          zeros[order], trace[order], np.ones(len(edges), bool))


def _set_rows(trace: ZeroTrace, rows: np.ndarray, part: ZeroTrace) -> None:
    """Write ``part`` into the rows ``rows`` (a bool mask) of ``trace``."""
    trace.points[rows], trace.values[rows], trace.counts[rows] = \
        part.points, part.values, part.counts
