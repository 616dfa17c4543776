"""What the recorder's diagnostics report, kept without ROS and safe from any thread."""

from __future__ import annotations

import threading

__all__ = ["RecordingStatus"]


class RecordingStatus:
    """The bag being recorded (``recording``, ``path``, ``storage``, ``messages``,
    ``bytes``, ``write_s``: seconds spent writing it, ``parameters_from``: the nodes whose
    parameters came for it, comma-separated), ``bags`` closed since start-up, the problem
    and the warning (until the next bag opens)."""

    def __init__(self, storage: str):
        self._lock = threading.Lock()
        self._values = {"recording": False, "path": "", "storage": storage, "messages": 0,
                        "bytes": 0, "write_s": 0.0, "parameters_from": "", "bags": 0}
        self._problem = self._warning = ""

    @property
    def path(self) -> str:
        with self._lock:
            return self._values["path"]

    def opened(self, path) -> None:
        """A bag opened at ``path``: nothing written yet, no problem."""
        with self._lock:
            self._values.update(recording=True, path=str(path), messages=0, bytes=0,
                                write_s=0.0, parameters_from="")
            self._problem = self._warning = ""

    def wrote(self, messages: int, nbytes: int, seconds: float) -> None:
        """The bag holds ``messages`` of ``nbytes``; one more write took ``seconds``."""
        with self._lock:
            self._values.update(messages=messages, bytes=nbytes,
                                write_s=self._values["write_s"] + seconds)

    def parameters_came(self, node: str) -> None:
        """The parameters of ``node`` came for the bag being recorded."""
        with self._lock:
            came = self._values["parameters_from"]
            self._values["parameters_from"] = f"{came},{node}" if came else node

    def closed(self) -> float:
        """The bag was closed; the seconds spent writing it."""
        with self._lock:
            self._values.update(recording=False, bags=self._values["bags"] + 1)
            return self._values["write_s"]

    def abandoned(self) -> None:
        """The bag was given up (a failed write)."""
        with self._lock:
            self._values["recording"] = False

    def report(self, *, problem: str | None = None, warning: str | None = None) -> None:
        with self._lock:
            if problem is not None:
                self._problem = problem
            if warning is not None:
                self._warning = warning

    def snapshot(self) -> tuple[dict, str, str]:
        """``(values, problem, warning)`` as they are now."""
        with self._lock:
            return (dict(self._values, write_s=round(self._values["write_s"], 4)),
                    self._problem, self._warning)
