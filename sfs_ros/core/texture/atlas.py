"""The texture atlas: charts of faces laid out in one image.

A *chart* is a connected patch of faces that take their colour from the same view (the
labelling of :mod:`.selection`), laid out as that view sees it: each corner at its
projection in the view's image, in pixels, times ``texels_per_pixel``. The view sees
every face of the patch unhidden and facing it, so the projection is one to one and the
texture is the image itself, resampled only when ``texels_per_pixel`` is not 1 (texels
per metre on the object as many as the view's pixels per metre there). Faces no view
sees (the underside on the plate) are grouped by the axis (+-X, +-Y, +-Z) their normal
is nearest, and each connected patch of one group is projected onto the plane across
its mean normal when every face turns within 60 degrees of it, at half the seen faces' median
texels per metre (its colours are interpolated, smooth); otherwise (a curved patch), or
where its faces would take fewer texels so than the plane with its padding (a patch of
a few faces: the many a rough refined mesh breaks its underside into), its faces take
*cells*. A cell is one texel, the face's colour at its centroid, and the
face's three corners lie at its centre, so that a look-up anywhere in the face reads
that texel alone (bilinear or nearest, at any level of detail: the texture coordinates
do not vary across the face): the cells of all such faces are packed side by side as
one rectangle, with no padding between them. Seen faces that would still overlap another in the atlas (a
patch seen partly hidden) are made charts of their own (after :data:`_SPLIT_TRIES`
tries, cells), the faces of a curved unseen patch that would overlap take cells, and
the atlas is laid out again, from the scale the last layout reached (at an unchanged
scale the charts left whole claim the texels they claimed: no new overlap).

Charts are packed as rectangles on shelves (tallest first), ``2 * padding`` texels
apart, into an atlas about as wide as high; when that exceeds ``max_size`` texels a
side, the charts are scaled down to fit (fewer texels per pixel, down to
:data:`MIN_SCALE` of the asked density), and when the charts' padding alone does not
fit (a mesh of many faces in many small charts), the charts of fewest faces take cells,
more at each try, until the atlas fits. Texel ``(r, c)``'s centre is the point
``(c, r)`` of the atlas's coordinates (the renderer's pixel-centre convention, whose
edge rule gives each texel centre to one face at most: :mod:`sfs_ros.core.render`), and
a corner at ``(x, y)`` has the texture coordinates ``((x + 0.5) / W, 1 - (y + 0.5) / H)``
(OBJ's and trimesh's convention: v up from the image's bottom row).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import sparse
from scipy.sparse import csgraph

from ..geometry.camera import Camera
from ..render import covered_point, edge_tuple, pixel_box, triangle_edges

__all__ = ["MIN_SCALE", "Atlas", "build_atlas", "cell_corners", "chart_of_faces"]

#: The charts are scaled down to at most this share of the asked texels per pixel before
#: small charts are given cells instead.
MIN_SCALE = 0.25
#: Times the charts may be scaled down to fit ``max_size``.
_FIT_TRIES = 6
#: Times overlapping faces are split off into charts of their own before they take cells.
_SPLIT_TRIES = 4
#: A patch no view sees is projected onto a plane when its faces' normals are all within
#: acos of this of their mean.
_FLAT_COS = 0.5


@dataclass(frozen=True)
class Atlas:
    """Where each face lies in the texture.

    Attributes
    ----------
    shape : (H, W) texels
    corners : (m, 3, 2) float64
        Atlas coordinates ``(x, y)`` of each face's corners, texels (texel ``(r, c)``'s
        centre is ``(c, r)``).
    chart : (m,) int64
        The chart of each face.
    face_index : (H, W) int64
        The face each texel centre lies in, -1 for none.
    barycentric : (H, W, 3) float64
        The texel centre's barycentric coordinates in that face (zero where none).
    texels_per_pixel : float
        Scale of the charts against their views' pixels (below the asked one when
        scaled down to fit).
    """

    shape: tuple
    corners: np.ndarray
    chart: np.ndarray
    face_index: np.ndarray
    barycentric: np.ndarray
    texels_per_pixel: float

    @property
    def uv(self) -> np.ndarray:
        """(m, 3, 2) float64 texture coordinates of each face's corners, in [0, 1]."""
        height, width = self.shape
        return np.stack([(self.corners[..., 0] + 0.5) / width,
                         1.0 - (self.corners[..., 1] + 0.5) / height], axis=-1)


def chart_of_faces(labels: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """(m,) int64 chart of each face: the connected patches (across edges, ``neighbours``
    (m, 3)) of faces with one label (m,) (-1, unseen, being a label too)."""
    m = len(labels)
    f = np.repeat(np.arange(m), 3)
    g = neighbours.ravel()
    keep = (g >= 0) & (labels[f] == labels[np.maximum(g, 0)])
    graph = sparse.csr_matrix((np.ones(int(keep.sum())), (f[keep], g[keep])), shape=(m, m))
    return csgraph.connected_components(graph, directed=False)[1].astype(np.int64)


def _nearest_axis(normal: np.ndarray) -> np.ndarray:
    """(m,) int64 the axis +X, +Y, +Z, -X, -Y, -Z (0..5) nearest each face's ``normal``
    (m, 3)."""
    return np.argmax(np.concatenate([normal, -normal], axis=1), axis=1).astype(np.int64)


def _plane_axes(corners_3d: np.ndarray, normal: np.ndarray,
                patch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates (k, 3, 2) of faces with corners ``corners_3d`` (k, 3, 3) metres and
    normals ``normal`` (k, 3) (twice their area long) on the plane across their patch's
    mean normal (``patch`` (k,) their patches), metres; and (k,) bool where the patch is
    flat enough (:data:`_FLAT_COS`) for it."""
    _, local = np.unique(patch, return_inverse=True)
    mean = np.zeros((local.max() + 1, 3))
    np.add.at(mean, local, normal)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    axis_u = np.cross(mean, np.where(np.abs(mean[:, 2:]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0, 0]]))
    axis_u /= np.linalg.norm(axis_u, axis=1, keepdims=True)
    axis_v = np.cross(mean, axis_u)
    cos = np.einsum("kd,kd->k", normal, mean[local]) / np.maximum(
        np.linalg.norm(normal, axis=1), 1e-300)
    flat = np.ones(len(mean), bool)
    np.logical_and.at(flat, local, cos > _FLAT_COS)
    plane = np.stack([np.einsum("kcd,kd->kc", corners_3d, axis_u[local]),
                      np.einsum("kcd,kd->kc", corners_3d, axis_v[local])], axis=-1)
    return plane, flat[local]


@dataclass(frozen=True)
class _UnitCharts:
    """Each face's corners in its chart before packing and scaling, computed once for all
    the layouts tried (scaling a chart scales its bounds exactly: a product rounds
    monotonically).

    Attributes
    ----------
    corners : (m, 3, 2) float64
        A seen face's corners in its view's pixels; an unseen face's on its patch's
        plane (:func:`_plane_axes`), metres; zero for an unseen face of a curved patch.
    curved : (m,) bool
        The unseen faces whose patch is not flat: they take cells.
    area : (m,) float64
        Each face's area, square metres.
    plane_density : float
        Texels per metre of the unseen faces' planes at one texel per pixel: half the
        median over the seen faces (:func:`_plane_density`); a layout's scale times it.
    """

    corners: np.ndarray
    curved: np.ndarray
    area: np.ndarray
    plane_density: float

    @classmethod
    def of(cls, tri: np.ndarray, normal: np.ndarray, labels: np.ndarray, patch: np.ndarray,
           cameras: list[Camera]) -> _UnitCharts:
        """The unit charts of faces with corners ``tri`` (m, 3, 3) metres and normals
        ``normal`` (m, 3) (twice their area long) labelled ``labels`` (m,) (-1: unseen) in
        ``patch`` (m,) (the unseen faces' patches flattened each onto its plane)."""
        corners = np.zeros((len(tri), 3, 2))
        for label, camera in enumerate(cameras):
            mine = np.flatnonzero(labels == label)
            if mine.size:
                corners[mine] = camera.project(tri[mine].reshape(-1, 3)).reshape(-1, 3, 2)
        area = 0.5 * np.linalg.norm(normal, axis=1)
        unseen = np.flatnonzero(labels < 0)
        curved = np.zeros(len(tri), bool)
        if unseen.size:
            plane, flat = _plane_axes(tri[unseen], normal[unseen], patch[unseen])
            corners[unseen] = plane
            curved[unseen] = ~flat
        return cls(corners=corners, curved=curved, area=area,
                   plane_density=_plane_density(corners, area, np.flatnonzero(labels >= 0)))


def _plane_density(corners: np.ndarray, area: np.ndarray, seen: np.ndarray) -> float:
    """Texels per metre of the unseen faces' planes at one texel per pixel: half the
    median over the ``seen`` (k,) faces (``corners`` (m, 3, 2) in their views' pixels,
    ``area`` (m,) square metres) of their texels per metre; 0 without seen faces."""
    if not len(seen):
        return 0.0
    texels_per_m = np.empty(len(seen))
    _texels_per_metre(corners, area, seen, texels_per_m)
    return 0.5 * float(np.median(texels_per_m))


@njit(cache=True, nogil=True)
def _texels_per_metre(corners, area, seen, out):
    """:func:`_plane_density`'s loop: the square root of each ``seen`` (k,) face's area in
    pixels (its ``corners`` (m, 3, 2)) over its ``area`` (m,) into ``out``."""
    for i in range(seen.shape[0]):
        f = seen[i]
        x0, y0 = corners[f, 0, 0], corners[f, 0, 1]
        d1x, d1y = corners[f, 1, 0] - x0, corners[f, 1, 1] - y0
        d2x, d2y = corners[f, 2, 0] - x0, corners[f, 2, 1] - y0
        pixel_area = 0.5 * abs(d1x * d2y - d1y * d2x)
        out[i] = np.sqrt(pixel_area / max(area[f], 1e-300))


def cell_corners(count: int, columns: int) -> np.ndarray:
    """(count, 3, 2) corners of ``count`` faces in cells of one texel, ``columns`` cells a
    row, face k in cell ``(k % columns, k // columns)`` of a block whose first texel
    centre is (0, 0): all three at the cell's texel centre, so that a look-up anywhere in
    the face reads that texel alone."""
    k = np.arange(count)
    origin = np.stack([k % columns, k // columns], axis=1).astype(np.float64)
    return np.repeat(origin[:, None, :], 3, axis=1)


def _shelves(sizes: np.ndarray, width: int) -> tuple[np.ndarray, int]:
    """Shelf packing of rectangles ``sizes`` (k, 2) (width, height), tallest first, into a
    strip ``width`` wide: (k, 2) their top-left corners and the strip's height."""
    origin = np.zeros((len(sizes), 2))
    # The heights are whole texels: as 16-bit keys where they fit, a stable radix sort.
    key = -sizes[:, 1]
    key = key.astype(np.int16) if len(sizes) and sizes[:, 1].max() < 2 ** 15 else key
    height = _shelve(np.ascontiguousarray(sizes, np.float64), np.argsort(key, kind="stable"),
                     float(width), origin)
    return origin, int(math.ceil(height))


@njit(cache=True, nogil=True)
def _shelve(sizes, order, width, origin):
    """:func:`_shelves`' loop: fills ``origin`` (k, 2), returns the strip's height."""
    x = y = shelf = 0.0
    for k in order:
        w, h = sizes[k, 0], sizes[k, 1]
        if x + w > width:
            x, y, shelf = 0.0, y + shelf, 0.0
        origin[k, 0] = x
        origin[k, 1] = y
        x, shelf = x + w, max(shelf, h)
    return y + shelf


def _dense(ids: np.ndarray) -> np.ndarray:
    """(k,) int64 the rank of each of ``ids`` (k,) int >= 0 among their distinct values
    (``np.unique``'s inverse, without sorting)."""
    present = np.zeros(int(ids.max()) + 1 if len(ids) else 0, bool)
    present[ids] = True
    return (np.cumsum(present) - 1)[ids]


def _members(ids: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """(k,) bool where ``ids`` (k,) int >= 0 is one of ``chosen`` (``np.isin`` without
    sorting)."""
    table = np.zeros(int(ids.max()) + 1 if len(ids) else 0, bool)
    table[chosen] = True
    return table[ids]


def _chart_bounds(corners: np.ndarray, faces: np.ndarray, chart: np.ndarray) -> tuple:
    """Each of ``faces``' (k,) group (k,) int64 (its chart's rank among the charts of
    ``chart`` (k,) int >= 0, theirs) and each group's least and greatest corner
    coordinates, (n, 2) each, of the faces' ``corners`` (of all faces, (m, 3, 2))."""
    group = _dense(chart)
    n = int(group.max()) + 1 if len(group) else 0
    low, high = np.full((n, 2), np.inf), np.full((n, 2), -np.inf)
    _reduce_bounds(np.ascontiguousarray(corners, np.float64), faces, group, low, high)
    return group, low, high


@njit(cache=True, nogil=True)
def _reduce_bounds(corners, faces, group, low, high):
    """:func:`_chart_bounds`' loop: the least and greatest corner of each group into
    ``low`` and ``high`` (n, 2), which start at +inf and -inf."""
    for i in range(faces.shape[0]):
        f, g = faces[i], group[i]
        for k in range(3):
            for d in range(2):
                x = corners[f, k, d]
                if x < low[g, d]:
                    low[g, d] = x
                if x > high[g, d]:
                    high[g, d] = x


def _strip_width(sizes: np.ndarray) -> int:
    """Width of the strip rectangles ``sizes`` (k, 2) are packed into, texels: about the
    side of a square of their total area, at least the widest, a multiple of 4."""
    width = int(max(sizes[:, 0].max(), math.ceil(math.sqrt(1.05 * np.prod(sizes, axis=1).sum()))))
    return 4 * math.ceil(width / 4)


def _cell_block(n_cells: int, padding: int) -> tuple[int, np.ndarray | None]:
    """Columns of the block of ``n_cells`` cells of one texel, and its rectangle (1, 2)
    (width, height) texels with ``padding`` (None without cells)."""
    columns = max(1, math.ceil(math.sqrt(n_cells)))
    if not n_cells:
        return columns, None
    rows = math.ceil(n_cells / columns)
    return columns, np.array([[columns + 2 * padding, rows + 2 * padding]], float)


@njit(cache=True, nogil=True)
def _place(unit_corners, faces, group, density, low, origin, padding, out):
    """Corners of ``faces`` (k,) in charts ``group`` (k,) into ``out`` (m, 3, 2): their
    ``unit_corners`` (m, 3, 2) times their chart's ``density`` (n,), moved from the
    chart's least corner ``low`` (n, 2) (whole texels) to its ``origin`` (n, 2) in the
    atlas, ``padding`` texels in."""
    for i in range(faces.shape[0]):
        f, g = faces[i], group[i]
        for k in range(3):
            for d in range(2):
                out[f, k, d] = density[g] * unit_corners[f, k, d] - low[g, d] + origin[g, d] \
                    + padding


@njit(cache=True, nogil=True)
def _claim_texels(h, tri, face_id, bary, overlapping):
    """Rasterise the triangles ``tri`` (m, 3) of the homogeneous points ``h`` (3m, 3) into
    ``face_id`` (H, W) and ``bary`` (H, W, 3); marks in ``overlapping`` (m,) bool both
    faces of a texel claimed twice. Returns the count of such texels."""
    height, width = face_id.shape
    coef = np.empty((3, 4))
    again = 0
    for f in range(tri.shape[0]):
        c0, c1, r0, r1 = pixel_box(h, tri, f, width, height)
        if c0 > c1 or r0 > r1 or triangle_edges(h, tri, f, coef) == 0.0:
            continue
        edges = edge_tuple(coef)
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                e0, e1, e2, total = covered_point(edges, float(c), float(r))
                if total == 0.0:
                    continue
                if face_id[r, c] >= 0:
                    again += 1
                    overlapping[f] = True
                    overlapping[face_id[r, c]] = True
                face_id[r, c] = f
                bary[r, c, 0] = e0 / total
                bary[r, c, 1] = e1 / total
                bary[r, c, 2] = e2 / total
    return again


def rasterize_atlas(corners: np.ndarray, shape: tuple) -> tuple:
    """The face (H, W) int64 (-1: none) and barycentric coordinates (H, W, 3) of every texel
    centre of faces with atlas ``corners`` (m, 3, 2), the count of texels claimed twice,
    and (m,) bool the faces that claim them."""
    h = np.ones((corners.shape[0] * 3, 3))
    h[:, :2] = corners.reshape(-1, 2)
    tri = np.arange(len(h), dtype=np.int64).reshape(-1, 3)
    face_id = np.full(shape, -1, np.int64)
    bary = np.zeros((*shape, 3))
    overlapping = np.zeros(len(corners), bool)
    again = _claim_texels(h, tri, face_id, bary, overlapping)
    return face_id, bary, again, overlapping


def _fill_cells(face_id: np.ndarray, bary: np.ndarray, celled: np.ndarray,
                block: tuple) -> None:
    """Give the texel of each cell of the ``celled`` (m,) faces (``block`` from
    :func:`_layout`) to its face, at the face's centroid."""
    faces = np.flatnonzero(celled)
    row, column, _, columns = block
    k = np.arange(len(faces))
    r, c = row + k // columns, column + k % columns
    face_id[r, c] = faces
    bary[r, c] = 1.0 / 3.0


@dataclass(frozen=True)
class _Charts:
    """The charts of one split (:func:`build_atlas`) at unit density: of the faces not in
    cells (``charted`` (k,), ``group`` (k,) each one's chart by rank), each chart's least
    and greatest corner (n, 2) (:func:`_chart_bounds`), its faces (n,) and whether its
    view sees it (n,) bool (else: an unseen plane)."""

    charted: np.ndarray
    group: np.ndarray
    low: np.ndarray
    high: np.ndarray
    faces_in: np.ndarray
    seen: np.ndarray

    @classmethod
    def of(cls, unit: _UnitCharts, labels: np.ndarray, chart: np.ndarray,
           cells: np.ndarray) -> _Charts:
        """The charts ``chart`` (m,) of the faces not in ``cells`` (m,) bool."""
        charted = np.flatnonzero(~cells)
        group, low, high = _chart_bounds(unit.corners, charted, chart[charted])
        member = np.zeros(len(low), np.int64)
        member[group] = charted
        faces_in = np.bincount(chart, minlength=int(chart.max()) + 1)[chart[member]]
        return cls(charted=charted, group=group, low=low, high=high, faces_in=faces_in,
                   seen=labels[member] >= 0)


@dataclass(frozen=True)
class _Fit:
    """Where a layout's search for the atlas's scale stands: ``scale`` texels per pixel
    (of the ``asked`` one), and the charts of fewer than ``fewest`` faces in cells."""

    scale: float
    fewest: int
    asked: float


def _layout(unit: _UnitCharts, labels, chart, celled, fit: _Fit, padding: int,
            max_size: int) -> tuple:
    """Corners (m, 3, 2), shape, the fit reached, cell faces (m,) bool and cells' block of
    the packed charts, from ``fit`` on: scaled down to fit, down to
    :data:`MIN_SCALE` of the asked density, then the charts of fewest faces given cells
    until they fit."""
    cells = celled | unit.curved
    charts = _Charts.of(unit, labels, chart, cells)
    scale, fewest = fit.scale, fit.fewest
    while True:
        large = charts.faces_in >= fewest
        if not (large & charts.seen).any():       # planes take their density from views
            large &= charts.seen
        for _ in range(_FIT_TRIES):
            density = np.where(charts.seen, scale, scale * unit.plane_density)[:, None]
            low = np.floor(density * charts.low)    # texel centres on whole coordinates
            sizes = np.ceil(density * charts.high - low) + 1 + 2 * padding
            # A plane whose faces take fewer texels as cells than it takes with its
            # padding takes cells (its colours are smooth either way).
            kept = large & (charts.seen | (charts.faces_in > np.prod(sizes, axis=1)))
            if kept.all():
                in_cells = cells.copy()
            else:
                in_cells = np.ones(len(labels), bool)
                in_cells[charts.charted[kept[charts.group]]] = False
            n_cells = int(in_cells.sum())
            columns, block_size = _cell_block(n_cells, padding)
            density, low, sizes = density[kept], low[kept], sizes[kept]
            if block_size is not None:
                sizes = np.concatenate([sizes, block_size])
            width = _strip_width(sizes)
            origin, height = _shelves(sizes, width)
            shape = (4 * math.ceil(height / 4), width)
            if max(shape) <= max_size:
                return (_layout_corners(unit, charts, kept, density, low, origin, padding,
                                        len(labels)),
                        shape, _Fit(scale, fewest, fit.asked), in_cells,
                        _block_of(origin, padding, n_cells, columns))
            if scale <= MIN_SCALE * fit.asked:
                break
            scale = max(MIN_SCALE * fit.asked, scale * 0.97 * max_size / max(shape))
        if in_cells.all():
            raise ValueError(f"the mesh's {len(labels)} faces do not fit a {max_size} texel "
                             "atlas even at one texel each: allow a larger max_size or "
                             "simplify the mesh")
        fewest *= 4


def _block_of(origin: np.ndarray, padding: int, n_cells: int, columns: int) -> tuple | None:
    """The cells' block's first texel and shape ``(row, column, rows, columns)`` in cells
    (its rectangle packed last at ``origin[-1]``), None without cells."""
    if not n_cells:
        return None
    top_left = origin[-1] + padding
    return (int(top_left[1]), int(top_left[0]), math.ceil(n_cells / columns), columns)


def _layout_corners(unit: _UnitCharts, charts: _Charts, kept: np.ndarray, density: np.ndarray,
                    low: np.ndarray, origin: np.ndarray, padding: int, m: int) -> np.ndarray:
    """(m, 3, 2) the corners in the atlas of the faces of the ``kept`` (n,) charts at their
    ``density`` (k, 1) texels per unit, moved to their ``origin``; those of the faces in cells left
    unset (:func:`_corners_in_cells`, once the layout is kept)."""
    faces, group = charts.charted, charts.group
    if not kept.all():
        mine = kept[group]
        faces, group = faces[mine], (np.cumsum(kept) - 1)[group[mine]]
    out = np.empty((m, 3, 2))
    _place(unit.corners, faces, group, np.ascontiguousarray(density[:, 0]), low, origin,
           float(padding), out)
    return out


def _corners_in_cells(corners: np.ndarray, cells: np.ndarray, block: tuple | None) -> None:
    """Set the ``corners`` (m, 3, 2) of the faces in ``cells`` (m,) bool, in their block
    (``block`` from :func:`_layout`; :func:`cell_corners`)."""
    if block is not None:
        row, column, _, columns = block
        corners[cells] = cell_corners(int(cells.sum()), columns) + np.array(
            [column, row], np.float64)


def build_atlas(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
                neighbours: np.ndarray, cameras: list[Camera], *, texels_per_pixel: float = 1.0,
                max_size: int = 4096, padding: int = 2) -> Atlas:
    """Lay out the charts of the labelled faces (module docstring).

    ``vertices`` (n, 3) metres, ``faces`` (m, 3), ``labels`` (m,) the view of each face
    (-1: none), ``neighbours`` (m, 3) (:func:`.selection.face_neighbours`), ``cameras``
    the views; ``padding`` texels around each chart, ``max_size`` the largest side.
    """
    if not (math.isfinite(texels_per_pixel) and texels_per_pixel > 0):
        raise ValueError(f"texels_per_pixel must be a finite number > 0, got {texels_per_pixel}")
    if int(padding) < 1 or int(max_size) < 64:
        raise ValueError(f"padding must be >= 1 texel and max_size >= 64, got {padding}, "
                         f"{max_size}")
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])     # twice the area
    patch = chart_of_faces(np.where(labels >= 0, labels, -1 - _nearest_axis(normal)), neighbours)
    unit = _UnitCharts.of(tri, normal, labels, patch, cameras)
    del tri, normal
    alone = np.zeros(len(faces), bool)
    celled = np.zeros(len(faces), bool)
    # Each split starts from the scale the last one reached: at an unchanged scale a
    # chart's texel centres fall where they fell (its corner moves by whole texels), so
    # the faces left in a split chart claim no texel twice and the splits end.
    fit = _Fit(float(texels_per_pixel), 1, float(texels_per_pixel))
    for split in itertools.count():
        chart = _dense(np.where(alone | celled, patch.max() + 1 + np.arange(len(faces)), patch))
        corners, shape, fit, cells, block = _layout(
            unit, labels, chart, celled, fit, int(padding), int(max_size))
        charted = np.flatnonzero(~cells)
        face_id, bary, again, overlapping_charted = rasterize_atlas(corners[charted], shape)
        if not again:
            face_id = np.where(face_id >= 0, np.append(charted, -1)[face_id], -1)
            _corners_in_cells(corners, cells, block)
            if block is not None:
                _fill_cells(face_id, bary, cells, block)
            # A face in a cell has corners of its own.
            chart = np.where(cells, chart.max() + 1 + np.arange(len(faces)), chart)
            return Atlas(shape=shape, corners=corners,
                         chart=_dense(chart),
                         face_index=face_id, barycentric=bary, texels_per_pixel=fit.scale)
        overlapping = np.zeros(len(faces), bool)
        overlapping[charted] = overlapping_charted
        # A patch no view sees overlaps where it curves: all its faces take cells at once
        # (their colours are interpolated, smooth) rather than ring by ring. Seen faces
        # that still overlap after a few splits (folds finer than a texel, met again at
        # each new scale) take cells too: cells never overlap, so this ends.
        curved = _members(chart, chart[overlapping & (labels < 0)])
        celled |= curved | (overlapping if split >= _SPLIT_TRIES else False)
        alone |= overlapping & ~celled
