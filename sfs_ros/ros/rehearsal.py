"""A node's rehearsal: a small simulated scan reconstructed beside the node's work at start.

:func:`sfs_ros.cell_logic.rehearsal.rehearse` loads the code a reconstruction runs, so the
first real one finds it loaded. It runs in a thread of its own, beside the node's
worker (with kernels still to compile, on a fresh install, it takes minutes, and views
and requests must not wait for it), in a folder of the node's output folder that is
removed after; one named after the node, so that the cell's nodes sharing a folder do
not remove each other's.
"""

from __future__ import annotations

import shutil
import tempfile
import threading
import time
from pathlib import Path

from sfs_ros.cell_logic.rehearsal import rehearse

__all__ = ["REHEARSAL_PREFIX", "Rehearsal"]

#: Folder name prefix of a rehearsal's scan in the output folder (then the node's name).
REHEARSAL_PREFIX = ".rehearsal_"
#: How long stopping the node waits for a rehearsal still running, s.
REHEARSAL_JOIN_S = 2.0


class Rehearsal:
    """Rehearse in a thread for ``node`` (an rclpy node) in ``output_dir``; a failure (a
    full disk) is logged as a warning and changes nothing else."""

    def __init__(self, node, output_dir):
        self._node = node
        self._prefix = f"{REHEARSAL_PREFIX}{node.get_name()}_"
        self._output_dir = Path(output_dir)
        self._thread = threading.Thread(target=self._run, name="rehearsal", daemon=True)
        self._thread.start()

    def join(self) -> None:
        """Wait (:data:`REHEARSAL_JOIN_S` at most) for the rehearsal; one still running is
        left to end with the process (its folder goes at the next start)."""
        self._thread.join(timeout=REHEARSAL_JOIN_S)

    def _run(self) -> None:
        start = time.perf_counter()
        for stale in self._output_dir.glob(f"{self._prefix}*"):
            if stale.is_dir() and not stale.is_symlink():
                shutil.rmtree(stale, ignore_errors=True)
        try:
            with tempfile.TemporaryDirectory(prefix=self._prefix,
                                             dir=self._output_dir) as folder:
                rehearse(folder)
        except (ValueError, OSError) as exc:
            self._log("warning", f"rehearsal reconstruction failed ({exc}); the first "
                      "scan's reconstruction loads its code itself")
            return
        self._log("info", f"rehearsal reconstruction done in {time.perf_counter() - start:.2f} s")

    def _log(self, level: str, text: str) -> None:
        """Log from a thread that may outlive the node: nothing once it has stopped."""
        try:
            if self._node.context.ok():
                getattr(self._node.get_logger(), level)(text)
        except Exception:  # noqa: BLE001 -- stopped between the test and the call
            return
