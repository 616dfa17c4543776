"""Shape from silhouette: voxel carving, the carving box, view consistency and specks."""

from .bounds import axes_meeting_point, estimate_bounds, refine_bounds
from .carve import OUTSIDE_IMAGE, Carver, PreparedMasks, carve, validate_masks, view_coefficients
from .consistency import bbox_clips_object, hull_silhouettes
from .fusion import Fusion, ViewVerdict, fuse_silhouettes
from .hull import drop_specks

__all__ = ["OUTSIDE_IMAGE", "Carver", "Fusion", "PreparedMasks", "ViewVerdict",
           "axes_meeting_point", "bbox_clips_object", "carve", "drop_specks", "estimate_bounds",
           "fuse_silhouettes", "hull_silhouettes", "refine_bounds",
           "validate_masks", "view_coefficients"]
