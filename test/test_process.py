"""Nothing runs at import but definitions: importing every module of the package leaves
the environment as it was, starts no thread of ours and sets no malloc option; the
process is set up by :func:`sfs_ros.process.configure_process`, first in each
``main()``, and the processes a cell starts get the same settings from their start."""

import json
import os
import subprocess
import sys
from pathlib import Path

from sfs_ros.cli.bringup import Cell, cell_nodes, default_config_dir
from sfs_ros.process import KEEP_FREED_MEMORY_ENVIRONMENT, PROCESS_ENVIRONMENT

ROOT = Path(__file__).resolve().parents[1]

#: Imports every module of the package in a fresh interpreter, watching ctypes' look-ups
#: (audit events) for malloc's options; prints what changed. The libraries the package
#: uses are imported first: OpenCV's import adds to LD_LIBRARY_PATH, and rclpy's starts
#: threads of its own; what is looked at is what the package's modules do.
IMPORT_ALL = """
import json, os, pkgutil, sys, threading
import cv2, numba, numpy, rclpy, scipy, trimesh
before = dict(os.environ)
import sfs_ros
looked_up = []
sys.addaudithook(lambda event, args: looked_up.append(str(args[1]))
                 if event == "ctypes.dlsym" and "mall" in str(args[1]) else None)
names, failed = [], {}
for module in pkgutil.walk_packages(sfs_ros.__path__, "sfs_ros."):
    try:
        __import__(module.name)
        names.append(module.name)
    except Exception as exc:
        failed[module.name] = repr(exc)
print(json.dumps({"modules": names, "failed": failed, "looked_up": looked_up,
                  "threads": [t.name for t in threading.enumerate()],
                  "changed": sorted(k for k in set(os.environ) | set(before)
                                    if os.environ.get(k) != before.get(k))}))
"""


def _run(code: str, env: dict) -> dict:
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=600, env=dict(env, PYTHONPATH=str(ROOT)))
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])


def test_importing_every_module_runs_nothing_but_definitions():
    env = {k: v for k, v in os.environ.items()
           if k not in PROCESS_ENVIRONMENT and k not in KEEP_FREED_MEMORY_ENVIRONMENT}
    result = _run(IMPORT_ALL, env)
    assert not result["failed"], result["failed"]
    assert {"sfs_ros.nodes.carving_node", "sfs_ros.nodes.meshing_node", "sfs_ros.process",
            "sfs_ros.cli.reconstruct", "sfs_ros.core.resident_memory"} <= set(result["modules"])
    assert result["changed"] == []           # OPENBLAS_NUM_THREADS among them, once
    assert result["threads"] == ["MainThread"]
    assert result["looked_up"] == []         # mallopt, once called by two nodes' imports


def test_configure_process_sets_what_the_processes_need_and_keeps_the_users_values():
    code = ("import json, os\nfrom sfs_ros.process import configure_process\n"
            "kept = configure_process(keep_freed_memory=True)\n"
            "print(json.dumps({'kept': kept, 'blas': os.environ['OPENBLAS_NUM_THREADS']}))")
    env = {k: v for k, v in os.environ.items() if k not in PROCESS_ENVIRONMENT}
    assert _run(code, env) == {"kept": True, "blas": "1"}
    assert _run(code, dict(env, OPENBLAS_NUM_THREADS="3")) == {"kept": True, "blas": "3"}


def test_blas_loaded_before_the_set_up_is_limited_to_one_thread():
    """A caller that imported NumPy first (a node's module does): the loaded OpenBLAS is
    told the count, so its calls run on one thread as they would have."""
    code = ("import ctypes, json, numpy\nfrom sfs_ros.process import configure_process\n"
            "paths = {l.split()[-1] for l in open('/proc/self/maps') if 'openblas' in l}\n"
            "lib = ctypes.CDLL(sorted(paths)[0])\n"
            "get = next(getattr(lib, n) for n in ('openblas_get_num_threads',\n"
            "           'scipy_openblas_get_num_threads64_') if hasattr(lib, n))\n"
            "before = get()\nconfigure_process()\n"
            "print(json.dumps([before, get()]))")
    env = {k: v for k, v in os.environ.items() if k not in PROCESS_ENVIRONMENT}
    before, after = _run(code, env)
    assert after == 1, before      # before: OpenBLAS's own count (the cores it found)


def test_a_cells_nodes_start_with_the_settings_and_the_carving_and_meshing_with_malloc(
        tmp_path):
    """What sfs-cell gives each node's process (nothing is started here)."""
    specs = cell_nodes(default_config_dir(), tmp_path, mock=True)
    cell = Cell(specs, env={"PATH": os.environ.get("PATH", "")})
    for spec in specs:
        env = cell.environment_of(spec.name)
        assert env["OPENBLAS_NUM_THREADS"] == "1"
        keeps = spec.module in ("carving_node", "meshing_node")
        assert all(env.get(k) == v for k, v in KEEP_FREED_MEMORY_ENVIRONMENT.items()) == keeps
    user = Cell(specs, env={"OPENBLAS_NUM_THREADS": "2", "MALLOC_ARENA_MAX": "4"})
    assert user.environment_of("carving")["OPENBLAS_NUM_THREADS"] == "2"   # the user's wins
    assert user.environment_of("carving")["MALLOC_ARENA_MAX"] == "4"
