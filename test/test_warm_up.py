"""``sfs-warm-up`` (run by scripts/setup.sh): after it, a new process takes every kernel the
scan's reconstruction uses from numba's on-disk cache instead of compiling it again."""

import subprocess
import sys

#: A cold warm-up compiles every kernel: about two minutes on 2 busy cores; the bound
#: only catches a hang.
TIMEOUT_S = 900

#: Reconstructs the warm-up's scan again, then counts the compiled functions of the
#: package that came from the cache and those that were compiled.
SECOND_RUN = """
import sys, tempfile
from pathlib import Path
from numba.core.registry import CPUDispatcher
from sfs_ros.cli import warm_up
with tempfile.TemporaryDirectory() as tmp:
    warm_up.run(Path(tmp))
hits, compiled = 0, []
for name, module in list(sys.modules.items()):
    if name.startswith("sfs_ros"):
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.signatures:
                hits += sum(value.stats.cache_hits.values())
                if sum(value.stats.cache_misses.values()):
                    compiled.append(f"{name}.{attr}")
print(hits, " ".join(sorted(set(compiled))))
"""


def test_after_the_warm_up_nothing_compiles_again(tmp_path):
    # Both processes run in an empty folder: they import the same installed package.
    first = subprocess.run([sys.executable, "-m", "sfs_ros.cli.warm_up"], cwd=tmp_path,
                           capture_output=True, text=True, timeout=TIMEOUT_S)
    assert first.returncode == 0, first.stderr
    assert "kernels compiled and cached in" in first.stdout
    second = subprocess.run([sys.executable, "-c", SECOND_RUN], cwd=tmp_path,
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    assert second.returncode == 0, second.stderr
    hits, _, compiled = second.stdout.strip().partition(" ")
    assert compiled == "", f"compiled again instead of loaded from the cache: {compiled}"
    assert int(hits) >= 20  # the carving, meshing, colour and rendering kernels, at least
