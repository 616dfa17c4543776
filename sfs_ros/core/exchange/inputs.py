"""One entry point for every input format: :func:`load_views`."""

from __future__ import annotations

from pathlib import Path

from .colmap import CAMERAS_FILE, IMAGES_FILE, read_colmap
from .middlebury import read_middlebury
from .nerf import read_transforms
from .session import SESSION_FILE, VIEWS_FILE, read_session
from .views import ViewError, ViewSet

__all__ = ["ACCEPTED_INPUTS", "load_views"]

ACCEPTED_INPUTS = (f"a scan session folder (with {SESSION_FILE}), "
                   "a Middlebury *_par.txt file (or a folder holding one), "
                   "a NeRF transforms*.json file (or a folder holding one), "
                   f"or a COLMAP text model folder ({CAMERAS_FILE} + {IMAGES_FILE})")


def _one(found: list[Path], what: str, folder: Path) -> Path:
    if len(found) > 1:
        raise ViewError(f"{folder} holds several {what} files ({', '.join(p.name for p in found)}); "
                        "pass the one to use")
    return found[0]


def load_views(path: Path | str) -> ViewSet:
    """Load the views at ``path``, recognising the format from what the path is.

    * a folder with ``session.yaml`` or ``views.csv`` (or ``session.yaml``
      itself): a scan session;
    * a ``*_par.txt`` file, or a folder holding exactly one: Middlebury;
    * a ``*.json`` file, or a folder holding ``transforms*.json`` (with
      several, ``transforms.json`` is taken): NeRF / instant-ngp;
    * a folder holding ``cameras.txt`` and ``images.txt`` (or one of those
      files): COLMAP's text model.

    Raises
    ------
    ViewError
        A path that is none of these (the message lists the accepted inputs),
        or the error of the format's reader.
    """
    path = Path(path)
    if not path.exists():
        raise ViewError(f"input {path} does not exist; expected {ACCEPTED_INPUTS}")
    if path.is_file():
        if path.name == SESSION_FILE:
            return read_session(path.parent)
        if path.name.endswith("_par.txt"):
            return read_middlebury(path)
        if path.suffix.lower() == ".json":
            return read_transforms(path)
        if path.name in (CAMERAS_FILE, IMAGES_FILE):
            return read_colmap(path.parent)
    elif (path / SESSION_FILE).is_file() or (path / VIEWS_FILE).is_file():
        return read_session(path)  # without session.yaml: says that it is missing
    elif (path / CAMERAS_FILE).is_file() or (path / IMAGES_FILE).is_file():
        return read_colmap(path)  # with only one of them: says which is missing
    else:
        pars = sorted(path.glob("*_par.txt"))
        if pars:
            return read_middlebury(_one(pars, "*_par.txt", path))
        transforms = sorted(path.glob("transforms*.json"))
        if (path / "transforms.json").is_file():
            return read_transforms(path / "transforms.json")
        if transforms:
            return read_transforms(_one(transforms, "transforms*.json", path))
    raise ViewError(f"input {path} is not a recognised input; expected {ACCEPTED_INPUTS}")
