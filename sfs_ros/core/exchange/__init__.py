"""Files in and out: views with their cameras (session folders, Middlebury, NeRF), meshes
(PLY, OBJ, STL, GLB) and camera poses for other tools (COLMAP, NeRF)."""

from .export import SUPPORTED_SUFFIXES, export_mesh, load_mesh
from .inputs import ACCEPTED_INPUTS, load_views
from .middlebury import read_middlebury
from .nerf import read_transforms
from .pose_export import export_session, write_colmap, write_nerf_transforms
from .session import append_view, read_session, write_session
from .views import View, ViewError, ViewSet, read_image

__all__ = ["ACCEPTED_INPUTS", "SUPPORTED_SUFFIXES", "View", "ViewError", "ViewSet",
           "append_view", "export_mesh", "export_session", "load_mesh", "load_views",
           "read_image", "read_middlebury", "read_session", "read_transforms", "write_colmap",
           "write_nerf_transforms", "write_session"]
