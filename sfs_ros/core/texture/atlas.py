"""The texture atlas: charts of faces laid out in one image.

A *chart* is a connected patch of faces that take their colour from the same view (the
labelling of :mod:`.selection`), laid out as that view sees it: each corner at its
projection in the view's image, in pixels, times ``texels_per_pixel``. The view sees
every face of the patch unhidden and facing it, so the projection is one to one and the
texture is the image itself, resampled only when ``texels_per_pixel`` is not 1 (texels
per metre on the object as many as the view's pixels per metre there). Faces no view
sees (the underside on the plate, a refined mesh's hidden folds) carry only colours
interpolated from the seen ones, smooth: they take *cells*. A cell is one texel, and the
three corners of each face in it lie at its centre, so that a look-up anywhere in the
face reads that texel alone (bilinear or nearest, at any level of detail: the texture
coordinates do not vary across the face). The unseen faces whose lowest corner is one
vertex share its cell, of that vertex's colour (and the copies of their corners); a seen
face that takes a cell has its own, of its colour at its centroid. The cells are packed
side by side as one rectangle, with no padding between them. Faces that would still
overlap another in the atlas (a patch seen partly hidden) are made charts of their own
(after :data:`_SPLIT_TRIES` tries, cells), and the atlas is laid out again, from the
scale the last layout reached (at an unchanged scale the charts left whole claim the
texels they claimed: no new overlap).

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
    (m, 3)) of faces with one label (m,) >= 0; a face labelled -1 (unseen) is a chart of
    its own."""
    m = len(labels)
    f = np.repeat(np.arange(m), 3)
    g = neighbours.ravel()
    keep = (g >= 0) & (labels[f] >= 0) & (labels[f] == labels[np.maximum(g, 0)])
    graph = sparse.csr_matrix((np.ones(int(keep.sum())), (f[keep], g[keep])), shape=(m, m))
    return csgraph.connected_components(graph, directed=False)[1].astype(np.int64)


def _seen_corners(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
                  cameras: list[Camera]) -> np.ndarray:
    """(m, 3, 2) float64 each seen face's corners in its view's pixels (``labels`` (m,),
    -1: unseen, whose corners are zero): the charts before packing and scaling, made
    once for all the layouts tried (scaling a chart scales its bounds exactly: a product
    rounds monotonically)."""
    corners = np.zeros((len(faces), 3, 2))
    for label, camera in enumerate(cameras):
        mine = np.flatnonzero(labels == label)
        if mine.size:
            corners[mine] = camera.project(vertices[faces[mine]].reshape(-1, 3)).reshape(-1, 3, 2)
    return corners


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
def _place(unit_corners, faces, group, scale, low, origin, padding, out):
    """Corners of ``faces`` (k,) in charts ``group`` (k,) into ``out`` (m, 3, 2): their
    ``unit_corners`` (m, 3, 2) times ``scale``, moved from the chart's least corner
    ``low`` (n, 2) (whole texels) to its ``origin`` (n, 2) in the atlas, ``padding``
    texels in."""
    for i in range(faces.shape[0]):
        f, g = faces[i], group[i]
        for k in range(3):
            for d in range(2):
                out[f, k, d] = scale * unit_corners[f, k, d] - low[g, d] + origin[g, d] + padding


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


def _cell_keys(faces: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(m,) int64 the key of the cell each face takes if it takes one: for a face no view
    sees (``labels`` (m,) -1), its lowest corner, shared with the other unseen faces whose
    lowest corner it is; for another face, a key of its own (the vertices' count plus its
    index)."""
    n = int(faces.max()) + 1 if len(faces) else 0
    return np.where(labels < 0, faces.min(axis=1), n + np.arange(len(faces)))


def _fill_cells(face_id: np.ndarray, bary: np.ndarray, faces: np.ndarray, cells: np.ndarray,
                cell_of: np.ndarray, keys: np.ndarray, block: tuple) -> None:
    """Give the texel of each cell (``cell_of`` (k,) the cell of each of the faces in
    ``cells`` (m,) bool, ``keys`` (m,) :func:`_cell_keys`, ``block`` from :func:`_layout`)
    to one of its faces: at the face's corner that keys the cell (its colour the vertex's),
    or at its centroid (a cell of its own)."""
    in_cells = np.flatnonzero(cells)
    first = np.empty(int(cell_of.max()) + 1, np.int64)
    first[cell_of] = in_cells
    row, column, _, columns = block
    k = np.arange(len(first))
    r, c = row + k // columns, column + k % columns
    face_id[r, c] = first
    corner = np.argmin(faces[first], axis=1)
    by_vertex = keys[first] < (int(faces.max()) + 1)
    weights = np.full((len(first), 3), 1.0 / 3.0)
    weights[by_vertex] = np.eye(3)[corner[by_vertex]]
    bary[r, c] = weights


@dataclass(frozen=True)
class _Charts:
    """The charts of one split (:func:`build_atlas`) at unit density: of the faces not in
    cells (``charted`` (k,), ``group`` (k,) each one's chart by rank), each chart's least
    and greatest corner (n, 2) (:func:`_chart_bounds`) and its faces (n,)."""

    charted: np.ndarray
    group: np.ndarray
    low: np.ndarray
    high: np.ndarray
    faces_in: np.ndarray

    @classmethod
    def of(cls, corners: np.ndarray, chart: np.ndarray, cells: np.ndarray) -> _Charts:
        """The charts ``chart`` (m,) of the faces not in ``cells`` (m,) bool, their
        ``corners`` (m, 3, 2) (:func:`_seen_corners`)."""
        charted = np.flatnonzero(~cells)
        group, low, high = _chart_bounds(corners, charted, chart[charted])
        member = np.zeros(len(low), np.int64)
        member[group] = charted
        faces_in = np.bincount(chart, minlength=int(chart.max()) + 1)[chart[member]]
        return cls(charted=charted, group=group, low=low, high=high, faces_in=faces_in)


@dataclass(frozen=True)
class _Fit:
    """Where a layout's search for the atlas's scale stands: ``scale`` texels per pixel
    (of the ``asked`` one), and the charts of fewer than ``fewest`` faces in cells."""

    scale: float
    fewest: int
    asked: float


def _layout(unit_corners: np.ndarray, chart, cells, keys, fit: _Fit, padding: int,
            max_size: int) -> tuple:
    """Corners (m, 3, 2), shape, the fit reached, cell faces (m,) bool, the cell of each of
    them (k,) and the cells' block of the packed charts (``unit_corners`` (m, 3, 2),
    :func:`_seen_corners`), the faces in ``cells`` (m,) bool taking cells (those of one
    of ``keys`` (m,), :func:`_cell_keys`, sharing one), from ``fit`` on: scaled down to
    fit, down to :data:`MIN_SCALE` of the asked density, then the charts of fewest faces
    given cells until they fit."""
    charts = _Charts.of(unit_corners, chart, cells)
    scale, fewest = fit.scale, fit.fewest
    while True:
        kept = charts.faces_in >= fewest
        if kept.all():
            in_cells = cells.copy()
        else:
            in_cells = np.ones(len(chart), bool)
            in_cells[charts.charted[kept[charts.group]]] = False
        cell_of = _dense(keys[in_cells])
        n_cells = int(cell_of.max()) + 1 if len(cell_of) else 0
        columns, block_size = _cell_block(n_cells, padding)
        for _ in range(_FIT_TRIES):
            low = np.floor(scale * charts.low[kept])    # texel centres on whole coordinates
            sizes = np.ceil(scale * charts.high[kept] - low) + 1 + 2 * padding
            if block_size is not None:
                sizes = np.concatenate([sizes, block_size])
            width = _strip_width(sizes)
            origin, height = _shelves(sizes, width)
            shape = (4 * math.ceil(height / 4), width)
            if max(shape) <= max_size:
                return (_layout_corners(unit_corners, charts, kept, scale, low, origin,
                                        padding, len(chart)),
                        shape, _Fit(scale, fewest, fit.asked), in_cells, cell_of,
                        _block_of(origin, padding, n_cells, columns))
            if scale <= MIN_SCALE * fit.asked:
                break
            scale = max(MIN_SCALE * fit.asked, scale * 0.97 * max_size / max(shape))
        if in_cells.all():
            raise ValueError(f"the mesh's {len(chart)} faces do not fit a {max_size} texel "
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


def _layout_corners(unit_corners: np.ndarray, charts: _Charts, kept: np.ndarray, scale: float,
                    low: np.ndarray, origin: np.ndarray, padding: int, m: int) -> np.ndarray:
    """(m, 3, 2) the corners in the atlas of the faces of the ``kept`` (n,) charts at
    ``scale`` texels per pixel, moved to their ``origin``; those of the faces in cells
    left unset (:func:`_corners_in_cells`, once the layout is kept)."""
    faces, group = charts.charted, charts.group
    if not kept.all():
        mine = kept[group]
        faces, group = faces[mine], (np.cumsum(kept) - 1)[group[mine]]
    out = np.empty((m, 3, 2))
    _place(unit_corners, faces, group, float(scale), low, origin, float(padding), out)
    return out


def _corners_in_cells(corners: np.ndarray, cells: np.ndarray, cell_of: np.ndarray,
                      block: tuple | None) -> None:
    """Set the ``corners`` (m, 3, 2) of the faces in ``cells`` (m,) bool, in their cells
    ``cell_of`` (k,) of their block (``block`` from :func:`_layout`; :func:`cell_corners`)."""
    if block is not None:
        row, column, _, columns = block
        corners[cells] = cell_corners(int(cell_of.max()) + 1, columns)[cell_of] + np.array(
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
    patch = chart_of_faces(labels, neighbours)
    unit_corners = _seen_corners(vertices, faces, labels, cameras)
    keys = _cell_keys(faces, labels)
    alone = np.zeros(len(faces), bool)
    celled = labels < 0
    # Each split starts from the scale the last one reached: at an unchanged scale a
    # chart's texel centres fall where they fell (its corner moves by whole texels), so
    # the faces left in a split chart claim no texel twice and the splits end.
    fit = _Fit(float(texels_per_pixel), 1, float(texels_per_pixel))
    for split in itertools.count():
        chart = _dense(np.where(alone | celled, patch.max() + 1 + np.arange(len(faces)), patch))
        corners, shape, fit, cells, cell_of, block = _layout(
            unit_corners, chart, celled, keys, fit, int(padding), int(max_size))
        charted = np.flatnonzero(~cells)
        face_id, bary, again, overlapping_charted = rasterize_atlas(corners[charted], shape)
        if not again:
            face_id = np.where(face_id >= 0, np.append(charted, -1)[face_id], -1)
            _corners_in_cells(corners, cells, cell_of, block)
            if block is not None:
                _fill_cells(face_id, bary, faces, cells, cell_of, keys, block)
            # The faces of a cell share its corners.
            in_cell = np.zeros(len(faces), np.int64)
            in_cell[cells] = cell_of
            chart = np.where(cells, chart.max() + 1 + in_cell, chart)
            return Atlas(shape=shape, corners=corners,
                         chart=_dense(chart),
                         face_index=face_id, barycentric=bary, texels_per_pixel=fit.scale)
        overlapping = np.zeros(len(faces), bool)
        overlapping[charted] = overlapping_charted
        # Faces that still overlap after a few splits (folds finer than a texel, met again
        # at each new scale) take cells: cells never overlap, so this ends.
        if split >= _SPLIT_TRIES:
            celled |= overlapping
        alone |= overlapping & ~celled
