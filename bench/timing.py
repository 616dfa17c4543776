"""What the benchmarks share: the best of a few timed runs, and the table they print.

A suite is a function ``suite(quick=False)`` returning rows: dicts with ``name``,
``seconds``, ``baseline_seconds`` and ``ratio`` (baseline / ours; both None where
there is no baseline) and ``notes`` (lines printed after the table).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Iterable

from sfs_ros.process import configure_process


def best_of(fn, repeats: int) -> float:
    """Shortest wall time of ``repeats`` calls of ``fn()``, seconds (the least disturbed run
    on a noisy machine)."""
    return best_of_with_cpu(fn, repeats)[0]


def best_of_with_cpu(fn, repeats: int) -> tuple[float, float]:
    """``(wall, cpu)`` seconds of the fastest of ``repeats`` calls of ``fn()``: its wall
    time and the process's CPU time in it (every thread's), which over the wall time is the
    cores it kept busy."""
    best = (float("inf"), 0.0)
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        fn()
        best = min(best, (time.perf_counter() - start, time.process_time() - cpu))
    return best


def print_table(rows: Iterable[dict]) -> None:
    """Print benchmark rows as one table, each as soon as it comes, then their notes."""
    print(f"{'benchmark':<66} {'seconds':>9} {'baseline s':>11} {'ratio':>8}")
    notes = []
    for row in rows:
        base, ratio = row.get("baseline_seconds"), row.get("ratio")
        print(f"{row['name']:<66} {row['seconds']:>9.3f} "
              f"{'' if base is None else f'{base:.3f}':>11} "
              f"{'' if ratio is None else f'{ratio:.1f}x':>8}", flush=True)
        notes += row.get("notes", [])
    for note in notes:
        print("note: " + note)


def main(doc: str, *suites: Callable[..., list[dict]], quick_help: str,
         argv=None) -> None:
    """The command line of one benchmark module (``doc``: its docstring): ``--quick``,
    then the table of its ``suites``, in a process set up as the tools' are."""
    configure_process()
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help=quick_help)
    quick = parser.parse_args(argv).quick
    print_table(row for suite in suites for row in suite(quick=quick))
