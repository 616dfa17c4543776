"""What the mock camera sees: the scene on the plate and the cell it is seen through.

The mock hardware renders a scene (a known object, or the ChArUco calibration
board standing on the plate) through a *world* rig made from the cell as built
(the mock hardware's own ``world_rig`` parameters, whatever rig the rest of the
cell believes in): ``"perfect"`` is that rig as given, ``"wrong"`` adds the errors of
:func:`~sfs_ros.core.simulation.calibration_scene.wrong_world` (a tilted,
off-centre turntable axis, a barrel lens, other intrinsics, radius and camera
mounting, and the axes' true zeros away from the nominal ones). The camera
renders at the controller's true (commanded) position through the world rig,
so a zero error is an encoder zero a calibration must find, and the scan node
still sees its moves arrive; the controller's ``encoder_offset_deg`` adds a
small read-back offset on top.
"""

from __future__ import annotations

from sfs_ros.core.calibration.board import BoardSpec
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.simulation.calibration_scene import BoardPicture, wrong_world
from sfs_ros.core.simulation.objects import OBJECT_NAMES, SyntheticObject, make_object

__all__ = ["BOARD", "MOCK_BOARD", "SCENES", "WORLDS", "mock_scene", "world_rig"]

#: The scene name of the calibration board.
BOARD = "board"
#: The mock's board: 9 x 7 squares of 30 mm (markers 22 mm, DICT_5X5_100), 270 x 210 mm,
#: about the 640 x 480 camera's field at 0.6 m, so its corners reach the image's corners
#: (``sfs-calibrate --board 9x7``).
MOCK_BOARD = BoardSpec(9, 7, square_m=0.03, marker_m=0.022, dictionary="DICT_5X5_100")
#: Scenes the mock camera can render.
SCENES = (*OBJECT_NAMES, BOARD)
#: Worlds the mock camera can see.
WORLDS = ("perfect", "wrong")


def mock_scene(name: str, *, background_rgb=(255, 255, 255)) -> SyntheticObject | BoardPicture:
    """The scene ``name`` (one of :data:`SCENES`); the board on the grey of ``background_rgb``."""
    if name == BOARD:
        return BoardPicture(MOCK_BOARD, backdrop=round(sum(background_rgb) / 3))
    if name not in OBJECT_NAMES:
        raise ValueError(f"unknown mock scene {name!r}; expected one of {SCENES}")
    return make_object(name)


def world_rig(built: RigCalibration, world: str) -> RigCalibration:
    """The rig the mock camera renders through, given the cell as ``built``.

    Raises ``ValueError`` for an unknown world, or ``"wrong"`` with a rig it cannot
    spoil (not pinhole, not ``physical``, or not ideal already).
    """
    if world == "perfect":
        return built
    if world == "wrong":
        return wrong_world(built)
    raise ValueError(f"unknown mock world {world!r}; expected one of {WORLDS}")
