"""Below the visual hull: the photo-consistent refinement of a carved hull from the views'
colours (:mod:`.photo`), a stage above carving and meshing (it carves inside the hull and
meshes a coarse hull to see it)."""

from .photo import RefinedDistance, refine_hull

__all__ = ["RefinedDistance", "refine_hull"]
