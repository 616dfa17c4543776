"""Keep a long-running process's working memory resident between jobs.

A reconstruction allocates a few hundred megabytes of arrays and frees them
when it ends. glibc's malloc gives large blocks back to the system (``munmap``,
heap trimming), so the next reconstruction touches fresh pages again, and
every first touch of a page is a page fault: faulting the working set in again
is a large part of a reconstruction's latency (``doc/changelog.md``, 4 December,
evening).

The usual set-up of latency-bound processes (as ROS 2's real-time guides
describe for their nodes): :func:`keep_freed_memory` makes malloc keep what it
was given (``M_TRIM_THRESHOLD`` off, ``M_MMAP_MAX`` 0: every block from the
heap, none handed back) and makes all threads share one arena (``M_ARENA_MAX``
1: the thread that reconstructs reuses what the others touched); then
:func:`prefault` touches a block of the expected working size once and frees
it, so the heap holds faulted pages before the first job needs them. The cost
is that the process keeps its largest footprint until it ends.

glibc only: elsewhere (another C library) nothing is changed. Linux only for
the fault counts in :func:`page_faults`.
"""

from __future__ import annotations

import ctypes
import resource

import numpy as np

__all__ = ["keep_freed_memory", "prefault", "page_faults"]

# mallopt parameters (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8
#: Page size of the touch loop; larger pages (huge pages) are touched as well.
_PAGE_BYTES = 4096


def _mallopt():
    """glibc's ``mallopt``, or None when the C library has none."""
    try:
        function = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    function.argtypes, function.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return function


def keep_freed_memory() -> bool:
    """Make malloc keep what it frees (no trimming, no mmap) in one arena for all threads.

    Call it first thing in the process, before threads start, and so before
    importing rclpy, whose import starts some: a thread that took an arena of its
    own keeps it, and the threads made later are dealt out among the arenas there
    are, so a worker may allocate in another arena than the one the memory was
    touched in. True when the settings took (glibc), False when nothing was changed.
    """
    mallopt = _mallopt()
    if mallopt is None:
        return False
    # mallopt answers 1 on success; -1 as the trim threshold is the largest size_t.
    answers = [mallopt(_M_ARENA_MAX, 1), mallopt(_M_MMAP_MAX, 0), mallopt(_M_TRIM_THRESHOLD, -1)]
    return all(answer == 1 for answer in answers)


def prefault(reserve_bytes: int, *, memory_kept: bool) -> bool:
    """Touch ``reserve_bytes`` (integer >= 0) of fresh heap once and free it, so that the
    heap holds those pages for the jobs to come. Only where ``memory_kept`` (what
    :func:`keep_freed_memory` answered: else the pages would be handed back at once):
    whether it touched them."""
    if isinstance(reserve_bytes, bool) or not isinstance(reserve_bytes, (int, np.integer)) \
            or reserve_bytes < 0:
        raise ValueError(f"reserve_bytes must be an integer >= 0, got {reserve_bytes!r}")
    if not memory_kept or not reserve_bytes:
        return False
    block = np.empty(int(reserve_bytes), dtype=np.uint8)
    block[::_PAGE_BYTES] = 1        # one write per page faults it in
    del block
    return True


def page_faults() -> int:
    """Minor page faults of this process so far (all threads)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
