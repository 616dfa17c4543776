"""Atomic file writes: a reader sees the old file or the new one, never a part of one.

Each file is written to a temporary beside it (same folder, so the rename stays
on one file system), flushed and fsynced, then renamed over the final name
with ``os.replace``. On any failure, KeyboardInterrupt and SystemExit included,
the temporaries not yet renamed are removed and the old files stay as they were.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["FILE_MODE", "write_atomic", "write_atomic_all"]

#: Permissions of written files (mkstemp would leave them owner-only).
FILE_MODE = 0o644


def write_atomic(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (its folder must exist); returns the path."""
    return write_atomic_all([(path, data)])[0]


def write_atomic_all(files) -> list[Path]:
    """Write several files, each atomically, renaming them only once all are on disk.

    Parameters
    ----------
    files : iterable of (path-like, bytes-like)
        Destinations (their folders must exist) and contents. They are renamed
        into place in this order, so a reader that finds the last one new finds
        the earlier ones new too.

    Returns
    -------
    list of Path
        The written paths, in order.
    """
    files = [(Path(path), data) for path, data in files]
    staged: list[tuple[str, Path]] = []
    try:
        for path, data in files:
            staged.append((_stage(path, data), path))
        while staged:
            os.replace(*staged[0])
            staged.pop(0)
    finally:
        for tmp, _ in staged:       # (one may be renamed already if interrupted just then)
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
    return [path for path, _ in files]


def _stage(path: Path, data) -> str:
    """Write ``data`` to a new temporary file beside ``path``; returns its name."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, FILE_MODE)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
    except BaseException:
        os.unlink(tmp)
        raise
    return tmp
