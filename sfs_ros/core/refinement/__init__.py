"""Below the visual hull: the photo-consistent refinement of a carved hull from the views'
colours (:mod:`.photo`), a stage above carving and meshing (it carves inside the hull and
meshes a coarse hull to see it)."""

from .photo import RefinedDistance, RefineParams, refine_hull
from .scan import refine_carved_scan, refine_views

__all__ = ["RefineParams", "RefinedDistance", "refine_carved_scan", "refine_hull",
           "refine_views"]
