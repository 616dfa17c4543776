"""``sfs-warm-up``: compile the package's kernels once, when it is set up.

The numba kernels compile on first use and are cached on disk beside the installed
modules (``cache=True``; numba falls back to a cache in the user's home where that
folder is read-only). Without this step the first scan after installing pays for the
compilation: on 2 cores about a minute, against seconds for a warm reconstruction.
``scripts/setup.sh`` runs it. It reconstructs a small simulated scan of the mug, in a
temporary folder, both ways the package does: offline from the images (segmentation,
consensus, fusion, carving, meshing, evaluation) and live, view by view (incremental
carving, then the pipeline on the received masks with colour, the mesh file and its
pictures: :func:`sfs_ros.cell.rehearsal.rehearse`). Prints the seconds it took.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from ..cell.rehearsal import REHEARSAL_PLAN, REHEARSAL_RESOLUTION, REHEARSAL_RIG, rehearse
from ..core.exchange.inputs import load_views
from ..core.exchange.session import write_session
from ..core.pipeline import ReconstructionParams, reconstruct
from ..core.segment import segment
from ..core.simulation.objects import make_object
from ..core.simulation.synthetic import simulate_scan


def run(folder: Path) -> None:
    """Reconstruct a 25-view simulated scan of the mug offline and live, in ``folder``."""
    captures = simulate_scan(make_object("mug"), REHEARSAL_RIG, REHEARSAL_PLAN, seed=0)
    session = write_session(folder / "session", [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], REHEARSAL_RIG)
    reconstruct(load_views(session), ReconstructionParams(resolution=REHEARSAL_RESOLUTION))
    rehearse(folder / "live", [(segment(c.image).mask, c.image) for c in captures])


def build_parser() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(prog="sfs-warm-up", description=__doc__.split("\n\n")[0])


def main(argv=None) -> int:
    build_parser().parse_args(argv)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sfs_warm_up_") as tmp:
        run(Path(tmp))
    print(f"kernels compiled and cached in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
