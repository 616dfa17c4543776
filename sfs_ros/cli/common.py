"""What the command-line tools share: inputs, progress on a terminal, errors as one line."""

from __future__ import annotations

import sys
from pathlib import Path

from ..core.exchange.inputs import ACCEPTED_INPUTS as CORE_INPUTS
from ..core.exchange.inputs import load_views
from ..core.exchange.views import ViewError, ViewSet

#: What :func:`load_input` reads, in words.
ACCEPTED_INPUTS = f"{CORE_INPUTS}, or a rosbag2 recorded by sfs-recorder (folder, .mcap or .db3)"
_BAG_SUFFIXES = (".mcap", ".db3")


def _is_bag(path: Path) -> bool:
    if path.is_file():
        return path.suffix.lower() in _BAG_SUFFIXES
    return path.is_dir() and ((path / "metadata.yaml").is_file()
                              or any(p.suffix.lower() in _BAG_SUFFIXES for p in path.iterdir()))


def load_input(path, *, captures: bool = False) -> tuple[ViewSet, dict]:
    """The views at ``path`` (:func:`sfs_ros.core.exchange.inputs.load_views`, or a rosbag2 read
    by :func:`sfs_ros.cell.bag.read_bag`: its masks as the reconstruction node carved
    them, or with ``captures`` its captured images) and the recorded defaults of a bag
    (``{"resolution": ..., "mesher": ...}`` as the reconstruction node had them; empty
    for other inputs). Raises ViewError with one line."""
    path = Path(path)
    if not _is_bag(path):
        return load_views(path), {}
    try:
        from ..cell.bag import read_bag
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] != "rosbags":
            raise
        raise ViewError(f"input {path} is a rosbag2: reading it needs the rosbags package "
                        "(pip install rosbags)") from None
    views = read_bag(path, captures=captures)
    recorded = {"resolution": views.resolution, "mesher": views.mesher}
    return views, {k: v for k, v in recorded.items() if v is not None}


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


def run_reporting_errors(prog: str, run, args):
    """``(0, run(args))``, or ``(status, None)`` after printing one line on stderr.

    Bad input (``ValueError``, ``OSError``) exits with status 2, Ctrl-C with 130.
    """
    try:
        return 0, run(args)
    except (ValueError, OSError) as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130, None
    return 2, None
