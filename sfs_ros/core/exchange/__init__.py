"""Files in and out: views with their cameras (the input formats of :data:`INPUT_FORMATS`),
meshes (the file formats of :data:`MESH_FORMATS`) and camera poses for other tools (COLMAP,
NeRF).

Names are imported on first use (:mod:`..lazy_exports`)."""

from ..lazy_exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    ".export": ("MESH_FORMATS", "SUPPORTED_SUFFIXES", "export_mesh", "load_mesh"),
    ".inputs": ("INPUT_FORMATS", "accepted_inputs", "load_views"),
    ".middlebury": ("read_middlebury",),
    ".nerf": ("read_transforms",),
    ".pose_export": ("export_session", "write_colmap", "write_nerf_transforms"),
    ".session": ("append_view", "read_session", "write_session"),
    ".views": ("View", "ViewError", "ViewSet", "read_image"),
})
