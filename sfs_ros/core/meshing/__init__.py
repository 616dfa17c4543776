"""From a carved hull to a checked, coloured mesh: cloud of points, advancing front,
edge swaps, marching cubes, mesh checks and vertex colour."""

from .advancing_front import AdvancingFrontResult, advancing_front, estimate_normals
from .cloud import CloudOfPoints, cloud_of_points, surface_voxels
from .colour import VertexColours, vertex_colours, vertex_normals
from .edge_swap import swap_edges
from .marching import marching_cubes_mesh
from .mesh_checks import MeshReport, check_mesh

__all__ = ["AdvancingFrontResult", "CloudOfPoints", "MeshReport", "VertexColours",
           "advancing_front", "check_mesh", "cloud_of_points", "estimate_normals",
           "marching_cubes_mesh", "surface_voxels", "swap_edges", "vertex_colours",
           "vertex_normals"]
