"""Progress on a terminal: one updating line per stage, plain lines when piped."""

from __future__ import annotations

import sys


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
