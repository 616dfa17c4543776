"""The cell's recordings as an input format: a rosbag2 written by ``sfs-recorder``.

Importing this module adds :data:`ROSBAG2` to the core's table of input formats
(:data:`sfs_ros.core.exchange.inputs.INPUT_FORMATS`), so that
:func:`sfs_ros.core.exchange.inputs.load_views` reads a bag like any other input: the
command-line tools import it; a notebook imports it before reading a bag. The core
cannot name it itself: reading a bag replays it through the cell's live reconstruction
(:func:`sfs_ros.cell_logic.bag.read_bag`), a floor above the core. The reader, and the
``rosbags`` package it needs, are imported only when a bag is read.
"""

from __future__ import annotations

from pathlib import Path

from ..core.exchange.inputs import INPUT_FORMATS, InputFormat
from ..core.exchange.views import ViewError, ViewSet

__all__ = ["BAG_SUFFIXES", "ROSBAG2"]

#: Storage file suffixes of a rosbag2 (MCAP, sqlite3).
BAG_SUFFIXES = (".mcap", ".db3")


def _bag(path: Path) -> Path | None:
    """``path`` if it is a rosbag2: a storage file, or a folder with ``metadata.yaml`` or
    a storage file."""
    if path.is_file():
        return path if path.suffix.lower() in BAG_SUFFIXES else None
    is_bag = ((path / "metadata.yaml").is_file()
              or any(p.suffix.lower() in BAG_SUFFIXES for p in path.iterdir()))
    return path if is_bag else None


def _read_bag(path: Path, *, captures: bool = False) -> ViewSet:
    try:
        from .bag import read_bag
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] != "rosbags":
            raise
        raise ViewError(f"input {path} is a rosbag2: reading it needs the rosbags package "
                        "(pip install rosbags)") from None
    return read_bag(path, captures=captures)


def _read_bag_captures(path: Path) -> ViewSet:
    return _read_bag(path, captures=True)


#: A bag: its masks as the carving node carved them (``captures``: its captured images),
#: its recorded resolution and mesher (:attr:`ViewSet.recorded_settings`).
ROSBAG2 = InputFormat("rosbag2", "a rosbag2 recorded by sfs-recorder (folder, .mcap or .db3)",
                      _bag, _read_bag, _read_bag_captures)

INPUT_FORMATS.setdefault(ROSBAG2.name, ROSBAG2)
