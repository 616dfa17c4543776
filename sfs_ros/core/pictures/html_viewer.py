"""A self-contained HTML viewer of a mesh: one file that any browser opens, no network.

The page embeds the mesh (base64 of little-endian float32 vertices, uint32 faces
and optional uint8 RGB colours; for a textured mesh also float32 texture coordinates
and the atlas as a PNG, which WebGL draws and the 2-D canvas replaces by the
vertices' colours) and a short script that draws it with WebGL or,
where WebGL is unavailable (no GPU and no software WebGL, or WebGL disabled),
on a 2-D canvas with the painter's algorithm (triangles sorted back to front,
flat shaded; slow on a large mesh, see ``doc/benchmarks.md``). The
renderer used is shown in the corner and set as ``data-renderer`` ("WebGL" or
"Canvas 2D") on the page's ``body``.

Drag orbits the camera about the vertical (Z) axis of the object frame, which
stays up on screen; the wheel zooms; double-click, R or the button resets the
view. Shading is two-sided: ``colour * (AMBIENT + (1 - AMBIENT) |n . l|)`` with
``n`` the surface normal and ``l`` the unit vector from the orbit centre to the
eye (a headlight). The perspective camera (vertical field of view ``FOV_RAD``)
orbits the centre of the mesh's bounding box at the distance where the bounding
sphere about that centre spans ``FIT`` of the window's smaller side.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from importlib.resources import files
from pathlib import Path
from string import Template

import numpy as np
from PIL import Image

from ..exchange.files import write_atomic
from ..render import as_mesh_arrays

__all__ = ["FOV_RAD", "FIT", "HOME_AZIMUTH_RAD", "HOME_ELEVATION_RAD", "AMBIENT", "BACKGROUND_RGB",
           "DEFAULT_RGB", "html_viewer", "write_html_viewer"]

FOV_RAD = math.pi / 6          #: vertical field of view of the perspective camera
FIT = 0.8                      #: bounding sphere diameter / smaller side of the window
#: Home view: the camera's azimuth about Z from +X and elevation above the XY plane;
#: from the front (-Y, so +X points right) turned 0.5 rad towards +X, a little above.
HOME_AZIMUTH_RAD, HOME_ELEVATION_RAD = -math.pi / 2 + 0.5, 0.35
AMBIENT = 0.3                  #: shade of a face seen edge-on, relative to one facing the eye
BACKGROUND_RGB = (245, 245, 245)
DEFAULT_RGB = (170, 120, 70)   #: colour of a mesh without vertex colours

#: The page (``string.Template``: $title, $background, $counts, $data, $script) and its
#: script, package data beside this module.
_PAGE = Template((files(__package__) / "viewer.html").read_text(encoding="utf-8"))
_SCRIPT = (files(__package__) / "viewer.js").read_text(encoding="utf-8")


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


def _png_b64(texture) -> str:
    """Base64 of ``texture`` (H, W, 3) uint8 RGB as PNG; ValueError for another array."""
    texture = np.asarray(texture)
    if texture.ndim != 3 or texture.shape[2] != 3 or texture.dtype != np.uint8:
        raise ValueError(f"texture must be (H, W, 3) uint8 RGB, got {texture.dtype} "
                         f"{texture.shape}")
    out = io.BytesIO()
    Image.fromarray(texture).save(out, format="PNG")
    return base64.b64encode(out.getvalue()).decode("ascii")


def html_viewer(vertices, faces, *, vertex_colors=None, title: str = "sfs_ros mesh",
                uv=None, texture=None) -> str:
    """The HTML text of a self-contained page that shows a triangle mesh (module docstring).

    Parameters
    ----------
    vertices : (n, 3) float, metres, object frame (Z up); embedded as float32
    faces : (m, 3) int, vertex indices; embedded as uint32
    vertex_colors : (n, 3) uint8 RGB, optional
        Per-vertex colour, interpolated across faces (WebGL) or averaged per
        face (2-D canvas); default a uniform tan.
    title : str
        Page title, also shown in the corner of the page.
    uv, texture : (n, 2) float in [0, 1] (v up) and (H, W, 3) uint8 RGB, optional
        Texture coordinates and atlas, drawn by WebGL instead of ``vertex_colors`` (which
        the 2-D canvas keeps); both or neither.

    The page is about ``16 n + 16 m`` bytes (base64 of 12 bytes per vertex and
    per face, 4 more per coloured vertex).
    """
    vertices, faces = as_mesh_arrays(vertices, faces)
    if len(vertices) == 0 or len(faces) == 0:
        raise ValueError("cannot view an empty mesh: vertices and faces must be non-empty")
    if len(vertices) >= 2 ** 32:
        raise ValueError(f"too many vertices for uint32 faces: {len(vertices)}")
    colors = None if vertex_colors is None else np.asarray(vertex_colors)
    if colors is not None and (colors.shape != vertices.shape or colors.dtype != np.uint8):
        raise ValueError(f"vertex_colors must be ({len(vertices)}, 3) uint8 RGB, got shape "
                         f"{colors.shape} dtype {colors.dtype}")
    if (uv is None) != (texture is None):
        raise ValueError("a texture needs both uv and texture")
    if uv is not None and np.shape(uv) != (len(vertices), 2):
        raise ValueError(f"uv must be ({len(vertices)}, 2), got shape {np.shape(uv)}")
    center = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    data = {"center": center.tolist(),  # the bounding sphere, metres: orbit centre and framing
            "radius": max(float(np.linalg.norm(vertices - center, axis=1).max()), 1e-9),
            "vertices": _b64(vertices.astype("<f4")), "faces": _b64(faces.astype("<u4")),
            "colors": None if colors is None else _b64(colors),
            "uv": None if uv is None else _b64(np.asarray(uv, dtype="<f4")),
            "texture": None if texture is None else _png_b64(texture),
            "fov_rad": FOV_RAD, "fit": FIT, "azimuth_rad": HOME_AZIMUTH_RAD,
            "elevation_rad": HOME_ELEVATION_RAD, "ambient": AMBIENT,
            "background": BACKGROUND_RGB, "color": DEFAULT_RGB}
    counts = f"{len(vertices):,} vertices, {len(faces):,} faces"
    return _PAGE.substitute(title=html.escape(str(title)), counts=counts,
                            background=BACKGROUND_RGB,
                            data=json.dumps(data).replace("<", "\\u003c"), script=_SCRIPT)


def write_html_viewer(path, vertices, faces, **kw) -> Path:
    """Write :func:`html_viewer` ``(vertices, faces, **kw)`` to ``path`` atomically; returns the path."""
    path = Path(path)
    write_atomic(path, html_viewer(vertices, faces, **kw).encode("utf-8"))
    return path
