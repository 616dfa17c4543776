"""A simulated GRBL 1.1 controller for the turntable (X = theta) and carriage (Y = phi).

:class:`SimulatedGrbl` opens a pseudo-terminal and answers on its master side
from a background thread; the slave path (``/dev/pts/N``) is what a client
opens with pyserial, exactly as it would open ``/dev/ttyACM0``. The wire
protocol is :mod:`.grbl`; the behaviour follows GRBL 1.1:

* real-time bytes (``?``, ``!``, ``~``, ctrl-x) are picked off the input
  stream wherever they appear, bytes above 0x7F are dropped, and line input is
  upper-cased with blanks, control characters and comments removed;
* ``ok`` for a motion line means "queued in the planner" (at most 15 blocks),
  not "arrived": the client polls ``?`` until ``Idle``;
* rapid moves follow a trapezoidal speed profile along the straight line,
  limited per axis by the maximum speed and acceleration;
* soft limits (machine coordinates) and hard limits raise ``ALARM:2`` /
  ``ALARM:1`` followed by ``[MSG:Reset to continue]``; then everything except
  a soft reset is ignored, status queries included. After the reset the
  controller stays in ``Alarm`` until ``$H`` or ``$X``;
* a soft reset while moving raises ``ALARM:3``; after a completed feed hold
  (``Hold:0``) it discards the remaining motion and keeps the position;
* ``$H`` answers ``ok`` when homing has finished; status queries during
  homing are answered after it. With ``start_locked`` (GRBL's homing
  lock-out) the controller starts in ``Alarm``.
* The controller is already running when a client opens the port (a board
  that does not reset on open): no banner until a soft reset.

Positions
---------
*Machine* coordinates are GRBL's step counters (degrees), zeroed by homing.
*True* (physical) angles are what the turntable and carriage really show: the
machine zero sits at the true angle the axis had at power-up, until homing
moves it onto the home switch. Status reports give the *encoder* read-back:
machine position of the true angle plus a fixed offset plus uniform noise, so
``MPos`` differs from both the target and the truth. :meth:`true_position_rad`
gives the truth (for a simulated camera). Only X and Y have hardware; the Z
word is accepted and reported without noise, as GRBL's third axis.

Faults (attributes of :attr:`SimulatedGrbl.faults`, methods on the simulator)
---------------------------------------------------------------------------
stall, no answer, disconnect, limit switch hit, homing failure or held open, garbage and
fragmented output; see :class:`Faults`, :meth:`SimulatedGrbl.disconnect`,
:meth:`SimulatedGrbl.trigger_limit` and :meth:`SimulatedGrbl.inject_output`.
"""

from __future__ import annotations

import math
import os
import re
import select
import threading
import time
import tty
from dataclasses import dataclass

import numpy as np

from . import grbl

__all__ = ["Faults", "SimulatedGrbl", "move_duration_s"]

_AXES = "XYZ"
_PLANNER_BLOCKS = 15            # GRBL 1.1 on an ATmega328p: 16-block ring, 15 usable
_RX_BUFFER_BYTES = 1024         # host bytes kept before processing; more are dropped
_OUT_BUFFER_BYTES = 65536       # bytes kept for a client that does not read
_Z_SPEED_DEG_S = 1000.0         # the dummy third axis
_Z_ACCEL_DEG_S2 = 10000.0
_NUMBER = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)")


@dataclass
class Faults:
    """Faults the simulator injects; change the attributes at any time.

    Attributes
    ----------
    no_answer : bool
        The controller hangs: input is read and discarded, nothing is sent.
    stall_axis : str or None
        ``"X"`` or ``"Y"``: every following move of that axis stalls after
        ``stall_fraction`` of its path.
    stall_fraction : float
        Fraction of the path (0..1) after which the stalled axis stops.
    stall_mode : str
        ``"idle"``: GRBL (open loop) finishes its steps and reports ``Idle``,
        the encoder shows where the axis really stopped. ``"run"``: the
        motion freezes at the stall point and the state stays ``Run``.
    limit_at_fraction : float or None
        One shot: the next move hits a hard limit switch after this fraction
        of its path (``ALARM:1``, immediate halt).
    homing_fails : bool
        ``$H`` searches, then fails with ``ALARM:9`` (switch not found).
    homing_hold : bool
        Homing does not end while this is set: the axes wait at the switches
        in state ``Home`` until it is cleared (holds the cycle open for as
        long as a test needs, whatever the machine's load).
    garbage : bytes
        Inserted before every message the controller sends (line noise, e.g.
        ``b"\\xff\\x00#&\\r\\n"`` as a line of its own, or a bare prefix).
    fragment_output : bool
        Send output a few bytes at a time, so that lines arrive split over
        many reads.
    """
    no_answer: bool = False
    stall_axis: str | None = None
    stall_fraction: float = 0.5
    stall_mode: str = "idle"
    limit_at_fraction: float | None = None
    homing_fails: bool = False
    homing_hold: bool = False
    garbage: bytes = b""
    fragment_output: bool = False

    def __setattr__(self, name, value):
        if name == "stall_axis" and value not in (None, "X", "Y"):
            raise ValueError(f"stall_axis must be None, 'X' or 'Y', got {value!r}")
        if name == "stall_mode" and value not in ("idle", "run"):
            raise ValueError(f"stall_mode must be 'idle' or 'run', got {value!r}")
        if name in ("stall_fraction", "limit_at_fraction") and value is not None \
                and not 0.0 <= value <= 1.0:
            raise ValueError(f"{name} must be in [0, 1], got {value!r}")
        super().__setattr__(name, value)


@dataclass
class _Motion:
    """One planner block being executed: path ``start + u * s(t)``."""
    start: np.ndarray            # (3,) machine degrees
    target: np.ndarray           # (3,) machine degrees
    u: np.ndarray                # (3,) unit direction
    length: float                # degrees along the path
    v_max: float                 # deg/s along the path
    accel: float                 # deg/s^2 along the path
    t0: float                    # start time (monotonic s)
    stall_axis: int | None
    stall_fraction: float
    stall_mode: str
    limit_fraction: float | None
    base_slip: np.ndarray         # (3,) slip before this block started
    hold_t0: float | None = None  # feed hold: deceleration starts at hold_t0 ...
    hold_s: float = 0.0           # ... from path position hold_s ...
    hold_v: float = 0.0           # ... at speed hold_v
    frozen_s: float | None = None  # stall_mode "run": stuck at this path position


def _trapezoid(length: float, v_max: float, accel: float, tau: float) -> tuple[float, float, bool]:
    """Path position, speed and done flag ``tau`` seconds into a rest-to-rest move."""
    if length <= 0.0:
        return 0.0, 0.0, True
    if length * accel >= v_max * v_max:
        t_acc = v_max / accel
        t_cruise = (length - v_max * v_max / accel) / v_max
        v_peak = v_max
    else:
        v_peak = math.sqrt(length * accel)
        t_acc = v_peak / accel
        t_cruise = 0.0
    total = 2.0 * t_acc + t_cruise
    if tau >= total:
        return length, 0.0, True
    if tau < t_acc:
        return 0.5 * accel * tau * tau, accel * tau, False
    d_acc = 0.5 * accel * t_acc * t_acc
    if tau < t_acc + t_cruise:
        return d_acc + v_peak * (tau - t_acc), v_peak, False
    t_dec = tau - t_acc - t_cruise
    s = d_acc + v_peak * t_cruise + v_peak * t_dec - 0.5 * accel * t_dec * t_dec
    return min(s, length), max(v_peak - accel * t_dec, 0.0), False


def move_duration_s(distance_deg: float, max_speed_deg_s: float, accel_deg_s2: float) -> float:
    """Duration of a rest-to-rest single-axis move under the simulator's trapezoidal profile."""
    d, v, a = abs(distance_deg), max_speed_deg_s, accel_deg_s2
    if d * a >= v * v:
        return d / v + v / a
    return 2.0 * math.sqrt(d / a)


def _pair(name: str, value, *, low: float | None = None, strict: bool = False) -> np.ndarray:
    """Two finite numbers (X, Y), optionally ``> low`` (strict) or ``>= low``."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be two finite numbers (theta/X, phi/Y), got {value!r}")
    if low is not None and np.any(arr <= low if strict else arr < low):
        raise ValueError(f"{name} must be {'>' if strict else '>='} {low}, got {value!r}")
    return arr


class SimulatedGrbl:
    """GRBL 1.1 on a pseudo-terminal; use as a context manager or call start()/close().

    Parameters
    ----------
    max_speed_deg_s : (2,) float
        Maximum rate of X (theta) and Y (phi), degrees per second (GRBL
        ``$110``/``$111`` divided by 60).
    accel_deg_s2 : (2,) float
        Acceleration of X and Y, degrees per second squared (``$120``/``$121``).
    soft_limits_deg : (2,) of (min, max) or None
        Machine travel per axis, degrees; ``None`` means unlimited (a
        turntable turns forever). Default: theta unlimited, phi in [-5, 95].
    encoder_offset_deg : (2,) float
        Fixed offset of the encoder read-back, degrees.
    encoder_noise_deg : (2,) float
        Half-width of the uniform read-back noise, degrees (so
        ``|MPos - machine position - offset| <= noise`` always).
    power_up_true_deg : (2,) float
        True angles of the axes at power-up (where machine zero starts).
    home_true_deg : (2,) float
        True angles of the home switches. The turntable switch is an index
        mark seen once per turn: homing X goes to the nearest
        ``home_true_deg[0] + k * 360``.
    homing_speed_deg_s : float
        Search speed of the homing cycle.
    start_locked : bool
        Start in ``Alarm`` (GRBL's homing lock-out): ``$H`` or ``$X`` first.
    seed : int or None
        Seed of the encoder noise.
    """

    def __init__(self, *, max_speed_deg_s=(90.0, 45.0), accel_deg_s2=(360.0, 180.0),
                 soft_limits_deg=(None, (-5.0, 95.0)), encoder_offset_deg=(0.03, -0.02),
                 encoder_noise_deg=(0.01, 0.01), power_up_true_deg=(0.0, 0.0),
                 home_true_deg=(0.0, 0.0), homing_speed_deg_s: float = 60.0,
                 start_locked: bool = True, seed: int | None = None):
        speed = _pair("max_speed_deg_s", max_speed_deg_s, low=0.0, strict=True)
        accel = _pair("accel_deg_s2", accel_deg_s2, low=0.0, strict=True)
        self._offset = _pair("encoder_offset_deg", encoder_offset_deg)
        self._noise = _pair("encoder_noise_deg", encoder_noise_deg, low=0.0)
        power_up = _pair("power_up_true_deg", power_up_true_deg)
        self._home_true = _pair("home_true_deg", home_true_deg)
        if not (math.isfinite(homing_speed_deg_s) and homing_speed_deg_s > 0):
            raise ValueError(f"homing_speed_deg_s must be > 0, got {homing_speed_deg_s!r}")
        if len(soft_limits_deg) != 2:
            raise ValueError(f"soft_limits_deg must give (min, max) or None for X and Y, "
                             f"got {soft_limits_deg!r}")
        self._limits: list[tuple[float, float] | None] = []
        for axis, lim in zip("XY", soft_limits_deg, strict=True):
            if lim is not None:
                lo, hi = (float(v) for v in lim)
                if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                    raise ValueError(f"soft limits of {axis} must be finite with min < max, "
                                     f"got {lim!r}")
                lim = (lo, hi)
            self._limits.append(lim)
        self._speed = np.array([speed[0], speed[1], _Z_SPEED_DEG_S])
        self._accel = np.array([accel[0], accel[1], _Z_ACCEL_DEG_S2])
        self._homing_speed = float(homing_speed_deg_s)
        self._rng = np.random.default_rng(seed)
        self.faults = Faults()

        self._lock = threading.RLock()
        self._cmd = np.zeros(3)                       # GRBL's machine position (step counters)
        self._zero = np.array([power_up[0], power_up[1], 0.0])  # true angle of machine zero
        self._slip = np.zeros(3)                      # true = zero + cmd - slip
        self._state = "Alarm" if start_locked else "Idle"
        self._critical = False
        self._hold_complete = False
        self._motion: _Motion | None = None
        self._queue: list[tuple] = []                 # ("move", target, rate) | ("dwell", s)
        self._parser_pos = np.zeros(3)                # g-code parser position (end of queue)
        self._absolute = True
        self._motion_mode = 0
        self._feed: float | None = None
        self._dwell_until: float | None = None
        self._homing: tuple | None = None             # (t0, duration, start_true, end_true)
        self._report_pending = False
        self._wco_counter = 0
        self._ovr_next = False
        self._rx = bytearray()
        self._out = bytearray()
        self._received = bytearray()

        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._disconnect = threading.Event()
        self._disconnected = threading.Event()
        self._open_port()

    def _open_port(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)     # no echo or line editing before a client configures it
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)

    @property
    def held_port(self) -> str:
        """A path of the pty that exists only while this process holds it
        (``/proc/<pid>/fd/<n>``, Linux). A link to it leads nowhere once the
        process dies, even SIGKILLed; a link to :attr:`port` would lead to
        whichever process gets that pty number next."""
        return f"/proc/{os.getpid()}/fd/{self._slave}"

    # --- life cycle ------------------------------------------------------------

    def start(self) -> SimulatedGrbl:
        """Start the controller thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="SimulatedGrbl", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and close the pseudo-terminal (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._close_port()

    def __enter__(self) -> SimulatedGrbl:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # --- fault injection and inspection -------------------------------------------

    def disconnect(self, *, timeout_s: float = 1.0) -> None:
        """Close the pseudo-terminal as an unplugged USB cable would (mid-operation is fine)."""
        self._disconnect.set()
        if self._thread is None:
            self._close_port()
        elif not self._disconnected.wait(timeout_s):
            raise RuntimeError("simulator thread did not close the port in time")

    def replug(self) -> str:
        """Plug the cable back in after :meth:`disconnect`: a new pseudo-terminal (its path,
        also :attr:`port`, is returned). The controller kept its power: position, state and
        queued motion are as they were; bytes in flight on the old port are lost."""
        if not self._disconnected.is_set():
            raise RuntimeError("replug() needs a disconnect() first")
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        with self._lock:
            self._rx.clear()
            self._out.clear()
            self._open_port()
            self._disconnect.clear()
            self._disconnected.clear()
        if self._thread is not None:
            self._thread = None
            self.start()
        return self.port

    def trigger_limit(self) -> None:
        """A limit switch closes now: ``ALARM:1``, immediate halt, reset required."""
        with self._lock:
            now = time.monotonic()
            self._update(now)
            if self._homing is not None:
                self._slip = self._zero + self._cmd - self._true_now(now)
            self._hard_limit()

    def inject_output(self, data: bytes) -> None:
        """Send raw bytes to the client (noise, partial lines, unsolicited messages)."""
        with self._lock:
            self._out += bytes(data)

    def received(self) -> bytes:
        """Every byte received from the client so far, in order."""
        with self._lock:
            return bytes(self._received)

    def clear_received(self) -> None:
        with self._lock:
            self._received.clear()

    @property
    def state(self) -> str:
        """Machine state as a status report would give it (``"Hold:0"`` etc.)."""
        with self._lock:
            return self._state_text()

    def machine_position_deg(self) -> tuple[float, float]:
        """GRBL's own (step-counter) position of X and Y, degrees."""
        with self._lock:
            self._update(time.monotonic())
            return float(self._cmd[0]), float(self._cmd[1])

    def true_position_deg(self) -> tuple[float, float]:
        """True physical (theta, phi) in degrees: what the turntable and carriage show."""
        with self._lock:
            now = time.monotonic()
            self._update(now)
            true = self._true_now(now)
            return float(true[0]), float(true[1])

    def true_position_rad(self) -> tuple[float, float]:
        """True physical (theta, phi) in radians."""
        theta, phi = self.true_position_deg()
        return math.radians(theta), math.radians(phi)

    # --- thread ------------------------------------------------------------------------

    def _close_port(self) -> None:
        with self._lock:
            for name in ("_master", "_slave"):
                fd = getattr(self, name)
                if fd is not None:
                    os.close(fd)
                    setattr(self, name, None)
        self._disconnected.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._disconnect.is_set():
                self._close_port()
                return
            with self._lock:
                busy = (self._motion is not None or self._homing is not None or bool(self._out)
                        or self._dwell_until is not None)
                fragment = self.faults.fragment_output and bool(self._out)
            timeout = 0.001 if fragment else (0.004 if busy else 0.03)
            try:
                readable, _, _ = select.select([self._master], [], [], timeout)
                data = os.read(self._master, 4096) if readable else b""
            except BlockingIOError:
                data = b""
            except OSError:          # the client side went away (EIO) or the fd was closed
                data = b""
                time.sleep(timeout)
            with self._lock:
                now = time.monotonic()
                if data:
                    self._received += data
                    if not self.faults.no_answer:
                        self._receive(data, now)
                self._update(now)
                self._process_lines(now)
                self._flush()

    def _flush(self) -> None:
        if not self._out or self._master is None:
            return
        chunk = self._out[:3] if self.faults.fragment_output else self._out
        try:
            written = os.write(self._master, chunk)
        except (BlockingIOError, OSError):
            written = 0
        del self._out[:written]

    def _emit(self, data: bytes) -> None:
        if self.faults.no_answer:
            return
        self._out += self.faults.garbage + data
        if len(self._out) > _OUT_BUFFER_BYTES:      # nobody reads: like a UART, lose data
            del self._out[:len(self._out) - _OUT_BUFFER_BYTES]

    def _emit_line(self, text: str) -> None:
        self._emit(text.encode("ascii") + b"\r\n")

    def _emit_feedback(self, kind: str, text: str) -> None:
        self._emit_line(f"[{kind}:{text}]")

    # --- input: real-time bytes are picked off, the rest is buffered -------------

    def _receive(self, data: bytes, now: float) -> None:
        self._update(now)
        for byte in data:
            if byte == grbl.SOFT_RESET[0]:
                self._soft_reset(now)
            elif self._critical:
                continue                     # blocked until reset, status queries included
            elif byte == grbl.STATUS_QUERY[0]:
                if self._homing is not None:
                    self._report_pending = True
                else:
                    self._report(now)
            elif byte == grbl.FEED_HOLD[0]:
                self._feed_hold(now)
            elif byte == grbl.CYCLE_START[0]:
                self._cycle_start(now)
            elif byte > 0x7F:
                continue                     # unknown extended-ASCII real-time byte: dropped
            elif len(self._rx) < _RX_BUFFER_BYTES:
                self._rx.append(byte)

    def _process_lines(self, now: float) -> None:
        while not (self._critical or self._homing is not None or self._dwell_until is not None
                   or len(self._queue) >= _PLANNER_BLOCKS):
            ends = [i for i in (self._rx.find(b"\n"), self._rx.find(b"\r")) if i >= 0]
            if not ends:
                return
            end = min(ends)
            raw = bytes(self._rx[:end])
            del self._rx[:end + 1]
            self._execute_line(raw, now)

    @staticmethod
    def _clean(raw: bytes) -> tuple[bytes, bool]:
        """GRBL's line pre-processing: comments, blanks and control bytes out, upper case."""
        out = bytearray()
        paren = False
        for byte in raw:
            if paren:
                paren = byte != ord(")")
            elif byte == ord("("):
                paren = True
            elif byte == ord(";"):
                break
            elif byte > 0x20:
                out.append(byte - 32 if ord("a") <= byte <= ord("z") else byte)
        return bytes(out), len(out) >= grbl.LINE_BUFFER_SIZE

    def _execute_line(self, raw: bytes, now: float) -> None:
        line, overflow = self._clean(raw)
        if overflow:
            status = 11
        elif not line:
            status = 0
        elif line.startswith(b"$"):
            status = self._system_command(line, now)
        elif self._state == "Alarm":
            status = 9
        else:
            status = self._gcode(line, now)
        if status == 0:
            self._emit_line("ok")
        elif status is not None:
            self._emit_line(f"error:{status}")

    # --- '$' commands ---------------------------------------------------------------

    def _system_command(self, line: bytes, now: float) -> int | None:
        if line == b"$":
            self._emit_feedback("HLP", "$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H "
                                       "~ ! ? ctrl-x")
            return 0
        if line == b"$I":
            self._emit_feedback("VER", f"{grbl.VERSION}.20190830:")
            self._emit_feedback("OPT", "V,15,128")
            return 0
        if line == b"$X":
            if self._state == "Alarm":
                self._emit_feedback("MSG", grbl.MSG_UNLOCKED)
                self._state = "Idle"
            return 0
        if line == b"$H":
            if self._state not in ("Idle", "Alarm"):
                return 8
            self._start_homing(now)
            return None                      # answered when homing ends
        return 3

    def _start_homing(self, now: float) -> None:
        start = self._true_now(now)
        end = start.copy()
        end[0] = self._home_true[0] + 360.0 * round((start[0] - self._home_true[0]) / 360.0)
        end[1] = self._home_true[1]
        if self.faults.homing_fails:         # searches 1.5 x travel, finds nothing
            end = start
            duration = 1.5 * 100.0 / self._homing_speed
        else:
            duration = float(np.max(np.abs(end - start)[:2])) / self._homing_speed
        self._state = "Home"
        self._homing = (now, duration, start, end)

    def _finish_homing(self, now: float) -> None:
        t0, duration, start, end = self._homing
        self._homing = None
        if self.faults.homing_fails:
            self._report_pending = False
            self._emit_line("ALARM:9")
            self._state = "Alarm"
            self._slip = self._zero + self._cmd - end
            self._soft_reset(now, alarm_known=True)
            return
        self._zero = end.copy()
        self._cmd = np.zeros(3)
        self._slip = np.zeros(3)
        self._parser_pos = self._cmd.copy()
        self._state = "Idle"
        if self._report_pending:
            self._report_pending = False
            self._report(now)
        self._emit_line("ok")

    # --- g-code ----------------------------------------------------------------------

    def _gcode(self, line: bytes, now: float) -> int:
        words: dict[str, float] = {}
        g_motion = g_distance = None
        dwell = False
        i = 0
        while i < len(line):
            letter = chr(line[i])
            if not "A" <= letter <= "Z":
                return 1
            m = _NUMBER.match(line, i + 1)
            if m is None:
                return 2
            value = float(m.group())
            i = m.end()
            if letter == "G":
                if value != int(value):
                    return 20
                code = int(value)
                if code in (0, 1):
                    if g_motion is not None:
                        return 21
                    g_motion = code
                elif code in (90, 91):
                    if g_distance is not None:
                        return 21
                    g_distance = code
                elif code == 4:
                    if dwell:
                        return 21
                    dwell = True
                elif code != 21:             # G21 (mm = degrees here) is the only unit mode
                    return 20
            elif letter in "XYZFNP":
                if letter in words:
                    return 25
                words[letter] = value
            else:
                return 20
        if "N" in words and not (words["N"] == int(words["N"]) and 1 <= words["N"] <= 9999999):
            return 27
        if "F" in words and words["F"] < 0:
            return 4
        if "P" in words and not dwell:
            return 36
        if dwell and "P" not in words:
            return 28
        if dwell and words["P"] < 0:
            return 4
        motion = self._motion_mode if g_motion is None else g_motion
        axes = [a for a in _AXES if a in words]
        feed = words.get("F", self._feed)
        if axes and motion == 1 and not feed:
            return 22
        absolute = self._absolute if g_distance is None else g_distance == 90
        target = self._parser_pos.copy()
        for k, axis in enumerate(_AXES):
            if axis in words:
                target[k] = words[axis] if absolute else target[k] + words[axis]
        if axes:
            for k, lim in enumerate(self._limits):
                if lim is not None and not lim[0] <= target[k] <= lim[1]:
                    self._critical_alarm(2)
                    return None
        # The block is valid: commit its modal state, then queue what it does.
        self._absolute = absolute
        self._motion_mode = motion
        if "F" in words:
            self._feed = words["F"]
        if dwell:
            self._queue.append(("dwell", words["P"]))
        if axes and np.any(target != self._parser_pos):
            rate = self._feed / 60.0 if motion == 1 else None
            self._queue.append(("move", target, rate))
            self._parser_pos = target
        self._start_next(now)
        if dwell:
            return None                      # answered when the dwell ends
        return 0

    # --- motion ----------------------------------------------------------------------

    def _start_next(self, now: float) -> None:
        """Auto cycle start: begin the next queued block if nothing is executing."""
        while self._motion is None and self._dwell_until is None and self._queue:
            if self._state not in ("Idle", "Run"):
                return
            block = self._queue.pop(0)
            if block[0] == "dwell":
                self._dwell_until = now + block[1]
                return
            _, target, rate = block
            delta = target - self._cmd
            length = float(np.linalg.norm(delta))
            if length < 1e-9:
                continue
            u = delta / length
            moving = np.abs(u) > 1e-12
            v_max = float(np.min(self._speed[moving] / np.abs(u[moving])))
            if rate is not None:
                v_max = min(v_max, rate)
            accel = float(np.min(self._accel[moving] / np.abs(u[moving])))
            faults = self.faults
            stall_axis = _AXES.index(faults.stall_axis) if faults.stall_axis else None
            if stall_axis is not None and not moving[stall_axis]:
                stall_axis = None
            limit = faults.limit_at_fraction
            faults.limit_at_fraction = None
            self._motion = _Motion(self._cmd.copy(), target.copy(), u, length, v_max, accel, now,
                                   stall_axis, float(faults.stall_fraction), faults.stall_mode,
                                   limit, self._slip.copy())
            self._state = "Run"

    def _path(self, m: _Motion, now: float) -> tuple[float, float, bool]:
        """Path position, speed and done flag of the executing block at ``now``."""
        if m.frozen_s is not None:
            return m.frozen_s, 0.0, False
        if m.hold_t0 is not None:
            tau = min(now - m.hold_t0, m.hold_v / m.accel)
            s = m.hold_s + m.hold_v * tau - 0.5 * m.accel * tau * tau
            return min(s, m.length), max(m.hold_v - m.accel * tau, 0.0), False
        return _trapezoid(m.length, m.v_max, m.accel, now - m.t0)

    def _stall_extra(self, m: _Motion, s: float) -> np.ndarray:
        """How far the stalled axis lags its commanded position at path position ``s``."""
        extra = np.zeros(3)
        if m.stall_axis is not None:
            k = m.stall_axis
            extra[k] = m.u[k] * max(0.0, s - m.stall_fraction * m.length)
        return extra

    def _true_now(self, now: float) -> np.ndarray:
        if self._homing is not None:
            t0, duration, start, end = self._homing
            f = 1.0 if duration <= 0 else min((now - t0) / duration, 1.0)
            return start + f * (end - start)
        return self._zero + self._cmd - self._slip

    def _update(self, now: float) -> None:
        if self._homing is not None:
            if now - self._homing[0] >= self._homing[1] and not self.faults.homing_hold:
                self._finish_homing(now)
            return
        if self._dwell_until is not None and now >= self._dwell_until:
            self._dwell_until = None
            self._emit_line("ok")
        m = self._motion
        if m is None:
            self._start_next(now)
            return
        s, _, done = self._path(m, now)
        if m.limit_fraction is not None and s >= m.limit_fraction * m.length:
            s = m.limit_fraction * m.length
            self._set_path_position(m, s)
            self._hard_limit()
            return
        if m.stall_mode == "run" and m.stall_axis is not None and m.frozen_s is None \
                and s >= m.stall_fraction * m.length:
            m.frozen_s = s = m.stall_fraction * m.length
            done = False                     # even when first looked at after the whole move
        self._set_path_position(m, s)
        if m.hold_t0 is not None and now - m.hold_t0 >= m.hold_v / m.accel:
            self._hold_complete = True
        if done:
            self._cmd = m.target.copy()
            self._slip = m.base_slip + self._stall_extra(m, m.length)
            self._motion = None
            self._state = "Idle"
            self._start_next(now)

    def _set_path_position(self, m: _Motion, s: float) -> None:
        """Put GRBL's position at path position ``s`` of the block, the stall lag in ``_slip``."""
        self._cmd = m.start + m.u * s
        self._slip = m.base_slip + self._stall_extra(m, s)

    def _halt(self) -> None:
        """Sudden stop: the current point becomes the machine position, the rest is dropped."""
        self._motion = None
        self._queue.clear()
        self._dwell_until = None
        self._parser_pos = self._cmd.copy()

    def _feed_hold(self, now: float) -> None:
        if self._state in ("Alarm", "Home"):
            return
        if self._state == "Idle":
            self._state, self._hold_complete = "Hold", True
            return
        if self._state == "Run":
            m = self._motion
            if m is None:                     # dwelling
                self._state, self._hold_complete = "Hold", True
                return
            s, v, _ = self._path(m, now)
            m.hold_t0, m.hold_s, m.hold_v = now, s, v
            self._state, self._hold_complete = "Hold", v <= 0.0

    def _cycle_start(self, now: float) -> None:
        if self._state == "Hold" and self._hold_complete:
            m = self._motion
            self._state, self._hold_complete = "Idle", False
            if m is not None:                # resume: re-plan the rest of the block from rest
                self._set_path_position(m, self._path(m, now)[0])
                self._motion = None
                self._queue.insert(0, ("move", m.target, m.v_max))
            self._start_next(now)
        elif self._state == "Idle":
            self._start_next(now)

    def _critical_alarm(self, code: int) -> None:
        self._halt()
        self._state = "Alarm"
        self._critical = True
        self._report_pending = False
        self._emit_line(f"ALARM:{code}")
        self._emit_feedback("MSG", grbl.MSG_RESET_TO_CONTINUE)

    def _hard_limit(self) -> None:
        """Limit switch: halt where the axes are now (``_update`` has put them there)."""
        self._homing = None
        self._critical_alarm(1)

    def _soft_reset(self, now: float, *, alarm_known: bool = False) -> None:
        """Ctrl-x: abort everything; ALARM:3 if in motion (ALARM:6 while homing)."""
        if self._homing is not None:
            self._slip = self._zero + self._cmd - self._true_now(now)
            self._homing = None
            self._state = "Alarm"
            self._emit_line("ALARM:6")
        elif not self._critical and not alarm_known and (
                (self._state == "Run" and self._motion is not None)
                or (self._state == "Hold" and not self._hold_complete)):
            self._state = "Alarm"
            self._emit_line("ALARM:3")
        elif self._state in ("Hold", "Run"):
            self._state = "Idle"
        self._halt()
        self._critical = False
        self._hold_complete = False
        self._report_pending = False
        self._rx.clear()
        self._absolute, self._motion_mode = True, 0
        self._wco_counter, self._ovr_next = 0, False
        self._emit(grbl.welcome_line())
        if self._state == "Alarm":
            self._emit_feedback("MSG", grbl.MSG_UNLOCK)

    # --- status report ---------------------------------------------------------------

    def _state_text(self) -> str:
        if self._state == "Hold":
            return f"Hold:{0 if self._hold_complete else 1}"
        return self._state

    def _report(self, now: float) -> None:
        self._update(now)
        machine_true = self._true_now(now) - self._zero      # true angle in machine coordinates
        noise = self._rng.uniform(-1.0, 1.0, 2) * self._noise
        mpos = (machine_true[0] + self._offset[0] + noise[0],
                machine_true[1] + self._offset[1] + noise[1], machine_true[2])
        speed = self._path(self._motion, now)[1] if self._motion is not None else 0.0
        extra = {}
        busy = self._state in ("Run", "Hold", "Home")
        if self._wco_counter > 0:
            self._wco_counter -= 1
            if self._ovr_next:
                extra["Ov"] = "100,100,100"
                self._ovr_next = False
        else:                               # GRBL: WCO every 10 idle / 30 busy reports
            self._wco_counter = (30 if busy else 10) - 1
            self._ovr_next = True
            extra["WCO"] = "0.000,0.000,0.000"
        state, _, sub = self._state_text().partition(":")
        self._emit(grbl.format_status_report(state, mpos, substate=int(sub) if sub else None,
                                             feed=speed * 60.0, extra=extra))
