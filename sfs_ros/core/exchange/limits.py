"""Reading input files defensively: size caps, image headers before decoding, plain
documents (YAML, JSON) without aliases or deep nesting, paths confined to the input.

Every input format goes through these checks before anything large is allocated,
so a hostile or broken file costs at most a header read and gives a one-line
:class:`~.errors.ViewError` naming the file, what was wrong and what is expected.

Limits (module constants, stated in the README):

* an image file is at most :data:`MAX_IMAGE_FILE_BYTES` and at most
  :data:`MAX_IMAGE_PIXELS` pixels, checked from its header before decoding;
* a text file (session YAML, views table, Middlebury parameters, NeRF JSON) is
  at most :data:`MAX_TEXT_FILE_BYTES`;
* a record of a bag (an MCAP chunk, declared and expanded; an sqlite3 row) is
  at most :data:`MAX_BAG_RECORD_BYTES`;
* a YAML or JSON document nests at most :data:`MAX_DOCUMENT_DEPTH` levels and a
  YAML document has no anchors or aliases (the project never writes them, and
  aliases are how a few hundred bytes expand into gigabytes).
"""

from __future__ import annotations

import io
import json
import os
import warnings
from pathlib import Path, PurePosixPath

import numpy as np
import yaml

from .errors import ViewError

__all__ = ["MAX_IMAGE_FILE_BYTES", "MAX_IMAGE_PIXELS", "MAX_TEXT_FILE_BYTES",
           "MAX_DOCUMENT_DEPTH", "MAX_BAG_RECORD_BYTES", "MAX_WAITING_BYTES",
           "check_file_size", "image_header", "decode_image_bytes",
           "read_text", "load_yaml",
           "load_json", "brief", "printable", "confined_path"]

#: Largest image file read, bytes (a 100-megapixel 16-bit RGBA PNG stays below).
MAX_IMAGE_FILE_BYTES = 1 << 30
#: Largest image decoded, pixels (width x height): 100 megapixels.
MAX_IMAGE_PIXELS = 100_000_000
#: Largest text file read, bytes.
MAX_TEXT_FILE_BYTES = 64 << 20
#: Deepest nesting of a YAML or JSON document, levels.
MAX_DOCUMENT_DEPTH = 32
#: Largest record read from a bag, bytes: an MCAP chunk as it declares and as it expands,
#: an sqlite3 message row. Room for one message of a :data:`MAX_IMAGE_PIXELS` 8-bit RGB
#: image (a chunk holds at least one message).
MAX_BAG_RECORD_BYTES = 512 << 20
#: Most bytes of messages a node keeps waiting for their partner, per topic: a capture
#: waiting for its joint state, a mask for its view, an image for colour.
MAX_WAITING_BYTES = 512 << 20


def check_file_size(path: Path, limit: int, what: str) -> int:
    """Size of the file ``path`` in bytes; ViewError if it is not a file or exceeds ``limit``."""
    try:
        size = os.stat(path).st_size
    except FileNotFoundError:
        raise ViewError(f"{what} {path} does not exist") from None
    except OSError as err:
        raise ViewError(f"{what} {path} cannot be read ({err.strerror})") from None
    if not Path(path).is_file():
        raise ViewError(f"{what} {path} is not a file")
    if size > limit:
        raise ViewError(f"{what} {path} is {size / 2**20:.1f} MiB, more than the limit of "
                        f"{limit / 2**20:.0f} MiB")
    return size


def image_header(path: Path) -> tuple[int, int]:
    """``(width, height)`` of an image file from its header, pixels, without decoding it.

    Raises ViewError for a file over :data:`MAX_IMAGE_FILE_BYTES`, a header
    that is not an image's, or a size over :data:`MAX_IMAGE_PIXELS`.
    """
    from PIL import Image, UnidentifiedImageError  # when an image is read, not at import

    check_file_size(path, MAX_IMAGE_FILE_BYTES, "image")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as image:  # reads the header only
                width, height = image.size
    except Image.DecompressionBombError:
        raise ViewError(f"image {path} declares more pixels than Pillow opens; at most "
                        f"{MAX_IMAGE_PIXELS / 1e6:.0f} megapixels are read") from None
    except (UnidentifiedImageError, OSError, ValueError,
            SyntaxError):  # Pillow reports some malformed headers as SyntaxError
        raise ViewError(f"image {path} is not a readable image (empty, corrupt or an "
                        "unsupported format; expected e.g. PNG, JPEG, TIFF, BMP)") from None
    if width <= 0 or height <= 0 or width * height > MAX_IMAGE_PIXELS:
        raise ViewError(f"image {path} declares {width}x{height} pixels; at most "
                        f"{MAX_IMAGE_PIXELS / 1e6:.0f} megapixels are read")
    return int(width), int(height)


#: Formats :func:`decode_image_bytes` decodes (Pillow's names).
DECODED_FORMATS = ("JPEG", "PNG")


def decode_image_bytes(data: bytes, what: str, *, max_pixels: int = MAX_IMAGE_PIXELS):
    """The pixels of a JPEG or PNG image held in memory (a ``CompressedImage``'s data).

    Returns (H, W, 3) uint8 RGB, (H, W) uint8 (grey) or (H, W) uint16 (16-bit
    grey). The size is checked from the header before anything is decoded:
    at most :data:`MAX_IMAGE_FILE_BYTES` of data and ``max_pixels`` pixels
    (default :data:`MAX_IMAGE_PIXELS`), so a small file declaring a huge image
    (a decompression bomb) costs a header read. Raises ViewError naming
    ``what``, what was wrong and what is expected.
    """
    from PIL import Image, UnidentifiedImageError

    if len(data) > MAX_IMAGE_FILE_BYTES:
        raise ViewError(f"{what} is {len(data) / 2**20:.1f} MiB, more than the limit of "
                        f"{MAX_IMAGE_FILE_BYTES / 2**20:.0f} MiB")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(bytes(data)), formats=DECODED_FORMATS) as image:
                width, height = image.size
                if width <= 0 or height <= 0 or width * height > max_pixels:
                    raise ViewError(f"{what} declares {width}x{height} pixels; at most "
                                    f"{max_pixels / 1e6:g} megapixels are decoded")
                image.load()
                mode = image.mode
                if mode in ("I;16", "I;16B", "I;16L", "I"):
                    return np.asarray(image, dtype=np.uint16)
                if mode in ("L", "1"):
                    return np.asarray(image.convert("L"), dtype=np.uint8)
                return np.asarray(image.convert("RGB"), dtype=np.uint8)
    except ViewError:
        raise
    except Image.DecompressionBombError:
        raise ViewError(f"{what} declares more pixels than Pillow opens; at most "
                        f"{max_pixels / 1e6:g} megapixels are decoded") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        raise ViewError(f"{what} is not a readable image ({len(data)} bytes: empty, corrupt "
                        f"or another format; expected {' or '.join(DECODED_FORMATS)})") from None


def read_text(path: Path, what: str) -> str:
    """The UTF-8 text of ``path`` (a byte-order mark tolerated), at most :data:`MAX_TEXT_FILE_BYTES`."""
    check_file_size(path, MAX_TEXT_FILE_BYTES, what)
    try:
        return Path(path).read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ViewError(f"{what} {path} is not a UTF-8 text file") from None


class _PlainLoader(yaml.SafeLoader):
    """SafeLoader that refuses anchors and aliases and bounds the nesting depth."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent) or getattr(self.peek_event(), "anchor", None):
            mark = self.peek_event().start_mark
            raise yaml.constructor.ConstructorError(
                None, None, "anchors and aliases (&, *) are not accepted", mark)
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > MAX_DOCUMENT_DEPTH:
                raise yaml.constructor.ConstructorError(
                    None, None, f"nesting deeper than {MAX_DOCUMENT_DEPTH} levels",
                    self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def load_yaml(path: Path, what: str):
    """Parse the YAML file ``path`` as plain data (no aliases, bounded depth); ViewError if not."""
    text = read_text(path, what)
    try:
        return yaml.load(text, Loader=_PlainLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        line = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(err, "problem", None) or "syntax error"
        raise ViewError(f"{what} {path} is not valid YAML{line}: {brief(problem)}") from None
    except RecursionError:
        raise ViewError(f"{what} {path} nests deeper than {MAX_DOCUMENT_DEPTH} levels") from None


def _depth(value, limit: int) -> int:
    """Nesting depth of lists/dicts in ``value``, counted no further than ``limit + 1``."""
    stack, deepest = [(value, 1)], 0
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (list, dict)):
            deepest = max(deepest, depth)
            if deepest > limit:
                return deepest
            stack.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict) else item))
    return deepest


def load_json(path: Path, what: str):
    """Parse the JSON file ``path`` (bounded size and depth); ViewError if not."""
    text = read_text(path, what)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ViewError(f"{what} {path} is not valid JSON (line {err.lineno}: {err.msg})") \
            from None
    except RecursionError:
        raise ViewError(f"{what} {path} nests deeper than {MAX_DOCUMENT_DEPTH} levels") from None
    if _depth(data, MAX_DOCUMENT_DEPTH) > MAX_DOCUMENT_DEPTH:
        raise ViewError(f"{what} {path} nests deeper than {MAX_DOCUMENT_DEPTH} levels")
    return data


def brief(value, limit: int = 80) -> str:
    """``repr(value)`` on one line, cut to ``limit`` characters, for error messages.

    ``repr`` escapes control characters, so a name carrying terminal escape
    codes is shown, not obeyed.
    """
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def printable(text: str, limit: int = 80) -> str:
    """``text`` with control characters escaped, cut to ``limit`` characters (no quotes)."""
    text = str(text)
    if not text.isprintable():
        text = text.encode("unicode_escape").decode("ascii")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def confined_path(root: Path, relative: str, what: str) -> Path:
    """``root / relative``, refused unless it stays inside ``root`` with links resolved.

    ``relative`` must be a relative path (``/`` separated, no ``..``); the
    result, with every symbolic link resolved, must lie inside ``root`` (also
    resolved), so neither a name nor a link reads a file outside the input.
    """
    parts = PurePosixPath(relative).parts
    if (not relative or "\\" in relative or relative.startswith("/") or ".." in parts
            or "\x00" in relative or (len(relative) > 1 and relative[1] == ":")):
        raise ViewError(f"{what}: {brief(relative)} must be a relative path inside "
                        f"{root} (using '/', no '..')")
    root_real = Path(os.path.realpath(root))
    path = Path(root) / relative
    real = Path(os.path.realpath(path))
    if real != root_real and root_real not in real.parents:
        raise ViewError(f"{what}: {brief(relative)} leads outside {root} (a symbolic link to "
                        f"{real}); inputs are read only from inside their folder")
    return path
