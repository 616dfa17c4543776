"""Resident working memory: after keep_freed_memory and prefault, new arrays fault no pages.

Each case runs in a child process: the malloc settings are the whole process's.
"""

import os
import platform
import subprocess
import sys

import pytest

from sfs_ros.core.resident_memory import prefault
from sfs_ros.process import KEEP_FREED_MEMORY_ENVIRONMENT

#: The child: optionally keep freed memory and touch 64 MiB of heap, then take 32 arrays
#: of 1 MiB (below numpy's 4 MiB huge-page advice: plain 4 KiB pages), write every page,
#: and print the faults that took. 32 MiB of fresh memory is 8192 pages of 4 KiB.
CHILD = """
import sys
import numpy as np
from sfs_ros.core.resident_memory import keep_freed_memory, page_faults, prefault
kept = keep_freed_memory() if "keep" in sys.argv else False
touched = prefault(64 << 20, memory_kept=kept) if "prefault" in sys.argv else False
before = page_faults()
arrays = [np.ones(1 << 20, np.uint8) for _ in range(32)]
print(kept, touched, page_faults() - before)
"""
FRESH_PAGES = 32 * (1 << 20) // 4096
#: The child as the carving node runs when sfs-cell or a launch file starts it: malloc's
#: settings in its environment from the start (``KEEP_FREED_MEMORY_ENVIRONMENT``, read
#: before rclpy's import starts threads), its module imported, then main()'s set-up;
#: rclpy's threads (a multi-threaded executor spinning), the heap touched in the main
#: thread (the node's constructor), the arrays taken in another (its worker). Set up after
#: rclpy's import alone, the worker took its own arena about every other run, and 8194
#: faults.
NODE_CHILD = """
import threading
import sfs_ros.nodes.carving_node
from sfs_ros.process import configure_process
kept = configure_process(keep_freed_memory=True)
import numpy as np
import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from sfs_ros.core.resident_memory import page_faults, prefault
rclpy.init()
node = Node("resident_memory_probe")
executor = MultiThreadedExecutor(num_threads=3)
executor.add_node(node)
spinning = threading.Thread(target=executor.spin)
spinning.start()
touched = prefault(64 << 20, memory_kept=kept)
faults = []
def worker():
    before = page_faults()
    arrays = [np.ones(1 << 20, np.uint8) for _ in range(32)]
    faults.append(page_faults() - before)
thread = threading.Thread(target=worker)
thread.start()
thread.join()
print(kept, touched, faults[0])
executor.shutdown()
spinning.join()
node.destroy_node()
rclpy.try_shutdown()
"""


def _child(*flags: str, script: str = CHILD, env=None) -> tuple[bool, bool, int]:
    out = subprocess.run([sys.executable, "-c", script, *flags], capture_output=True,
                         text=True, check=True, timeout=120, env=env).stdout.split()
    return out[0] == "True", out[1] == "True", int(out[2])


def test_the_package_runs_on_glibc():
    """The settings are glibc's mallopt; the cell's machines (Debian) have it."""
    assert platform.libc_ver()[0] == "glibc"


def test_prefaulted_heap_serves_new_arrays_without_faults():
    kept, touched, faults = _child("keep", "prefault")
    assert kept and touched
    # Only the pages of bookkeeping and the interpreter's own allocations may fault: far
    # under a tenth of the 8192 a fresh 32 MiB takes.
    assert faults < FRESH_PAGES // 10


def test_without_prefault_the_same_arrays_fault_their_pages():
    """The control: kept memory alone does not make fresh pages resident."""
    kept, touched, faults = _child("keep")
    assert kept and not touched
    assert faults > FRESH_PAGES // 2     # every 4 KiB page faults once; some heap may exist


def test_prefault_only_after_keep_and_refuses_bad_sizes():
    # Without keep_freed_memory, freed pages would go back at once: none are touched.
    assert _child("prefault")[:2] == (False, False)
    for bad in (-1, True, 1.5, "1M"):
        with pytest.raises(ValueError, match="reserve_bytes"):
            prefault(bad, memory_kept=True)


def test_the_carving_nodes_worker_thread_reuses_the_heap_its_constructor_touched():
    # Started with malloc's settings in its environment (as sfs-cell and the launch files
    # start it), malloc is set up before rclpy's import starts threads: all threads share
    # the one arena, so the worker finds the pages the constructor touched.
    env = os.environ | KEEP_FREED_MEMORY_ENVIRONMENT
    kept, touched, faults = _child(script=NODE_CHILD, env=env)
    assert kept and touched
    assert faults < FRESH_PAGES // 10     # as in the single-threaded case above
