"""What the command-line tools share: inputs, progress on a terminal, errors as one line."""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..core.exchange.views import ViewSet
    from ..core.settings import Setting


def accepted_inputs() -> str:
    """What :func:`load_input` reads, in words: every input format, the cell's rosbag2
    among them (:func:`sfs_ros.core.exchange.inputs.accepted_inputs`)."""
    from ..cell_logic import bag_input  # noqa: F401 - adds the rosbag2 to the input formats
    from ..core.exchange.inputs import accepted_inputs as every_format
    return every_format()


def load_input(path, *, captures: bool = False) -> tuple[ViewSet, dict]:
    """The views at ``path`` (:func:`sfs_ros.core.exchange.inputs.load_views`, the cell's
    rosbag2 among the formats; ``captures``: a bag's captured images rather than its
    masks) and the settings the input recorded (``{"resolution": ..., "mesher": ...}`` as
    a bag's carving node had them; empty for other inputs). Raises ViewError with one
    line."""
    from ..cell_logic import bag_input  # noqa: F401 - adds the rosbag2 to the input formats
    from ..core.exchange.inputs import load_views
    views = load_views(Path(path), captures=captures)
    return views, views.recorded_settings


def add_setting(parser, setting: Setting, *short: str, **overrides):
    """Add ``setting`` (:mod:`sfs_ros.core.settings`) to ``parser`` (or a group of it) as
    its flag after the ``short`` ones: type, count, choices and help from the setting,
    default None (the run fills it in), a flag for a bool; ``overrides``: argparse's
    keywords."""
    keywords = {"help": setting.help()}
    if setting.kind is bool:
        keywords["action"] = "store_true"
    else:
        keywords.update(type=setting.kind, metavar=setting.metavar)
        if setting.length:
            keywords["nargs"] = setting.length
        if setting.choices is not None:
            keywords.update(choices=setting.choices(), metavar=None)
    keywords.update(overrides)
    return parser.add_argument(*short, setting.flag, **keywords)


def add_mesher_options(parser) -> None:
    """Add the meshers' own options (:data:`sfs_ros.core.meshing.meshers.MESHERS`), each
    once, its help naming the meshers that take it."""
    from ..core.meshing.meshers import MESHERS
    owners: dict[str, list] = {}
    for entry in MESHERS.values():
        for option in entry.options:
            owners.setdefault(option.name, [option]).append(entry.name)
    for option, *meshers in owners.values():
        add_setting(parser, option, dest=option.name,
                    help=f"{' and '.join(meshers)} only: {option.help()}")


def mesher_options(args) -> dict:
    """``{option name: value}`` of the meshers' options given on the command line."""
    from ..core.meshing.meshers import MESHERS
    names = {option.name for entry in MESHERS.values() for option in entry.options}
    return {name: getattr(args, name) for name in sorted(names)
            if getattr(args, name, None) is not None}


def input_files(path: Path, view_set: ViewSet) -> list[Path]:
    """Every file an input consists of: the input itself (a file, or every file in its
    folder) and the images its views read."""
    path = Path(path)
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else [path]
    return files + [v.image_path for v in view_set.views]


def check_outputs(outputs: dict[str, Path], inputs: list[Path]) -> None:
    """Refuse outputs that would overwrite an input file or each other.

    ``outputs`` maps a name (an option, e.g. ``"--html"``) to a file or, for
    names ending in ``/``, a folder to be written (None: not written); a folder
    clashes with every input file inside it. Paths are compared with links
    resolved.
    """
    real_inputs = {Path(os.path.realpath(p)) for p in inputs}
    seen: dict[Path, str] = {}
    for name, path in outputs.items():
        if path is None:
            continue
        real = Path(os.path.realpath(path))
        if real in seen:
            raise ValueError(f"{name} {path} is the same file as {seen[real]}; give each output "
                             "its own path")
        seen[real] = name
        if name.endswith("/"):
            inside = sorted(p for p in real_inputs if real == p or real in p.parents)
            if inside:
                raise ValueError(f"{name.rstrip('/')} {path} holds the input file {inside[0]}; "
                                 "write to a folder apart from the input")
        elif real in real_inputs:
            raise ValueError(f"{name} {path} is an input file; outputs never overwrite the input")


class StageProgress:
    """Callable ``(stage, fraction)`` printing progress to ``stream`` (stderr)."""

    def __init__(self, stream=None, *, quiet: bool = False):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = self.stream.isatty()
        self.stage = None

    def __call__(self, stage: str, fraction: float) -> None:
        if self.quiet:
            return
        if stage != self.stage:
            if self.stage is not None and self.tty:
                self.stream.write("\n")
            self.stage = stage
            if not self.tty:
                self.stream.write(f"{stage}...\n")
        if self.tty:
            self.stream.write(f"\r{stage:<14} {100 * min(max(fraction, 0.0), 1.0):5.1f}%")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self.stage is not None and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
        self.stage = None


#: Longest error line printed, characters.
_MAX_ERROR_CHARS = 400


class Terminated(BaseException):
    """SIGTERM arrived: unwind like Ctrl-C, so temporary files are removed on the way out."""


def _on_sigterm(signum, frame):
    raise Terminated()


def one_line(text, limit: int = _MAX_ERROR_CHARS) -> str:
    """``text`` as one printable line: control characters escaped, cut to ``limit``."""
    text = " ".join(str(text).split("\n"))
    if not text.isprintable():
        text = text.encode("unicode_escape").decode("ascii")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def run_reporting_errors(prog: str, run, args):
    """``(0, run(args))``, or ``(status, None)`` after printing one line on stderr.

    Bad input (``ValueError``, ``OSError``) and a result that cannot be made
    (``MemoryError``, ``RecursionError``) exit with status 2; any other
    exception is an internal error, reported as one line with its type, also
    status 2 (never a traceback). Ctrl-C exits with 130, SIGTERM with 143, both
    after the writers' ``finally`` clauses have removed their temporary files.
    """
    previous = signal.signal(signal.SIGTERM, _on_sigterm) \
        if threading.current_thread() is threading.main_thread() else None
    try:
        return 0, run(args)
    except (ValueError, OSError) as err:
        print(f"{prog}: error: {one_line(err)}", file=sys.stderr)
    except MemoryError:
        print(f"{prog}: error: not enough memory for this input and these options (lower "
              "the resolution or --max-memory)", file=sys.stderr)
    except RecursionError:
        print(f"{prog}: error: the input nests too deeply to be read", file=sys.stderr)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130, None
    except Terminated:
        print(f"{prog}: terminated", file=sys.stderr)
        return 143, None
    except Exception as err:  # noqa: BLE001 - the promise is one line, never a traceback
        print(f"{prog}: internal error: {type(err).__name__}: {one_line(err)}", file=sys.stderr)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 2, None


#: A command-line word that is a negative number (``-1e4``, ``-.5``, ``-inf``), not an option.
_NEGATIVE_NUMBER = re.compile(r"^-(\.?\d|inf$|infinity$|nan$)", re.IGNORECASE)


def accept_negative_numbers(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``parser`` taking every negative number as a value (``--bounds -1e4 ...``).

    argparse reads a word as an option unless it looks like ``-5`` or ``-0.5``, so
    ``-1e4`` or ``-inf`` end an option's values with "expected 6 arguments". None of
    the tools has an option that starts with a digit, so every word that starts with
    ``-`` and a digit (or ``-.`` and a digit, ``-inf``, ``-nan``) is a number, as
    Python 3.14's argparse reads it; the value's own check then says what is wrong
    with it.
    """
    parser._negative_number_matcher = _NEGATIVE_NUMBER
    return parser
