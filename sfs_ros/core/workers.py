"""Per-view work in threads: decoding, segmentation and distance transforms run in
OpenCV, which releases Python's lock, so views go through the cores side by side."""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor

__all__ = ["worker_count", "map_in_threads"]


def worker_count() -> int:
    """Threads for per-view work: the cores this process may run on (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # platforms without affinity
        return max(1, os.cpu_count() or 1)


def map_in_threads(fn: Callable, items: Iterable) -> Iterator:
    """``fn(item)`` for every item, computed :func:`worker_count` at a time; the results in
    the items' order, each as soon as it and those before it are done. At most twice as
    many results as threads wait to be taken (a memory bound for large results). An
    exception of ``fn`` is raised when its result is reached; the items not started by
    then are dropped."""
    items = list(items)
    workers = min(worker_count(), len(items))
    if workers <= 1:
        yield from map(fn, items)
        return
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        pending = deque()
        for item in items:
            pending.append(pool.submit(fn, item))
            if len(pending) >= 2 * workers:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
