"""Has the rig arrived? Deciding from encoder read-back when a move is over.

After a move command toward ``(theta, phi)`` the encoders are read
repeatedly. The move ends in one of three ways:

* **settled**: the last ``samples`` readings are all within ``tolerance_rad``
  of the target on both axes, and their spread (max - min per axis) is below
  ``tolerance_rad``: the axes are there and have stopped moving (a reading
  that only passes through the target while overshooting does not count);
* **stalled**: for ``stall_s`` seconds the readings have not spread more than
  ``tolerance_rad`` on either axis, but they are not at the target (a jammed
  axis, lost steps, a controller that dropped the command);
* **timeout**: ``timeout_s`` seconds after the command, neither of the above.

Everything is pure and deterministic: times are passed in (seconds, any
monotonic clock), nothing is read from a clock. Angles in radians, compared
without wrapping (targets and readings are absolute encoder positions).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["SETTLE_STATES", "SettleState", "SettleDetector"]

#: ``moving`` until one of the final states ``settled``, ``stalled``, ``timeout``.
SETTLE_STATES = ("moving", "settled", "stalled", "timeout")


@dataclass(frozen=True)
class SettleState:
    """Where a move stands.

    Attributes
    ----------
    state : str
        One of :data:`SETTLE_STATES`.
    reason : str
        One line saying why (empty while moving).
    error_rad : (float, float) or None
        Last reading minus target, (theta, phi), radians; None before any reading.
    elapsed_s : float
        Seconds since the move started.
    """

    state: str
    reason: str
    error_rad: tuple[float, float] | None
    elapsed_s: float

    @property
    def done(self) -> bool:
        """True once the move has ended (settled, stalled or timed out)."""
        return self.state != "moving"

    @property
    def settled(self) -> bool:
        return self.state == "settled"


def _positive(name: str, value) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value}")
    return value


class SettleDetector:
    """Decide from encoder readings when a move has settled, stalled or timed out.

    Parameters
    ----------
    tolerance_rad : float
        Largest accepted distance from the target and largest spread of the
        readings that counts as "not moving", per axis, radians.
    samples : int
        Consecutive readings that must all be at the target (>= 1).
    timeout_s : float
        Seconds after :meth:`start` after which an unsettled move has failed.
    stall_s : float, keyword-only
        Seconds without movement, away from the target, that make a stall.
        Must exceed the controller's reaction time (a move is not a stall
        before it begins); at most ``timeout_s`` to matter.

    Use: :meth:`start` with the target when the command is sent, then
    :meth:`update` with every reading (and :meth:`poll` from a timer, so a
    silent encoder still times out). Once the move has ended the final state
    is returned until the next :meth:`start`.
    """

    def __init__(self, tolerance_rad: float, samples: int, timeout_s: float, *,
                 stall_s: float = 1.0):
        self.tolerance_rad = _positive("tolerance_rad", tolerance_rad)
        if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
            raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
        self.samples = int(samples)
        self.timeout_s = _positive("timeout_s", timeout_s)
        self.stall_s = _positive("stall_s", stall_s)
        self._target: np.ndarray | None = None
        self._start_s = 0.0
        self._last_s = 0.0
        self._readings: deque = deque()  # (time_s, theta, phi)
        self._final: SettleState | None = None

    @property
    def target(self) -> tuple[float, float] | None:
        """(theta, phi) of the current move, radians; None before :meth:`start`."""
        return None if self._target is None else (float(self._target[0]), float(self._target[1]))

    def start(self, time_s: float, theta_rad: float, phi_rad: float) -> None:
        """Begin watching a move toward ``(theta_rad, phi_rad)`` commanded at ``time_s``."""
        values = [float(time_s), float(theta_rad), float(phi_rad)]
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"move start time and target must be finite, got {values}")
        self._start_s = self._last_s = values[0]
        self._target = np.array(values[1:])
        self._readings.clear()
        self._final = None

    def _check_time(self, time_s: float) -> float:
        if self._target is None:
            raise ValueError("no move started: call start() with the target first")
        time_s = float(time_s)
        if not math.isfinite(time_s):
            raise ValueError(f"time must be finite, got {time_s}")
        if time_s < self._last_s:
            raise ValueError(f"time went backwards: {time_s} s after {self._last_s} s")
        self._last_s = time_s
        return time_s

    def _state(self, state: str, reason: str, time_s: float) -> SettleState:
        error = None
        if self._readings:
            _, theta, phi = self._readings[-1]
            error = (theta - float(self._target[0]), phi - float(self._target[1]))
        result = SettleState(state, reason, error, time_s - self._start_s)
        if state != "moving":
            self._final = result
        return result

    def _where(self) -> str:
        _, theta, phi = self._readings[-1]
        d_theta, d_phi = theta - self._target[0], phi - self._target[1]
        return (f"at theta={theta:.4f}, phi={phi:.4f} rad, {d_theta:+.4f} / {d_phi:+.4f} rad "
                f"from the target (tolerance {self.tolerance_rad:g} rad)")

    def update(self, time_s: float, theta_rad: float, phi_rad: float) -> SettleState:
        """Take one encoder reading (radians) at ``time_s`` (seconds) and judge the move."""
        time_s = self._check_time(time_s)
        if self._final is not None:
            return self._final
        theta_rad, phi_rad = float(theta_rad), float(phi_rad)
        if not (math.isfinite(theta_rad) and math.isfinite(phi_rad)):
            raise ValueError(f"encoder readings must be finite, got theta={theta_rad}, "
                             f"phi={phi_rad}")
        self._readings.append((time_s, theta_rad, phi_rad))
        # Keep the last `samples` readings and the newest one at least stall_s old.
        while len(self._readings) > self.samples and self._readings[1][0] <= time_s - self.stall_s:
            self._readings.popleft()

        window = np.array(self._readings)[:, 1:]
        tol = self.tolerance_rad
        last = window[-self.samples:]
        if len(last) == self.samples and np.all(np.abs(last - self._target) <= tol) \
                and np.all(np.ptp(last, axis=0) < tol):
            return self._state("settled", f"settled {self._where()} after "
                               f"{time_s - self._start_s:.3f} s", time_s)
        still = np.all(np.ptp(window, axis=0) < tol)
        if still and len(window) >= self.samples and self._readings[0][0] <= time_s - self.stall_s:
            return self._state("stalled", f"stalled: the encoders have not moved for "
                               f"{self.stall_s:g} s, {self._where()}", time_s)
        return self.poll(time_s)

    def poll(self, time_s: float) -> SettleState:
        """Judge the move at ``time_s`` without a new reading (a timer tick)."""
        time_s = self._check_time(time_s)
        if self._final is not None:
            return self._final
        if time_s - self._start_s > self.timeout_s:
            where = self._where() if self._readings else "with no encoder reading received"
            return self._state("timeout", f"timeout: not settled within {self.timeout_s:g} s, "
                               f"{where}", time_s)
        return self._state("moving", "", time_s)
