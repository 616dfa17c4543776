"""Files in and out: views with their cameras (session folders, Middlebury, NeRF), meshes
(PLY, OBJ, STL, GLB) and camera poses for other tools (COLMAP, NeRF).

Names are imported on first use (:mod:`..lazy_exports`)."""

from ..lazy_exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    ".export": ("SUPPORTED_SUFFIXES", "export_mesh", "load_mesh"),
    ".inputs": ("ACCEPTED_INPUTS", "load_views"),
    ".middlebury": ("read_middlebury",),
    ".nerf": ("read_transforms",),
    ".pose_export": ("export_session", "write_colmap", "write_nerf_transforms"),
    ".session": ("append_view", "read_session", "write_session"),
    ".views": ("View", "ViewError", "ViewSet", "read_image"),
})
