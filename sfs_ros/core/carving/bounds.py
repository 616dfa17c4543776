"""A bounding box for carving when the input gives none.

The cameras of a turntable scan all look at the object. The box is found in
two steps: the region every camera can see around the point nearest to all
optical axes, then a coarse carve inside it whose occupied voxels (grown by
a margin) give the box.
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import Camera
from .carve import carve
from ..geometry.grid import VoxelGrid

__all__ = ["axes_meeting_point", "estimate_bounds"]


def axes_meeting_point(cameras: list[Camera]) -> np.ndarray:
    """(3,) least-squares point nearest to all optical axes, metres.

    For orthographic cameras the "axis" is the line through the image centre
    along the viewing direction.
    """
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.forward
        centre_px = np.array([(cam.width - 1) / 2.0, (cam.height - 1) / 2.0])
        origin = _point_on_axis(cam, centre_px)
        proj = np.eye(3) - np.outer(d, d)
        A += proj
        b += proj @ origin
    if np.linalg.matrix_rank(A, tol=1e-9) < 3:
        raise ValueError(
            "cannot estimate a bounding box: the optical axes are parallel; give bounds explicitly")
    return np.linalg.solve(A, b)


def _point_on_axis(cam: Camera, pixel: np.ndarray) -> np.ndarray:
    """A world point that projects to ``pixel`` (depth 0 for orthographic cameras)."""
    K = cam.K
    y = (pixel[1] - K[1, 2]) / K[1, 1]
    x = (pixel[0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    if cam.orthographic:
        local = np.array([x, y, 0.0])
    else:
        local = np.array([x, y, 1.0])
    return cam.R.T @ (local - cam.t)


def _visible_half_size(cam: Camera, centre: np.ndarray) -> float:
    """Half the larger image side, back-projected to the depth of ``centre``, metres."""
    half_px = 0.5 * max(cam.width, cam.height)
    if cam.orthographic:
        return half_px / min(cam.K[0, 0], cam.K[1, 1])
    depth = float(cam.depth(centre[None])[0])
    if depth <= 0:
        raise ValueError("cannot estimate a bounding box: a camera looks away from the object")
    return half_px * depth / min(cam.K[0, 0], cam.K[1, 1])


def estimate_bounds(cameras: list[Camera], masks: list[np.ndarray], *,
                    resolution: int = 48, margin_voxels: float = 2.0) -> np.ndarray:
    """(2, 3) bounding box ``[min, max]`` of the object seen in ``masks``, metres.

    Carves a ``resolution``^3 grid over the region all cameras can see around
    :func:`axes_meeting_point`, keeping only voxels inside the image in at
    least half the views, and grows the occupied box by ``margin_voxels``
    coarse voxels. Raises ``ValueError`` if nothing survives.
    """
    centre = axes_meeting_point(cameras)
    half = max(_visible_half_size(cam, centre) for cam in cameras)
    grid = VoxelGrid(centre - half, centre + half, 2 * half / resolution)
    occupancy = carve(grid, cameras, masks, outside_image="keep")
    ijk = np.argwhere(occupancy)
    if len(ijk) == 0:
        raise ValueError("cannot estimate a bounding box: the silhouettes have no common volume")
    points = grid.index_to_world(ijk)
    in_frame = np.zeros(len(points), dtype=np.int32)
    for cam in cameras:
        uv = cam.project(points)
        with np.errstate(invalid="ignore"):
            inside = ((uv[:, 0] > -0.5) & (uv[:, 0] < cam.width - 0.5)
                      & (uv[:, 1] > -0.5) & (uv[:, 1] < cam.height - 0.5))
        in_frame += inside
    points = points[2 * in_frame >= len(cameras)]
    if len(points) == 0:
        raise ValueError("cannot estimate a bounding box: the object is out of frame in most views")
    pad = (0.5 + margin_voxels) * grid.voxel_size
    return np.stack([points.min(axis=0) - pad, points.max(axis=0) + pad])
