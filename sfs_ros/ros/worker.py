"""One thread that runs a node's jobs in order, off the executor (no ROS imports).

A job is a callable and a name (the name is for logs and diagnostics); what
it returns, or the exception it raises, is the answer of the
:class:`concurrent.futures.Future` that :meth:`Worker.submit` gives back.
There is no protocol of job kinds: whatever was submitted is what runs, so an
unknown job cannot exist. An exception never ends the thread: it lands in the
job's future and is handed to ``on_error`` (to log it with the job's name).

Besides plain first-in-first-out, two things the motor node needs:

* :meth:`Worker.cancel_pending` drops the jobs still waiting (their futures
  get :class:`JobCancelled` with the reason), e.g. when a newer command
  supersedes them;
* :meth:`Worker.hold` keeps the worker from starting the next job until the
  hold is released (the running one goes on), e.g. while the axes are being
  stopped.

Stopping: :meth:`Worker.stop` lets the jobs already submitted run (or cancels
them with a reason), then the thread ends; :meth:`Worker.join` waits for that.
A job submitted after :meth:`Worker.stop` is not run: its future gets
:class:`JobCancelled` at once.
"""

from __future__ import annotations

import threading
import traceback
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, Callable

__all__ = ["JobCancelled", "JobsOnHold", "Worker", "internal_error"]



def internal_error(job: str, exc: Exception) -> str:
    """One line for a job that failed on a bug, not on its input: its name and the
    exception."""
    return f"internal error in {job}: {type(exc).__name__}: {exc}"

class JobCancelled(Exception):
    """The job was dropped before it ran; the text says why."""


@dataclass(frozen=True)
class _Job:
    name: str
    run: Callable[[], Any]
    future: Future = field(default_factory=Future)


class JobsOnHold:
    """Keeps a :class:`Worker` from starting jobs until :meth:`release` (idempotent);
    also a context manager."""

    def __init__(self, worker: "Worker"):
        self._worker = worker
        self._released = False

    def release(self) -> None:
        with self._worker._cv:
            if self._released:
                return
            self._released = True
            self._worker._holds -= 1
            self._worker._cv.notify_all()

    def __enter__(self) -> "JobsOnHold":
        return self

    def __exit__(self, *_exc) -> None:
        self.release()


class Worker:
    """A thread draining a queue of jobs in submission order.

    Parameters
    ----------
    name : str
        Name of the thread.
    on_error : callable(job_name: str, exc: Exception), keyword-only
        Called in the worker thread with every exception a job raises (after
        it was set on the job's future). An exception of ``on_error`` itself
        is printed to stderr: nothing may end the thread.

    A job whose future was cancelled (``Future.cancel``) before it started is
    skipped.
    """

    def __init__(self, name: str, *, on_error: Callable[[str, Exception], None]):
        self._on_error = on_error
        self._cv = threading.Condition()
        self._jobs: deque[_Job] = deque()
        self._holds = 0
        self._stopping = False
        self._current: str | None = None
        self._thread = threading.Thread(target=self._drain, name=name, daemon=True)
        self._thread.start()

    @property
    def current(self) -> str | None:
        """Name of the job running now, None when idle."""
        return self._current

    def pending(self) -> int:
        """Number of jobs waiting to run."""
        with self._cv:
            return len(self._jobs)

    def submit(self, run: Callable[[], Any], *, name: str | None = None) -> Future:
        """Queue ``run()`` (``name``: for logs, default the callable's ``__name__``); its
        future."""
        if not callable(run):
            raise ValueError(f"a job must be callable, got {run!r}")
        job = _Job(name or getattr(run, "__name__", type(run).__name__), run)
        with self._cv:
            if self._stopping:
                job.future.set_exception(JobCancelled(f"{job.name}: the worker is stopping"))
                return job.future
            self._jobs.append(job)
            self._cv.notify_all()
        return job.future

    def cancel_pending(self, reason: str) -> int:
        """Drop every job still waiting: its future gets ``JobCancelled(reason)``. How many."""
        with self._cv:
            dropped = list(self._jobs)
            self._jobs.clear()
        for job in dropped:
            job.future.set_exception(JobCancelled(reason))
        return len(dropped)

    def hold(self) -> JobsOnHold:
        """Start no further job until the returned :class:`Hold` is released."""
        with self._cv:
            self._holds += 1
        return JobsOnHold(self)

    def stop(self, *, cancel_reason: str | None = None) -> None:
        """End the thread once the waiting jobs have run (``cancel_reason`` given: once they
        are cancelled with it). Does not wait: see :meth:`join`."""
        with self._cv:
            self._stopping = True
            self._cv.notify_all()
        if cancel_reason is not None:
            self.cancel_pending(cancel_reason)

    def join(self, timeout_s: float | None = None) -> bool:
        """Wait for the thread to end (after :meth:`stop`); whether it has."""
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _drain(self) -> None:
        while True:
            with self._cv:
                while not (self._jobs and not self._holds) and not (
                        self._stopping and not self._jobs):
                    self._cv.wait()
                if not self._jobs:        # stopping, nothing left
                    return
                job = self._jobs.popleft()
                self._current = job.name
            if not job.future.set_running_or_notify_cancel():
                self._idle()
                continue
            try:
                answer = job.run()
            except Exception as exc:  # noqa: BLE001 -- a job's fault must not end the thread
                self._idle()
                job.future.set_exception(exc)
                try:
                    self._on_error(job.name, exc)
                except Exception:  # noqa: BLE001 -- nor may the report of it
                    traceback.print_exc()
            else:
                self._idle()
                job.future.set_result(answer)

    def _idle(self) -> None:
        """No job runs: cleared before a job's future is answered, so whoever sees the
        answer sees the worker idle (or on a later job)."""
        with self._cv:
            self._current = None
