"""Write triangle meshes for 3-D tools (.ply, .obj, .stl, .glb) and read them back.

Axes and units
--------------
Our object frame is right-handed, Z up (the turntable axis), in metres.
Each format is written in the axes its importers expect:

* ``.ply`` (binary) and ``.stl`` (binary): Z up, as written (Blender's PLY
  and STL importers assume Z up).
* ``.glb`` (binary glTF 2.0): Y up by specification, so ``(x, y, z)`` is
  written as ``(x, z, -y)``; a rotation of -90 degrees about X, which keeps the
  frame right-handed and the faces counter-clockwise seen from outside.
* ``.obj``: conventionally Y up (Blender's default OBJ import settings are
  forward -Z, up Y), converted the same way as glTF.

``units`` scales the metres we hold: ``"m"`` writes metres, ``"mm"``
millimetres. glTF is metres by specification, so ``.glb`` only takes ``"m"``.

Vertex colours (uint8 RGB/RGBA or float in [0, 1]) are kept by .ply
(``red green blue alpha`` uchar vertex properties), .glb (``COLOR_0``, RGBA) and
.obj (RGB only, as ``v x y z r g b`` with r, g, b in [0, 1], the extension
Blender's and MeshLab's OBJ importers read); binary STL cannot hold them, so
asking for colours in an .stl is an error rather than a silent loss.

A textured mesh (:class:`~sfs_ros.core.texture.TexturedMesh`) is written by
:func:`textured_mesh_files` / :func:`export_textured_mesh` as a binary glTF whose
material's ``baseColorTexture`` is the atlas (PNG inside the .glb), or as an OBJ with
``vt`` texture coordinates, an MTL beside it (``map_Kd``, diffuse colour 1) and the atlas
as ``<stem>.png``; same axes and units as above.

Files are written atomically: to a temporary file in the same folder, then
renamed, so a crash never leaves a partial file under the final name.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .files import write_atomic, write_atomic_all

__all__ = ["MESH_FORMATS", "SUPPORTED_SUFFIXES", "TEXTURED_SUFFIXES", "MeshFormat", "export_mesh",
           "export_textured_mesh", "load_mesh", "mesh_bytes", "textured_mesh_files"]

#: Metres -> file units.
UNIT_SCALE = {"m": 1.0, "mm": 1000.0}


@dataclass(frozen=True)
class MeshFormat:
    """One mesh file format, by its suffix.

    suffix : str, lower case with its dot.
    name : str, the format's name in messages and the docs.
    description : str, one sentence for the docs.
    encode : (vertices (n, 3) float64 in the file's units and axes, faces (m, 3) int,
        colours (n, 3|4) uint8 or None) -> bytes.
    y_up : bool, stored Y up (``(x, y, z)`` written as ``(x, z, -y)``), else Z up.
    vertex_colours : bool, holds vertex colours.
    units : the units it may be written in (:data:`UNIT_SCALE`' keys).
    textured : optional (textured mesh, path, vertices (k, 3) in the file's units and
        axes) -> [(path, bytes)]: the files of a textured mesh; None: no texture.
    file_type : str, trimesh's name of the format (to read it back).
    soup : bool, stores a triangle soup: its identical vertices are merged when read back.
    """

    suffix: str
    name: str
    description: str
    encode: Callable[[np.ndarray, np.ndarray, np.ndarray | None], bytes]
    file_type: str
    y_up: bool = False
    vertex_colours: bool = True
    units: tuple[str, ...] = tuple(UNIT_SCALE)
    textured: Callable | None = None
    soup: bool = False


def export_mesh(vertices, faces, path, *, vertex_colors=None, units: str = "m") -> Path:
    """Write a triangle mesh, choosing the format from the file suffix.

    Parameters
    ----------
    vertices : (n, 3) float64
        Metres, object frame (Z up).
    faces : (m, 3) int
        Vertex indices, counter-clockwise seen from outside.
    path : str or os.PathLike
        Destination ending in a suffix of :data:`MESH_FORMATS` (any case); its folder
        must exist.
    vertex_colors : (n, 3) or (n, 4) uint8, or float in [0, 1], optional
        RGB(A) per vertex; ValueError for .stl, which cannot store them.
    units : {"m", "mm"}, keyword-only
        Length unit written to the file ("m" only for .glb).

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    return write_atomic(path, mesh_bytes(vertices, faces, path, vertex_colors=vertex_colors,
                                         units=units))


def mesh_bytes(vertices, faces, path, *, vertex_colors=None, units: str = "m") -> bytes:
    """The bytes :func:`export_mesh` writes to ``path`` (format from its suffix; nothing is
    written), for callers that place the file themselves; same parameters and errors."""
    fmt = _format(Path(path))
    _check_units(fmt, units)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError(f"vertices must be an (n, 3) array with n >= 1, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices must be finite")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(
            f"faces must be an (m, 3) integer array with m >= 1, got {f.dtype} {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"face indices must lie in [0, {len(v)}), got [{f.min()}, {f.max()}]")
    colors = None
    if vertex_colors is not None:
        if not fmt.vertex_colours:
            holders = [s for s, other in MESH_FORMATS.items() if other.vertex_colours]
            raise ValueError(f"{fmt.name} cannot store vertex colours; pass vertex_colors=None "
                             f"or write {', '.join(holders[:-1])} or {holders[-1]}")
        colors = _colors_uint8(vertex_colors, len(v))
    return fmt.encode(_file_axes(fmt, v * UNIT_SCALE[units]), f, colors)


def load_mesh(path, *, units: str = "m", with_colors: bool = False):
    """Read a mesh written by :func:`export_mesh`, back in our frame.

    Undoes the Y-up conversion of .glb/.obj and the unit scale. STL stores
    a triangle soup, so its bit-identical vertices are merged; other formats
    keep the file's vertices and order.

    Parameters
    ----------
    path : str or os.PathLike
        A file of one of :data:`MESH_FORMATS`.
    units : {"m", "mm"}, keyword-only
        Length unit of the file.
    with_colors : bool, keyword-only
        Also return the vertex colours.

    Returns
    -------
    vertices : (n, 3) float64
        Metres, object frame (Z up).
    faces : (m, 3) int64
    colors : (n, 4) uint8 RGBA or None, only with ``with_colors=True``
        None when the file has no vertex colours (always for .stl); alpha is
        255 where the format stores none (.obj).
    """
    path = Path(path)
    fmt = _format(path)
    if units not in UNIT_SCALE:
        raise ValueError(f"units must be one of {sorted(UNIT_SCALE)}, got {units!r}")
    import trimesh

    mesh = trimesh.load(path, file_type=fmt.file_type, force="mesh", process=False)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    if fmt.soup:
        v, inverse = np.unique(v, axis=0, return_inverse=True)
        f = inverse.reshape(-1)[f]
    if fmt.y_up:
        v = np.column_stack((v[:, 0], -v[:, 2], v[:, 1]))
    if not with_colors:
        return v / UNIT_SCALE[units], f
    colors = (np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
              if mesh.visual.kind == "vertex" else None)
    return v / UNIT_SCALE[units], f, colors


def _format(path: Path) -> MeshFormat:
    """The format of ``path`` by its suffix (any case); ValueError naming the supported ones."""
    try:
        return MESH_FORMATS[path.suffix.lower()]
    except KeyError:
        raise ValueError(f"unsupported mesh file suffix {path.suffix!r} in {path.name!r}; "
                         f"supported: {', '.join(MESH_FORMATS)}") from None


def _check_units(fmt: MeshFormat, units: str) -> None:
    if units not in UNIT_SCALE:
        raise ValueError(f"units must be one of {sorted(UNIT_SCALE)}, got {units!r}")
    if units not in fmt.units:
        raise ValueError(f"{fmt.name} ({fmt.suffix}) is written in units "
                         f"{' or '.join(map(repr, fmt.units))} only, got {units!r}")


def _file_axes(fmt: MeshFormat, vertices: np.ndarray) -> np.ndarray:
    """(n, 3) ``vertices`` in the format's axes: as they are (Z up) or Y up."""
    if not fmt.y_up:
        return vertices
    return np.column_stack((vertices[:, 0], vertices[:, 2], -vertices[:, 1]))


def _trimesh_encoder(file_type: str) -> Callable:
    """An ``encode`` through trimesh's exporter of ``file_type``."""
    def encode(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None) -> bytes:
        import trimesh  # here, not at the top: the formats' names cost no trimesh

        mesh = trimesh.Trimesh(vertices=vertices, faces=faces.astype(np.int64),
                               vertex_colors=colors, process=False)
        data = mesh.export(file_type=file_type)
        return data.encode("utf-8") if isinstance(data, str) else data
    return encode


def _ply_bytes(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None) -> bytes:
    """Binary little-endian PLY: vertices (n, 3) as float32 ``x y z`` (with colours (n, 3|4)
    uint8, ``red green blue alpha``, alpha 255 where not given), faces (m, 3) as
    ``list uchar int vertex_indices``: the layout trimesh writes, in one numpy pass."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        fields += [(c, "u1") for c in ("red", "green", "blue", "alpha")]
    vertex = np.empty(len(vertices), dtype=fields)
    for k, axis in enumerate("xyz"):
        vertex[axis] = vertices[:, k]
    if colors is not None:
        for k, channel in enumerate(("red", "green", "blue")):
            vertex[channel] = colors[:, k]
        vertex["alpha"] = colors[:, 3] if colors.shape[1] == 4 else 255
    face = np.empty(len(faces), dtype=[("n", "u1"), ("corners", "<i4", (3,))])
    face["n"] = 3
    face["corners"] = faces
    properties = "".join(f"property {'float' if kind == '<f4' else 'uchar'} {name}\n"
                         for name, kind in fields)
    header = ("ply\nformat binary_little_endian 1.0\ncomment sfs_ros\n"
              f"element vertex {len(vertices)}\n{properties}"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\n"
              "end_header\n")
    return header.encode("ascii") + vertex.tobytes() + face.tobytes()


def _colors_uint8(colors, n: int) -> np.ndarray:
    """(n, 3|4) uint8 or float in [0, 1] -> (n, 3|4) uint8."""
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise ValueError(f"vertex_colors must be ({n}, 3) or ({n}, 4), got shape {c.shape}")
    if c.dtype == np.uint8:
        return c
    if np.issubdtype(c.dtype, np.floating):
        if not (np.all(np.isfinite(c)) and c.min() >= 0.0 and c.max() <= 1.0):
            raise ValueError("float vertex_colors must lie in [0, 1]")
        return np.round(c * 255.0).astype(np.uint8)
    raise ValueError(f"vertex_colors must be uint8 or float in [0, 1], got dtype {c.dtype}")


def _png(texture: np.ndarray) -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(texture, dtype=np.uint8)).save(out, format="PNG")
    return out.getvalue()


def _obj_text(vertices: np.ndarray, uv: np.ndarray, faces: np.ndarray, mtl: str) -> bytes:
    """OBJ with one ``vt`` per vertex (``f a/a b/b c/c``), using material ``atlas``."""
    corners = faces + 1
    lines = [f"mtllib {mtl}", *(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices),
             *(f"vt {u:.9g} {v:.9g}" for u, v in uv), "usemtl atlas",
             *(f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in corners)]
    return ("\n".join(lines) + "\n").encode("ascii")


def textured_mesh_files(textured, path, *, units: str = "m") -> list[tuple[Path, bytes]]:
    """The files (path, bytes) of a textured mesh written to ``path`` (.glb: one file; .obj:
    the OBJ, ``<stem>.mtl`` and ``<stem>.png`` beside it); nothing is written.

    ``textured`` is a :class:`~sfs_ros.core.texture.TexturedMesh` (its ``vertices`` (k, 3)
    metres, ``faces`` (m, 3), ``uv`` (k, 2) in [0, 1] v up, ``texture`` (H, W, 3) uint8);
    ``units`` as :func:`export_mesh`'s. ValueError for another suffix.
    """
    path = Path(path)
    fmt = _format(path)
    if fmt.textured is None:
        raise ValueError(f"a texture needs {' or '.join(TEXTURED_SUFFIXES)}, not "
                         f"{path.suffix!r} ({path.name}): {fmt.name} holds no texture")
    _check_units(fmt, units)
    v = _file_axes(fmt, np.asarray(textured.vertices, dtype=np.float64) * UNIT_SCALE[units])
    return fmt.textured(textured, path, v)


def _obj_textured(textured, path: Path, vertices: np.ndarray) -> list[tuple[Path, bytes]]:
    """The OBJ, ``<stem>.mtl`` (``map_Kd``, diffuse colour 1) and the atlas ``<stem>.png``."""
    mtl, png = path.with_suffix(".mtl"), path.with_suffix(".png")
    material = (f"newmtl atlas\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\n"
                f"map_Kd {png.name}\n").encode("ascii")
    return [(png, _png(textured.texture)), (mtl, material),
            (path, _obj_text(vertices, textured.uv, textured.faces, mtl.name))]


def _glb_textured(textured, path: Path, vertices: np.ndarray) -> list[tuple[Path, bytes]]:
    """One binary glTF whose material's ``baseColorTexture`` is the atlas."""
    import trimesh
    from PIL import Image
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    material = PBRMaterial(baseColorTexture=Image.fromarray(textured.texture),
                           metallicFactor=0.0, roughnessFactor=1.0, doubleSided=False)
    mesh = trimesh.Trimesh(vertices=vertices, faces=textured.faces,
                           visual=TextureVisuals(uv=textured.uv, material=material), process=False)
    return [(path, mesh.export(file_type="glb"))]


def export_textured_mesh(textured, path, *, units: str = "m") -> list[Path]:
    """Write :func:`textured_mesh_files` atomically, the mesh last; returns the paths."""
    return write_atomic_all(textured_mesh_files(textured, path, units=units))


#: The mesh file formats by suffix: what ``export_mesh``, ``sfs-reconstruct -o`` and the
#: nodes' output names accept. Adding one is its ``encode`` and one entry here.
MESH_FORMATS: dict[str, MeshFormat] = {f.suffix: f for f in (
    MeshFormat(".ply", "PLY", "Binary PLY, Z up; vertex colours as uchar red, green, blue, "
               "alpha.", _ply_bytes, "ply"),
    MeshFormat(".obj", "OBJ", "Wavefront OBJ, Y up; vertex colours as v x y z r g b; a "
               "texture as vt, an .mtl and a .png beside it.", _trimesh_encoder("obj"), "obj",
               y_up=True, textured=_obj_textured),
    MeshFormat(".stl", "STL", "Binary STL, Z up; no colours.", _trimesh_encoder("stl"), "stl",
               vertex_colours=False, soup=True),
    MeshFormat(".glb", "glTF", "Binary glTF 2.0, Y up, metres; vertex colours as COLOR_0; a "
               "texture as the material's baseColorTexture.", _trimesh_encoder("glb"), "glb",
               y_up=True, units=("m",), textured=_glb_textured),
)}
#: The suffixes of :data:`MESH_FORMATS`.
SUPPORTED_SUFFIXES = tuple(MESH_FORMATS)
#: The suffixes of the formats that carry a texture atlas.
TEXTURED_SUFFIXES = tuple(s for s, f in MESH_FORMATS.items() if f.textured is not None)
