"""From a carved hull to a checked, coloured mesh: cloud of points, advancing front,
edge swaps, marching cubes, the signed distance to the hull (sub-voxel surface), mesh
checks and vertex colour.

Names are imported on first use (:mod:`..lazy_exports`)."""

from ..lazy_exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    ".advancing_front": ("AdvancingFrontResult", "advancing_front", "estimate_normals"),
    ".cloud": ("CloudOfPoints", "cloud_of_points", "surface_voxels"),
    ".colour": ("VertexColours", "vertex_colours", "vertex_normals"),
    ".edge_swap": ("swap_edges",),
    ".hull_distance": ("HullDistance",),
    ".marching": ("hull_marching_cubes_mesh", "marching_cubes_mesh"),
    ".mesh_checks": ("MeshReport", "check_mesh"),
})
