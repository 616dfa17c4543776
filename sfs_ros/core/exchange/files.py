"""Atomic file writes: a reader sees the old file or the new one, never a part of one.

Each file is written to a temporary beside it (same folder, so the rename stays
on one file system), flushed and fsynced, then renamed over the final name
with ``os.replace``. On any failure, KeyboardInterrupt and SystemExit included,
the temporaries not yet renamed are removed and the old files stay as they were;
the error names the destination, never the temporary.

With ``within`` (a folder every path must lie in), the folders below it are
opened one by one without following symbolic links (``O_NOFOLLOW``) and the
files are created and renamed relative to those open folders: a folder swapped
for a link after the paths were checked cannot send a write elsewhere.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path

__all__ = ["FILE_MODE", "write_atomic", "write_atomic_all"]

#: Permissions of written files (mkstemp would leave them owner-only).
FILE_MODE = 0o644
#: Characters of a file's name its temporary keeps: with the 14 added, within the 255 bytes
#: of a name on common file systems whenever the name itself is.
_NAME_KEPT = 200


def write_atomic(path, data: bytes, *, within=None) -> Path:
    """Write ``data`` to ``path`` atomically (its folder must exist, unless ``within`` is
    given: see :func:`write_atomic_all`); returns the path."""
    return write_atomic_all([(path, data)], within=within)[0]


def write_atomic_all(files, *, within=None) -> list[Path]:
    """Write several files, each atomically, renaming them only once all are on disk.

    Parameters
    ----------
    files : iterable of (path-like, bytes-like or None)
        Destinations and contents. They are renamed into place in this order,
        so a reader that finds the last one new finds the earlier ones new too.
        None removes the file at that point of the order (if it is there): a
        file that describes a later one goes before it, so that it never stays
        beside a file it does not describe.
    within : path-like or None, keyword-only
        None: each destination's folder must exist. A folder: every destination
        must lie inside it; missing sub-folders are created, and no symbolic
        link below it is followed (``ValueError`` for a path outside it,
        ``OSError`` if a link is met on the way).

    Returns
    -------
    list of Path
        The written paths, in order. An OSError names the destination it was
        writing (its ``filename``), or the folder it could not open or create,
        never a temporary file.
    """
    files = [(Path(path), data) for path, data in files]
    with contextlib.ExitStack() as folders:
        fds = [_folder_fd(path, within, folders) for path, _ in files]
        staged: list[tuple[int, str | None, Path]] = []    # (folder fd, temporary, path)
        try:
            for fd, (path, data) in zip(fds, files):
                with _naming(path):
                    staged.append((fd, None if data is None else _stage(fd, path.name, data),
                                   path))
            while staged:
                fd, tmp, path = staged[0]
                with _naming(path):
                    if tmp is None:
                        with contextlib.suppress(FileNotFoundError):
                            os.unlink(path.name, dir_fd=fd)
                    else:
                        os.replace(tmp, path.name, src_dir_fd=fd, dst_dir_fd=fd)
                staged.pop(0)
        finally:
            for fd, tmp, _ in staged:   # (one may be renamed already if interrupted just then)
                if tmp is not None:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(tmp, dir_fd=fd)
    return [path for path, _ in files]


@contextlib.contextmanager
def _naming(path: Path):
    """An OSError raised inside names ``path`` (its ``filename``) instead of what it named
    (a temporary file, or a name relative to an open folder)."""
    try:
        yield
    except OSError as exc:
        if exc.errno is None:
            raise
        raise OSError(exc.errno, exc.strerror, str(path)) from None


def _folder_fd(path: Path, within, folders: contextlib.ExitStack) -> int:
    """An open descriptor of ``path``'s folder (closed with ``folders``)."""
    def opened(fd: int) -> int:
        folders.callback(os.close, fd)
        return fd

    if within is None:
        with _naming(path.parent):
            return opened(os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY))
    root = Path(within)
    try:
        parts = path.parent.relative_to(root).parts
    except ValueError:
        raise ValueError(f"{path} is not inside the output folder {root}") from None
    if ".." in parts:
        raise ValueError(f"{path} leaves the output folder {root} through '..'")
    with _naming(root):
        fd = opened(os.open(root, os.O_RDONLY | os.O_DIRECTORY))
    for n, part in enumerate(parts):
        with _naming(root.joinpath(*parts[:n + 1])):
            with contextlib.suppress(FileExistsError):
                os.mkdir(part, dir_fd=fd)
            fd = opened(os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=fd))
    return fd


def _stage(folder_fd: int, name: str, data) -> str:
    """Write ``data`` to a new temporary file beside ``name`` in the open folder; its name."""
    for _ in range(100):
        tmp = f".{name[:_NAME_KEPT]}.{secrets.token_hex(4)}.tmp"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, FILE_MODE,
                         dir_fd=folder_fd)
            break
        except FileExistsError:
            continue
    else:
        raise FileExistsError(f"no free temporary name beside {name}")
    try:
        os.fchmod(fd, FILE_MODE)    # whatever the umask
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
    except BaseException:
        os.unlink(tmp, dir_fd=folder_fd)
        raise
    return tmp
