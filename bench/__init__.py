"""Benchmarks: ``python -m bench.run``."""

import sfs_ros  # noqa: F401  (first: its thread settings must precede numpy's import)
