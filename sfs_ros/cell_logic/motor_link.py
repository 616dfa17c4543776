"""The motor node's link to its GRBL controller, and what it reports of it (no ROS).

:class:`MotorLink` opens the port and reopens it after a loss, polls the controller's
status, drives moves and homing, stops the axes, and keeps the state the diagnostics
report: the controller's state and alarm, the last fault (until the next good move or
homing), the counts, a late or missing status report. It tells through two callables:
``log(level, text)`` (``"info"``, ``"warning"`` or ``"error"``) and ``changed()`` (the
diagnostics are due).

The alarm lock of a controller just powered up (GRBL with homing enabled: state Alarm
without an alarm code) is a state, not a fault (:data:`LOCKED`); a status report later
than the poll's timeout is a warning; the controller silent for ``silent_error_s`` is a
fault ("no answer").
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from sfs_ros.hardware.driver import (
    ConnectionLost,
    GrblClient,
    MotionCancelled,
    MotorAlarm,
    MotorError,
    MotorTimeout,
)

__all__ = ["LOCKED", "MotorLink"]

#: The alarm of a controller just powered up with homing enabled: a state, its remedy home.
LOCKED = "alarm lock since power-up: home the axes (motor/home) before moving"


class MotorLink:
    """The controller on ``port`` at ``baudrate``, reopened every ``reconnect_period_s``
    after a loss (by the caller's timer, :meth:`reconnect`). Its methods are called from
    the node's timers, services and worker: the port is taken and given up under a lock,
    each call works on the client it found."""

    def __init__(self, port: str, baudrate: int, reconnect_period_s: float, *,
                 log: Callable[[str, str], None], changed: Callable[[], None]):
        self.port = port
        self._baudrate = baudrate
        self._reconnect_period_s = reconnect_period_s
        self._log = log
        self._changed = changed
        self._client_lock = threading.Lock()
        self._fault_lock = threading.RLock()  # a fault reported with its own text
        self.client: GrblClient | None = None
        self.connection_error = ""
        self.fault = ""                    # the last fault, "" after a good move / homing
        self.faults = 0
        self.refused = 0
        self.state = "unknown"
        self.position: tuple[float, float] | None = None
        self.alarm = ""
        self.answered_at = time.monotonic()   # the controller's last status report
        self.late = ""                     # a status poll went unanswered (warning)

    # -- connection --------------------------------------------------------------------------

    def open(self, *, first: bool) -> bool:
        """Open the port; whether it is open. A port that cannot be opened is a warning at
        the first try (``first``) and, after a loss, an error once per reason."""
        try:
            client = GrblClient(self.port, baudrate=self._baudrate)
        except (MotorError, ValueError) as exc:
            if first:
                self._log("warning", f"configure failed: {exc}")
            elif str(exc) != self.connection_error:
                self._log("error", f"{exc}; retrying every {self._reconnect_period_s} s")
            self.connection_error = str(exc)
            self._changed()
            return False
        with self._client_lock:
            self.client = client
        self.connection_error = ""
        self.answered_at = time.monotonic()
        self._log("info", f"connected to the motor controller on {self.port}")
        self._changed()
        return True

    def reconnect(self) -> None:
        """Reopen a lost port (a timer's call)."""
        if self.client is None:
            self.open(first=False)

    def lost(self, exc: Exception) -> None:
        """The port failed: close it; :meth:`reconnect` reopens it."""
        with self._client_lock:
            client, self.client = self.client, None
        if client is not None:
            client.close()
            self.connection_error = f"connection lost: {exc}"
            self.state, self.position = "disconnected", None
            self._log("error", f"{self.connection_error}; retrying every "
                               f"{self._reconnect_period_s} s")
            self._changed()

    def close(self) -> None:
        with self._client_lock:
            client, self.client = self.client, None
        if client is not None:
            client.close()
        self.state, self.position, self.connection_error = "unknown", None, ""

    # -- polling -----------------------------------------------------------------------------

    def expect_reports(self) -> None:
        """The polling starts: the controller's silence counts from now."""
        self.answered_at = time.monotonic()

    def poll(self, timeout_s: float, silent_error_s: float) -> tuple[float, float] | None:
        """Ask the controller's status (``timeout_s`` at most); the axes' ``(theta, phi)``,
        rad, when known, else None."""
        client = self.client
        if client is None:
            return None
        try:
            status = client.status(timeout_s=timeout_s)
        except ConnectionLost as exc:
            self.lost(exc)
            return None
        except MotorAlarm as exc:
            self.state, self.position = "Alarm", None
            self._set_alarm(str(exc))
            return None
        except MotorTimeout as exc:
            self._unanswered(str(exc), silent_error_s)
            return None
        except MotorError as exc:
            self.report_fault(str(exc))
            return None
        self._answered()
        self.state = status.state
        if status.state == "Alarm":
            code = client.alarm_code
            self._set_alarm(str(MotorAlarm(code)) if code is not None else LOCKED)
        else:
            self.alarm = ""
        if math.isfinite(status.theta_rad) and math.isfinite(status.phi_rad):
            self.position = (status.theta_rad, status.phi_rad)
            return self.position
        return None

    def _unanswered(self, text: str, silent_error_s: float) -> None:
        """A status poll went unanswered: a warning, and once the controller has been silent
        for ``silent_error_s`` a fault (state "no answer"), each said once."""
        silent_s = time.monotonic() - self.answered_at
        if silent_s >= silent_error_s:
            if self.state != "no answer":
                self.state = "no answer"
                self.report_fault(f"no answer from the motor controller for {silent_s:.1f} s: "
                                  f"{text}")
        elif not self.late:
            self.late = f"a status report came late ({text}); waiting for the next one"
            self._log("warning", self.late)
            self._changed()

    def _answered(self) -> None:
        """A status report came: the controller answers (again)."""
        self.answered_at = time.monotonic()
        if self.state == "no answer":
            self._log("info", "the motor controller answers again")
        self.late = ""

    def _set_alarm(self, text: str) -> None:
        """The controller is in alarm: the lock of a controller just powered up is a state
        (info; a warning in the diagnostics until homed), any other alarm a fault (error)."""
        if text != self.alarm:
            self.alarm = text
            self._log("info" if text == LOCKED else "error", text)
            self._changed()

    # -- motion ------------------------------------------------------------------------------

    def drive(self, kind: str, motion: Callable[[GrblClient], None], *,
              on_timeout: Callable[[], None] = lambda: None) -> str | None:
        """Run ``motion(client)`` (a ``kind`` of "move" or "home"); the error text (reported
        as a fault), or None. ``on_timeout()`` is called after a timeout (the axes may still
        be moving)."""
        client = self.client
        if client is None:
            error = f"{kind} refused: not connected ({self.connection_error})"
            self.report_fault(error)
            return error
        try:
            motion(client)
        except MotionCancelled as exc:
            self._log("info", str(exc))
            return str(exc)
        except ConnectionLost as exc:
            self.lost(exc)
            return str(exc)
        except MotorTimeout as exc:
            self.report_fault(str(exc))
            on_timeout()
            return str(exc)
        except MotorError as exc:
            self.report_fault(str(exc))
            return str(exc)
        self.fault = ""
        self.alarm = ""
        self._log("info", f"{kind} done")
        self._changed()
        return None

    def halt(self) -> None:
        """Stop the axes for a job that must end (a stop's failure is the job's to report)."""
        client = self.client
        try:
            if client is not None:
                client.stop()
        except ConnectionLost as exc:
            self.lost(exc)
        except MotorError as exc:          # alarm, timeout: the running job reports it
            self._log("warning", f"could not stop the running move: {exc}")

    def stop(self) -> tuple[bool, str]:
        """Stop the axes now, keeping the position: ``(at rest, what happened)``."""
        client = self.client
        try:
            if client is None:
                return False, f"not connected: {self.connection_error}"
            status = client.stop()
        except MotorAlarm as exc:
            return True, f"axes stopped by an alarm: {exc}"
        except ConnectionLost as exc:
            self.lost(exc)
            return False, str(exc)
        except MotorError as exc:
            self.report_fault(f"stop failed: {exc}")
            return False, str(exc)
        text = (f"stopped at theta={status.theta_rad:.4f} rad, "
                f"phi={status.phi_rad:.4f} rad (state {status.state})")
        self._log("info", text)
        return True, text

    # -- what the diagnostics report ---------------------------------------------------------

    def report_fault(self, text: str) -> None:
        """Log ``text`` as an ERROR and report it in the diagnostics, each fault published
        with its own text even when two are reported at once (from two threads)."""
        with self._fault_lock:
            self.fault = text
            self.faults += 1
            self._log("error", text)
            self._changed()

    def health(self, lifecycle: str) -> tuple[str, str, str]:
        """``(problem, warning, ok)`` of the diagnostics in the node's ``lifecycle`` state: a
        fault is a problem; what waits on someone (a node not active, the alarm lock of
        power-up, a late report) a warning."""
        client = self.client
        if lifecycle != "active":
            closed = "" if client is not None else " (port closed)"
            return "", (f"the motor node is {lifecycle}: activate it (lifecycle "
                        f"change_state){closed}"), ""
        problem = (self.connection_error or "not connected") if client is None else (
            self.fault or (self.alarm if self.alarm != LOCKED else ""))
        return problem, self.alarm or self.late, f"state {self.state}"

    def values(self, lifecycle: str, job: str) -> dict:
        """The diagnostics' values, the running ``job`` among them."""
        client = self.client
        values = {
            "lifecycle": lifecycle, "port": self.port,
            "connected": client is not None, "state": self.state,
            "alarm": self.alarm, "last_fault": self.fault, "faults": self.faults,
            "refused_commands": self.refused,
            "noise_lines": client.noise_lines if client is not None else "",
            "job": job,
        }
        if self.position is not None:
            values.update(theta_rad=f"{self.position[0]:.6f}", phi_rad=f"{self.position[1]:.6f}")
        return values
