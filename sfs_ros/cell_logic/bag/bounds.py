"""Bags read within :data:`~sfs_ros.core.exchange.limits.MAX_BAG_RECORD_BYTES` a record.

A few kilobytes of zstd expand into gigabytes, so nothing of a bag is expanded
unchecked:

* MCAP chunks: rosbags decompresses them through its table
  ``rosbags.rosbag2.storage_mcap.DECOMPRESSORS``, handing each the size the
  chunk declares. :func:`install` puts bounded decompressors there: a declared
  size over the limit is refused before anything is expanded, and a chunk is
  expanded by at most one byte past what it declares (one that would go on is
  refused), so a chunk costs at most the limit however it lies;
* sqlite3 storage: :func:`check_storage` refuses a ``.db3`` file with a message
  row over the limit (its length, from the row, before any is read);
* rosbag2 compression of whole files or of each message (``compression_mode``
  in ``metadata.yaml``), which rosbags expands without a bound, is refused by
  :func:`check_storage` with how to decompress the bag first.

A refusal is a :class:`RecordTooLarge`; :mod:`.reading` names the bag in it.
"""

from __future__ import annotations

import contextlib
import sqlite3
import sys
from pathlib import Path

import lz4.frame
from rosbags.rosbag2 import storage_mcap

from ...core.exchange.errors import ViewError
from ...core.exchange.limits import MAX_BAG_RECORD_BYTES, load_yaml

if sys.version_info >= (3, 14):
    from compression import zstd
else:
    from backports import zstd

__all__ = ["RecordTooLarge", "check_storage", "install"]


class RecordTooLarge(Exception):
    """A bag's record over :data:`MAX_BAG_RECORD_BYTES` (the text says which and how large).

    Not a ValueError: it passes the readers' fallbacks for damaged bags untouched."""


def _limit_text() -> str:
    return f"the limit of {MAX_BAG_RECORD_BYTES >> 20} MiB a record"


def _bounded(new_decompressor):
    """A ``DECOMPRESSORS`` entry ``(data, declared size) -> bytes`` that expands frames
    made by ``new_decompressor()`` to at most the declared size plus one byte."""
    def decompress(data: bytes, size: int) -> bytes:
        if size > MAX_BAG_RECORD_BYTES:
            raise RecordTooLarge(f"a chunk declares {size / 2**20:.1f} MiB uncompressed, more "
                                 f"than {_limit_text()}")
        parts, total, decompressor = [], 0, None
        while data and total <= size:
            decompressor = new_decompressor()
            part = decompressor.decompress(data, max_length=size + 1 - total)
            parts.append(part)
            total += len(part)
            if not decompressor.eof:
                break
            data = decompressor.unused_data
        if total > size or (decompressor is not None and not decompressor.eof
                            and not decompressor.needs_input):
            raise RecordTooLarge(f"a chunk expands past the {size} bytes it declares")
        return b"".join(parts)
    return decompress


def install() -> None:
    """Put the bounded decompressors in rosbags' table of MCAP chunk decompressors."""
    storage_mcap.DECOMPRESSORS["zstd"] = _bounded(zstd.ZstdDecompressor)
    storage_mcap.DECOMPRESSORS["lz4"] = _bounded(lz4.frame.LZ4FrameDecompressor)


def check_storage(folder: Path | None, files: list[Path]) -> None:
    """RecordTooLarge for a ``.db3`` file among ``files`` with a row over the limit;
    ViewError for a bag ``folder`` whose ``metadata.yaml`` declares rosbag2 compression
    (a metadata file that cannot be read is left to the reader)."""
    if folder is not None and (folder / "metadata.yaml").is_file():
        try:
            info = load_yaml(folder / "metadata.yaml", "bag metadata")
        except ViewError:
            info = None
        info = info.get("rosbag2_bagfile_information") if isinstance(info, dict) else None
        mode = info.get("compression_mode") if isinstance(info, dict) else None
        if mode and str(mode).lower() != "none":
            raise ViewError(f"bag {folder} is compressed ({folder / 'metadata.yaml'}: "
                            f"compression_mode {str(mode)[:20]!r}), which is not read: "
                            "decompress it first (ros2 bag convert, with an output of "
                            "no compression)")
    for file in files:
        if file.suffix == ".db3":
            largest = _largest_row(file)
            if largest > MAX_BAG_RECORD_BYTES:
                raise RecordTooLarge(f"{file.name} holds a message of {largest / 2**20:.1f} "
                                     f"MiB, more than {_limit_text()}")


def _largest_row(file: Path) -> int:
    """Bytes of the largest message row of the sqlite3 file (0 when it has none or cannot
    be read as one: the reader says why)."""
    try:
        with contextlib.closing(sqlite3.connect(
                f"{Path(file).resolve().as_uri()}?mode=ro&immutable=1", uri=True)) as db:
            (largest,) = db.execute("SELECT max(length(data)) FROM messages").fetchone()
    except sqlite3.Error:
        return 0
    return int(largest or 0)
