"""What the benchmarks share: the best of a few timed runs."""

from __future__ import annotations

import time


def best_of(fn, repeats: int) -> float:
    """Shortest wall time of ``repeats`` calls of ``fn()``, seconds (the least disturbed run
    on a noisy machine)."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best
