"""Client for a GRBL 1.1 controller driving the turntable (X = theta) and carriage (Y = phi).

Radians in this API, degrees on the wire (:mod:`.grbl`). Every wait has a
deadline; every failure is a :class:`MotorError` subclass with a message that
says what happened and what to do.

Reading
-------
All bytes from the port pass through one reader (:meth:`GrblClient._pump`),
whichever thread happens to hold the port lock: it splits them into lines
(keeping partial lines for the next read), classifies each line, and records
what it means in the client's shared state:

* ``ok`` / ``error:N`` answer the oldest outstanding line command (GRBL
  answers strictly in order). A command whose caller gave up waiting stays in
  the queue, so its late answer is not taken for the next command's;
* status reports update the latest :class:`Status`;
* ``ALARM:N`` is latched (``[MSG:Reset to continue]`` marks it critical: the
  controller then answers nothing but a soft reset);
* the welcome banner (power-up or soft reset) clears the command queue: GRBL
  has forgotten every command it had not answered;
* anything else is line noise: counted in :attr:`GrblClient.noise_lines`,
  never fatal. A known message at the end of a corrupted line is recovered.

Threads
-------
One lock guards the port and the shared state. It is held for one exchange at
a time (send a command, read for at most a short slice), never for a whole
move or homing cycle, so a timer can poll :meth:`GrblClient.status` while
another thread runs :meth:`GrblClient.move_to`.
"""

from __future__ import annotations

import collections
import math
import numbers
import termios
import threading
import time
from dataclasses import dataclass

import serial

from . import grbl

__all__ = [
    "MotorError", "MotorTimeout", "MotorAlarm", "MotorStalled", "MotionCancelled",
    "CommandRejected", "ConnectionLost", "ProtocolError", "Status", "GrblClient",
]

_SLICE_S = 0.02                # longest single read while other threads may want the lock
_MAX_LINE_BYTES = 256          # a "line" longer than this without a newline is noise


class _TurnLock:
    """A re-entrant lock that a thread looping on it hands over to the threads waiting.

    CPython's locks are not fair: a thread that releases and at once re-acquires
    a lock can keep it for as long as it loops, so a status query or a stop
    from another thread during a long command (homing) could wait until the
    command ended. The looping thread calls :meth:`let_waiters_in` between
    two turns; it returns once every thread then waiting has had the lock.
    """

    def __init__(self):
        self._lock = threading.RLock()
        self._turn = threading.Condition()
        self._waiting = 0

    def __enter__(self) -> _TurnLock:
        with self._turn:
            self._waiting += 1
        try:
            self._lock.acquire()
        finally:
            with self._turn:
                self._waiting -= 1
                self._turn.notify_all()
        return self

    def __exit__(self, *exc) -> None:
        self._lock.release()

    def let_waiters_in(self, timeout_s: float) -> None:
        """Wait (at most ``timeout_s``) until no thread is waiting for the lock."""
        with self._turn:
            self._turn.wait_for(lambda: self._waiting == 0, timeout=max(timeout_s, 0.0))


class MotorError(RuntimeError):
    """Base class of every error of the motor hardware layer."""


class MotorTimeout(MotorError):
    """The controller did not answer, or a motion did not finish, within the time allowed."""


class MotorAlarm(MotorError):
    """The controller is in alarm; ``code`` is GRBL's ``ALARM:N`` code (None if unknown)."""

    def __init__(self, code: int | None, meaning: str | None = None, *, critical: bool = False):
        self.code = code
        self.meaning = meaning if meaning is not None else grbl.alarm_meaning(code)
        self.critical = critical
        what = f"ALARM:{code}" if code is not None else "alarm lock"
        todo = ("reset(), then home() (or unlock())" if critical
                else "home() (or unlock() if the position is known to be good)")
        super().__init__(f"motor controller {what}: {self.meaning}; recover with {todo}")


class MotorStalled(MotorError):
    """An axis stopped short of its target (read-back outside tolerance) or stopped moving."""


class MotionCancelled(MotorError):
    """The move was interrupted by :meth:`GrblClient.stop` or a feed hold."""


class CommandRejected(MotorError):
    """The controller answered ``error:N`` to a line command."""

    def __init__(self, command: str, code: int):
        self.command = command
        self.code = code
        self.meaning = grbl.error_meaning(code)
        super().__init__(f"motor controller rejected {command!r}: error:{code} ({self.meaning})")


class ConnectionLost(MotorError):
    """The serial port failed (cable unplugged, device gone); open a new client."""


class ProtocolError(MotorError):
    """The controller said something that contradicts the protocol (e.g. an impossible report)."""


@dataclass(frozen=True)
class Status:
    """One status report.

    Attributes
    ----------
    state : str
        GRBL machine state: ``Idle``, ``Run``, ``Hold``, ``Home``, ``Alarm``, ...
    theta_rad, phi_rad : float
        Encoder read-back of the turntable (X) and carriage (Y), radians.
    substate : int or None
        ``Hold``: 0 = hold complete, 1 = decelerating.
    """
    state: str
    theta_rad: float
    phi_rad: float
    substate: int | None = None


class _Pending:
    """A line command waiting for its ``ok`` / ``error:N``."""
    __slots__ = ("command", "answer", "abandoned")

    def __init__(self, command: str):
        self.command = command
        self.answer: grbl.Ok | grbl.Error | None = None
        self.abandoned = False          # its caller timed out; the answer may still come


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return value


def _check_angles(theta_rad, phi_rad) -> None:
    for name, value in (("theta_rad", theta_rad), ("phi_rad", phi_rad)):
        if isinstance(value, bool) or not isinstance(value, numbers.Real) \
                or not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number of radians, got {value!r}")


def _read_back(status: Status, target: tuple[float, float]) -> str:
    """The axes' read-back and ``target`` (radians), in degrees, for a message."""
    return (f"read-back theta={math.degrees(status.theta_rad):.3f} deg, phi="
            f"{math.degrees(status.phi_rad):.3f} deg, target theta="
            f"{math.degrees(target[0]):.3f} deg, phi={math.degrees(target[1]):.3f} deg")


class GrblClient:
    """A GRBL 1.1 controller on a serial port.

    Parameters
    ----------
    port : str
        Device path (``/dev/ttyACM0``, ``/dev/pts/3``) or a pyserial URL
        (``loop://``, ``rfc2217://host:port``).
    baudrate : int
        GRBL 1.1 default: 115200.
    timeout_s : float
        Default deadline for one answer (status report, ``ok``), seconds.
    tolerance_rad : float
        A move has arrived when both read-backs are within this of the target.
    poll_interval_s : float
        Status polling period while waiting for motion. GRBL recommends at
        most 5-10 Hz on an 8-bit board.
    stall_timeout_s : float
        While ``Run``, a move that has not come ``min_progress_rad`` closer to
        its target for this long is reported as stalled.
    min_progress_rad : float
        Progress smaller than this (encoder noise) does not count.
    """

    def __init__(self, port: str, *, baudrate: int = 115200, timeout_s: float = 1.0,
                 tolerance_rad: float = math.radians(0.5), poll_interval_s: float = 0.1,
                 stall_timeout_s: float = 2.0, min_progress_rad: float = math.radians(0.1)):
        self.timeout_s = _positive("timeout_s", timeout_s)
        self.tolerance_rad = _positive("tolerance_rad", tolerance_rad)
        self.poll_interval_s = _positive("poll_interval_s", poll_interval_s)
        self.stall_timeout_s = _positive("stall_timeout_s", stall_timeout_s)
        self.min_progress_rad = _positive("min_progress_rad", min_progress_rad)
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a device path or pyserial URL, got {port!r}")
        self.port = port
        self._lock = _TurnLock()
        self._rx = bytearray()
        self._pending: collections.deque[_Pending] = collections.deque()
        self._status: Status | None = None
        self._status_seq = 0
        self._alarm_code: int | None = None
        self._alarm_seq = 0
        self._critical = False
        self._welcome_seq = 0
        self._cancel_seq = 0
        self._homing = False
        self._lost: str | None = None
        self._build_info: str | None = None
        #: Lines that were not protocol messages (noise), and lines recovered from noise.
        self.noise_lines = 0
        self.salvaged_lines = 0
        #: Unsolicited ``[MSG:...]`` texts, most recent last (bounded).
        self.messages: collections.deque[str] = collections.deque(maxlen=32)
        try:
            self._serial = serial.serial_for_url(port, baudrate=baudrate, timeout=_SLICE_S,
                                                 write_timeout=self.timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConnectionLost(f"cannot open motor controller port {port!r}: {exc}") from exc

    # --- public API --------------------------------------------------------------

    @property
    def alarm_code(self) -> int | None:
        """Last ``ALARM:N`` code seen since the last unlock / homing, or None."""
        return self._alarm_code

    def status(self, *, timeout_s: float | None = None) -> Status:
        """Query one real-time status report (``?``).

        During :meth:`home` GRBL does not answer status queries; the last known
        positions (NaN if none was ever reported) are returned with state ``Home``.

        Raises
        ------
        MotorAlarm
            The controller is locked after a hard or soft limit alarm and will
            not answer until :meth:`reset`.
        MotorTimeout
            No report within ``timeout_s``.
        """
        deadline = time.monotonic() + self._timeout(timeout_s)
        with self._lock:
            self._check_open()
            self._pump(block=False)
            if self._critical:
                raise MotorAlarm(self._alarm_code, critical=True)
            if self._homing:
                last = self._status or Status("Home", math.nan, math.nan)
                return Status("Home", last.theta_rad, last.phi_rad)
            seq = self._status_seq
            self._write(grbl.STATUS_QUERY)
            while self._status_seq == seq:
                if self._critical:
                    raise MotorAlarm(self._alarm_code, critical=True)
                if not self._pump_until(deadline):
                    raise MotorTimeout(
                        f"no status report from the motor controller on {self.port} within "
                        f"{self._timeout(timeout_s):.3g} s (not powered, wrong port or baud "
                        f"rate, or hung)")
            return self._status

    def move_to(self, theta_rad: float, phi_rad: float, *, timeout_s: float) -> Status:
        """Move both axes to absolute positions and wait until they are there.

        Sends ``G90 G0 X<deg> Y<deg>`` and polls the status every
        ``poll_interval_s`` until the controller is ``Idle`` with both
        read-backs within ``tolerance_rad`` of the target.

        Parameters
        ----------
        theta_rad, phi_rad : float
            Target turntable and carriage angles, radians (machine coordinates).
        timeout_s : float
            Deadline for the whole move, seconds.

        Returns
        -------
        Status
            The final status (``Idle``, read-backs at the target).

        Raises
        ------
        MotorAlarm
            Alarm before or during the move (``code`` 2: target outside the
            soft limits; 1: limit switch hit; None: alarm lock, home first).
        MotorStalled
            ``Idle`` short of the target, or no progress for ``stall_timeout_s``.
        MotionCancelled
            :meth:`stop` (or a feed hold) interrupted the move.
        MotorTimeout
            Not arrived within ``timeout_s`` (the controller may still be
            moving: call :meth:`stop`).
        CommandRejected
            ``error:N`` for the move command.
        """
        _check_angles(theta_rad, phi_rad)
        timeout = _positive("timeout_s", timeout_s)
        deadline = time.monotonic() + timeout
        command = grbl.format_move(math.degrees(theta_rad), math.degrees(phi_rad))
        with self._lock:
            cancel_seq, alarm_seq = self._cancel_seq, self._alarm_seq
        self._command(command, deadline, alarm_seq=alarm_seq)
        target = (float(theta_rad), float(phi_rad))
        best = math.inf
        best_time = time.monotonic()
        idle_off_target = 0
        while True:
            # A healthy controller answers "?" within ~20 ms: past the deadline, wait 50 ms more.
            status = self.status(timeout_s=min(self.timeout_s,
                                               max(deadline - time.monotonic(), 0.05)))
            now = time.monotonic()
            self._check_not_interrupted(status, cancel_seq, alarm_seq, target)
            error = max(abs(status.theta_rad - target[0]), abs(status.phi_rad - target[1]))
            if status.state == "Idle":
                if error <= self.tolerance_rad:
                    return status
                # GRBL may report Idle for a moment between "ok" and the start of motion:
                # an off-target Idle counts as a stall only when a second poll confirms it.
                idle_off_target += 1
                if idle_off_target >= 2:
                    raise MotorStalled(
                        f"motion ended short of the target: {_read_back(status, target)} "
                        f"(tolerance {math.degrees(self.tolerance_rad):.3f} deg)")
            else:
                idle_off_target = 0
            if error < best - self.min_progress_rad:
                best, best_time = error, now
            elif status.state == "Run" and now - best_time > self.stall_timeout_s:
                raise MotorStalled(
                    f"no progress for {self.stall_timeout_s:.3g} s while running: "
                    f"{_read_back(status, target)}")
            if now >= deadline:
                raise MotorTimeout(
                    f"move to theta={math.degrees(target[0]):.3f} deg, phi="
                    f"{math.degrees(target[1]):.3f} deg not finished within {timeout:.3g} s "
                    f"(state {status.state}, {math.degrees(error):.3f} deg to go); the axes "
                    f"may still be moving: call stop()")
            time.sleep(min(self.poll_interval_s, max(deadline - now, 0.0)))

    def _check_not_interrupted(self, status: Status, cancel_seq: int, alarm_seq: int,
                               target: tuple[float, float]) -> None:
        """MotorAlarm or MotionCancelled if an alarm, :meth:`stop` or a feed hold came
        since the move to ``target`` (radians) began (``cancel_seq``, ``alarm_seq``)."""
        with self._lock:
            cancelled = self._cancel_seq != cancel_seq
            alarmed = self._alarm_seq != alarm_seq
        if alarmed or status.state == "Alarm":
            raise MotorAlarm(self._alarm_code, critical=self._critical)
        if cancelled or status.state == "Hold":
            raise MotionCancelled(f"move to theta={target[0]:.4f} rad, phi={target[1]:.4f} rad "
                                  f"interrupted ({'stop()' if cancelled else 'feed hold'})")

    def home(self, *, timeout_s: float) -> Status:
        """Run the homing cycle (``$H``); returns the status once it has finished.

        Raises MotorAlarm (e.g. code 9: switch not found), CommandRejected or
        MotorTimeout.
        """
        deadline = time.monotonic() + _positive("timeout_s", timeout_s)
        with self._lock:
            alarm_seq = self._alarm_seq
            self._homing = True
        try:
            self._command(b"$H\n", deadline, alarm_seq=alarm_seq)
        finally:
            with self._lock:
                self._homing = False
        with self._lock:
            self._alarm_code = None
        return self.status(timeout_s=max(deadline - time.monotonic(), self.timeout_s))

    def build_info(self, *, timeout_s: float | None = None) -> str:
        """Firmware version and build date: the ``[VER:...]`` text of ``$I``."""
        with self._lock:
            self._build_info = None
        self._command(b"$I\n", time.monotonic() + self._timeout(timeout_s))
        with self._lock:
            if self._build_info is None:
                raise ProtocolError(f"controller on {self.port} answered $I without a [VER:] line")
            return self._build_info

    def unlock(self, *, timeout_s: float | None = None) -> Status:
        """Kill the alarm lock (``$X``) without homing; the position may be wrong."""
        deadline = time.monotonic() + self._timeout(timeout_s)
        with self._lock:
            if self._critical:
                raise MotorAlarm(self._alarm_code, critical=True)
        self._command(b"$X\n", deadline)
        with self._lock:
            self._alarm_code = None
        return self.status(timeout_s=max(deadline - time.monotonic(), 1e-3))

    def reset(self, *, timeout_s: float | None = None) -> Status:
        """Soft reset (ctrl-x): abort motion and pending commands, clear a critical alarm.

        Resetting while the axes move makes GRBL raise ``ALARM:3`` (position
        possibly lost); the returned status then says ``Alarm``: home or unlock.
        """
        timeout = self._timeout(timeout_s)
        deadline = time.monotonic() + timeout
        with self._lock:
            self._check_open()
            self._cancel_seq += 1
            seq = self._welcome_seq
            self._write(grbl.SOFT_RESET)
            while self._welcome_seq == seq:
                if not self._pump_until(deadline):
                    raise MotorTimeout(f"motor controller on {self.port} did not restart within "
                                       f"{timeout:.3g} s of a soft reset")
        return self.status(timeout_s=max(deadline - time.monotonic(), 1e-3))

    def stop(self, *, timeout_s: float | None = None) -> Status:
        """Stop now: feed hold (``!``), wait for the hold to complete, then flush the queue.

        A soft reset after a completed hold discards the rest of the motion
        while keeping the position (no alarm). Interrupts a :meth:`move_to`
        running in another thread (it raises :class:`MotionCancelled`).
        In an alarm the axes are already stopped: nothing is sent. ``Idle`` after
        the hold (another thread's stop finished first) is at rest too.
        """
        timeout = self._timeout(timeout_s)
        deadline = time.monotonic() + timeout
        with self._lock:
            self._check_open()
            self._cancel_seq += 1
            if self._critical:
                raise MotorAlarm(self._alarm_code, critical=True)
            homing = self._homing
            if not homing:
                self._write(grbl.FEED_HOLD)
        if homing:                      # GRBL ignores a feed hold while homing
            return self.reset(timeout_s=timeout)
        while True:
            status = self.status(timeout_s=max(deadline - time.monotonic(), 1e-3))
            # Idle: at rest with an empty planner (a stop from another thread got there
            # first, its soft reset clearing this hold): nothing left to stop.
            if status.state in ("Alarm", "Idle") or (status.state == "Hold"
                                                     and status.substate == 0):
                break
            if time.monotonic() >= deadline:
                raise MotorTimeout(f"axes did not come to a hold within {timeout:.3g} s "
                                   f"(state {status.state})")
            time.sleep(min(self.poll_interval_s, 0.05))
        if status.state in ("Alarm", "Idle"):
            return status
        return self.reset(timeout_s=max(deadline - time.monotonic(), self.timeout_s))

    def close(self) -> None:
        """Close the port (idempotent)."""
        with self._lock:
            if self._lost is None:
                self._lost = "closed by the client"
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass                # closing a port whose device is gone

    def __enter__(self) -> GrblClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- internals -------------------------------------------------------------------

    def _timeout(self, timeout_s: float | None) -> float:
        return self.timeout_s if timeout_s is None else _positive("timeout_s", timeout_s)

    def _check_open(self) -> None:
        if self._lost is not None:
            raise ConnectionLost(f"motor controller port {self.port} is not usable: {self._lost}")

    def _fail(self, exc: Exception) -> ConnectionLost:
        self._lost = f"{type(exc).__name__}: {exc}"
        try:
            self._serial.close()
        except (serial.SerialException, OSError):
            pass
        return ConnectionLost(f"lost the motor controller on {self.port}: {exc}")

    def _write(self, data: bytes) -> None:
        try:
            self._serial.write(data)
            self._serial.flush()
        except serial.SerialTimeoutException as exc:
            raise MotorTimeout(f"could not write to {self.port} within {self.timeout_s:.3g} s"
                               ) from exc
        except (serial.SerialException, OSError, termios.error) as exc:
            # flush() (tcdrain) on a vanished port raises termios.error, no OSError.
            raise self._fail(exc) from exc

    def _command(self, line: bytes, deadline: float, *, alarm_seq: int | None = None) -> None:
        """Send one line command and wait for its answer (``ok``, else raise)."""
        text = line.decode("ascii").rstrip("\n")
        with self._lock:
            self._check_open()
            self._pump(block=False)
            if self._critical:
                raise MotorAlarm(self._alarm_code, critical=True)
            # GRBL answers in order, without naming the command: while an earlier command is
            # unanswered, a new one could be credited with the earlier answer.
            for earlier in self._pending:
                if earlier.abandoned:
                    raise MotorTimeout(f"{earlier.command!r} sent to {self.port} earlier was never "
                                       f"answered; call reset() to resynchronise")
                raise MotorError(f"cannot send {text!r}: {earlier.command!r} is still in "
                                 f"progress on {self.port}")
            pending = _Pending(text)
            self._pending.append(pending)
            welcome = self._welcome_seq
            self._write(line)
        while True:
            with self._lock:
                if pending.answer is None and self._welcome_seq == welcome \
                        and not (alarm_seq is not None and self._alarm_seq != alarm_seq):
                    self._pump_until(deadline)
                answer = pending.answer
                if isinstance(answer, grbl.Ok):
                    return
                if isinstance(answer, grbl.Error):
                    if answer.code == 9:
                        raise MotorAlarm(self._alarm_code)
                    raise CommandRejected(text, answer.code)
                if alarm_seq is not None and self._alarm_seq != alarm_seq:
                    raise MotorAlarm(self._alarm_code, critical=self._critical
                                     or self._alarm_code in grbl.CRITICAL_ALARMS)
                if self._welcome_seq != welcome:
                    raise MotionCancelled(f"controller restarted before answering {text!r}")
                if time.monotonic() >= deadline:
                    # Stays queued: a late answer must not be taken for the next command's.
                    pending.abandoned = True
                    raise MotorTimeout(f"no answer to {text!r} from the motor controller on "
                                       f"{self.port} in time")
            self._lock.let_waiters_in(deadline - time.monotonic())

    def _pump_until(self, deadline: float) -> bool:
        """Read for one slice (at most ``_SLICE_S``); False if ``deadline`` had already passed."""
        if time.monotonic() >= deadline:
            return False
        self._pump(block=True)
        return True

    def _pump(self, *, block: bool) -> None:
        """Read what the port has (with ``block``, wait up to one slice for a first byte)
        and dispatch every complete line."""
        try:
            waiting = self._serial.in_waiting
            data = self._serial.read(waiting or 1) if (waiting or block) else b""
            if data and self._serial.in_waiting:
                data += self._serial.read(self._serial.in_waiting)
        except (serial.SerialException, OSError) as exc:
            raise self._fail(exc) from exc
        self._rx += data
        while (end := self._rx.find(b"\n")) >= 0:
            line = bytes(self._rx[:end])
            del self._rx[:end + 1]
            self._dispatch(line)
        if len(self._rx) > _MAX_LINE_BYTES:
            self._rx.clear()
            self.noise_lines += 1

    def _dispatch(self, line: bytes) -> None:
        if not line.strip(b"\r"):
            return                      # the empty line before a banner
        message, salvaged = grbl.parse_line(line)
        if message is None or salvaged:
            self.noise_lines += 1
            self.salvaged_lines += salvaged
        if isinstance(message, (grbl.Ok, grbl.Error)):
            if self._pending:
                self._pending.popleft().answer = message
            else:
                self.noise_lines += 1   # an answer nobody waits for (e.g. after a reset)
        elif isinstance(message, grbl.StatusReport):
            if message.mpos is None:
                raise ProtocolError(f"status report without machine position (MPos): "
                                    f"{line!r}; configure the controller with $10=1")
            self._status = Status(message.state, math.radians(message.mpos[0]),
                                  math.radians(message.mpos[1]), message.substate)
            self._status_seq += 1
        elif isinstance(message, grbl.Alarm):
            self._alarm_code = message.code
            self._alarm_seq += 1
        elif isinstance(message, grbl.Feedback):
            if message.kind == "VER":
                self._build_info = message.text
            elif message.kind == "MSG":
                self.messages.append(message.text)
                if message.text == grbl.MSG_RESET_TO_CONTINUE:
                    self._critical = True
        elif isinstance(message, grbl.Welcome):
            self._pending.clear()
            self._critical = False
            self._welcome_seq += 1
