"""Accuracy metrics: volume and silhouette IoU, ground-truth occupancy, Chamfer distance."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from .geometry.camera import Camera
from .geometry.grid import VoxelGrid
from .outline import edge_faces, outline_cover
from .render import (
    FRONT_FACING,
    as_mesh_arrays,
    covered_point,
    edge_tuple,
    face_orientation,
    projected_pixel_box,
    rasterize_silhouette,
    triangle_edges,
)

__all__ = ["ChamferResult", "volume_iou", "silhouette_iou", "reprojection_iou",
           "reprojection_ious",
           "occupancy_from_contains", "mesh_occupancy", "chamfer_distance"]


def _iou(a, b, what: str) -> float:
    a = np.asarray(a)
    b = np.asarray(b)
    if a.shape != b.shape:
        raise ValueError(f"{what} must have the same shape, got {a.shape} and {b.shape}")
    if a.dtype != bool or b.dtype != bool:
        raise ValueError(f"{what} must be bool arrays, got {a.dtype} and {b.dtype}")
    union = np.count_nonzero(a | b)
    if union == 0:
        return 1.0
    return np.count_nonzero(a & b) / union


def volume_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two occupancy arrays (same shape, bool).

    Two empty volumes are identical: IoU 1.0.
    """
    return _iou(a, b, "occupancy arrays")


def silhouette_iou(mask_a: np.ndarray, mask_b: np.ndarray) -> float:
    """Intersection over union of two (H, W) bool masks; two empty masks give 1.0."""
    if np.ndim(mask_a) != 2:
        raise ValueError(f"masks must be (H, W) arrays, got shape {np.shape(mask_a)}")
    return _iou(mask_a, mask_b, "masks")


def reprojection_iou(vertices, faces, camera: Camera, mask: np.ndarray) -> float:
    """IoU between a mesh's silhouette in ``camera`` and a (H, W) bool ``mask``.

    vertices : (n, 3) float64, metres; faces : (m, 3) int.
    """
    mask = np.asarray(mask)
    if mask.shape != (camera.height, camera.width):
        raise ValueError(
            f"mask shape {mask.shape} does not match the camera image "
            f"({camera.height}, {camera.width})")
    return silhouette_iou(rasterize_silhouette(vertices, faces, camera), mask)


@njit(cache=True, inline="always")
def _view_coverage(vertices, faces, ends, sides, P, heights, widths, masks, moff, mask_px,
                   front_only, out, v, h, uv, cover, coef, front, crossings):
    """Row ``v`` of :func:`_coverage_overlap`'s ``out``, with the scratch arrays given."""
    H = heights[v]
    W = widths[v]
    in_front = True
    for i in range(vertices.shape[0]):
        x, y, z = vertices[i, 0], vertices[i, 1], vertices[i, 2]
        w = P[v, 2, 0] * x + P[v, 2, 1] * y + P[v, 2, 2] * z + P[v, 2, 3]
        uv[i, 0] = (P[v, 0, 0] * x + P[v, 0, 1] * y + P[v, 0, 2] * z + P[v, 0, 3]) / w
        uv[i, 1] = (P[v, 1, 0] * x + P[v, 1, 1] * y + P[v, 1, 2] * z + P[v, 1, 3]) / w
        in_front = in_front and w > 0.0
    if sides.shape[0] > 0 and in_front:
        r0, r1, c0, c1 = outline_cover(uv, faces, ends, sides, W, H, front, crossings, cover)
    else:
        for i in range(vertices.shape[0]):
            for r in range(3):
                h[i, r] = (P[v, r, 0] * vertices[i, 0] + P[v, r, 1] * vertices[i, 1]
                           + P[v, r, 2] * vertices[i, 2] + P[v, r, 3])
        _drawn_coverage(faces, h, uv, H, W, front_only, cover, coef)
        r0, r1, c0, c1 = 0, H - 1, 0, W - 1
    both = 0
    covered = 0
    for row in range(r0, r1 + 1):   # nothing is covered outside the box
        for col in range(c0, c1 + 1):
            k = row * W + col
            both += cover[k] & masks[moff[v] + k]
            covered += cover[k]
    out[v, 0] = both
    out[v, 1] = mask_px[v] + covered - both


@njit(cache=True, inline="always")
def _drawn_coverage(faces, h, uv, H, W, front_only, cover, coef):
    """``cover`` (>= H * W) uint8: 1 at the pixel centres the faces cover, drawn one by one
    (only those turned towards the camera when ``front_only``)."""
    cover[:H * W] = 0
    for f in range(faces.shape[0]):
        c0, c1, r0, r1 = projected_pixel_box(h, uv, faces, f, W, H)
        if c0 > c1 or r0 > r1:
            continue  # most faces of a fine mesh hold no pixel centre (some lie off the image)
        if front_only and face_orientation(h, faces, f) != FRONT_FACING:
            continue  # (the edges of a back face are not needed)
        if triangle_edges(h, faces, f, coef) == 0.0:
            continue
        edges = edge_tuple(coef)
        for row in range(r0, r1 + 1):
            y = float(row)
            for col in range(c0, c1 + 1):
                if covered_point(edges, float(col), y)[3] != 0.0:
                    cover[row * W + col] = 1


@njit(parallel=True, cache=True, nogil=True)
def _coverage_overlap(vertices, faces, ends, sides, P, heights, widths, masks, moff, mask_px,
                      front_only, lanes, out):
    """Per view v: out[v] = (pixels covered by the mesh and in the mask, in either), with
    ``mask_px`` (views,) the pixels in each mask; the views go through ``lanes`` threads,
    each with its scratch allocated once. With ``ends`` and ``sides``
    (:func:`~sfs_ros.core.outline.edge_faces` of a closed mesh; empty (0, 2) for none) a
    view the whole mesh lies in front of is covered from its outline."""
    for lane in prange(lanes):
        h = np.empty((vertices.shape[0], 3))
        uv = np.empty((vertices.shape[0], 2))
        pixels = heights.max() * widths.max()
        cover = np.empty(pixels, np.uint8)
        coef = np.empty((3, 4))
        with_outline = sides.shape[0] > 0
        front = np.empty(faces.shape[0] if with_outline else 0, np.bool_)
        crossings = np.zeros(pixels if with_outline else 0, np.int32)   # (left zero)
        for v in range(lane, P.shape[0], lanes):
            _view_coverage(vertices, faces, ends, sides, P, heights, widths, masks, moff,
                           mask_px, front_only, out, v, h, uv, cover, coef, front, crossings)


def reprojection_ious(vertices, faces, cameras, masks, *, closed: bool = False,
                      edges=None) -> np.ndarray:
    """(n,) float64: per camera, IoU of the mesh's silhouette with its (H, W) bool mask.

    The same pixel-centre coverage as :func:`reprojection_iou`, for all views
    at once (one parallel pass, no image kept). ``closed=True`` promises a
    closed, outward-oriented mesh: a view the mesh lies wholly in front of is
    then covered from the mesh's outline (:mod:`sfs_ros.core.outline`: faster
    on a fine mesh; a pixel centre exactly on the outline may go
    the other way), any other from the faces turned towards the camera (every
    ray into a closed surface enters through one). A mesh found not to be
    closed is drawn face by face. ``edges``: :func:`~sfs_ros.core.outline.edge_faces` of
    the mesh, when made already (with ``closed``; it is made here otherwise). vertices :
    (n, 3) float64, metres; faces : (m, 3) int.
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    cameras = list(cameras)
    if len(masks) != len(cameras):
        raise ValueError(f"got {len(cameras)} cameras but {len(masks)} masks; expected one "
                         "mask per camera")
    for n, (cam, mask) in enumerate(zip(cameras, masks)):
        if np.shape(mask) != (cam.height, cam.width) or np.asarray(mask).dtype != bool:
            raise ValueError(f"mask {n} must be a ({cam.height}, {cam.width}) bool array like "
                             f"its camera's image, got {np.shape(mask)} "
                             f"{np.asarray(mask).dtype}")
    heights = np.array([c.height for c in cameras], np.int64)
    widths = np.array([c.width for c in cameras], np.int64)
    moff = np.zeros(len(cameras), np.int64)
    moff[1:] = np.cumsum(heights * widths)[:-1]
    flat = np.concatenate([np.asarray(m).ravel() for m in masks]).view(np.uint8)
    P = np.ascontiguousarray([c.projection_matrix for c in cameras], dtype=np.float64)
    counts = np.zeros((len(cameras), 2), np.int64)
    mask_px = np.array([np.count_nonzero(m) for m in masks], np.int64)
    if len(faces):
        none = np.zeros((0, 2), np.int32)
        if closed and edges is None:
            edges = edge_faces(faces, len(vertices))
        ends, sides = (edges if closed else None) or (none, none)
        # (32-bit indices: half the memory each view reads)
        _coverage_overlap(vertices, faces.astype(np.int32), ends, sides, P, heights, widths,
                          flat, moff, mask_px, bool(closed),
                          min(len(cameras), numba.get_num_threads()), counts)
    else:
        counts[:, 1] = mask_px
    union = np.maximum(counts[:, 1], 1)
    return np.where(counts[:, 1] == 0, 1.0, counts[:, 0] / union)


def occupancy_from_contains(contains_fn, grid: VoxelGrid, *, chunk_voxels: int = 1 << 20) -> np.ndarray:
    """(nx, ny, nz) bool: ``contains_fn`` evaluated at every voxel centre.

    ``contains_fn`` maps points (n, 3), metres, to (n,) bool. The grid is
    evaluated in slabs of whole X-planes of about ``chunk_voxels`` voxels, which
    bounds the memory of the temporary point arrays.
    """
    if int(chunk_voxels) < 1:
        raise ValueError(f"chunk_voxels must be >= 1, got {chunk_voxels}")
    nx, ny, nz = grid.shape
    xs, ys, zs = (grid.centers_axis(k) for k in range(3))
    plane = np.stack(np.meshgrid(ys, zs, indexing="ij"), axis=-1).reshape(-1, 2)  # (ny * nz, 2)
    step = max(1, int(chunk_voxels) // (ny * nz))
    out = np.empty(grid.shape, dtype=bool)
    for i0 in range(0, nx, step):
        x = xs[i0:i0 + step]
        points = np.column_stack([np.repeat(x, len(plane)), np.tile(plane, (len(x), 1))])
        inside = np.asarray(contains_fn(points))
        if inside.shape != (len(points),):
            raise ValueError(
                f"contains_fn must return ({len(points)},) values for {len(points)} points, "
                f"got shape {inside.shape}")
        out[i0:i0 + step] = inside.astype(bool).reshape(len(x), ny, nz)
    return out


#: Offset of the +Z rays from the voxel-column centres, in voxels (u, v).
COLUMN_NUDGE = (1e-6, 1e-9)


@njit(cache=True)
def _column_crossings(h, zk, faces, crossings):
    """Add +1 where a +Z column enters the surface, -1 where it leaves, at the first voxel above."""
    nx, ny, nz = crossings.shape
    coef = np.empty((3, 4))
    for f in range(faces.shape[0]):
        orientation = triangle_edges(h, faces, f, coef)
        if orientation == 0.0:
            continue
        edges = edge_tuple(coef)
        # (u, v) = (i, j): a counter-clockwise triangle in X-Y faces +Z, so the
        # column leaves the solid there.
        step = -1 if orientation > 0.0 else 1
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        i0 = max(0, int(np.ceil(min(h[a, 0], h[b, 0], h[c, 0]) - 1e-6)))
        i1 = min(nx - 1, int(np.floor(max(h[a, 0], h[b, 0], h[c, 0]) + 1e-6)))
        j0 = max(0, int(np.ceil(min(h[a, 1], h[b, 1], h[c, 1]) - 1e-6)))
        j1 = min(ny - 1, int(np.floor(max(h[a, 1], h[b, 1], h[c, 1]) + 1e-6)))
        for i in range(i0, i1 + 1):
            u = float(i)
            for j in range(j0, j1 + 1):
                e0, e1, e2, total = covered_point(edges, u, float(j))
                if total == 0.0:
                    continue
                z = (e0 * zk[a] + e1 * zk[b] + e2 * zk[c]) / total  # fractional k of the crossing
                k = int(np.floor(z)) + 1                            # first voxel centre above it
                if k < nz:
                    crossings[i, j, max(k, 0)] += step


@njit(cache=True)
def _winding_to_occupancy(crossings, out):
    nx, ny, nz = crossings.shape
    for i in range(nx):
        for j in range(ny):
            winding = 0
            for k in range(nz):
                winding += crossings[i, j, k]
                out[i, j, k] = winding > 0


def mesh_occupancy(vertices, faces, grid: VoxelGrid) -> np.ndarray:
    """(nx, ny, nz) bool: voxel centres inside a closed, outward-oriented triangle mesh.

    Casts one ray along +Z through every column of voxel centres and counts
    signed crossings (entering +1, leaving -1): a centre is inside where the
    winding number is positive. Meshes made of several overlapping closed parts
    therefore give their union. Crossings are exact at column centres with
    shared edges and vertices counted once (see :mod:`.render`).

    vertices : (n, 3) float64, metres; faces : (m, 3) int.
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    index = grid.world_to_index(vertices)
    # Columns run at (i, j) + COLUMN_NUDGE: far above rounding, far below a voxel.
    # Faces standing exactly on a column line (marching cubes puts vertical faces
    # at integer i or j) have an orientation that is pure rounding noise there;
    # nudged columns never touch them. The nudge points the way of the tie rule
    # (eps, eps^2), so shapes with edges on exact column centres keep that rule.
    h = np.ascontiguousarray(np.column_stack([index[:, 0] - COLUMN_NUDGE[0],
                                              index[:, 1] - COLUMN_NUDGE[1], np.ones(len(index))]))
    crossings = np.zeros(grid.shape, dtype=np.int16)
    _column_crossings(h, np.ascontiguousarray(index[:, 2]), faces, crossings)
    out = np.empty(grid.shape, dtype=bool)
    _winding_to_occupancy(crossings, out)
    return out


@dataclass(frozen=True)
class ChamferResult:
    """Nearest-neighbour distances between two point sets, metres.

    a_to_b_mean : mean over points of A of the distance to the nearest point of B.
    b_to_a_mean : the same from B to A.
    mean : (a_to_b_mean + b_to_a_mean) / 2, the symmetric Chamfer distance.
    hausdorff : largest nearest-neighbour distance in either direction.
    """

    a_to_b_mean: float
    b_to_a_mean: float
    mean: float
    hausdorff: float


def _points(points, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ValueError(f"{name} must be a non-empty (n, 3) array, got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} contains NaN or infinity")
    return points


def chamfer_distance(points_a, points_b) -> ChamferResult:
    """Chamfer and Hausdorff distances between point sets (n, 3) and (m, 3), metres."""
    from scipy.spatial import cKDTree  # here: a reconstruction's evaluation needs none

    a = _points(points_a, "points_a")
    b = _points(points_b, "points_b")
    a_to_b, _ = cKDTree(b).query(a)
    b_to_a, _ = cKDTree(a).query(b)
    a_mean, b_mean = float(a_to_b.mean()), float(b_to_a.mean())
    return ChamferResult(a_to_b_mean=a_mean, b_to_a_mean=b_mean, mean=0.5 * (a_mean + b_mean),
                         hausdorff=float(max(a_to_b.max(), b_to_a.max())))
