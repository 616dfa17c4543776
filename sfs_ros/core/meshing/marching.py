"""Surface of a voxel occupancy by marching cubes (scikit-image, Lewiner).

The occupancy is cropped to its occupied bounding box, padded with empty
voxels on every side (so the level set is closed even where the object
touches the grid box), optionally smoothed with a small Gaussian (to round
off the voxel staircase), and contoured at the level 0.5 (see ``LEVEL``): on
unsmoothed data the surface passes half-way between an occupied and an empty
voxel centre, i.e. on the voxel faces. Faces are returned counter-clockwise seen from
outside (positive signed volume).

:func:`hull_marching_cubes_mesh` contours the signed distance to the visual
hull instead (:class:`.hull_distance.HullDistance`, sampled on the voxel
centres near the carved surface) at level 0, with no voxel staircase to smooth
away; each vertex is placed where the distance itself is zero along its grid edge
(``BandDistance.crossings``), not at the chord between the edge's two samples, which
cuts inside the hull where two views' cones meet within the edge (its sharp edges).
Its marching cubes is :func:`.lewiner.march_band`, which visits only the cubes with a
corner in the band: scikit-image's mesh (Lewiner's tables), vertex for vertex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange
from scipy import ndimage
from skimage import measure

from ..carving.carve import same_grid
from ..carving.hull import column_runs, occupied_bounds
from ..geometry.grid import VoxelGrid
from .hull_distance import HullDistance
from .lewiner import band_rows, march_band

__all__ = ["BandDistance", "BandEdges", "FoundBand", "band_marching_cubes", "band_values",
           "band_voxel_indices", "crossing_edges", "crossing_ends", "hull_band_distance",
           "hull_band_floor_m", "hull_marching_cubes_mesh", "marching_cubes_mesh",
           "padded_crop", "voxel_centres"]

#: Iso-level between empty (0) and occupied (1) voxels: just below 0.5. At
#: exactly 0.5, Lewiner's ambiguity tests tie on 0/1 data (a cube face whose
#: diagonal corners are occupied has its bilinear saddle at exactly 0.5) and
#: neighbouring cubes break the tie differently, leaving non-manifold edges
#: and duplicate faces. Just below, diagonal neighbours are always joined and
#: the surface moves outward by only 1/1024 voxel.
LEVEL = 0.5 - 2.0 ** -10
#: Gaussian kernel radius, in standard deviations (scipy's default).
GAUSS_TRUNCATE = 4.0
#: Evaluations of the hull's distance per crossing edge (:func:`hull_band_distance`):
#: the distance is the largest of the views' values, piecewise linear along an edge with
#: kinks where two views' cones meet (the hull's sharp edges); the chord between the
#: edge's ends puts the vertex inside there, and a few steps of regula falsi on the
#: distance itself find the kink's side (most edges, decided by one view, are done after
#: the first: :data:`CROSSING_TOLERANCE`).
CROSSING_ITERATIONS = 4
#: A crossing is placed when the distance there is this near zero, voxels (far below
#: what a view's pixel tells: the crossings a single view decides, most of them, are
#: found by the first step).
CROSSING_TOLERANCE = 1e-3
#: A crossing moves its vertex no nearer an end of its edge than this, voxels: the
#: mesh's faces keep an area (linear interpolation may come nearer, but marching cubes
#: drops the faces it makes degenerate before the vertices move).
_CROSSING_MARGIN = 1e-3


def marching_cubes_mesh(occupancy, grid: VoxelGrid, *, smooth_sigma_vox: float = 0.5):
    """Closed, outward-oriented triangle mesh of an occupancy grid.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
        True = object; index ``[i, j, k]`` is the voxel centred at
        ``grid.origin + (i, j, k) * grid.voxel_size``.
    grid : VoxelGrid
        The grid the occupancy lives on; ``grid.shape`` must equal
        ``occupancy.shape``.
    smooth_sigma_vox : float, keyword-only
        Standard deviation of the Gaussian applied to the 0/1 occupancy before
        contouring, in voxels; 0 disables smoothing (the surface then lies on
        voxel faces, with 45-degree chamfers at the steps). Smoothing rounds
        corners and can drop features thinner than about ``2 * sigma`` voxels.

    Returns
    -------
    vertices : (n, 3) float64
        Metres, object frame.
    faces : (m, 3) int64
        Vertex indices, counter-clockwise seen from outside.

    Raises
    ------
    ValueError
        If the occupancy is not a 3-D array of the grid's shape, if it has no
        occupied voxel, if ``smooth_sigma_vox`` is negative or not finite, or
        if smoothing removes the whole object.
    """
    occ = _check_occupancy(occupancy, grid)
    sigma = float(smooth_sigma_vox)
    if not (math.isfinite(sigma) and sigma >= 0):
        raise ValueError(
            f"smooth_sigma_vox must be a finite number >= 0 voxels, got {smooth_sigma_vox}")

    lo, hi = _occupied_bounds(occ)
    # Empty border wide enough that the smoothed values on it are exactly 0.
    pad = 1 + (math.ceil(GAUSS_TRUNCATE * sigma) if sigma > 0 else 0)
    crop = occ[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    volume = np.pad(crop.astype(np.float32), pad, mode="constant", constant_values=0.0)
    if sigma > 0:
        ndimage.gaussian_filter(volume, sigma, output=volume, mode="constant", cval=0.0,
                                truncate=GAUSS_TRUNCATE)
        if float(volume.max()) <= LEVEL:
            raise ValueError(
                f"smoothing with sigma {sigma} voxels removes the whole object "
                f"(occupied box {(hi - lo).tolist()} voxels); use a smaller smooth_sigma_vox")

    return _contour(volume, LEVEL, lo - pad, grid)


@dataclass(frozen=True)
class BandDistance:
    """The signed distance to the hull at the voxels near a carved surface: what
    :func:`band_marching_cubes` needs besides the occupancy (:func:`hull_band_distance`).

    values : (n,) float32
        Distance in voxels, positive outside, clipped to ``+-(band_voxels + 1)``, at the
        band's voxels (:func:`band_voxel_indices`) in index order.
    band_voxels : int >= 1
        Width of the band, voxels on either side of the occupancy's boundary.
    crossings : (m,) float32 or None
        Where the hull surface crosses each grid edge the values change sign along
        (:func:`crossing_edges`, in their order), as the fraction of the edge from its
        lower end (the smaller index): the vertex of marching cubes on that edge. None:
        the linear interpolation of the values.
    found : :class:`FoundBand` or None
        What :func:`hull_band_distance` found of the occupancy, so that
        :func:`band_marching_cubes` of the same occupancy need not find it again; None
        (e.g. after crossing a process): found again, the same.
    """

    values: np.ndarray
    band_voxels: int = 1
    crossings: np.ndarray | None = None
    found: FoundBand | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class FoundBand:
    """The band of an occupancy as :func:`hull_band_distance` found it.

    crop, corner : :func:`padded_crop` of the occupancy.
    voxels : (n, 3) int32, :func:`band_voxel_indices` of ``crop``.
    values : the band's values the crossings were found from (the very array).
    ordinal, crossed : :func:`crossing_edges` of ``crop``, ``voxels`` and ``values``.
    """

    crop: np.ndarray
    corner: np.ndarray
    voxels: np.ndarray
    values: np.ndarray
    ordinal: np.ndarray
    crossed: int


def padded_crop(occ: np.ndarray, band: int) -> tuple[np.ndarray, np.ndarray]:
    """The occupancy's occupied box padded by ``band + 1`` empty voxels, and the grid index
    of its ``[0, 0, 0]``; ValueError if nothing is occupied."""
    lo, hi = _occupied_bounds(occ)
    # An empty border one voxel wider than the band: its outer layer stays
    # outside (the level set is closed even where the object touches the grid box).
    pad = band + 1
    return np.pad(occ[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]], pad), lo - pad


def band_voxel_indices(crop: np.ndarray, band: int) -> np.ndarray:
    """(n, 3) int64 indices, in C order, of the voxels of a 3-D bool ``crop`` within
    ``band`` steps (26-neighbour) of its boundary, on either side: where the distance is
    computed. The same voxels as scipy's ``binary_dilation(crop, cube, band) &
    ~binary_erosion(crop, cube, band, border_value=0)`` with the 3^3 cube ``cube``: those
    whose (2 band + 1)^3 cube, beyond the array empty, holds both an occupied and an
    empty voxel. Found from the occupied runs along z of each column
    (:func:`~sfs_ros.core.carving.hull.column_runs`), in compiled passes over the
    x-planes side by side: the band's intervals of z in each column (:func:`_band_pass`),
    then their voxels: no pass over the whole volume per step, and no (n, 3) search of a
    dense mask."""
    crop = np.ascontiguousarray(crop, dtype=bool)
    column_start, run_lo, run_hi = column_runs(crop)
    nx, ny, nz = crop.shape
    # Room for each plane's intervals: a column's are at most twice the runs of the
    # (2 band + 1)^2 columns around it (each union of widened runs, less the erosion,
    # whose intervals are at most as many).
    runs = np.diff(column_start).reshape(nx, ny).sum(axis=1)
    near = np.convolve(np.concatenate([np.zeros(band, np.int64), runs,
                                       np.zeros(band, np.int64)]),
                       np.ones(2 * band + 1, np.int64), mode="valid")
    room = np.zeros(nx + 1, np.int64)
    np.cumsum(2 * (2 * band + 1) * near + 1, out=room[1:])
    intervals = np.empty((room[-1], 3), np.int32)     # j, first z, last z
    n_intervals = np.zeros(nx, np.int64)
    counts = np.zeros(nx + 1, np.int64)
    _band_pass(column_start, run_lo, run_hi, ny, nz, band, room, intervals, n_intervals,
               counts)
    np.cumsum(counts, out=counts)    # counts[i + 1] - counts[i]: the voxels of plane i
    out = np.empty((counts[-1], 3), np.int64)
    _interval_voxels(room, intervals, n_intervals, counts, out)
    return out


@njit(parallel=True, cache=True, nogil=True)
def _interval_voxels(room, intervals, n_intervals, counts, out):
    """The voxels of each plane's intervals (:func:`_band_pass`) into ``out`` from row
    ``counts[i]``, in C order."""
    for i in prange(n_intervals.shape[0]):
        row = counts[i]
        for q in range(room[i], room[i] + n_intervals[i]):
            for k in range(intervals[q, 1], intervals[q, 2] + 1):
                out[row, 0], out[row, 1], out[row, 2] = i, intervals[q, 0], k
                row += 1


def voxel_centres(grid: VoxelGrid, voxels: np.ndarray, corner: np.ndarray) -> np.ndarray:
    """(n, 3) float64 metres: ``grid.index_to_world(voxels + corner)`` (the same numbers)
    of ``voxels`` (n, 3) indices (int, or float64 for points between them) of a crop whose
    ``[0, 0, 0]`` is the grid's voxel ``corner`` (3,), in one compiled pass over them side
    by side."""
    out = np.empty((len(voxels), 3))
    _centres(np.ascontiguousarray(voxels), np.asarray(corner, np.int64), grid.origin,
             float(grid.voxel_size), out)
    return out


@njit(parallel=True, cache=True, nogil=True)
def _centres(voxels, corner, origin, size, out):
    """``out[p] = origin + (voxels[p] + corner) * size``, as numpy computes it."""
    for p in prange(voxels.shape[0]):
        for axis in range(3):
            out[p, axis] = origin[axis] + np.float64(voxels[p, axis] + corner[axis]) * size


def hull_band_floor_m(grid: VoxelGrid, band_voxels: int) -> float:
    """The floor (metres, < 0) of :func:`hull_band_distance`'s distances: below
    ``-(band_voxels + 1)`` voxels a value is clipped anyway, and the floor spares the views
    that see a group of points deep inside their silhouette."""
    return -(band_voxels + 1) * grid.voxel_size


def _check_band(band_voxels) -> int:
    if isinstance(band_voxels, bool) or not isinstance(band_voxels, (int, np.integer)) \
            or band_voxels < 1:
        raise ValueError(f"band_voxels must be an integer >= 1, got {band_voxels!r}")
    return int(band_voxels)


def hull_band_distance(occupancy, grid: VoxelGrid, hull: HullDistance, *,
                       band_voxels: int = 1) -> BandDistance:
    """The signed distance to the hull near the carved surface, for
    :func:`band_marching_cubes`.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
        The hull carved on ``grid`` from the views behind ``hull``; it says where
        the surface is to a voxel (the distance is only computed near it).
    grid : VoxelGrid
    hull : HullDistance
        Signed distance to the hull of the same views (and carving box). Its ``kept``
        values (:class:`.kept_band.KeptBand`, of the same grid and band) are read where
        they are kept: the same distances.
    band_voxels : int, keyword-only
        Voxels within this many steps (26-neighbour) of the occupancy's
        boundary, on either side, get the distance computed. With 1, every
        corner of every grid cube that the carved surface crosses is computed;
        the hull surface lies within a fraction of a voxel of the carved one
        (both come from the same pixel test), so that suffices (on a sphere
        seen from 60 views, bands of 1, 2 and 3 voxels gave the same errors to
        0.1 micrometre).

    Returns the band's values and, on each grid edge they change sign along, where
    the distance itself is zero (:data:`CROSSING_ITERATIONS`).

    Raises
    ------
    ValueError
        If the occupancy is not a 3-D array of the grid's shape, if it has no
        occupied voxel, or if ``band_voxels`` is below 1.
    """
    occ = _check_occupancy(occupancy, grid)
    band = _check_band(band_voxels)
    crop, corner = padded_crop(occ, band)
    voxels = band_voxel_indices(crop, band)
    kept = hull.kept
    if kept is None or kept.band_voxels != band or not same_grid(kept.grid, grid):
        kept = None
    distance = band_values(
        kept.distance(hull, voxels + corner) if kept is not None else
        hull(voxel_centres(grid, voxels, corner), floor_m=hull_band_floor_m(grid, band)),
        grid, band)
    ordinal = np.empty((len(voxels), 6), np.int32)
    edges = BandEdges.of(crop, corner, voxels, distance, grid, band, ordinal=ordinal)
    fractions = kept.crossings(hull, edges) if kept is not None else edges.zeros(hull)
    return BandDistance(values=distance, band_voxels=band,
                        crossings=fractions.astype(np.float32),
                        found=FoundBand(crop, corner, voxels.astype(np.int32), distance,
                                        ordinal, len(edges)))


def band_values(distance_m: np.ndarray, grid: VoxelGrid, band_voxels: int) -> np.ndarray:
    """:attr:`BandDistance.values` of the hull's distance (n,) metres at the band's voxels:
    in voxels, clipped to ``+-(band_voxels + 1)``, float32, none exactly 0."""
    pad = band_voxels + 1
    distance = np.clip(distance_m / grid.voxel_size, -pad, pad).astype(np.float32)
    # A sample exactly on the level makes Lewiner's ambiguity tests tie (see
    # LEVEL); counting it as just outside (by 1e-6 voxel) breaks the tie.
    distance[distance == 0.0] = np.float32(1e-6)
    return distance


@dataclass(frozen=True)
class BandEdges:
    """The grid edges the level of a band's values crosses (:func:`crossing_edges`, in
    its order), where :func:`hull_band_distance` finds the hull's zero: their ``lower``
    and ``upper`` ends, (m, 3) int64 grid indices (one step apart along an axis), and the
    distance there as :meth:`HullDistance.segment_zeros` takes it, ``f_lower`` and
    ``f_upper`` (m,) metres (the band's values, or its ``+-(band + 1)`` voxels off it);
    on ``grid``, for a band of ``band_voxels``."""

    lower: np.ndarray
    upper: np.ndarray
    f_lower: np.ndarray
    f_upper: np.ndarray
    grid: VoxelGrid
    band_voxels: int

    @classmethod
    def of(cls, crop: np.ndarray, corner: np.ndarray, voxels: np.ndarray,
           values: np.ndarray, grid: VoxelGrid, band_voxels: int, *,
           ordinal: np.ndarray | None = None) -> "BandEdges":
        """The edges of the band's ``values`` (:func:`band_values`) at ``voxels`` (n, 3)
        of ``crop`` (:func:`padded_crop` of the occupancy, whose ``[0, 0, 0]`` is the grid
        index ``corner``); ``ordinal`` filled as :func:`crossing_ends` fills it."""
        lower, upper, f_lower, f_upper = crossing_ends(crop, voxels, values, band_voxels + 1,
                                                       ordinal=ordinal)
        return cls(lower + corner, upper + corner, grid.voxel_size * f_lower,
                   grid.voxel_size * f_upper, grid, band_voxels)

    def __len__(self) -> int:
        return len(self.lower)

    def zeros(self, hull: HullDistance, rows=slice(None), *, traced: bool = False):
        """(m,) float64: where ``hull``'s distance is zero along the edges ``rows`` (all by
        default), as the fraction from the lower end (:data:`CROSSING_ITERATIONS` steps);
        with ``traced``, ``(that, its ZeroTrace)``
        (:meth:`HullDistance.traced_segment_zeros`)."""
        find = hull.traced_segment_zeros if traced else hull.segment_zeros
        return find(voxel_centres(self.grid, self.lower[rows], _NO_CORNER),
                    voxel_centres(self.grid, self.upper[rows], _NO_CORNER),
                    self.f_lower[rows], self.f_upper[rows], iterations=CROSSING_ITERATIONS,
                    tolerance_m=CROSSING_TOLERANCE * self.grid.voxel_size,
                    floor_m=hull_band_floor_m(self.grid, self.band_voxels))


_NO_CORNER = np.zeros(3, np.int64)


def band_marching_cubes(occupancy, grid: VoxelGrid, band: BandDistance):
    """Closed, outward-oriented triangle mesh of the zero level of the band's signed
    distance (the visual hull at sub-voxel precision).

    Off the band the volume keeps the occupancy's sign (``+-(band_voxels + 1)``
    voxels), so the level set is closed.

    Returns
    -------
    vertices : (n, 3) float64
        Metres, object frame, on the zero level of the distance: on the band's
        crossings, where it has them; else linearly interpolated between voxel centres.
    faces : (m, 3) int64
        Vertex indices, counter-clockwise seen from outside.

    Raises
    ------
    ValueError
        If the occupancy is not of the grid's shape or is empty, or the band's
        values are not one per band voxel.
    """
    occ = _check_occupancy(occupancy, grid)
    width = _check_band(band.band_voxels)
    pad = width + 1
    found = band.found
    if found is not None and len(found.voxels) == len(band.values):
        crop, corner, voxels = found.crop, found.corner, found.voxels
    else:
        crop, corner = padded_crop(occ, width)
        voxels = band_voxel_indices(crop, width)
    values = np.asarray(band.values)
    if values.dtype != np.float32 or values.shape != (len(voxels),):
        raise ValueError(f"band distance has {values.dtype} {values.shape}, expected float32 "
                         f"({len(voxels)},): one value per voxel of the band")
    ordinal = crossings = None
    if band.crossings is not None:
        if found is not None and found.values is band.values and found.voxels is voxels:
            ordinal, m = found.ordinal, found.crossed
        else:
            ordinal, m = crossing_edges(crop, voxels, values)
        crossings = np.asarray(band.crossings)
        if crossings.dtype != np.float32 or crossings.shape != (m,):
            raise ValueError(f"band crossings are {crossings.dtype} {crossings.shape}, expected "
                             f"float32 ({m},): one per grid edge the level crosses")
    # The level crosses only cubes with a corner in the band (off it the values keep the
    # occupancy's sign, and a cube whose corners differ there has them on its boundary):
    # only those are visited. The volume is the signed distance in voxels (positive
    # outside) negated: as for the occupancy, larger means more inside.
    verts, faces = march_band(crop, pad, voxels, -values, ordinal, crossings,
                              margin=_CROSSING_MARGIN)
    return _oriented(verts, faces, corner, grid)


def crossing_edges(crop: np.ndarray, voxels: np.ndarray,
                   values: np.ndarray) -> tuple[np.ndarray, int]:
    """The grid edges at a band voxel whose ends lie on either side of the hull's surface:
    where marching cubes puts a vertex. The volume is the distance ``values`` (n,) float32
    (voxels, positive outside) at the band's ``voxels`` (n, 3) of the 3-D bool ``crop``
    (C order) and, off the band, the occupancy's sign: an end is inside where the distance
    is below 0, or off the band where occupied. An edge is at the band voxel ``voxels[i]``
    as its lower end, or as its upper end when its lower end is off the band (where the
    distance was not computed, and keeps the occupancy's sign: a band voxel beside it may
    be on the other side of the hull's surface, which lies up to a voxel from the carved
    one).

    Returns ``ordinal`` (n, 6) int32: for band voxel ``i``, the edge's place in the order
    (band voxel by band voxel) from it ahead along x, y, z (columns 0-2) and behind it
    (columns 3-5), -1 where the level does not cross or the edge is another voxel's;
    and ``m``, how many edges the level crosses. Found from the band's rows
    (:func:`.lewiner.band_rows`), the crop's planes side by side (a count, then the
    numbers): no pass over the crop.
    """
    band = _Band.of(crop, voxels, values)
    counts = band.plane_crossings()
    ordinal = np.empty((len(voxels), 6), np.int32)
    band.fill(counts, 1.0, ordinal, _NO_ENDS, _NO_END_VALUES)
    return ordinal, int(counts[-1])


def crossing_ends(crop: np.ndarray, voxels: np.ndarray, values: np.ndarray, pad: float, *,
                  ordinal: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The ends of the grid edges the level crosses (:func:`crossing_edges`, in its
    order) and the distance there: ``lower``, ``upper`` (m, 3) int64 indices of ``crop``
    (the upper end one step from the lower along the edge's axis) and the distance at each,
    (m,) float32 voxels: the band's value, else ``-pad`` where ``crop`` is occupied and
    ``pad`` where it is not (the occupancy's sign, as off the band in
    :func:`band_marching_cubes`). Read from the band's values and the occupancy: no volume
    of the crop's size. ``ordinal`` ((n, 6) int32, optional): filled with
    :func:`crossing_edges`' ``ordinal`` in the same pass."""
    band = _Band.of(crop, voxels, values)
    counts = band.plane_crossings()
    m = int(counts[-1])
    ends, end_values = np.empty((m, 4), np.int64), np.empty((m, 2), np.float32)
    if m or ordinal is not None:
        band.fill(counts, pad, _NO_ORDINAL if ordinal is None else ordinal, ends, end_values)
    lower = np.ascontiguousarray(ends[:, :3])
    upper = lower.copy()
    upper[np.arange(m), ends[:, 3]] += 1
    return lower, upper, end_values[:, 0].copy(), end_values[:, 1].copy()


_NO_ORDINAL = np.empty((0, 6), np.int32)
_NO_ENDS = np.empty((0, 4), np.int64)
_NO_END_VALUES = np.empty((0, 2), np.float32)


@dataclass(frozen=True)
class _Band:
    """A band as :func:`_crossings_pass` reads it: the crop, the band's rows
    (:func:`.lewiner.band_rows`), their voxels' k and values, and which edges of each
    voxel the level crosses (filled by :meth:`plane_crossings`)."""

    crop: np.ndarray
    rows: np.ndarray
    band_k: np.ndarray
    values: np.ndarray
    crossed: np.ndarray

    @classmethod
    def of(cls, crop, voxels, values) -> _Band:
        crop = np.ascontiguousarray(crop, dtype=bool)
        return cls(crop, band_rows(voxels, crop.shape[0], crop.shape[1]),
                   np.ascontiguousarray(voxels[:, 2], dtype=np.int64),
                   np.ascontiguousarray(values, dtype=np.float32),
                   np.empty(len(voxels), np.uint8))

    def plane_crossings(self) -> np.ndarray:
        counts = np.zeros(self.crop.shape[0] + 1, np.int64)
        _crossings_pass(self.crop, self.rows, self.band_k, self.values, np.float32(1.0),
                        False, counts, self.crossed, _NO_ORDINAL, _NO_ENDS, _NO_END_VALUES)
        return np.cumsum(counts, out=counts)

    def fill(self, counts, pad, ordinal, ends, end_values) -> None:
        """After :meth:`plane_crossings`."""
        _crossings_pass(self.crop, self.rows, self.band_k, self.values, np.float32(pad), True,
                        counts, self.crossed, ordinal, ends, end_values)


def hull_marching_cubes_mesh(occupancy, grid: VoxelGrid, hull: HullDistance, *,
                             band_voxels: int = 1):
    """:func:`band_marching_cubes` of :func:`hull_band_distance`: the closed, outward
    mesh of the visual hull at sub-voxel precision, ``(vertices (n, 3) float64 metres,
    faces (m, 3) int64)``."""
    return band_marching_cubes(occupancy, grid, hull_band_distance(
        occupancy, grid, hull, band_voxels=band_voxels))


def _check_occupancy(occupancy, grid: VoxelGrid) -> np.ndarray:
    """(nx, ny, nz) bool occupancy of the grid's shape; ValueError otherwise."""
    occ = np.asarray(occupancy)
    if occ.ndim != 3:
        raise ValueError(f"occupancy must be a 3-D (nx, ny, nz) array, got shape {occ.shape}")
    if tuple(occ.shape) != tuple(grid.shape):
        raise ValueError(f"occupancy shape {occ.shape} does not match the grid shape {grid.shape}")
    return occ.astype(bool, copy=False)


def _occupied_bounds(occ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`.hull.occupied_bounds` of an occupancy to mesh; ValueError if it is empty."""
    box = occupied_bounds(occ)
    if box is None:
        raise ValueError("occupancy is empty: no voxel is occupied, there is no surface to mesh")
    return box


def _contour(volume: np.ndarray, level: float, corner: np.ndarray, grid: VoxelGrid):
    """Mesh of ``volume`` (larger = inside) at ``level`` by scikit-image's marching cubes;
    its ``[0, 0, 0]`` is voxel ``corner``."""
    # Vertices come back as float32 voxel indices of the volume; scale in float64.
    verts, faces, _, _ = measure.marching_cubes(volume, level, allow_degenerate=False)
    return _oriented(verts.astype(np.float64), faces, corner, grid)


def _oriented(verts: np.ndarray, faces: np.ndarray, corner: np.ndarray, grid: VoxelGrid):
    """``(vertices (n, 3) float64 metres, faces (m, 3) int64)`` of a mesh of voxel indices
    ``verts`` (n, 3) float64 of a volume whose ``[0, 0, 0]`` is voxel ``corner``, its faces
    turned counter-clockwise seen from outside."""
    vertices = voxel_centres(grid, verts, corner)
    faces = faces.astype(np.int64, copy=False)
    if _signed_volume(vertices, faces) < 0:
        faces = faces[:, ::-1].copy()
    return vertices, faces


@njit(cache=True, nogil=True)
def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume (m^3) of a closed mesh by the divergence theorem: the sum over faces
    of p0 . (p1 x p2) / 6 (a face at a time: no (m, 3, 3) copy of the corners)."""
    total = 0.0
    for f in range(faces.shape[0]):
        a, b, c = vertices[faces[f, 0]], vertices[faces[f, 1]], vertices[faces[f, 2]]
        total += (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])
                  + a[2] * (b[0] * c[1] - b[1] * c[0]))
    return total / 6.0


@njit(parallel=True, cache=True, nogil=True)
def _band_pass(column_start, run_lo, run_hi, ny, nz, band, room, intervals, n_intervals,
               counts):
    """The band's voxels (:func:`band_voxel_indices`) of each x-plane i as intervals of z,
    ``(j, first z, last z)`` in C order, into ``intervals`` from row ``room[i]`` (``room[i +
    1] - room[i]`` of them at most), how many into ``n_intervals[i]``, and their voxels
    into ``counts[1 + i]``.

    Along a column, as intervals of z: the dilation holds the runs of the (2 band + 1)^2
    columns around it each widened by ``band`` (their union), the erosion the runs each
    narrowed by ``band`` (their intersection; empty when a column around lies beyond the
    array); the band is the one less the other."""
    nx = (column_start.shape[0] - 1) // ny
    most_runs = 0
    for c in range(column_start.shape[0] - 1):
        most_runs = max(most_runs, column_start[c + 1] - column_start[c])
    scratch = (2 * band + 1) ** 2 * most_runs + 1
    for i in prange(nx):
        grown = np.empty((scratch, 2), np.int64)     # widened runs, by their start
        shrunk = np.empty((scratch, 2), np.int64)    # the intersection so far
        other = np.empty((scratch, 2), np.int64)
        row = 0
        q = room[i]
        for j in range(ny):
            n_grown = 0
            n_shrunk = 0
            whole = i >= band and i + band < nx and j >= band and j + band < ny
            first = True
            for ii in range(max(0, i - band), min(nx, i + band + 1)):
                for jj in range(max(0, j - band), min(ny, j + band + 1)):
                    c = ii * ny + jj
                    for r in range(column_start[c], column_start[c + 1]):
                        a, b = max(0, run_lo[r] - band), min(nz - 1, run_hi[r] + band)
                        m = n_grown
                        while m > 0 and grown[m - 1, 0] > a:
                            grown[m, 0], grown[m, 1] = grown[m - 1, 0], grown[m - 1, 1]
                            m -= 1
                        grown[m, 0], grown[m, 1] = a, b
                        n_grown += 1
                    if whole and (first or n_shrunk > 0):
                        n_shrunk = _narrowed_meet(run_lo, run_hi, column_start[c],
                                                  column_start[c + 1], band, shrunk,
                                                  n_shrunk, first, other)
                        shrunk, other = other, shrunk
                        first = False
            if not whole:
                n_shrunk = 0
            e = 0
            g = 0
            while g < n_grown:      # each union of overlapping widened runs, less the erosion
                a, b = grown[g, 0], grown[g, 1]
                g += 1
                while g < n_grown and grown[g, 0] <= b + 1:
                    b = max(b, grown[g, 1])
                    g += 1
                z = a
                while z <= b:
                    while e < n_shrunk and shrunk[e, 1] < z:
                        e += 1
                    stop = b if e == n_shrunk or shrunk[e, 0] > b else shrunk[e, 0] - 1
                    if stop >= z:
                        intervals[q, 0], intervals[q, 1], intervals[q, 2] = j, z, stop
                        q += 1
                        row += stop - z + 1
                    z = stop + 1 if e == n_shrunk or shrunk[e, 0] > b \
                        else shrunk[e, 1] + 1
        n_intervals[i] = q - room[i]
        counts[1 + i] = row


@njit(cache=True, nogil=True)
def _narrowed_meet(run_lo, run_hi, r0, r1, band, so_far, n, first, out):
    """Into ``out``: the runs ``r0:r1`` each narrowed by ``band`` (z intervals, inclusive),
    met with the ``n`` disjoint sorted intervals ``so_far`` (or alone when ``first``);
    returns how many."""
    m = 0
    s = 0
    for r in range(r0, r1):
        a, b = run_lo[r] + band, run_hi[r] - band
        if a > b:
            continue
        if first:
            out[m, 0], out[m, 1] = a, b
            m += 1
            continue
        while s < n and so_far[s, 1] < a:
            s += 1
        t = s
        while t < n and so_far[t, 0] <= b:
            lo, hi = max(a, so_far[t, 0]), min(b, so_far[t, 1])
            if lo <= hi:
                out[m, 0], out[m, 1] = lo, hi
                m += 1
            t += 1
    return m


@njit(parallel=True, cache=True, nogil=True)
def _crossings_pass(crop, rows, band_k, values, pad, fill, counts, crossed, ordinal, ends,
                    end_values):
    """The grid edges the level crosses at the band's voxels (:func:`crossing_edges`), in
    parallel over the crop's i-planes: without ``fill``, ``counts[1 + i]`` = the crossings
    of plane i, and ``crossed[n]`` (n,) uint8 the edges band voxel n has (bit s: the edge
    ahead along axis s, 3 + s behind). With ``fill`` (``counts`` their running sum from 0,
    the first crossing of each plane; ``crossed`` as the count left it, so that only those
    edges are looked at again): their numbers into ``ordinal`` (n, 6) (if not empty), and
    (if ``ends`` is not empty) each crossing's lower end and axis into ``ends`` (m, 4)
    int64 ``[i, j, k, axis]`` and the distance at its lower and upper end into
    ``end_values`` (m, 2) float32 (the band's value, else ``-pad`` where occupied, ``pad``
    where not)."""
    n0, n1, n2 = crop.shape
    with_ordinal = ordinal.shape[0] > 0
    with_ends = ends.shape[0] > 0
    for i in prange(n0):
        m = counts[i] if fill else 0
        ptr = np.empty(4, np.int64)      # rows (i + 1, j), (i, j + 1), (i - 1, j), (i, j - 1)
        end = np.empty(4, np.int64)
        for j in range(n1):
            first, last = rows[i * n1 + j], rows[i * n1 + j + 1]
            for s in range(4):
                ii, jj = i + (s == 0) - (s == 2), j + (s == 1) - (s == 3)
                ptr[s] = end[s] = 0
                if 0 <= ii < n0 and 0 <= jj < n1:
                    ptr[s], end[s] = rows[ii * n1 + jj], rows[ii * n1 + jj + 1]
            for n in range(first, last):
                if fill:
                    if with_ordinal:
                        for s in range(6):
                            ordinal[n, s] = -1
                    if crossed[n] == 0:
                        continue
                else:
                    crossed[n] = 0
                k = band_k[n]
                inside = values[n] < 0.0
                for s in range(6):      # ahead along i, j, k, then behind
                    if fill and not (crossed[n] >> s) & 1:
                        continue
                    step = 1 if s < 3 else -1
                    ii = i + step * (s % 3 == 0)
                    jj = j + step * (s % 3 == 1)
                    kk = k + step * (s % 3 == 2)
                    if not (0 <= ii < n0 and 0 <= jj < n1 and 0 <= kk < n2):
                        continue
                    if s % 3 == 2:      # along the row itself: its neighbour voxel
                        at = n + step
                        banded = first <= at < last and band_k[at] == kk
                    else:               # (the rows' pointers only move ahead: k grows)
                        r = (0, 1, 0, 2, 3, 0)[s]
                        while ptr[r] < end[r] and band_k[ptr[r]] < kk:
                            ptr[r] += 1
                        at = ptr[r]
                        banded = at < end[r] and band_k[at] == kk
                    if s >= 3 and banded:
                        continue        # the edge is the band voxel behind's
                    other = (values[at] < 0.0) if banded else crop[ii, jj, kk]
                    if other == inside:
                        continue
                    if not fill:
                        crossed[n] |= np.uint8(1 << s)
                    if fill and with_ordinal:
                        ordinal[n, s] = m
                    if fill and with_ends:
                        value = values[at] if banded else (-pad if other else pad)
                        ahead = s < 3
                        ends[m, 0] = i if ahead else ii
                        ends[m, 1] = j if ahead else jj
                        ends[m, 2] = k if ahead else kk
                        ends[m, 3] = s % 3
                        end_values[m, 0] = values[n] if ahead else value
                        end_values[m, 1] = value if ahead else values[n]
                    m += 1
        if not fill:
            counts[1 + i] = m
