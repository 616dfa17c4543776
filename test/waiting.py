"""Waiting for a condition without racing the clock: poll it until a deadline.

The deadline only bounds a hang; a test never asserts how fast something happened.
"""

import time
from typing import Callable


def wait(condition: Callable[[], bool], *, what: str, timeout: float = 60.0,
         interval_s: float = 0.05) -> None:
    """Poll ``condition`` every ``interval_s`` until it is true; AssertionError after
    ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval_s)
