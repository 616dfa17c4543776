"""All benchmarks in one run: ``python -m bench.run [--quick]`` from the repository.

Each row is a time measured in this run and, where there is one, a baseline
measured in the same run, printed as a ratio baseline / ours (above 1: faster
than the baseline): the machine is noisy, so ratios are what to compare
between runs, not seconds.
"""

from __future__ import annotations

import argparse
import importlib
import os
import platform
import sys

import numpy as np

from sfs_ros.process import configure_process

from .timing import print_table

SUITES = [("bench_carve", "run"), ("bench_marching", "run"),
          ("bench_marching", "run_hull_surface"), ("bench_marching", "run_band"),
          ("bench_mesh", "run_advancing_front"),
          ("bench_lens", "run"), ("bench_segment", "run"), ("bench_colour", "run"),
          ("bench_cell", "run"), ("bench_reconstruct", "run"), ("bench_startup", "run"),
          ("bench_refine", "run")]


def main(argv=None) -> int:
    configure_process()      # as the tools' processes are set up
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke run")
    parser.add_argument("--only", nargs="+", help="run only these suites, e.g. bench_carve")
    args = parser.parse_args(argv)
    print(f"python {platform.python_version()}, numpy {np.__version__}, "
          f"{platform.machine()}, {len(os.sched_getaffinity(0))} cores")
    rows = (row for module_name, function in SUITES
            if not args.only or module_name in args.only
            for row in getattr(importlib.import_module(f"bench.{module_name}"),
                               function)(quick=args.quick))
    print_table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
