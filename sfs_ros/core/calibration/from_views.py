"""Calibrate from a loaded scan session of board photographs (:class:`ViewSet`)."""

from __future__ import annotations

from ..exchange.views import ViewSet, read_image
from .board import BoardSpec, detect_board
from .solver import RigFit, calibrate_rig

__all__ = ["calibrate_views"]


def calibrate_views(views: ViewSet, board: BoardSpec, *, min_corners: int = 8,
                    **options) -> RigFit:
    """Detect ``board`` in every view and calibrate the rig (:func:`calibrate_rig`).

    Parameters
    ----------
    views : ViewSet
        A session with encoder angles; its calibration is the nominal rig.
    board : BoardSpec
    min_corners : int, keyword-only
        A view with fewer board corners is rejected.
    **options
        Keyword options of :func:`calibrate_rig`.

    Raises
    ------
    ValueError
        Views without encoder angles, a board found in no image, or what
        :func:`calibrate_rig` raises.
    """
    if views.calibration is None or any(v.theta_rad is None for v in views.views):
        raise ValueError("calibration needs a session with encoder angles "
                         "(views.csv columns image,theta_rad,phi_rad)")
    rig = views.calibration
    rejected = list(views.rejected)
    detections = []
    for view in views.views:
        image = read_image(view.image_path, expected_size=(rig.width, rig.height))
        found, reason = detect_board(image, board, min_corners=min_corners)
        if found is None:
            rejected.append((view.name, reason))
        else:
            detections.append((view.name, view.theta_rad, view.phi_rad, found))
    if not detections:
        name, reason = rejected[len(views.rejected)]
        raise ValueError(f"the board ({board.squares_x}x{board.squares_y} squares, "
                         f"{board.dictionary}) was found in none of the {len(views.views)} "
                         f"images (first: {name}: {reason}); check the board definition")
    return calibrate_rig(detections, board, rig, rejected=rejected, **options)
