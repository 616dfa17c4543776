"""A process's set-up, made explicitly, first in each entry point's ``main()``: importing a
module of the package changes nothing (no environment variable, no malloc setting, no
thread).

:func:`configure_process` makes three settings, each of which only takes if it is in place
before something else happens in the process:

* **BLAS threads.** Per-view work runs in the package's own threads (and numba's); BLAS
  only ever multiplies thin (n, 3) by (3, 3) matrices here, where threads of its own
  gain nothing and, on a busy machine, spin against the others (``doc/changelog.md``).
  OpenBLAS reads ``OPENBLAS_NUM_THREADS`` once, when NumPy first loads it, and starts
  its threads then, so the variable must be set before the first ``import numpy``.
  ``sfs-reconstruct``, ``sfs-export`` and ``sfs-replay`` import NumPy only inside
  ``main()``, after this call (their modules' tops import the standard library alone);
  a node's module imports rclpy and its messages (and so NumPy) at the top, so there
  the variable comes from the process that starts it: ``sfs-cell`` calls this first and
  its nodes inherit the variable (:data:`PROCESS_ENVIRONMENT`, also given to them
  explicitly), the launch files set it. Where NumPy is loaded all the same (a command
  line whose module imports it, a node run by hand, a caller in another program), the
  call limits the loaded OpenBLAS to that count through its own
  ``openblas_set_num_threads``: its calls then run on one thread as well, though its
  idle threads were started. A value the user set wins.
* **OpenMP threads wait asleep.** numba's parallel kernels run on GNU OpenMP, whose
  threads otherwise spin for a few milliseconds after each kernel before they sleep: a
  reconstruction's kernels, with Python work between them, then burn a core's worth of
  those milliseconds that the next stage (or another node) needs (``doc/benchmarks.md``,
  "Where the time goes after the last view"). ``OMP_WAIT_POLICY=PASSIVE`` makes them wait
  asleep; OpenMP reads it when numba first loads it, at the first parallel kernel.
* **malloc** (``keep_freed_memory``: the carving and meshing nodes, ``sfs-reconstruct``
  and ``sfs-simulate``):
  :func:`sfs_ros.core.resident_memory.keep_freed_memory` makes malloc keep what it frees,
  in one arena for all threads; an arena a thread took before stays its own, and
  ``import rclpy`` starts threads. glibc reads the same settings from the environment
  when the process starts (:data:`KEEP_FREED_MEMORY_ENVIRONMENT`), before any thread:
  ``sfs-cell`` and the launch files start those two nodes with them, and the call here
  sets them again (a node started otherwise gets them from here, after rclpy's import).
"""

from __future__ import annotations

import os
import sys

__all__ = ["PROCESS_ENVIRONMENT", "KEEP_FREED_MEMORY_ENVIRONMENT", "STOP_GRACE_S",
           "configure_process"]

#: What every process of the package runs with (a variable already set is left as it is).
PROCESS_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}
#: glibc's malloc settings of :func:`~sfs_ros.core.resident_memory.keep_freed_memory`
#: (one arena, no mmap, no trimming: the largest size_t), read when a process starts.
KEEP_FREED_MEMORY_ENVIRONMENT = {"MALLOC_ARENA_MAX": "1", "MALLOC_MMAP_MAX_": "0",
                                 "MALLOC_TRIM_THRESHOLD_": str(2 ** 64 - 1)}
#: Seconds a node gets to stop after SIGINT, and again after SIGTERM, before it is killed
#: (``sfs-cell``; the launch files' ``sigterm_timeout`` and ``sigkill_timeout``). On SIGINT
#: a node finishes the work it has queued (a mesh's pictures after its answer): 10 s was
#: not enough for the meshing node on a 2-core machine running two test suites.
STOP_GRACE_S = 60.0


def configure_process(*, keep_freed_memory: bool = False) -> bool:
    """Set this process up (module docstring): :data:`PROCESS_ENVIRONMENT` where the
    environment does not set it, and with ``keep_freed_memory`` malloc's settings.

    Call it first in ``main()``, before the imports that load NumPy. Returns whether
    malloc keeps freed memory (False without ``keep_freed_memory``, or without glibc).
    """
    unset = [name for name in PROCESS_ENVIRONMENT if name not in os.environ]
    for name in unset:
        os.environ[name] = PROCESS_ENVIRONMENT[name]
    if "OPENBLAS_NUM_THREADS" in unset and "numpy" in sys.modules:
        _limit_loaded_openblas(int(PROCESS_ENVIRONMENT["OPENBLAS_NUM_THREADS"]))
    if not keep_freed_memory:
        return False
    from .core.resident_memory import keep_freed_memory as keep

    return keep()


#: The thread-count setters of OpenBLAS builds: the plain library, and NumPy's wheels'
#: (``scipy_openblas``, 64-bit integers).
_OPENBLAS_SETTERS = ("openblas_set_num_threads", "scipy_openblas_set_num_threads64_",
                     "openblas_set_num_threads64_", "scipy_openblas_set_num_threads")


def _limit_loaded_openblas(threads: int) -> None:
    """Set the thread count of every OpenBLAS this process has loaded (Linux: found in
    ``/proc/self/maps``); nothing where there is none or it has no setter."""
    import ctypes

    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower()}
    except OSError:
        return
    for path in sorted(p for p in paths if ".so" in p):
        try:
            library = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(library, name) for name in _OPENBLAS_SETTERS
                       if hasattr(library, name)), None)
        if setter is not None:
            setter(threads)
