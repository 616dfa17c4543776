"""A simulated scan: a known object rendered from a plan of viewpoints.

Like the real cell, the carriage and turntable do not stop exactly where the
plan says: each view is rendered at the planned angles plus a positioning
error and tagged with those *actual* angles (what the encoders read).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..carving.carve import carve
from ..carving.hull import drop_specks
from ..geometry.grid import VoxelGrid
from ..geometry.rig import RigCalibration, rig_camera
from ..meshing.marching import marching_cubes_mesh
from ..metrics import (
    chamfer_distance,
    mesh_occupancy,
    occupancy_from_contains,
    reprojection_ious,
    volume_iou,
)
from ..render import rasterize_silhouette, render_image
from .objects import SyntheticObject

__all__ = ["Capture", "carving_box", "exact_silhouettes", "simulate_scan", "score_against_truth",
           "true_visual_hull"]


@dataclass(frozen=True)
class Capture:
    """One simulated shot: ``image`` (H, W, 3) uint8 RGB taken at the encoder
    angles ``theta_rad``, ``phi_rad`` (the plan asked for ``planned_rad``)."""

    name: str
    image: np.ndarray
    theta_rad: float
    phi_rad: float
    planned_rad: tuple[float, float]


def carving_box(obj: SyntheticObject, *, margin_m: float = 0.01) -> np.ndarray:
    """(2, 3) carving box: ``obj``'s box grown by ``margin_m``, its floor on the plate.

    Every view looks from above the plate, so nothing below it can be carved:
    the plate (z = 0) is the floor of the box, as in the real cell.
    """
    lo = obj.bounds[0] - margin_m
    lo[2] = 0.0
    return np.stack([lo, obj.bounds[1] + margin_m])


def simulate_scan(obj: SyntheticObject, calibration: RigCalibration, plan: np.ndarray, *,
                  angle_error_rad: float = 0.003, noise_sigma: float = 2.0,
                  background_rgb=(255, 255, 255), seed: int = 0, surface_color=None,
                  ambient: float = 0.25) -> list[Capture]:
    """Render ``obj`` from every ``(theta_rad, phi_rad)`` row of ``plan`` (n, 2).

    ``angle_error_rad`` is the standard deviation of the positioning error of
    each axis; phi stays within [-pi/2, pi/2]. ``surface_color`` (optional):
    a function of points (k, 3), metres, to their RGB (k, 3) in [0, 255], drawn at
    every pixel (e.g. :func:`.objects.fine_color_at`) instead of ``obj``'s smooth
    pattern at the vertices; ``ambient`` as :func:`~sfs_ros.core.render.render_image`'s
    (1: unshaded).
    """
    plan = np.asarray(plan, dtype=np.float64).reshape(-1, 2)
    rng = np.random.default_rng(seed)
    vertices, faces = obj.mesh.vertices, obj.mesh.faces
    colors = obj.color_at(vertices)
    pixel_colors = None
    if surface_color is not None:
        def pixel_colors(face_index, barycentric):
            corners = vertices[faces[face_index]]                 # (k, 3 corners, 3)
            return surface_color(np.einsum("kc,kcd->kd", barycentric, corners))
    captures = []
    for n, (theta, phi) in enumerate(plan):
        actual_theta = float(theta + rng.normal(0.0, angle_error_rad))
        actual_phi = float(np.clip(phi + rng.normal(0.0, angle_error_rad), -np.pi / 2, np.pi / 2))
        camera = rig_camera(actual_theta, actual_phi, calibration)
        image = render_image(vertices, faces, camera, vertex_colors=colors,
                             background_rgb=background_rgb, noise_sigma=noise_sigma,
                             seed=int(rng.integers(2**31)), ambient=ambient,
                             pixel_colors=pixel_colors)
        captures.append(Capture(name=f"view_{n:03d}.png", image=image, theta_rad=actual_theta,
                                phi_rad=actual_phi, planned_rad=(float(theta), float(phi))))
    return captures


def exact_silhouettes(obj: SyntheticObject, cameras) -> list[np.ndarray]:
    """The renderer's exact silhouette of ``obj`` in each camera: (H, W) bool each."""
    return [rasterize_silhouette(obj.mesh.vertices, obj.mesh.faces, c) for c in cameras]


def true_visual_hull(cameras, silhouettes, grid: VoxelGrid, *,
                     refine: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The best any shape from silhouette can do from ``cameras``: the hull carved from
    the exact ``silhouettes`` (:func:`exact_silhouettes`) on a grid ``refine`` times
    finer than ``grid`` over its box (at most 512 voxels along its longest side), meshed.

    Returns vertices (n, 3) float64, metres, and faces (m, 3) int64.
    """
    n = min(512, int(refine) * max(grid.shape))
    fine = VoxelGrid.cube(grid.bounds_min, grid.bounds_max, n)
    occupancy, _ = drop_specks(carve(fine, list(cameras), silhouettes))
    return marching_cubes_mesh(occupancy, fine)


def score_against_truth(obj: SyntheticObject, vertices: np.ndarray, faces: np.ndarray,
                        grid, *, cameras=None, n_samples: int = 20000, seed: int = 0) -> dict:
    """Accuracy of a closed mesh against the truth ``obj``, which the reconstruction never saw.

    Volume IoU is evaluated at the centres of ``grid``; Chamfer distances
    (metres) between ``n_samples`` points on each surface. With ``cameras``
    (the views of the scan) also, per view, the IoU of the mesh's silhouette
    with the renderer's exact silhouette of ``obj``, and the Chamfer distance
    to the true visual hull (:func:`true_visual_hull`): what the views allow,
    separating the reconstruction's own error from the views' limit.
    """
    truth = occupancy_from_contains(obj.contains, grid)
    iou = volume_iou(mesh_occupancy(vertices, faces, grid), truth)
    mesh_points = trimesh.Trimesh(vertices, faces, process=False).sample(n_samples, seed=seed)
    chamfer = chamfer_distance(mesh_points, obj.sample_surface(n_samples, seed=seed))
    score = {"volume_iou": float(iou), "chamfer_mean_m": chamfer.mean,
             "hausdorff_m": chamfer.hausdorff, "true_volume_m3": obj.volume_m3}
    if cameras is not None:
        cameras = list(cameras)
        exact = exact_silhouettes(obj, cameras)
        ious = reprojection_ious(vertices, faces, cameras, exact)
        hull_v, hull_f = true_visual_hull(cameras, exact, grid)
        hull_points = trimesh.Trimesh(hull_v, hull_f, process=False).sample(n_samples,
                                                                            seed=seed)
        to_hull = chamfer_distance(mesh_points, hull_points)
        score.update({"exact_silhouette_iou": {"per_view": [float(x) for x in ious],
                                               "mean": float(np.mean(ious)),
                                               "min": float(np.min(ious))},
                      "chamfer_to_true_hull_m": to_hull.mean,
                      "hausdorff_to_true_hull_m": to_hull.hausdorff})
    return score
