"""A small filesystem for disk-full tests: a tmpfs with a size limit (mounting needs root, as
the tests and CI run), and a way to fill it up at the operating system's level."""

import errno
import subprocess
import threading
from contextlib import contextmanager

import pytest


@contextmanager
def small_disk(mount_point, size: str):
    """A tmpfs of ``size`` (as ``mount -o size=``, e.g. ``"4m"``) mounted at the existing
    folder ``mount_point``; the test is skipped, saying why, where mounting is impossible."""
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs",
                           str(mount_point)], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or done.returncode}): "
                    "the disk-full tests need root (CAP_SYS_ADMIN)")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=True)


def fill(path) -> None:
    """Append zeros to ``path`` until its filesystem refuses (ENOSPC): it is then full."""
    with open(path, "ab", buffering=0) as f:
        for size in (1 << 20, 1 << 12):      # megabytes, then the last pages
            try:
                while f.write(bytes(size)) == size:
                    pass
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise


def keep_full(path, release: threading.Event) -> None:
    """Keep the filesystem of ``path`` full (also taking what another process frees) until
    ``release`` is set."""
    while not release.is_set():
        fill(path)
        release.wait(0.05)
