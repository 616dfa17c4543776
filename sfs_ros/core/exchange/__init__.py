"""Files in and out: views with their cameras (the input formats of :data:`INPUT_FORMATS`),
meshes (the file formats of :data:`MESH_FORMATS`) and camera poses for other tools (COLMAP,
NeRF)."""

from .export import MESH_FORMATS, SUPPORTED_SUFFIXES, export_mesh, load_mesh
from .inputs import INPUT_FORMATS, accepted_inputs, load_views
from .middlebury import read_middlebury
from .nerf import read_transforms
from .pose_export import export_session, write_colmap, write_nerf_transforms
from .session import append_view, read_session, write_session
from .views import View, ViewError, ViewSet, read_image

__all__ = ["INPUT_FORMATS", "MESH_FORMATS", "SUPPORTED_SUFFIXES", "View", "ViewError",
           "ViewSet", "accepted_inputs", "append_view", "export_mesh", "export_session",
           "load_mesh", "load_views", "read_image", "read_middlebury", "read_session",
           "read_transforms", "write_colmap", "write_nerf_transforms", "write_session"]
