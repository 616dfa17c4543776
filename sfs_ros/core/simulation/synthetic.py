"""A simulated scan: a known object rendered from a plan of viewpoints.

Like the real cell, the carriage and turntable do not stop exactly where the
plan says: each view is rendered at the planned angles plus a positioning
error and tagged with those *actual* angles (what the encoders read).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..carving.carve import carve
from ..carving.hull import drop_specks
from ..geometry.grid import VoxelGrid
from ..geometry.rig import RigCalibration, rig_camera, rotation_z
from ..meshing.marching import marching_cubes_mesh
from ..metrics import (
    chamfer_distance,
    mesh_occupancy,
    occupancy_from_contains,
    reprojection_ious,
    volume_iou,
)
from ..render import corner_normals, rasterize_silhouette, render_image, solid_colors
from .objects import SyntheticObject

__all__ = ["Capture", "carving_box", "exact_silhouettes", "simulate_scan", "score_against_truth",
           "distance_to_mesh", "held_out_colour_error", "surface_errors", "true_visual_hull"]


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


#: Direction towards the light fixed in the lab for textured scans (lab frame: from above,
#: in front of the object and to the side of the C-arm's plane).
LAB_LIGHT = (0.5, -0.6, 0.8)


def simulate_scan(obj: SyntheticObject, calibration: RigCalibration, plan: np.ndarray, *,
                  angle_error_rad: float = 0.003, noise_sigma: float = 2.0,
                  background_rgb=(255, 255, 255), seed: int = 0, surface_color=None,
                  ambient: float = 0.25, textured: bool = False) -> list[Capture]:
    """Render ``obj`` from every ``(theta_rad, phi_rad)`` row of ``plan`` (n, 2).

    ``angle_error_rad`` is the standard deviation of the positioning error of
    each axis; phi stays within [-pi/2, pi/2]. ``surface_color`` (optional):
    a function of points (k, 3), metres, to their RGB (k, 3) in [0, 255], drawn at
    every pixel (e.g. :func:`.objects.fine_color_at`) instead of ``obj``'s smooth
    pattern at the vertices; ``ambient`` as :func:`~sfs_ros.core.render.render_image`'s
    (1: unshaded). ``textured``: the object's solid texture
    (:meth:`SyntheticObject.texture_at`, unless ``surface_color`` is given) under a
    light fixed in the lab (:data:`LAB_LIGHT`), so the shading of a point changes as
    the object turns; else the light is beside each camera.
    """
    plan = np.asarray(plan, dtype=np.float64).reshape(-1, 2)
    rng = np.random.default_rng(seed)
    vertices, faces = obj.mesh.vertices, obj.mesh.faces
    colors = obj.color_at(vertices)
    surface = obj.texture_at if textured and surface_color is None else surface_color
    pixel_colors = None if surface is None else solid_colors(vertices, faces, surface)
    normals = corner_normals(vertices, faces)
    captures = []
    for n, (theta, phi) in enumerate(plan):
        actual_theta = float(theta + rng.normal(0.0, angle_error_rad))
        actual_phi = float(np.clip(phi + rng.normal(0.0, angle_error_rad), -np.pi / 2, np.pi / 2))
        camera = rig_camera(actual_theta, actual_phi, calibration)
        # The turntable turns the object by theta in the lab: the lab's light, in the
        # object frame, turns by -theta.
        light = rotation_z(actual_theta).T @ np.asarray(LAB_LIGHT) if textured else None
        image = render_image(vertices, faces, camera, vertex_colors=colors,
                             background_rgb=background_rgb, noise_sigma=noise_sigma,
                             seed=int(rng.integers(2**31)), ambient=ambient, normals=normals,
                             light_dir=light, pixel_colors=pixel_colors)
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


def held_out_colour_error(obj: SyntheticObject, captures, calibration: RigCalibration,
                          vertices: np.ndarray, faces: np.ndarray, *, erode_px: int = 2,
                          **colouring) -> float:
    """Mean absolute colour error (grey levels) of a coloured mesh drawn unshaded into
    ``captures`` (views the reconstruction did not use, taken with ``calibration``) against
    their images, over the pixels both the mesh and the true ``obj`` cover, eroded by
    ``erode_px`` (the outline's pixels mix object and backdrop). ``colouring``: the mesh's
    colours as :func:`~sfs_ros.core.render.render_image` takes them (``vertex_colors`` or
    ``pixel_colors``)."""
    size = 2 * int(erode_px) + 1
    errors = []
    for capture in captures:
        camera = rig_camera(capture.theta_rad, capture.phi_rad, calibration)
        drawn = render_image(vertices, faces, camera, ambient=1.0, noise_sigma=0.0, **colouring)
        both = (rasterize_silhouette(vertices, faces, camera)
                & rasterize_silhouette(obj.mesh.vertices, obj.mesh.faces, camera))
        both = cv2.erode(both.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)
        errors.append(np.abs(drawn.astype(float) - capture.image)[both].mean())
    return float(np.mean(errors))


def _closest_on_triangles(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(n, k) distances, metres, of points (n, 3) to triangles (n, k, 3 corners, 3):
    the closest point on each triangle (Ericson's regions, vectorised)."""
    p = points[:, None, :]
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    ab, ac = b - a, c - a
    normal = np.cross(ab, ac)
    # The closest point of the plane, if it falls inside the triangle, else of an edge.
    n2 = np.maximum(np.einsum("nkd,nkd->nk", normal, normal), 1e-300)
    plane = p - (np.einsum("nkd,nkd->nk", p - a, normal) / n2)[..., None] * normal
    inside = np.ones(plane.shape[:2], dtype=bool)
    for start, end in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("nkd,nkd->nk", np.cross(end - start, plane - start), normal) >= 0
    best = np.where(inside, np.linalg.norm(p - plane, axis=-1), np.inf)
    for start, end in ((a, b), (b, c), (c, a)):
        edge = end - start
        t = np.clip(np.einsum("nkd,nkd->nk", p - start, edge)
                    / np.maximum(np.einsum("nkd,nkd->nk", edge, edge), 1e-300), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - start - t[..., None] * edge, axis=-1))
    return best


def distance_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, *,
                     candidates: int = 24) -> np.ndarray:
    """(n,) distance, metres, of points (n, 3) to a triangle mesh: the nearest of the
    ``candidates`` faces whose centroids are nearest each point. Exact for meshes of
    small, well-shaped triangles (marching cubes'), where the nearest face is among them."""
    tri = np.asarray(vertices)[np.asarray(faces)]
    _, near = cKDTree(tri.mean(axis=1)).query(points, k=min(candidates, len(tri)))
    out = np.empty(len(points))
    for start in range(0, len(points), 4096):
        part = np.atleast_2d(near[start:start + 4096])
        out[start:start + 4096] = _closest_on_triangles(points[start:start + 4096],
                                                        tri[part]).min(axis=1)
    return out


def surface_errors(obj: SyntheticObject, vertices: np.ndarray, faces: np.ndarray, *,
                   n_samples: int = 20000, seed: int = 0) -> dict:
    """Accuracy and completeness of a mesh against the true surface of ``obj``, metres, as
    in the DTU and Middlebury multi-view stereo evaluations.

    Accuracy: distance from ``n_samples`` points on the mesh to the true surface
    (``|obj.signed_distance|``, exact outside the object and for one-part objects).
    Completeness: distance from ``n_samples`` points on the true surface to the mesh
    (:func:`distance_to_mesh`). Each as its mean and 90th percentile.
    """
    on_mesh = trimesh.Trimesh(vertices, faces, process=False).sample(n_samples, seed=seed)
    accuracy = np.abs(obj.signed_distance(on_mesh))
    completeness = distance_to_mesh(obj.sample_surface(n_samples, seed=seed), vertices, faces)
    return {"accuracy_mean_m": float(accuracy.mean()),
            "accuracy_p90_m": float(np.percentile(accuracy, 90)),
            "completeness_mean_m": float(completeness.mean()),
            "completeness_p90_m": float(np.percentile(completeness, 90))}
