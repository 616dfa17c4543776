"""A request sent again gets the answer already made, not the work done twice.

A ROS 2 service request can be lost, and so can its answer: a client that has just found a
restarted server may send before the server's endpoints are matched with its own (the
dead server's endpoints stay in the graph until their lease ends). The client then sends
again (:meth:`sfs_ros.ros.cell_client.CellClient.reconstruct`); a request carries no id
of its own a server could see, and a resend is a new call. So the server recognises a
repeat by what is asked: the same options, carved of the same views, answered a moment
ago. Requests wait in line while one is made (one at a time), so the repeats of a
long reconstruction come right after its answer; :data:`REPEAT_WINDOW_S` leaves room for
a loaded machine, where the line moves slowly. A request later than that, one that asks
anything else or one of a scan that changed is made afresh (so are the copies of a
request that failed).
"""

from __future__ import annotations

import threading
import time
from dataclasses import astuple

import numpy as np

from .mesh_options import MeshOptions

__all__ = ["REPEAT_WINDOW_S", "RepeatedRequests", "request_key"]

#: Seconds after an answer during which the same request on the same scan is a repeat.
REPEAT_WINDOW_S = 30.0


def request_key(options: MeshOptions, scan: str, views_received: int) -> tuple:
    """What makes two requests the same: every option (the box by its exact bytes), and the
    carving they got: the scan's folder ``scan`` and its ``views_received`` (a scan only
    grows, so the count names the views)."""
    fields = tuple(v.tobytes() if isinstance(v, np.ndarray) else v for v in astuple(options))
    return fields, scan, int(views_received)


class RepeatedRequests:
    """The last answer, given again to the same request within ``window_s`` of it.

    Thread-safe. ``clock``: seconds, monotonic (tests pass their own).
    """

    def __init__(self, window_s: float = REPEAT_WINDOW_S, clock=time.monotonic):
        if not window_s >= 0:
            raise ValueError(f"window_s must be >= 0 seconds, got {window_s}")
        self.window_s = float(window_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._last: tuple | None = None     # (key, answer, when)

    def recall(self, key):
        """The answer given to ``key`` less than ``window_s`` ago, else None."""
        with self._lock:
            if self._last is None:
                return None
            last_key, answer, when = self._last
            return answer if last_key == key and self._clock() - when <= self.window_s \
                else None

    def remember(self, key, answer) -> None:
        """``answer`` was given to ``key`` now (it replaces the one before)."""
        with self._lock:
            self._last = (key, answer, self._clock())
