"""``sfs-warm-up``: compile the package's kernels once, when it is set up.

The numba kernels compile on first use and are cached on disk beside the installed
modules (``cache=True``; numba falls back to a cache in the user's home where that
folder is read-only). Without this step the first scan after installing pays for the
compilation: on 2 cores about a minute, against seconds for a warm reconstruction.
``scripts/setup.sh`` runs it. It reconstructs a small simulated scan of the mug, in a
temporary folder, both ways the package does: offline from the images (segmentation,
consensus, fusion, carving, meshing, evaluation) and live, view by view (incremental
carving, then the pipeline on the received masks with colour, the mesh file and its
pictures). Prints the seconds it took.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from ..cell.live import LiveReconstruction
from ..core.exchange.inputs import load_views
from ..core.exchange.session import write_session
from ..core.geometry.rig import RigCalibration
from ..core.pipeline import ReconstructionParams, reconstruct
from ..core.segment import segment
from ..core.simulation.objects import make_object
from ..core.simulation.plan import ring_plan
from ..core.simulation.synthetic import carving_box, simulate_scan

#: A small camera: the kernels compile for the array types, not for the sizes.
WARM_UP_RIG = RigCalibration(width=160, height=120, projection="pinhole", fx=350.0, fy=350.0,
                             camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
RESOLUTION = 48


def run(folder: Path) -> None:
    """Reconstruct a 13-view simulated scan of the mug offline and live, in ``folder``."""
    mug = make_object("mug")
    captures = simulate_scan(mug, WARM_UP_RIG, ring_plan([20.0, 50.0], 6, top_view=True),
                             seed=0)
    session = write_session(folder / "session", [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], WARM_UP_RIG)
    reconstruct(load_views(session), ReconstructionParams(resolution=RESOLUTION))
    live = LiveReconstruction(WARM_UP_RIG, carving_box(mug), output_dir=folder / "live",
                              resolution=RESOLUTION)
    for capture in captures:
        live.add_view(capture.name, segment(capture.image).mask, capture.theta_rad,
                      capture.phi_rad)
        live.add_colour_image(capture.name, capture.image)
    live.reconstruct()


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
