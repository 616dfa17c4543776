"""Output files named by a request (a service call, a parameter), kept inside one folder.

A name that arrives over the network must never choose where a file is
written: :func:`confined_path` accepts only a plain relative name, with an
allowed suffix, that resolves (symbolic links followed) inside the configured
folder.
"""

from __future__ import annotations

import re
from pathlib import Path, PurePosixPath

__all__ = ["APPLIED_RIG", "MAX_NAME_BYTES", "MAX_COMPONENT_BYTES", "check_scan_name_format",
           "confined_path", "plain_file_name"]

#: Longest accepted requested name, bytes of UTF-8.
MAX_NAME_BYTES = 1024
#: Longest accepted file or folder name (POSIX NAME_MAX), bytes of UTF-8.
MAX_COMPONENT_BYTES = 255
#: The rig applied last to a running cell, relative to its output folder: written by
#: :func:`sfs_ros.ros.rig_apply.apply_rig`, given to the nodes that hold the rig by
#: ``sfs-cell`` whenever it starts one.
APPLIED_RIG = PurePosixPath("calibration/rig.yaml")
_SCAN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")


def check_scan_name_format(scan_name: str) -> None:
    """ValueError unless ``scan_name`` can name a scan folder: 1-100 letters, digits, ``_``,
    ``-`` or ``.``, not starting with ``.``, ``_`` or ``-``."""
    if not isinstance(scan_name, str) or not _SCAN_NAME.fullmatch(scan_name):
        raise ValueError(f"scan name {scan_name!r} must be 1-100 letters, digits, "
                         "'_', '-' or '.', not starting with '.', '_' or '-'")


def plain_file_name(root, requested_name: str, *, suffixes) -> Path:
    """:func:`confined_path` of a name without folders (``"part.obj"``, not ``"a/part.obj"``);
    ValueError naming what is wrong."""
    if "/" in requested_name:
        raise ValueError(f"output name {requested_name!r} has a folder; expected a file name "
                         f"such as 'part{tuple(suffixes)[0]}' (written in the output folder)")
    return confined_path(root, requested_name, suffixes=suffixes)


def _relative_parts(name: str) -> tuple[str, ...]:
    """The components of ``name``; ValueError naming the problem."""
    if not isinstance(name, str):
        raise ValueError(f"output name must be a string, got {type(name).__name__}")
    if not name.strip():
        raise ValueError("output name is empty; expected a file name such as 'scan.ply'")
    if "\x00" in name:
        raise ValueError(f"output name {name!r} contains a NUL byte")
    if any(ord(c) < 0x20 or ord(c) == 0x7F for c in name):
        raise ValueError(f"output name {name!r} contains control characters")
    try:
        size = len(name.encode("utf-8"))
    except UnicodeEncodeError:
        raise ValueError(f"output name {name!r} is not valid Unicode text") from None
    if size > MAX_NAME_BYTES:
        raise ValueError(f"output name is too long ({size} bytes, at most {MAX_NAME_BYTES})")
    if "\\" in name:
        raise ValueError(f"output name {name!r} contains '\\'; use '/' between folders")
    path = PurePosixPath(name)
    if path.is_absolute():
        raise ValueError(f"output name {name!r} is an absolute path; expected a name relative "
                         "to the output folder")
    for part in path.parts:
        if part == "..":
            raise ValueError(f"output name {name!r} contains '..'; expected a name inside the "
                             "output folder")
        if part.startswith("."):
            raise ValueError(f"output name {name!r} has a hidden component {part!r} "
                             "(starting with '.')")
        if len(part.encode("utf-8")) > MAX_COMPONENT_BYTES:
            raise ValueError(f"output name has a component of {len(part.encode('utf-8'))} "
                             f"bytes; at most {MAX_COMPONENT_BYTES}")
    return path.parts


def confined_path(root, requested_name: str, *, suffixes) -> Path:
    """Where to write ``requested_name`` inside the folder ``root``.

    Parameters
    ----------
    root : path-like
        The configured output folder; must exist.
    requested_name : str
        A relative file name, optionally with sub-folders (``"a/b.ply"``).
        Refused: empty, absolute, containing ``..``, a NUL byte, control
        characters or ``\\``, a hidden component, too long, or resolving
        (through symbolic links) outside ``root``.
    suffixes : iterable of str
        Allowed endings such as ``(".ply", ".obj")``, compared case-insensitively.

    Returns
    -------
    Path
        Absolute, symbolic links resolved, inside ``root`` resolved. Missing
        sub-folders are not created (the caller does that).

    Raises
    ------
    ValueError
        Naming what is wrong with the name (or the folder).
    """
    allowed = tuple(s.lower() for s in suffixes)
    if not allowed or not all(s.startswith(".") and len(s) > 1 for s in allowed):
        raise ValueError(f"suffixes must be non-empty endings such as '.ply', got {suffixes!r}")
    parts = _relative_parts(requested_name)
    if not parts[-1].lower().endswith(allowed) or parts[-1].lower() in allowed:
        raise ValueError(f"output name {requested_name!r} must end in one of "
                         f"{', '.join(allowed)} (after a file stem)")
    base = Path(root)
    if not base.is_dir():
        raise ValueError(f"output folder {base} does not exist or is not a folder")
    base = base.resolve(strict=True)
    target = base.joinpath(*parts).resolve(strict=False)
    if not target.is_relative_to(base) or target == base:
        raise ValueError(f"output name {requested_name!r} leads outside the output folder "
                         f"{base} (through a symbolic link)")
    if target.is_dir():
        raise ValueError(f"output name {requested_name!r} names a folder in {base}")
    return target
