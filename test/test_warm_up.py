"""``sfs-warm-up`` (run by scripts/setup.sh, and by test/conftest.py for the copy the tests
import): after it, a new process takes every kernel the scan's reconstruction uses from
numba's on-disk cache instead of compiling it again; its stamp says which sources it
compiled."""

import os
import subprocess
import sys
from pathlib import Path

from sfs_ros.cli import warm_up

from ros_harness import SOURCE_ROOT

#: A cold warm-up compiles every kernel: about two minutes on 2 busy cores; the bound
#: only catches a hang.
TIMEOUT_S = 900

#: Reconstructs the warm-up's scan again, then names the compiled functions of the
#: package that came from the cache and those that were compiled (a line each).
SECOND_RUN = """
import sys, tempfile
from pathlib import Path
from numba.core.registry import CPUDispatcher
from sfs_ros.cli import warm_up
with tempfile.TemporaryDirectory() as tmp:
    warm_up.run(Path(tmp))
loaded, compiled = [], []
for name, module in list(sys.modules.items()):
    if name.startswith("sfs_ros"):
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.signatures:
                if sum(value.stats.cache_hits.values()):
                    loaded.append(f"{name}.{attr}")
                if sum(value.stats.cache_misses.values()):
                    compiled.append(f"{name}.{attr}")
print(" ".join(sorted(set(loaded))))
print(" ".join(sorted(set(compiled))))
"""

#: Kernels the cell's nodes call in the middle of a scan that a rehearsal of clean views
#: never reaches: the carving's kept band once it has followed the hull, the removal of a
#: speck or the filling of a hole in a view's mask, the threshold method's colour distance.
MID_SCAN_KERNELS = {"sfs_ros.core.meshing.hull_distance._largest_kernel",
                    "sfs_ros.core.meshing.hull_distance._floored_values_kernel",
                    "sfs_ros.core.meshing.hull_distance._raises_kernel",
                    "sfs_ros.core.segmentation.segment._lookup",
                    "sfs_ros.core.segmentation.segment._distance_kernel"}


def _compiled_again(cwd, env=None) -> tuple[set, str]:
    """The warm-up's scan reconstructed in a new process (run in ``cwd``): the names of
    the kernels it loaded from the cache, and of those it compiled, space-separated."""
    second = subprocess.run([sys.executable, "-c", SECOND_RUN], cwd=cwd, env=env,
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    assert second.returncode == 0, second.stderr
    loaded, compiled = (second.stdout.rstrip("\n").split("\n") + [""])[:2]
    return set(loaded.split()), compiled


def test_after_the_warm_up_nothing_compiles_again(tmp_path):
    # Both processes run in an empty folder: they import the same installed package.
    first = subprocess.run([sys.executable, "-m", "sfs_ros.cli.warm_up"], cwd=tmp_path,
                           capture_output=True, text=True, timeout=TIMEOUT_S)
    assert first.returncode == 0, first.stderr
    assert "kernels compiled and cached in" in first.stdout
    loaded, compiled = _compiled_again(tmp_path)
    assert compiled == "", f"compiled again instead of loaded from the cache: {compiled}"
    assert len(loaded) >= 20  # the carving, meshing, colour and rendering kernels, at least
    assert MID_SCAN_KERNELS <= loaded, sorted(MID_SCAN_KERNELS - loaded)


def test_the_copy_the_tests_import_is_warm_for_its_node_processes(kernels_warmed):
    # As test/ros_harness.py starts a node: the tests' sfs_ros first on the module path.
    env = dict(os.environ, PYTHONPATH=str(SOURCE_ROOT))
    assert warm_up.is_warm()
    loaded, compiled = _compiled_again(SOURCE_ROOT, env)
    assert compiled == "", f"compiled again instead of loaded from the cache: {compiled}"
    assert len(loaded) >= 20 and MID_SCAN_KERNELS <= loaded


def _package(root: Path) -> Path:
    """A package with a cached kernel in ``kernels.py`` and none in ``plain.py``."""
    package = root / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "sub" / "kernels.py").write_text("@njit(cache=True)\ndef f(x):\n    return x\n")
    (package / "plain.py").write_text("def g(x):\n    return x\n")
    return package


def test_the_stamp_follows_the_kernels_sources(tmp_path):
    package = _package(tmp_path)
    assert warm_up.kernel_modules(package) == [package / "sub" / "kernels.py"]
    assert not warm_up.is_warm(package)                  # never warmed
    assert warm_up.mark_warm(warm_up.cache_key(package), package)
    assert warm_up.is_warm(package)
    (package / "plain.py").write_text("def g(x):\n    return 2 * x\n")
    assert warm_up.is_warm(package)                      # no kernel there: the cache holds
    (package / "sub" / "kernels.py").write_text("@njit(cache=True)\ndef f(x):\n    return -x\n")
    assert not warm_up.is_warm(package)                  # numba compiles this one again
    assert warm_up.mark_warm(warm_up.cache_key(package), package)
    moved = tmp_path / "elsewhere"
    package.rename(moved)
    assert warm_up.is_warm(moved)        # numba's cache beside the sources moves with them


def test_a_package_where_no_stamp_can_be_written_is_never_called_warm(tmp_path):
    package = _package(tmp_path)
    (package / "__pycache__").write_text("")    # a file where the stamp's folder would be
    assert not warm_up.mark_warm(warm_up.cache_key(package), package)
    assert not warm_up.is_warm(package)
