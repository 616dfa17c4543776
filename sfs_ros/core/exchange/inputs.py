"""One door for every input format: :func:`load_views`, and the table it reads.

Each format in :data:`INPUT_FORMATS` is a detector and a reader: the detector looks at
a path (a file, or a folder and the names in it) and answers with the path its reader
takes, or None; the first format whose detector answers reads it. Adding a format is one
module with its reader and one entry in the table (``doc/architecture.md``,
"Extending"); ``sfs-reconstruct``'s help and ``doc/reference.md`` list what the table
holds.

Formats that live above the core join the table when their module is imported: the
cell's rosbag2 (:mod:`sfs_ros.cell_logic.bag_input`, imported by the command-line tools; in
a notebook, ``import sfs_ros.cell_logic.bag_input`` before reading a bag).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .colmap import CAMERAS_FILE, IMAGES_FILE, read_colmap
from .middlebury import read_middlebury
from .nerf import read_transforms
from .session import SESSION_FILE, VIEWS_FILE, read_session
from .views import ViewError, ViewSet

__all__ = ["INPUT_FORMATS", "InputFormat", "accepted_inputs", "input_format", "load_views"]


@dataclass(frozen=True)
class InputFormat:
    """One input format.

    name : str, the format's name (the report's ``input.source``).
    description : str, what the path is, for the help and the docs ("a ... folder").
    detect : (Path) -> Path or None: the path ``read`` takes when ``path`` is of this
        format (e.g. the one file of the format in a folder), else None; ViewError when it
        is of this format but unreadable as given (e.g. several candidate files).
    read : (Path) -> ViewSet; ViewError (one line) for a file it cannot read.
    read_captures : (Path) -> ViewSet, optional: for a format that holds masks and the
        images they came from, the images (None: ``read``).
    """

    name: str
    description: str
    detect: Callable[[Path], Path | None]
    read: Callable[[Path], ViewSet]
    read_captures: Callable[[Path], ViewSet] | None = None


def _one(found: list[Path], what: str, folder: Path) -> Path:
    if len(found) > 1:
        raise ViewError(f"{folder} holds several {what} files ({', '.join(p.name for p in found)}); "
                        "pass the one to use")
    return found[0]


def _session(path: Path) -> Path | None:
    if path.is_file():
        return path.parent if path.name == SESSION_FILE else None
    # Without session.yaml the reader says that it is missing.
    return path if (path / SESSION_FILE).is_file() or (path / VIEWS_FILE).is_file() else None


def _colmap(path: Path) -> Path | None:
    if path.is_file():
        return path.parent if path.name in (CAMERAS_FILE, IMAGES_FILE) else None
    # With only one of the two files the reader says which is missing.
    return path if (path / CAMERAS_FILE).is_file() or (path / IMAGES_FILE).is_file() else None


def _middlebury(path: Path) -> Path | None:
    if path.is_file():
        return path if path.name.endswith("_par.txt") else None
    pars = sorted(path.glob("*_par.txt"))
    return _one(pars, "*_par.txt", path) if pars else None


def _nerf(path: Path) -> Path | None:
    if path.is_file():
        return path if path.suffix.lower() == ".json" else None
    if (path / "transforms.json").is_file():
        return path / "transforms.json"
    transforms = sorted(path.glob("transforms*.json"))
    return _one(transforms, "transforms*.json", path) if transforms else None


#: The input formats, tried in order.
INPUT_FORMATS: dict[str, InputFormat] = {f.name: f for f in (
    InputFormat("session", f"a scan session folder (with {SESSION_FILE})", _session,
                read_session),
    InputFormat("colmap", f"a COLMAP text model folder ({CAMERAS_FILE} + {IMAGES_FILE})",
                _colmap, read_colmap),
    InputFormat("middlebury", "a Middlebury *_par.txt file (or a folder holding one)",
                _middlebury, read_middlebury),
    InputFormat("nerf", "a NeRF transforms*.json file (or a folder holding one)", _nerf,
                read_transforms),
)}


def accepted_inputs() -> str:
    """What :func:`load_views` reads, in words (every format of :data:`INPUT_FORMATS`)."""
    descriptions = [f.description for f in INPUT_FORMATS.values()]
    return ", ".join(descriptions[:-1]) + f", or {descriptions[-1]}"


def input_format(path: Path | str) -> tuple[InputFormat, Path]:
    """The format of ``path`` (the first of :data:`INPUT_FORMATS` whose detector answers)
    and the path its reader takes; ViewError naming the accepted inputs when none does."""
    path = Path(path)
    if not path.exists():
        raise ViewError(f"input {path} does not exist; expected {accepted_inputs()}")
    for candidate in INPUT_FORMATS.values():
        found = candidate.detect(path)
        if found is not None:
            return candidate, found
    raise ViewError(f"input {path} is not a recognised input; expected {accepted_inputs()}")


def load_views(path: Path | str, *, captures: bool = False) -> ViewSet:
    """The views at ``path``, in the format its detector recognises
    (:data:`INPUT_FORMATS`): a scan session folder (or its ``session.yaml``), a COLMAP
    text model (a folder with ``cameras.txt`` and ``images.txt``, or one of them), a
    Middlebury ``*_par.txt`` (or a folder holding exactly one), a NeRF ``*.json`` (or a
    folder with ``transforms*.json``; with several, ``transforms.json``), and the formats
    added from above the core (a rosbag2 recorded by ``sfs-recorder``).

    With ``captures``, a format holding masks and the images they came from (a bag)
    gives the images.

    Raises
    ------
    ViewError
        A path that is none of these (the message lists the accepted inputs),
        or the error of the format's reader.
    """
    found, target = input_format(path)
    read = found.read_captures if captures and found.read_captures else found.read
    return read(target)
