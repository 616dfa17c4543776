"""A photo-real texture atlas for a reconstructed mesh, from its calibrated views.

:func:`texture_mesh` (mesh, images, cameras -> :class:`TexturedMesh`); view selection per
face (:mod:`.selection`), the atlas (:mod:`.atlas`), levelling along the seams
(:mod:`.levelling`); :func:`texture_reconstruction` textures a pipeline's result from
its views, :func:`texture_from_views` any mesh in the views' object frame.
"""

from .from_views import texture_from_views, texture_reconstruction
from .textured import TexturedMesh, texture_mesh

__all__ = ["TexturedMesh", "texture_from_views", "texture_mesh", "texture_reconstruction"]
