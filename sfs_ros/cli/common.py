"""What the command-line tools share: progress on a terminal, errors as one line."""

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
