"""A simplified copy of a mesh within a triangle budget, for display: vertex clustering.

:func:`decimate` snaps the vertices to a cubic grid and merges those in one cell (their
mean position, their mean colour), then drops the triangles that collapsed (two corners
in one cell) and the duplicates. The cell is grown until the triangles fit the budget.
Vertex clustering keeps the shape to within a cell everywhere, needs only numpy and is
deterministic; it may join nearby sheets (a thin wall's two sides) into a non-manifold
surface, which a viewer draws as well: the copy is for display, the full mesh stays in its
file. Coordinates in the mesh's units (metres), colours (n, 3) uint8.
"""

from __future__ import annotations

import numpy as np

__all__ = ["decimate"]

#: Each round grows the cell by the square root of (triangles / budget) times this margin.
_MARGIN = 1.05
#: Most vertices (a merged triangle's three indices are packed in one int64).
_MAX_VERTICES = 2_000_000
#: Rounds before giving up on meeting the budget (each at least 5 % coarser).
_MAX_ROUNDS = 60


def decimate(vertices, faces, max_faces: int, colours=None):
    """``(vertices (k, 3) float64, faces (m, 3) int64, colours (k, 3) uint8 or None)``: the
    mesh with at most ``max_faces`` triangles (the mesh itself when it has no more).

    vertices : (n, 3) float; faces : (f, 3) int indices; colours : (n, 3) uint8, optional,
    one per vertex (averaged per merged vertex). ValueError for a budget below 1 or arrays
    of the wrong shape.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if max_faces < 1:
        raise ValueError(f"max_faces must be at least 1, got {max_faces}")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"vertices must be (n, 3) and faces (m, 3), got {vertices.shape} and "
                         f"{faces.shape}")
    if colours is not None and np.shape(colours) != vertices.shape:
        raise ValueError(f"colours must be ({len(vertices)}, 3), got {np.shape(colours)}")
    if len(faces) <= max_faces:
        return vertices, faces, None if colours is None else np.asarray(colours, np.uint8)
    if len(vertices) >= _MAX_VERTICES:
        raise ValueError(f"at most {_MAX_VERTICES} vertices are decimated, got {len(vertices)}")
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    area = max(0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()), 1e-30)
    # A surface of area A on a grid of cells of side s has about 2 A / s^2 triangles.
    cell = np.sqrt(2.0 * area / max_faces)
    for _ in range(_MAX_ROUNDS):
        out = _cluster(vertices, faces, colours, cell)
        if len(out[1]) <= max_faces:
            return out
        cell *= np.sqrt(len(out[1]) / max_faces) * _MARGIN
    raise ValueError(f"could not bring {len(faces)} triangles within {max_faces}")


def _cluster(vertices: np.ndarray, faces: np.ndarray, colours, cell: float):
    """The mesh with its vertices merged per grid cell of side ``cell``."""
    cells = np.floor((vertices - vertices.min(axis=0)) / cell).astype(np.int64)
    sides = cells.max(axis=0) + 1
    keys = (cells[:, 0] * sides[1] + cells[:, 1]) * sides[2] + cells[:, 2]
    _, label, counts = np.unique(keys, return_inverse=True, return_counts=True)
    label = label.reshape(-1)
    merged = np.zeros((len(counts), 3))
    np.add.at(merged, label, vertices)
    merged /= counts[:, None]
    corners = label[faces]
    keep = (corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2]) \
        & (corners[:, 0] != corners[:, 2])
    corners = corners[keep]
    # One of each triangle (either winding counts as the same), in first-seen order.
    k = np.int64(len(counts))
    ordered = np.sort(corners, axis=1)
    _, first = np.unique((ordered[:, 0] * k + ordered[:, 1]) * k + ordered[:, 2],
                         return_index=True)
    corners = corners[np.sort(first)]
    used, corners = np.unique(corners, return_inverse=True)
    corners = corners.reshape(-1, 3)
    rgb = None
    if colours is not None:
        total = np.zeros((len(counts), 3))
        np.add.at(total, label, np.asarray(colours, dtype=np.float64))
        rgb = np.rint(total / counts[:, None]).astype(np.uint8)[used]
    return merged[used], corners, rgb
