"""Synthetic renderer: exact silhouettes and shaded, noisy images of triangle meshes.

Rasterisation is *2-D homogeneous* (Olano & Greer 1997): every vertex is taken
to homogeneous pixel coordinates ``h = P @ (X, 1)`` with the camera's (3, 4)
projection matrix, and a pixel centre ``p = (u, v, 1)`` is covered by triangle
``(a, b, c)`` when the three edge functions ``p . (h_b x h_c)``,
``p . (h_c x h_a)``, ``p . (h_a x h_b)`` all share the sign of
``det(h_a, h_b, h_c)``. For a pinhole camera that is exactly "the ray through
``p`` meets the triangle *in front of* the camera", so triangles partly or wholly
behind the camera need no clipping and are never drawn mirrored; for the
orthographic camera (``w = 1``) it is the usual 2-D edge test. The normalised
edge functions are the perspective-correct barycentric coordinates of the
visible point, used for the z-buffer and for interpolation.

Coverage is evaluated at pixel centres (pixel ``(r, c)`` <-> ``(u = c, v = r)``).
Each edge function is computed from its two vertices in a fixed (index) order,
so triangles sharing an edge evaluate it identically, and a pixel centre lying
exactly on an edge or a vertex is resolved as if it were moved by an
infinitesimal ``(eps, eps^2)``: it belongs to exactly one of the triangles
around it. (Column tests in :mod:`.metrics` rely on this to count crossings.)
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .geometry.camera import Camera
from .geometry.lens import render_through_lens

__all__ = ["rasterize_depth", "rasterize_faces", "rasterize_silhouette", "render_image",
           "solid_colors"]


def as_mesh_arrays(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert a triangle mesh.

    Returns ``vertices`` (n, 3) float64 and ``faces`` (m, 3) int64, both C-contiguous.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must be an (n, 3) array, got shape {vertices.shape}")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("vertices contain NaN or infinity")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be an (m, 3) array of vertex indices, got shape {faces.shape}")
    if faces.size and not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must hold integer vertex indices, got dtype {faces.dtype}")
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(
            f"face indices must lie in [0, {len(vertices) - 1}], got "
            f"[{faces.min()}, {faces.max()}]")
    return vertices, faces


def homogeneous_pixels(vertices: np.ndarray, camera: Camera) -> np.ndarray:
    """(n, 3) float64 homogeneous pixel coordinates ``P @ (X, 1)`` of world points (n, 3).

    Pinhole: the third coordinate is the depth (metres). Orthographic: it is 1.
    """
    return _projected(vertices, camera)[0]


@njit(cache=True, nogil=True)
def _project_kernel(vertices, P, R, t, h, depth, uv):
    for i in range(vertices.shape[0]):
        x, y, z = vertices[i, 0], vertices[i, 1], vertices[i, 2]
        for r in range(3):
            h[i, r] = P[r, 0] * x + P[r, 1] * y + P[r, 2] * z + P[r, 3]
        depth[i] = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        if h[i, 2] > 0.0:   # (else behind a pinhole camera, or on its plane: not read)
            uv[i, 0] = h[i, 0] / h[i, 2]
            uv[i, 1] = h[i, 1] / h[i, 2]
        else:
            uv[i, 0] = uv[i, 1] = np.nan


def _projected(vertices: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """:func:`homogeneous_pixels` (n, 3), :meth:`Camera.depth` (n,) and the pixels ``(u,
    v)`` (n, 2) of ``vertices`` (meaningful where the third homogeneous coordinate is
    positive), in one compiled pass. (A matrix product here would go through BLAS, whose
    own threads fight the per-view threads that render views side by side.)"""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    h, depth, uv = np.empty((len(vertices), 3)), np.empty(len(vertices)), \
        np.empty((len(vertices), 2))
    _project_kernel(vertices, camera.projection_matrix, camera.R, camera.t, h, depth, uv)
    return h, depth, uv


#: Orientation (sign of det(h_a, h_b, h_c), :func:`face_orientation`) of the faces of an
#: outward-oriented mesh that are turned towards the camera.
FRONT_FACING = -1.0


@njit(cache=True)
def face_orientation(h, faces, f):
    """Orientation of face ``f`` in the homogeneous pixels ``h``: the sign of
    det(h_a, h_b, h_c) (+1, -1, or 0 if degenerate or NaN); :func:`triangle_edges`'s."""
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    det = (h[a, 0] * (h[b, 1] * h[c, 2] - h[b, 2] * h[c, 1])
           - h[a, 1] * (h[b, 0] * h[c, 2] - h[b, 2] * h[c, 0])
           + h[a, 2] * (h[b, 0] * h[c, 1] - h[b, 1] * h[c, 0]))
    if not (det > 0.0 or det < 0.0):  # zero (edge-on) or NaN
        return 0.0
    return 1.0 if det > 0.0 else -1.0


@njit(cache=True)
def triangle_edges(h, faces, f, coef):
    """Oriented edge functions of face ``f``; returns the orientation (+1, -1, or 0 if degenerate).

    ``coef[k] = (A, B, C, T)``: the edge opposite vertex ``k`` evaluates to
    ``e = A u + B v + C``, positive inside the triangle whatever its orientation.
    A point with ``e == 0`` (exactly on the edge) is inside iff ``T == 1``: iff
    moving it by ``(eps, eps^2)`` would make ``e`` positive.
    """
    orientation = face_orientation(h, faces, f)
    if orientation == 0.0:
        return 0.0
    for k in range(3):
        p = faces[f, (k + 1) % 3]
        q = faces[f, (k + 2) % 3]
        sign = orientation
        if p > q:  # evaluate every edge in index order so neighbours agree bit for bit
            p, q = q, p
            sign = -orientation
        A = sign * (h[p, 1] * h[q, 2] - h[p, 2] * h[q, 1])
        B = sign * (h[p, 2] * h[q, 0] - h[p, 0] * h[q, 2])
        coef[k, 0] = A
        coef[k, 1] = B
        coef[k, 2] = sign * (h[p, 0] * h[q, 1] - h[p, 1] * h[q, 0])
        coef[k, 3] = 1.0 if (A > 0.0 or (A == 0.0 and B > 0.0)) else 0.0
    return orientation


@njit(cache=True, inline="always")
def edge_tuple(coef):
    """The edge functions of :func:`triangle_edges` as a tuple ``(A0, B0, C0, T0, A1, ...,
    T2)`` (T as bool), for :func:`covered_point`: read once per face, held in registers."""
    return (coef[0, 0], coef[0, 1], coef[0, 2], coef[0, 3] > 0.0,
            coef[1, 0], coef[1, 1], coef[1, 2], coef[1, 3] > 0.0,
            coef[2, 0], coef[2, 1], coef[2, 2], coef[2, 3] > 0.0)


@njit(cache=True, inline="always")
def covered_point(edges, u, v):
    """Whether the triangle of ``edges`` (:func:`edge_tuple`) covers the point (u, v).

    Returns ``(e0, e1, e2, total)``: the edge functions there and their sum,
    ``total == 0.0`` when it is not covered (outside, on an edge that belongs to
    the neighbouring face, or degenerate). Inlined where called (numba IR).
    """
    e0 = edges[0] * u + edges[1] * v + edges[2]
    e1 = edges[4] * u + edges[5] * v + edges[6]
    e2 = edges[8] * u + edges[9] * v + edges[10]
    if e0 < 0.0 or e1 < 0.0 or e2 < 0.0:
        return e0, e1, e2, 0.0
    if (e0 == 0.0 and not edges[3]) or (e1 == 0.0 and not edges[7]) \
            or (e2 == 0.0 and not edges[11]):
        return e0, e1, e2, 0.0
    total = e0 + e1 + e2
    return e0, e1, e2, (0.0 if total <= 0.0 else total)


@njit(cache=True, inline="always")
def centre_box(umin, umax, vmin, vmax, width, height):
    """Inclusive pixel bounds (c0, c1, r0, r1) of the image's pixel centres in the box
    ``[umin, umax] x [vmin, vmax]`` (pixels); (0, -1, 0, -1) if none.

    The box only bounds the work (the edge tests decide); its margin of 1e-6 px
    dwarfs the rounding of u, v (~1e-13 px) so no centre is lost.
    """
    c0 = max(0.0, np.ceil(umin - 1e-6))
    c1 = min(width - 1.0, np.floor(umax + 1e-6))
    r0 = max(0.0, np.ceil(vmin - 1e-6))
    r1 = min(height - 1.0, np.floor(vmax + 1e-6))
    if c0 > c1 or r0 > r1:
        return 0, -1, 0, -1
    return int(c0), int(c1), int(r0), int(r1)


@njit(cache=True)
def pixel_box(h, faces, f, width, height):
    """Inclusive pixel bounds (c0, c1, r0, r1) that may hold covered centres; c0 > c1 if none."""
    w0, w1, w2 = h[faces[f, 0], 2], h[faces[f, 1], 2], h[faces[f, 2], 2]
    if w0 > 0.0 and w1 > 0.0 and w2 > 0.0:
        umin = vmin = np.inf
        umax = vmax = -np.inf
        for k in range(3):
            i = faces[f, k]
            u = h[i, 0] / h[i, 2]
            v = h[i, 1] / h[i, 2]
            umin, umax = min(umin, u), max(umax, u)
            vmin, vmax = min(vmin, v), max(vmax, v)
        return centre_box(umin, umax, vmin, vmax, width, height)
    if w0 <= 0.0 and w1 <= 0.0 and w2 <= 0.0:  # wholly behind a pinhole camera
        return 0, -1, 0, -1
    # crosses the camera plane: its image is unbounded, test the whole frame
    return 0, width - 1, 0, height - 1


@njit(cache=True, inline="always")
def projected_pixel_box(h, uv, faces, f, width, height):
    """:func:`pixel_box` of face ``f``, from its corners' pixels ``uv`` (divided out once
    per vertex: :func:`_projected`) where all three lie in front of the camera."""
    i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
    if h[i, 2] > 0.0 and h[j, 2] > 0.0 and h[k, 2] > 0.0:
        return centre_box(min(uv[i, 0], uv[j, 0], uv[k, 0]), max(uv[i, 0], uv[j, 0], uv[k, 0]),
                          min(uv[i, 1], uv[j, 1], uv[k, 1]), max(uv[i, 1], uv[j, 1], uv[k, 1]),
                          width, height)
    return pixel_box(h, faces, f, width, height)


@njit(cache=True, nogil=True)
def _rasterize_kernel(h, depth, uv, faces, face_id, bary, zbuf, front_only):
    """Z-buffer ``zbuf`` (H, W) of the faces (only those turned towards the camera when
    ``front_only``); ``face_id`` (H, W) and ``bary`` (H, W, 3) too, unless they are empty
    (0, 0) and (0, 0, 3) (the depth alone). ``h``, ``depth``, ``uv``: :func:`_projected`'s."""
    height, width = zbuf.shape
    with_ids = face_id.shape[0] > 0
    coef = np.empty((3, 4))
    for f in range(faces.shape[0]):
        # (a closed mesh's back faces first: half the faces, one determinant each; then the
        # box, which most faces of a fine mesh fail: they hold no pixel centre)
        if front_only and face_orientation(h, faces, f) != FRONT_FACING:
            continue
        c0, c1, r0, r1 = projected_pixel_box(h, uv, faces, f, width, height)
        if c0 > c1 or r0 > r1:
            continue
        if triangle_edges(h, faces, f, coef) == 0.0:
            continue
        edges = edge_tuple(coef)
        d0, d1, d2 = depth[faces[f, 0]], depth[faces[f, 1]], depth[faces[f, 2]]
        for r in range(r0, r1 + 1):
            v = float(r)
            for c in range(c0, c1 + 1):
                e0, e1, e2, total = covered_point(edges, float(c), v)
                if total == 0.0:
                    continue
                z = (e0 * d0 + e1 * d1 + e2 * d2) / total
                if z < zbuf[r, c]:
                    zbuf[r, c] = z
                    if with_ids:
                        face_id[r, c] = f
                        bary[r, c, 0] = e0 / total
                        bary[r, c, 1] = e1 / total
                        bary[r, c, 2] = e2 / total


def rasterize_faces(vertices, faces, camera: Camera):
    """Z-buffered visibility at every pixel centre.

    Parameters
    ----------
    vertices : (n, 3) float64, metres, object frame
    faces : (m, 3) int, vertex indices
    camera : Camera

    Returns
    -------
    face_index : (H, W) int64
        Index of the nearest face covering each pixel centre, -1 where none does.
    barycentric : (H, W, 3) float64
        Barycentric coordinates of the visible point in that face (3-D,
        perspective-correct); zero where ``face_index`` is -1.
    depth : (H, W) float64
        Depth of the visible point along the viewing direction, metres; +inf
        where ``face_index`` is -1.
    """
    face_id = np.full((camera.height, camera.width), -1, dtype=np.int64)
    bary = np.zeros((camera.height, camera.width, 3))
    return face_id, bary, _rasterize(vertices, faces, camera, face_id, bary, False)


def rasterize_depth(vertices, faces, camera: Camera, *, closed: bool = False) -> np.ndarray:
    """(H, W) float64 depth of the nearest face at every pixel centre, metres (+inf where
    none): the ``depth`` of :func:`rasterize_faces`, without the faces and weights.

    ``closed=True`` promises a closed, outward-oriented mesh: only the faces turned
    towards the camera are drawn, about half the work. A ray into a closed surface
    enters it through such a face, so the depths are the same, but for a pixel centre
    exactly on the outline, where the face turned away may be the one that holds it.
    """
    return _rasterize(vertices, faces, camera, np.empty((0, 0), np.int64),
                      np.empty((0, 0, 3)), bool(closed))


def depth_of_checked(vertices: np.ndarray, faces: np.ndarray, camera: Camera, *,
                     closed: bool = False) -> np.ndarray:
    """:func:`rasterize_depth` of a mesh as :func:`as_mesh_arrays` returned it: its checks
    and conversions not made again (for a mesh drawn into many views)."""
    return _rasterize(vertices, faces, camera, np.empty((0, 0), np.int64),
                      np.empty((0, 0, 3)), bool(closed), checked=True)


def _rasterize(vertices, faces, camera: Camera, face_id, bary, front_only: bool, *,
               checked: bool = False) -> np.ndarray:
    """The z-buffer of :func:`_rasterize_kernel` (filling ``face_id`` and ``bary``);
    ``checked``: the mesh is as :func:`as_mesh_arrays` returns it."""
    if not checked:
        vertices, faces = as_mesh_arrays(vertices, faces)
    zbuf = np.full((camera.height, camera.width), np.inf)
    if len(faces):
        _rasterize_kernel(*_projected(vertices, camera), faces, face_id, bary, zbuf,
                          front_only)
    return zbuf


def rasterize_silhouette(vertices, faces, camera: Camera) -> np.ndarray:
    """(H, W) bool mask: True where a pixel centre sees the mesh.

    Exact coverage at pixel centres for both camera models; pinhole triangles
    behind the camera contribute only their part in front of it. A camera with
    lens distortion sees the mask its lens forms (the ideal one resampled,
    nearest pixel: :func:`~sfs_ros.core.geometry.lens.render_through_lens`).

    Parameters
    ----------
    vertices : (n, 3) float64, metres, object frame
    faces : (m, 3) int, vertex indices
    camera : Camera
    """
    return render_through_lens(camera, lambda ideal: rasterize_faces(vertices, faces, ideal)[0]
                               >= 0, nearest=True)


@njit(cache=True)
def _corner_normals_kernel(faces, face_normals, incident, start, cos_crease, out):
    for f in range(faces.shape[0]):
        nf = face_normals[f]
        for k in range(3):
            i = faces[f, k]
            s0 = s1 = s2 = 0.0
            for j in range(start[i], start[i + 1]):
                ng = face_normals[incident[j]]
                if ng[0] * nf[0] + ng[1] * nf[1] + ng[2] * nf[2] >= cos_crease:
                    s0 += ng[0]
                    s1 += ng[1]
                    s2 += ng[2]
            length = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            if length > 0.0:
                out[f, k, 0] = s0 / length
                out[f, k, 1] = s1 / length
                out[f, k, 2] = s2 / length


def corner_normals(vertices: np.ndarray, faces: np.ndarray, *, crease_deg: float = 45.0) -> np.ndarray:
    """(m, 3, 3) unit shading normal at each corner of each face.

    Mean of the unit normals of the faces around the corner's vertex, counting
    only faces within ``crease_deg`` of this face: curved surfaces shade smoothly,
    sharp edges (a cylinder's rim) stay sharp. Zero for degenerate faces.
    """
    tri = vertices[faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(face_n, axis=1, keepdims=True)
    face_n = np.divide(face_n, length, out=np.zeros_like(face_n), where=length > 0)
    flat = faces.ravel()
    incident = np.argsort(flat, kind="stable") // 3       # faces around each vertex, grouped
    start = np.concatenate([[0], np.cumsum(np.bincount(flat, minlength=len(vertices)))])
    out = np.zeros((len(faces), 3, 3))
    _corner_normals_kernel(faces, face_n, incident, start, np.cos(np.radians(crease_deg)), out)
    return out


@njit(cache=True, nogil=True)
def _shade_kernel(face_id, bary, faces, normals, colors, pixel_rgb, light, ambient, background,
                  image):
    """``normals`` (m, 3, 3) per face corner, ``colors`` (n, 3) per vertex, or ``pixel_rgb``
    (H, W, 3) per pixel unless it is empty (0, 0, 3)."""
    height, width = face_id.shape
    for r in range(height):
        for c in range(width):
            f = face_id[r, c]
            if f < 0:
                for ch in range(3):
                    image[r, c, ch] = background[ch]
                continue
            n0 = n1 = n2 = 0.0
            rgb0 = rgb1 = rgb2 = 0.0
            for k in range(3):
                i = faces[f, k]
                w = bary[r, c, k]
                n0 += w * normals[f, k, 0]
                n1 += w * normals[f, k, 1]
                n2 += w * normals[f, k, 2]
                rgb0 += w * colors[i, 0]
                rgb1 += w * colors[i, 1]
                rgb2 += w * colors[i, 2]
            if pixel_rgb.shape[0]:
                rgb0, rgb1, rgb2 = pixel_rgb[r, c, 0], pixel_rgb[r, c, 1], pixel_rgb[r, c, 2]
            length = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            lit = (n0 * light[0] + n1 * light[1] + n2 * light[2]) / length if length > 0 else 0.0
            shade = ambient + (1.0 - ambient) * max(lit, 0.0)
            image[r, c, 0] = rgb0 * shade
            image[r, c, 1] = rgb1 * shade
            image[r, c, 2] = rgb2 * shade


def _rgb(value, name: str) -> np.ndarray:
    rgb = np.asarray(value, dtype=np.float64).reshape(-1)
    if rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 255)):
        raise ValueError(f"{name} must be 3 values in [0, 255], got {value!r}")
    return rgb


def solid_colors(vertices, faces, color_of_points):
    """A ``pixel_colors`` for :func:`render_image` that paints each pixel with
    ``color_of_points(points)``: (k, 3) RGB in [0, 255] of the surface points (k, 3) the
    pixels see, metres, in the mesh's frame (a solid texture, as fine as the pixels)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)

    def pixel_colors(face_index, barycentric):
        corners = vertices[faces[face_index]]                         # (k, 3 corners, 3)
        return color_of_points(np.einsum("kc,kcd->kd", barycentric, corners))
    return pixel_colors


def _shading_inputs(vertices, faces, camera: Camera, *, vertex_colors, background_rgb,
                    color_rgb, light_dir, ambient, noise_sigma, normals) -> tuple:
    """:func:`render_image`'s options checked: ``(background (3,), vertex colours (n, 3)
    float64, unit light direction (3,), corner normals (m, 3, 3))``."""
    background = _rgb(background_rgb, "background_rgb")
    if vertex_colors is None:
        colors = np.tile(_rgb(color_rgb, "color_rgb"), (len(vertices), 1))
    else:
        colors = np.asarray(vertex_colors, dtype=np.float64)
        if colors.shape != vertices.shape or not np.all((colors >= 0) & (colors <= 255)):
            raise ValueError(
                f"vertex_colors must be ({len(vertices)}, 3) values in [0, 255], "
                f"got shape {colors.shape}")
    if not 0.0 <= float(ambient) <= 1.0:
        raise ValueError(f"ambient must be in [0, 1], got {ambient}")
    if not (np.isfinite(noise_sigma) and noise_sigma >= 0):
        raise ValueError(f"noise_sigma must be a finite value >= 0, got {noise_sigma}")
    if light_dir is None:
        light = camera.R.T @ np.array([-0.4, -0.6, -1.0])  # camera frame: left, up, backwards
    else:
        light = np.asarray(light_dir, dtype=np.float64).reshape(-1)
        if light.shape != (3,) or not np.all(np.isfinite(light)) or not np.any(light):
            raise ValueError(f"light_dir must be a finite non-zero 3-vector, got {light_dir!r}")
    light = light / np.linalg.norm(light)

    if normals is None:
        normals = corner_normals(vertices, faces)
    elif np.shape(normals) != (len(faces), 3, 3):
        raise ValueError(f"normals must be ({len(faces)}, 3, 3) corner normals, one per face "
                         f"corner, got shape {np.shape(normals)}")
    normals = np.asarray(normals, dtype=np.float64)
    return background, colors, light, normals


def render_image(vertices, faces, camera: Camera, *, vertex_colors=None,
                 background_rgb=(255, 255, 255), color_rgb=(170, 120, 70), light_dir=None,
                 ambient: float = 0.25, noise_sigma: float = 2.0, seed=None,
                 normals=None, pixel_colors=None) -> np.ndarray:
    """Render a z-buffered, Lambert-shaded, noisy RGB image of a mesh on a plain background.

    Shading is per pixel from interpolated corner normals (:func:`corner_normals`):
    ``colour * (ambient + (1 - ambient) * max(0, n . light))``. ``ambient=1``
    renders the unshaded colours (albedo), e.g. to check colour reconstruction.
    A camera with lens distortion gives the image its lens forms (rendered
    ideally, resampled: :func:`~sfs_ros.core.geometry.lens.render_through_lens`;
    the noise is added after).

    Parameters
    ----------
    vertices : (n, 3) float64, metres, object frame
    faces : (m, 3) int, vertex indices, counter-clockwise seen from outside
    camera : Camera
    vertex_colors : (n, 3) uint8 or float in [0, 255], optional
        Per-vertex RGB, interpolated across faces; default ``color_rgb`` everywhere.
    background_rgb, color_rgb : 3 values in [0, 255]
    light_dir : (3,) float, optional
        Direction *towards* the light in the object frame. Default: from the
        camera, up and to the left (so the visible side is lit, its rim darker).
    ambient : float in [0, 1]
    noise_sigma : float >= 0
        Standard deviation of additive Gaussian noise, grey levels, on every pixel.
    seed : int or numpy Generator, optional
        Seed of the noise.
    normals : (m, 3, 3) float64, optional
        The mesh's :func:`corner_normals`, computed when not given (pass them when
        rendering one mesh from several cameras).
    pixel_colors : callable, optional
        ``pixel_colors(face_index, barycentric)`` -> (k, 3) float in [0, 255]: the colour
        of the visible point of each of k pixels, given its face (k,) int64 and its
        barycentric coordinates in it (k, 3); replaces ``vertex_colors`` (a procedural
        pattern finer than the faces, or a texture).

    Returns
    -------
    (H, W, 3) uint8 RGB image.
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    background, colors, light, normals = _shading_inputs(
        vertices, faces, camera, vertex_colors=vertex_colors, background_rgb=background_rgb,
        color_rgb=color_rgb, light_dir=light_dir, ambient=ambient, noise_sigma=noise_sigma,
        normals=normals)

    def shade(ideal: Camera) -> np.ndarray:
        face_id, bary, _ = rasterize_faces(vertices, faces, ideal)
        image = np.empty((ideal.height, ideal.width, 3), dtype=np.float32)
        per_pixel = np.zeros((0, 0, 3))
        if pixel_colors is not None:
            seen = face_id >= 0
            per_pixel = np.zeros((ideal.height, ideal.width, 3))
            per_pixel[seen] = pixel_colors(face_id[seen], bary[seen])
        _shade_kernel(face_id, bary, faces, normals, np.ascontiguousarray(colors), per_pixel,
                      light, float(ambient), background, image)
        return image

    image = render_through_lens(camera, shade)
    if noise_sigma > 0:
        rng = np.random.default_rng(seed)
        image += float(noise_sigma) * rng.standard_normal(image.shape, dtype=np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
