"""Simulated captures written as image files with their cameras, reconstructed from
those files as a user's folder would be (the default parameters, no box given), and the
mesh scored against the captures' exact silhouettes."""

import cv2

from sfs_ros.core.exchange.views import View, ViewSet
from sfs_ros.core.metrics import reprojection_ious
from sfs_ros.core.pipeline import reconstruct


def reconstruct_written(captures, folder):
    """Write each capture's RGB ``image`` as ``folder / name`` (PNG) and reconstruct the
    folder's views with their ``camera``s; returns the :class:`Reconstruction`."""
    views = []
    for c in captures:
        cv2.imwrite(str(folder / c.name), cv2.cvtColor(c.image, cv2.COLOR_RGB2BGR))
        views.append(View(c.name, folder / c.name, c.camera))
    return reconstruct(ViewSet(views=views, source="session"))


def exact_ious(result, captures):
    """(n,) IoU of the reconstruction's mesh, drawn into each capture's camera, with the
    capture's exact ``object_mask``."""
    return reprojection_ious(result.vertices, result.faces, [c.camera for c in captures],
                             [c.object_mask for c in captures])
