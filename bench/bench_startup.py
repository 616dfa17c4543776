"""Start-up of the command lines: ``sfs-reconstruct --help`` and the import of its module,
each a fresh interpreter, against a bare interpreter (``python -c pass``) measured in the
same run. Ratio = bare / ours (below 1: the time the command adds to Python's own
start); the notes give ours / bare, ours in seconds (the acceptance: under 0.3 s) and the
machine's load. For scale, the import of the pipeline (numba, SciPy, OpenCV, trimesh),
which the help once loaded, is measured too.

Run: ``python -m bench.bench_startup`` (``--quick``: fewer repeats).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from .timing import best_of, main

ROOT = Path(__file__).resolve().parents[1]
CASES = {
    "sfs-reconstruct --help": "from sfs_ros.cli.reconstruct import main; main(['--help'])",
    "import sfs_ros.cli.reconstruct": "import sfs_ros.cli.reconstruct",
    "sfs-export --help": "from sfs_ros.cli.export import main; main(['--help'])",
    "import sfs_ros.core.pipeline (what the help once loaded)": "import sfs_ros.core.pipeline",
}


def _interpreter(code: str):
    """A call that runs ``code`` in a fresh interpreter, its output discarded."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))

    def call() -> None:
        subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return call


def run(quick: bool = False) -> list[dict]:
    """Rows ``{name, seconds, baseline_seconds, ratio, notes}``, one per case."""
    repeats = 3 if quick else 9
    _interpreter("import sfs_ros.core.pipeline")()     # byte-code compiled, files cached
    rows = []
    for name, code in CASES.items():
        bare = best_of(_interpreter("pass"), repeats)
        ours = best_of(_interpreter(code), repeats)
        load = os.getloadavg()[0]
        rows.append({"name": f"start-up: {name}", "seconds": ours, "baseline_seconds": bare,
                     "ratio": bare / ours,
                     "notes": [f"{name}: {ours:.3f} s, {ours / bare:.1f}x a bare interpreter "
                               f"({bare:.3f} s), best of {repeats}; load {load:.1f} on "
                               f"{os.cpu_count()} cores"]})
    return rows


if __name__ == "__main__":
    main(__doc__, run, quick_help="3 repeats instead of 9")
