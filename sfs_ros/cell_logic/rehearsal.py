"""A small live scan, received and reconstructed to make a process ready for real ones.

The first reconstruction in a process pays for loading what it uses: its
compiled kernels from numba's disk cache, the code pages of OpenCV, SciPy and
scikit-image, the worker threads. In the cell's nodes that reconstruct, that would add
to the latency from the last view to the mesh (``doc/changelog.md``, 4 December, evening).
:func:`rehearse` does it once beforehand, on a scan of 25 views of 160 x 120
at 48^3: every stage of :meth:`~sfs_ros.cell_logic.live_reconstruction.LiveReconstruction.reconstruct`
(carving, fusion, meshing, colour, evaluation, the files and pictures) on
arrays of the types a real scan has. It has more views than the colour takes
(:data:`~sfs_ros.core.meshing.colour.MAX_COLOUR_VIEWS`), so the evaluation draws
the others, as in a real scan, and so loads the evaluation's kernels too.
``sfs-warm-up`` runs it too, where it compiles the live path's kernels.
"""

from __future__ import annotations

from pathlib import Path

from ..core.geometry.rig import RigCalibration, rig_camera
from ..core.render import rasterize_silhouette
from ..core.simulation.objects import make_object
from ..core.simulation.plan import ring_plan
from ..core.simulation.synthetic import carving_box
from .live_reconstruction import LiveReconstruction, mask_to_rgb

__all__ = ["REHEARSAL_RIG", "REHEARSAL_PLAN", "REHEARSAL_RESOLUTION", "rehearse"]

#: A small camera: the kernels are loaded for the array types, not for the sizes.
REHEARSAL_RIG = RigCalibration(width=160, height=120, projection="pinhole", fx=350.0, fy=350.0,
                               camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
#: (theta, phi) of the 25 views, radians: two rings of 12 and one from above.
REHEARSAL_PLAN = ring_plan([20.0, 50.0], 12, top_view=True)
REHEARSAL_RESOLUTION = 48


def rehearse(folder, views=None) -> dict:
    """Receive a scan of the mug view by view in ``folder`` and reconstruct it.

    Parameters
    ----------
    folder : path-like
        An empty folder for the scan's session folder, mesh and pictures.
    views : sequence of (mask (H, W) bool, rgb (H, W, 3) uint8) or None
        One per row of :data:`REHEARSAL_PLAN`, of :data:`REHEARSAL_RIG`'s size;
        None: the mug's exact silhouettes, each also as its image.

    Returns
    -------
    dict
        The summary of :meth:`LiveReconstruction.reconstruct`.
    """
    mug = make_object("mug")
    if views is None:
        views = []
        for theta, phi in REHEARSAL_PLAN:
            mask = rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces,
                                        rig_camera(theta, phi, REHEARSAL_RIG))
            views.append((mask, mask_to_rgb(mask)))
    if len(views) != len(REHEARSAL_PLAN):
        raise ValueError(f"a rehearsal takes {len(REHEARSAL_PLAN)} views, got {len(views)}")
    live = LiveReconstruction(REHEARSAL_RIG, carving_box(mug), output_dir=Path(folder),
                              resolution=REHEARSAL_RESOLUTION)
    for n, ((mask, rgb), (theta, phi)) in enumerate(zip(views, REHEARSAL_PLAN)):
        live.add_view(n, mask, theta, phi)
        live.add_colour_image(n, rgb)
    summary = live.reconstruct(pictures=False)      # as the node does: the mesh, then
    live.write_pictures()                           # the pictures
    return summary
