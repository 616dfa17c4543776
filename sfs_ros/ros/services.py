"""Calling a service from a worker thread: a deadline and specific exceptions.

As controller_manager's ``controller_manager_services.py`` does: wait for the
service, call it, wait for the answer, each with a deadline, and raise an
exception that says which service failed and how. The node must be spun by
another thread (a multi-threaded executor) while :func:`call` waits.
"""

from __future__ import annotations

import threading
import time

__all__ = ["PARAMETER_RESEND_S", "ServiceError", "call"]

#: Seconds after which an unanswered parameter get or set is sent again (each may run
#: twice; Fast DDS may drop the answer to a client it has just matched: :func:`call`).
PARAMETER_RESEND_S = 2.0


class ServiceError(RuntimeError):
    """A service was not available or did not answer in time."""


def call(client, request, *, timeout_s: float, cancelled: threading.Event | None = None,
         resend_after_s: float | None = None, keep_resending: bool = False):
    """Call ``client`` with ``request``; the response, or :class:`ServiceError`.

    ``cancelled``, when set meanwhile, ends the wait early (ServiceError too).
    ``resend_after_s``: for quick services that may safely run twice, send the
    request again when no answer has come after this long. Fast DDS drops a
    response when the client's reply reader is not matched yet at the server
    (it waits 100 ms), which happens to a client just made ready on a loaded
    machine; the first answer to come is taken. ``keep_resending``: then again
    after twice as long each time, until the deadline (for a server that knows a
    request sent again, however long its work takes: a request sent to a server just
    restarted may be lost too).
    """
    deadline = time.monotonic() + timeout_s
    while not client.service_is_ready():
        if time.monotonic() > deadline:
            raise ServiceError(f"service {client.srv_name} is not available "
                               f"(waited {timeout_s:g} s): is its node running?")
        if cancelled is not None and cancelled.is_set():
            raise ServiceError(f"call of {client.srv_name} cancelled")
        time.sleep(0.05)
    answered = threading.Event()
    futures = []

    def send():
        future = client.call_async(request)
        future.add_done_callback(lambda _f: answered.set())
        futures.append(future)

    send()
    wait_s = resend_after_s
    resend_at = None if wait_s is None else time.monotonic() + wait_s
    while not answered.wait(0.05):
        now = time.monotonic()
        if now > deadline or (cancelled is not None and cancelled.is_set()):
            for future in futures:
                future.cancel()
                client.remove_pending_request(future)
            why = "cancelled" if now <= deadline else f"not answered within {timeout_s:g} s"
            raise ServiceError(f"call of {client.srv_name} {why}")
        if resend_at is not None and now > resend_at:
            send()
            wait_s *= 2
            resend_at = now + wait_s if keep_resending else None
    done = next(f for f in futures if f.done())
    for future in futures:
        if future is not done:
            future.cancel()
            client.remove_pending_request(future)
    return done.result()
