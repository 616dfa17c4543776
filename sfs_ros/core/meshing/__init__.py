"""From a carved hull to a checked, coloured mesh: cloud of points, advancing front,
edge swaps, marching cubes, the signed distance to the hull (sub-voxel surface), mesh
checks and vertex colour."""

from .advancing_front import AdvancingFrontResult, advancing_front, estimate_normals
from .cloud import CloudOfPoints, cloud_of_points, surface_voxels
from .colour import VertexColours, vertex_colours, vertex_normals
from .edge_swap import swap_edges
from .hull_distance import HullDistance
from .marching import hull_marching_cubes_mesh, marching_cubes_mesh
from .mesh_checks import MeshReport, check_mesh

__all__ = ["AdvancingFrontResult", "CloudOfPoints", "HullDistance", "MeshReport",
           "VertexColours", "advancing_front", "check_mesh", "cloud_of_points",
           "estimate_normals", "hull_marching_cubes_mesh", "marching_cubes_mesh",
           "surface_voxels", "swap_edges", "vertex_colours", "vertex_normals"]
