"""Per-view work in threads: results in order, errors where they belong."""

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from sfs_ros.core.workers import map_in_threads, worker_count


def test_results_come_in_the_items_order():
    # With two threads or more, each odd item finishes before the even one before it
    # (which waits for it to start), yet the results come back in the items' order.
    started = [threading.Event() for _ in range(40)]

    def work(n):
        started[n].set()
        if n % 2 == 0 and worker_count() > 1:
            assert started[n + 1].wait(timeout=60.0)  # a bound on a hang, never reached
        return n * n

    assert list(map_in_threads(work, range(40))) == [n * n for n in range(40)]
    assert list(map_in_threads(work, [])) == []


def test_an_error_is_raised_at_its_item():
    def work(n):
        if n == 5:
            raise ValueError("item 5 is bad")
        return n

    results = map_in_threads(work, range(20))
    assert [next(results) for _ in range(5)] == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match="item 5 is bad"):
        next(results)


def test_at_least_one_worker():
    assert worker_count() >= 1


@pytest.mark.parametrize("given, expected", [(None, "1"), ("3", "3")])
def test_blas_runs_one_thread_unless_the_user_says_otherwise(given, expected):
    # A process's set-up (first in each main()) sets BLAS's threads before numpy loads; a
    # user's value wins.
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    out = subprocess.run([sys.executable, "-c", "import os; from sfs_ros.process import "
                          "configure_process; configure_process(); import numpy; "
                          "print(os.environ['OPENBLAS_NUM_THREADS'])"],
                         env=env, capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == expected
