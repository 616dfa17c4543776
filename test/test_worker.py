"""The nodes' job worker (sfs_ros.ros.worker), without ROS: order, errors, holds, stopping."""

import threading

import pytest

from sfs_ros.ros.worker import JobCancelled, Worker

WAIT_S = 10.0   # generous deadline for a thread to react; never reached when all is well


def _worker(errors=None):
    return Worker("test-worker", on_error=lambda name, exc: (errors if errors is not None
                                                               else []).append((name, exc)))


def _blocker(worker):
    """Submit a job that runs until the returned event is set; returns (started, release)."""
    started, release = threading.Event(), threading.Event()

    def block():
        started.set()
        assert release.wait(WAIT_S)
    worker.submit(block, name="block")
    assert started.wait(WAIT_S)
    return started, release


def test_jobs_run_in_submission_order_and_futures_carry_their_answers():
    worker = _worker()
    order = []
    futures = [worker.submit(lambda i=i: order.append(i) or i * i, name=f"job{i}")
               for i in range(50)]
    assert [f.result(WAIT_S) for f in futures] == [i * i for i in range(50)]
    assert order == list(range(50))
    worker.stop()
    assert worker.join(WAIT_S)


def test_an_exception_lands_in_the_future_and_on_error_and_the_thread_goes_on():
    errors = []
    worker = _worker(errors)

    def broken():
        raise KeyError("no such view")
    failed = worker.submit(broken, name="view")
    after = worker.submit(lambda: "still serving")
    with pytest.raises(KeyError, match="no such view"):
        failed.result(WAIT_S)
    assert after.result(WAIT_S) == "still serving"
    assert [(name, type(exc)) for name, exc in errors] == [("view", KeyError)]
    worker.stop()
    assert worker.join(WAIT_S)


def test_a_failing_error_handler_does_not_end_the_thread(capsys):
    def bad_handler(_name, _exc):
        raise RuntimeError("handler broke")
    worker = Worker("test-worker", on_error=bad_handler)
    worker.submit(lambda: 1 / 0, name="divide")
    assert worker.submit(lambda: 7).result(WAIT_S) == 7
    assert "handler broke" in capsys.readouterr().err
    worker.stop()
    assert worker.join(WAIT_S)


def test_stop_runs_the_jobs_already_submitted_then_ends():
    worker = _worker()
    _, release = _blocker(worker)
    futures = [worker.submit(lambda i=i: i) for i in range(5)]
    worker.stop()
    late = worker.submit(lambda: "too late", name="late")
    release.set()
    assert worker.join(WAIT_S)
    assert [f.result(0) for f in futures] == list(range(5))
    with pytest.raises(JobCancelled, match="late: the worker is stopping"):
        late.result(0)


def test_stop_with_a_reason_cancels_the_waiting_jobs():
    worker = _worker()
    ran = []
    _, release = _blocker(worker)
    futures = [worker.submit(lambda i=i: ran.append(i)) for i in range(3)]
    worker.stop(cancel_reason="node shutting down")
    release.set()
    assert worker.join(WAIT_S)
    assert ran == []
    for future in futures:
        with pytest.raises(JobCancelled, match="node shutting down"):
            future.result(0)


def test_cancel_pending_drops_waiting_jobs_but_not_the_running_one():
    worker = _worker()
    started, release = threading.Event(), threading.Event()
    running = worker.submit(lambda: started.set() or release.wait(WAIT_S), name="move")
    assert started.wait(WAIT_S)
    assert worker.current == "move"
    waiting = worker.submit(lambda: "old", name="move")
    assert worker.pending() == 1
    assert worker.cancel_pending("superseded by a later request") == 1
    newest = worker.submit(lambda: "new", name="move")
    release.set()
    assert running.result(WAIT_S) is True
    assert newest.result(WAIT_S) == "new"
    with pytest.raises(JobCancelled, match="superseded"):
        waiting.result(0)
    worker.stop()
    assert worker.join(WAIT_S)
    assert worker.current is None


def test_a_hold_keeps_the_next_job_waiting_until_released():
    worker = _worker()
    hold = worker.hold()
    future = worker.submit(lambda: "ran")
    # While held the job must not start: it stays pending (checked at once, and again after
    # a job on another worker has had every chance to run).
    other = _worker()
    other.submit(lambda: None).result(WAIT_S)
    assert not future.done() and worker.pending() == 1
    with hold:
        pass                       # leaving the context releases it
    hold.release()                 # idempotent: a second release changes nothing
    assert future.result(WAIT_S) == "ran"
    second = worker.hold()
    assert second is not hold
    second.release()
    assert worker.submit(lambda: 2).result(WAIT_S) == 2
    for w in (worker, other):
        w.stop()
        assert w.join(WAIT_S)


def test_a_future_cancelled_by_its_caller_is_skipped():
    worker = _worker()
    ran = []
    _, release = _blocker(worker)
    future = worker.submit(lambda: ran.append("no"))
    assert future.cancel()
    after = worker.submit(lambda: "yes")
    release.set()
    assert after.result(WAIT_S) == "yes"
    assert ran == []
    worker.stop()
    assert worker.join(WAIT_S)


def test_a_job_must_be_callable():
    worker = _worker()
    with pytest.raises(ValueError, match="must be callable"):
        worker.submit(("start", None, 3))
    worker.stop()
    assert worker.join(WAIT_S)


def test_the_worker_is_idle_once_a_job_is_answered():
    worker = _worker()
    for run in (lambda: "fine", lambda: 1 / 0):
        future = worker.submit(run, name="move")
        future.exception(WAIT_S)
        assert worker.current is None     # no stale "move" for a caller that saw the answer
    worker.stop()
    assert worker.join(WAIT_S)
