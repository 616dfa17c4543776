"""A hostile cell: the object rendered with what a real capture shows around it.

:func:`simulate_scan` renders the object alone on a plain backdrop. A real
cell also shows, in the same picture:

* the **turntable plate** the object stands on (a grey disc reaching the edge
  of the frame in most views);
* a **soft cast shadow** of the object on the plate (the object flattened
  along the light direction onto the plate plane, blurred);
* a **dark cloth** hanging in from one side of the backdrop, with folds;
* **specular highlights** on the object (Blinn-Phong, saturated to white) and
  **dark detail** on it (near-black dashes, like paint marks or deep shadows);
* the object **touching the frame** in some views (the principal point moved
  so that part of it falls outside the image);
* optionally a **dark sector** of the object (a third of it around the axis, facing +X,
  in a dark colour), dark on a black backdrop and next to its own cast shadow.

The exact object silhouette is kept for every view (``object_mask``): it is
the set of pixel centres whose nearest surface belongs to the object, computed
by the same z-buffered rasteriser, so segmentation can be scored exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import trimesh

from ..geometry.camera import Camera
from ..geometry.rig import RigCalibration, rig_camera
from ..render import corner_normals, rasterize_faces, rasterize_silhouette, render_image
from .objects import SyntheticObject

__all__ = ["BACKDROPS", "SceneCapture", "simulate_hostile_scan"]

#: Backdrop colours (RGB) by name.
BACKDROPS = {"black": (8, 8, 10), "white": (246, 246, 242)}

_OBJECT_RGB = (205, 160, 110)     # warm clay; 30 % of the object's own colour pattern mixed in
_PLATE_RGB = (128, 128, 134)      # matte grey turntable plate
_CLOTH_RGB = (40, 36, 44)         # dark, slightly purple cloth (folds 0.6x to 1.4x)
_PLATE_THICKNESS_M = 0.006
#: Towards the light in the camera frame: beside the camera, up and to the left.
_LIGHT_CAMERA = np.array([-0.4, -0.6, -1.0])


@dataclass(frozen=True)
class SceneCapture:
    """One view of the hostile cell.

    name : str
    image : (H, W, 3) uint8 RGB, what the camera records
    object_mask : (H, W) bool, exact silhouette of the object alone (ground truth)
    camera : Camera
    theta_rad, phi_rad : float, the angles the view was rendered at
    """

    name: str
    image: np.ndarray
    object_mask: np.ndarray
    camera: Camera
    theta_rad: float
    phi_rad: float


def _plate_mesh(obj: SyntheticObject, radius_factor: float) -> trimesh.Trimesh:
    """A disc under the object, top face at z = 0, radius ``radius_factor`` x the object's reach."""
    reach = float(np.max(np.abs(obj.bounds[:, :2])))
    plate = trimesh.creation.cylinder(radius=radius_factor * reach, height=_PLATE_THICKNESS_M,
                                      sections=256)
    plate.apply_translation((0.0, 0.0, -0.5 * _PLATE_THICKNESS_M))
    return plate


def _shifted_camera(camera: Camera, mask: np.ndarray, out_fraction: float) -> Camera:
    """``camera`` with its principal point moved so that ``out_fraction`` of the width of
    ``mask``'s bounding box falls beyond the right edge of the image."""
    cols = np.flatnonzero(mask.any(axis=0))
    if not len(cols):
        return camera
    shift = camera.width - 1 - cols[-1] + out_fraction * (cols[-1] - cols[0] + 1)
    K = camera.K.copy()
    K[0, 2] += shift
    return Camera(K=K, R=camera.R, t=camera.t, width=camera.width, height=camera.height,
                  orthographic=camera.orthographic)


def _cloth(height: int, width: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A dark cloth hanging in from the left or right edge.

    Returns its coverage (H, W) bool and its colour (H, W, 3) float32: the base
    colour modulated by vertical folds (0.6x to 1.4x) and a fine weave.
    """
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    reach = width * rng.uniform(0.15, 0.3)
    edge = reach * (1.0 + 0.25 * np.sin(2 * np.pi * yy / (0.7 * height) + rng.uniform(0, 6.3)))
    from_left = rng.random() < 0.5
    covered = (xx < edge) if from_left else (xx > width - 1 - edge)
    folds = 1.0 + 0.4 * np.sin(2 * np.pi * (xx + 0.3 * yy) / rng.uniform(25, 45))
    weave = rng.normal(1.0, 0.08, (height, width)).astype(np.float32)
    colour = np.asarray(_CLOTH_RGB, np.float32) * (folds * weave)[..., None]
    return covered, colour


def _surface_points_normals(vertices, faces, normals, face_id, bary, pixels):
    """Surface point (k, 3) and unit shading normal (k, 3) at the given pixels ((k,) flat indices)."""
    f = face_id.reshape(-1)[pixels]
    w = bary.reshape(-1, 3)[pixels]
    points = np.einsum("kj,kjc->kc", w, vertices[faces[f]])
    n = np.einsum("kj,kjc->kc", w, normals[f])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return points, n


def _check_options(backdrop: str, plate_radius_factor: float, out_of_frame_every: int,
                   out_fraction: float, stripe_period_m: float, dark_rgb) -> None:
    """ValueError naming the first of :func:`simulate_hostile_scan`'s options out of range."""
    if dark_rgb is not None:
        try:
            rgb = np.asarray(dark_rgb, np.float64)
        except (TypeError, ValueError):
            rgb = np.full(1, np.nan)
        if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 255)):  # NaN fails too
            raise ValueError(f"dark_rgb must be None or three values in [0, 255], got {dark_rgb!r}")
    if backdrop not in BACKDROPS:
        raise ValueError(f"backdrop must be one of {sorted(BACKDROPS)}, got {backdrop!r}")
    if not plate_radius_factor > 1:
        raise ValueError(f"plate_radius_factor must be > 1, got {plate_radius_factor}")
    if isinstance(out_of_frame_every, bool) or not isinstance(out_of_frame_every, int) \
            or out_of_frame_every < 0:
        raise ValueError(f"out_of_frame_every must be an integer >= 0, got {out_of_frame_every!r}")
    if not 0 < out_fraction < 1:
        raise ValueError(f"out_fraction must be in (0, 1), got {out_fraction}")
    if not stripe_period_m > 0:
        raise ValueError(f"stripe_period_m must be > 0, got {stripe_period_m}")


@dataclass(frozen=True)
class _Scene:
    """The object on its plate, one mesh: ``vertices`` (n, 3) metres and ``faces`` (m, 3),
    the object's first (its ``object_faces``, on ``object_vertices``), their RGB
    ``colours`` (n, 3) float64, corner ``normals`` (m, 3, 3) and the ``background`` RGB."""

    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray
    normals: np.ndarray
    object_vertices: np.ndarray
    object_faces: np.ndarray
    background: np.ndarray

    @classmethod
    def of(cls, obj: SyntheticObject, plate_radius_factor: float, backdrop: str,
           dark_rgb=None) -> _Scene:
        plate = _plate_mesh(obj, plate_radius_factor)
        obj_v, obj_f = obj.mesh.vertices, obj.mesh.faces
        vertices = np.vstack([obj_v, plate.vertices])
        faces = np.vstack([obj_f, plate.faces + len(obj_v)])
        albedo = 0.7 * np.asarray(_OBJECT_RGB, np.float64) + 0.3 * obj.color_at(obj_v)
        if dark_rgb is not None:  # the third of the object around the axis facing +X
            dark = np.cos(np.arctan2(obj_v[:, 1], obj_v[:, 0])) > 0.5
            albedo[dark] = np.asarray(dark_rgb, np.float64)
        colours = np.vstack([albedo, np.tile(np.asarray(_PLATE_RGB, np.float64),
                                             (len(plate.vertices), 1))])
        return cls(vertices, faces, colours, corner_normals(vertices, faces), obj_v, obj_f,
                   np.asarray(BACKDROPS[backdrop], np.float32))

    def render(self, camera: Camera, rng: np.random.Generator, stripe_period_m: float,
               noise_sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """What ``camera`` records, (H, W, 3) uint8 RGB, and the object's exact
        silhouette (H, W) bool; ``rng`` draws the cloth, then the noise."""
        h, w = camera.height, camera.width
        light = camera.R.T @ (_LIGHT_CAMERA / np.linalg.norm(_LIGHT_CAMERA))
        image = render_image(self.vertices, self.faces, camera, vertex_colors=self.colours,
                             background_rgb=self.background, light_dir=light, ambient=0.4,
                             noise_sigma=0.0).astype(np.float32)
        face_id, bary, _ = rasterize_faces(self.vertices, self.faces, camera)
        n_obj_faces = len(self.object_faces)
        on_object = (face_id >= 0) & (face_id < n_obj_faces)
        on_plate = face_id >= n_obj_faces
        # Soft cast shadow: darkens the plate by up to 60 %, edge blurred over ~2 % of the width.
        shadow = self.cast_shadow(camera, light)
        shadow = cv2.GaussianBlur(shadow, (0, 0), max(1.0, 0.02 * w))
        image[on_plate] *= (1.0 - 0.6 * shadow[on_plate])[:, None]
        # Cloth on the backdrop (behind object and plate).
        covered, cloth = _cloth(h, w, rng)
        behind = covered & (face_id < 0)
        image[behind] = cloth[behind]
        self.mark_object(image, camera, light, face_id, bary, on_object, stripe_period_m)
        if noise_sigma > 0:
            image += float(noise_sigma) * rng.standard_normal(image.shape, dtype=np.float32)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8), on_object

    def cast_shadow(self, camera: Camera, light: np.ndarray) -> np.ndarray:
        """(H, W) float32 in {0, 1}: the object flattened onto the plate plane along the
        light (``light``: towards it, unit, object frame)."""
        obj_v = self.object_vertices
        shadow_v = obj_v - np.outer(obj_v[:, 2] / max(light[2], 0.2), light)
        shadow_v[:, 2] = 1e-4  # just above the plate, so the plate never hides it
        return rasterize_silhouette(shadow_v, self.object_faces, camera).astype(np.float32)

    def mark_object(self, image: np.ndarray, camera: Camera, light: np.ndarray, face_id,
                    bary, on_object: np.ndarray, stripe_period_m: float) -> None:
        """Dark dashes and specular highlights drawn into ``image`` (H, W, 3) float32 on
        the object's pixels."""
        pixels = np.flatnonzero(on_object)
        points, nrm = _surface_points_normals(self.vertices, self.faces, self.normals,
                                              face_id, bary, pixels)
        azimuth = np.arctan2(points[:, 1], points[:, 0])
        stripes = (np.sin(2 * np.pi * points[:, 2] / stripe_period_m) > 0.85) \
            & (np.sin(3 * azimuth) > 0.0)  # dashes: half of each ring
        view = camera.center - points if not camera.orthographic else -camera.forward[None, :]
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        half = view + light
        half /= np.linalg.norm(half, axis=1, keepdims=True)
        specular = 300.0 * np.clip((nrm * half).sum(axis=1), 0.0, 1.0) ** 80
        flat = image.reshape(-1, 3)
        flat[pixels] = np.where(stripes[:, None], 0.1 * flat[pixels], flat[pixels])
        flat[pixels] += specular[:, None].astype(np.float32)


def simulate_hostile_scan(obj: SyntheticObject, calibration: RigCalibration, plan: np.ndarray, *,
                          backdrop: str = "black", plate_radius_factor: float = 2.5,
                          out_of_frame_every: int = 4, out_fraction: float = 0.15,
                          stripe_period_m: float = 0.02, noise_sigma: float = 2.0,
                          dark_rgb=None, seed: int = 0) -> list[SceneCapture]:
    """Render ``obj`` in a hostile cell from every ``(theta_rad, phi_rad)`` row of ``plan`` (n, 2).

    Parameters
    ----------
    obj : SyntheticObject
    calibration : RigCalibration
    plan : (n, 2) float64, radians
    backdrop : "black" or "white"
    plate_radius_factor : float > 1
        Plate radius as a multiple of the object's horizontal reach from the axis.
    out_of_frame_every : int >= 0
        Every k-th view (k > 0) has ``out_fraction`` of the object's width out
        of the frame on the right; 0 = never.
    out_fraction : float in (0, 1)
    stripe_period_m : float > 0
        Period of the dark dashes along Z on the object (rings broken into
        three arcs; about a sixth of each period is near-black).
    noise_sigma : float >= 0
        Gaussian noise, grey levels.
    dark_rgb : None or 3 values in [0, 255]
        The colour (RGB albedo) of a dark third of the object: the vertices whose
        azimuth is within 60 degrees of +X. None: no dark part.
    seed : int

    Returns
    -------
    list of SceneCapture, in plan order.
    """
    _check_options(backdrop, plate_radius_factor, out_of_frame_every, out_fraction,
                   stripe_period_m, dark_rgb)
    plan = np.asarray(plan, dtype=np.float64).reshape(-1, 2)
    rng = np.random.default_rng(seed)
    scene = _Scene.of(obj, plate_radius_factor, backdrop, dark_rgb)
    captures = []
    for n, (theta, phi) in enumerate(plan):
        camera = rig_camera(float(theta), float(phi), calibration)
        if out_of_frame_every and n % out_of_frame_every == out_of_frame_every - 1:
            camera = _shifted_camera(
                camera, rasterize_silhouette(scene.object_vertices, scene.object_faces, camera),
                out_fraction)
        image, on_object = scene.render(camera, rng, stripe_period_m, noise_sigma)
        captures.append(SceneCapture(name=f"view_{n:03d}.png", image=image,
                                     object_mask=on_object, camera=camera,
                                     theta_rad=float(theta), phi_rad=float(phi)))
    return captures
