"""What the meshing node's status and diagnostics report, kept without ROS and safe from
any thread."""

from __future__ import annotations

import threading

__all__ = ["MeshingStatus"]


class MeshingStatus:
    """The meshes made and failed, the last mesh and its session folder, the problem (until
    the next mesh), and where the last carved scan's images came from (``images_held``:
    held here as they came; ``images_carried``: carried by it)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._counts = {"reconstructions": 0, "reconstruction_failures": 0,
                        "images_held": 0, "images_carried": 0}
        self._problem = ""
        self._mesh_path = self._session_dir = ""

    def meshed(self, mesh_path: str, session_dir: str, images_held: int,
               images_carried: int) -> None:
        """A mesh was written to ``mesh_path`` from the scan in ``session_dir``."""
        with self._lock:
            self._counts["reconstructions"] += 1
            self._counts["images_held"] = images_held
            self._counts["images_carried"] = images_carried
            self._mesh_path, self._session_dir = mesh_path, session_dir
            self._problem = ""

    def failed(self) -> None:
        """A reconstruction failed (its problem is reported too)."""
        with self._lock:
            self._counts["reconstruction_failures"] += 1

    def report(self, problem: str) -> None:
        with self._lock:
            self._problem = problem

    def status(self) -> dict:
        """The ``ReconstructionStatus`` fields: ``session_dir``, ``reconstructions``,
        ``mesh_path``, ``problem``."""
        with self._lock:
            return {"session_dir": self._session_dir,
                    "reconstructions": self._counts["reconstructions"],
                    "mesh_path": self._mesh_path, "problem": self._problem}

    def diagnostics(self) -> tuple[dict, str]:
        """``(counts, problem)`` as they are now."""
        with self._lock:
            return dict(self._counts), self._problem
