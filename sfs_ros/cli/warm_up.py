"""``sfs-warm-up``: compile the package's kernels once, when it is set up.

The numba kernels compile on first use and are cached on disk beside the installed
modules (``cache=True``; numba falls back to a cache in the user's home where that
folder is read-only). Without this step the first scan after installing pays for the
compilation, which takes far longer than a warm reconstruction
(``doc/benchmarks.md``, the kernels in a test session).
``scripts/setup.sh`` runs it. It reconstructs a small simulated scan of the mug, in a
temporary folder, both ways the package does: offline from the images (segmentation,
consensus, fusion, carving, meshing, evaluation) and live, view by view (incremental
carving, then the pipeline on the received masks with colour, the mesh file and its
pictures: :func:`sfs_ros.cell_logic.rehearsal.rehearse`); then what the cell's nodes
reach in the middle of a real scan and those runs do not (:func:`follow_a_band`,
:func:`segment_a_speckled_picture`). Prints the seconds it took.

numba keys a cached kernel on its source file's content (and location: beside the file,
or under ``NUMBA_CACHE_DIR``), its own version, the Python and the host CPU. Each copy of
the package has its own cache: the installed one and a source tree that tests import
(``colcon test`` runs pytest in the source tree) are warmed apart. After a warm-up the
package's folder holds a stamp of those keys (:func:`cache_key`), so that
:func:`is_warm` tells without compiling anything whether this copy's kernels are cached
(``test/conftest.py`` warms the copy the tests import when it is not).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import platform
import re
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numba
import numpy as np

from ..cell_logic import rehearsal
from ..cell_logic.live_reconstruction import LiveReconstruction
from ..cell_logic.rehearsal import REHEARSAL_PLAN, REHEARSAL_RESOLUTION, REHEARSAL_RIG, rehearse
from ..core.exchange.inputs import load_views
from ..core.exchange.session import write_session
from ..core.geometry.rig import rig_camera
from ..core.pipeline import ReconstructionParams, reconstruct
from ..core.render import rasterize_silhouette
from ..core.segmentation.band_cut import band_cut
from ..core.segmentation.grabcut import grabcut
from ..core.segmentation.kmeans import OpenCVRandom
from ..core.segmentation.segment import SegmentationParams, segment
from ..core.simulation.objects import make_object
from ..core.simulation.plan import ring_plan
from ..core.simulation.synthetic import carving_box, simulate_scan
from ..process import configure_process

#: This package's folder (``.../sfs_ros``): the copy whose kernels a warm-up compiles.
PACKAGE = Path(__file__).resolve().parents[1]
#: The decorator of a numba function whose compiled code is cached on disk.
_CACHED = re.compile(r"^\s*@[\w.]*jit\(.*\bcache=True", re.MULTILINE)
#: The lines of ``/proc/cpuinfo`` that name the CPU numba compiles for (x86; ARM).
_CPU_FIELDS = ("model name", "flags", "CPU implementer", "CPU part", "Features")


#: A live scan long enough for the carving's kept band to follow the hull (every
#: ``ExpectedCarves.BAND_FOLLOWS_EVERY`` views once the grid has settled) and for views to
#: come after it: the rehearsal's 25 views end while the grid still changes. On a camera
#: smaller still: the kernels are compiled for the arrays' types, not their sizes.
BAND_PLAN = ring_plan([20.0, 50.0], 20, top_view=True)
BAND_RIG = replace(REHEARSAL_RIG, width=80, height=60, fx=175.0, fy=175.0)


def run(folder: Path) -> None:
    """Reconstruct a 25-view simulated scan of the mug offline and live, in ``folder``;
    then what those leave out (a longer live scan, small pictures)."""
    captures = simulate_scan(make_object("mug"), REHEARSAL_RIG, REHEARSAL_PLAN, seed=0)
    session = write_session(folder / "session", [(c.name, c.image) for c in captures],
                            [(c.theta_rad, c.phi_rad) for c in captures], REHEARSAL_RIG)
    reconstruct(load_views(session), ReconstructionParams(resolution=REHEARSAL_RESOLUTION))
    rehearse(folder / "live", [(segment(c.image).mask, c.image) for c in captures])
    follow_a_band(folder / "band")
    cut_a_band()
    grabcut_a_picture()
    segment_a_speckled_picture()


def follow_a_band(folder: Path) -> None:
    """The live carving's kept band (:class:`~sfs_ros.core.meshing.kept_band.KeptBand`):
    the mug's silhouettes from :data:`BAND_PLAN` on :data:`BAND_RIG` received view by view
    in ``folder``, then carved."""
    mug = make_object("mug")
    live = LiveReconstruction(BAND_RIG, carving_box(mug), output_dir=folder,
                              resolution=REHEARSAL_RESOLUTION)
    for n, (theta, phi) in enumerate(BAND_PLAN):
        camera = rig_camera(theta, phi, BAND_RIG)
        live.add_view(n, rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces, camera),
                      theta, phi)
    live.carve(colour=False)


def cut_a_band() -> None:
    """The consensus' full-resolution band cut (:func:`~sfs_ros.core.segmentation.band_cut.band_cut`)
    on a small picture: it runs only on views larger than the rehearsal's, which are cut
    again whole."""
    image = np.zeros((8, 8, 3), np.uint8)
    image[:, 4:] = 200
    labels = np.full((8, 8), cv2.GC_BGD, np.uint8)
    labels[:, 4:] = cv2.GC_FGD
    labels[:, 3] = cv2.GC_PR_BGD
    labels[:, 4] = cv2.GC_PR_FGD
    model = np.zeros((1, 65))
    model[0, 0] = 1.0
    model[0, 20:29] = np.eye(3).ravel()
    band_cut(image, labels, (model, model))


def grabcut_a_picture() -> None:
    """The segmentation's GrabCut (:func:`~sfs_ros.core.segmentation.grabcut.grabcut`) on
    a small picture: the rehearsal's renders may leave it nothing to decide."""
    image = np.zeros((8, 8, 3), np.uint8)
    image[:, 4:] = 200
    labels = np.full((8, 8), cv2.GC_PR_BGD, np.uint8)
    labels[:, 4:] = cv2.GC_PR_FGD
    labels[:, 0] = cv2.GC_BGD
    grabcut(image, labels, 1, OpenCVRandom())


def segment_a_speckled_picture() -> None:
    """Both segmentation methods on a small picture with a speck and a hole: the
    rehearsal's clean renders leave the threshold method, the removal of specks and the
    filling of holes unused."""
    image = np.full((160, 200, 3), 225, np.uint8)
    image[:, :, 0] += np.linspace(0, 20, 200, dtype=np.uint8)   # a backdrop not flat
    image[20:140, 30:170] = (60, 40, 30)
    image[70:76, 90:96] = 225                                   # a hole
    image[5:9, 185:189] = (60, 40, 30)                          # a speck
    for method in ("graph-cut", "threshold"):
        segment(image, SegmentationParams(method=method))


def host_cpu() -> str:
    """The machine type and the first CPU's model and features (``/proc/cpuinfo``, where
    there is one): numba compiles each kernel for the host's CPU."""
    try:
        first = Path("/proc/cpuinfo").read_text().split("\n\n", 1)[0]
    except OSError:
        first = ""
    return "\n".join([platform.machine(), *(line for line in first.splitlines()
                                             if line.startswith(_CPU_FIELDS))])


def kernel_modules(package: Path = PACKAGE) -> list[Path]:
    """The package's modules that define cached kernels, sorted."""
    return sorted(p for p in package.rglob("*.py") if _CACHED.search(p.read_text()))


def cache_key(package: Path = PACKAGE) -> str:
    """Hex digest of what numba's cache of the package's kernels depends on: each kernel
    module's path in the package and bytes, numba's version, the Python (its cache tag),
    the host CPU and ``NUMBA_CACHE_DIR``; and of what the warm-up runs (this module's and
    the rehearsal's bytes: a kernel they come to call is not cached yet)."""
    digest = hashlib.sha256()
    for path in kernel_modules(package):
        digest.update(f"{path.relative_to(package)}\0".encode())
        digest.update(path.read_bytes())
    for path in (Path(__file__), Path(rehearsal.__file__)):
        digest.update(path.read_bytes())
    digest.update(f"\0{numba.__version__}\0{sys.implementation.cache_tag}\0{host_cpu()}\0"
                  f"{os.environ.get('NUMBA_CACHE_DIR', '')}".encode())
    return digest.hexdigest()


def stamp_file(package: Path = PACKAGE) -> Path:
    """Where a warm-up leaves :func:`cache_key` (beside the package's own cache)."""
    return package / "__pycache__" / "sfs_warm_up.stamp"


def is_warm(package: Path = PACKAGE) -> bool:
    """Whether a warm-up ran on this copy of the package's kernels as they are now."""
    try:
        return stamp_file(package).read_text() == cache_key(package)
    except OSError:
        return False


def mark_warm(key: str, package: Path = PACKAGE) -> bool:
    """Leave ``key`` (the :func:`cache_key` of the sources the warm-up compiled) as the
    stamp :func:`is_warm` reads, atomically; False where the package's folder is read-only
    (numba then caches in the user's home; :func:`is_warm` stays False)."""
    stamp = stamp_file(package)
    try:
        stamp.parent.mkdir(exist_ok=True)
        partial = stamp.with_name(f"{stamp.name}.{os.getpid()}")
        partial.write_text(key)
        partial.replace(stamp)
    except OSError:
        return False
    return True


def build_parser() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(prog="sfs-warm-up", description=__doc__.split("\n\n")[0])


def main(argv=None) -> int:
    configure_process()
    build_parser().parse_args(argv)
    start = time.perf_counter()
    key = cache_key()
    with tempfile.TemporaryDirectory(prefix="sfs_warm_up_") as tmp:
        run(Path(tmp))
    stamped = mark_warm(key)
    print(f"kernels compiled and cached in {time.perf_counter() - start:.0f} s"
          + ("" if stamped else f" (no stamp: {stamp_file()} cannot be written)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
