"""Bookkeeping of the scan node, without ROS: encoder history and the captures sent.

* :class:`EncoderHistory` keeps the last encoder readings with their stamps,
  so that a capture is tagged with the reading *nearest to its shutter time*
  (not merely the latest one, which may predate the shutter by a polling
  period or come from after it).
* :class:`CaptureLedger` keeps every capture of the scan until the scan is
  over: which planned view it is, when it was sent, whether the
  reconstruction has receipted it. Captures without a receipt in time are
  due to be sent again (at-least-once delivery; the reconstruction stores a
  view once), up to a limit, after which they are reported as lost in
  transport but still kept. After a restart of the receiving side, every
  capture is due again.

Times are seconds of any monotonic clock, passed in; stamps are
``(sec, nanosec)`` pairs.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

__all__ = ["EncoderHistory", "EncoderReading", "CaptureLedger", "LedgerEntry"]

Stamp = tuple[int, int]


def _seconds(stamp: Stamp) -> float:
    """Seconds of a ``(sec, nanosec)`` stamp."""
    return stamp[0] + 1e-9 * stamp[1]


@dataclass(frozen=True)
class EncoderReading:
    """One encoder read-back: its ``stamp`` (sec, nanosec) and angles in radians."""

    stamp: Stamp
    theta_rad: float
    phi_rad: float


class EncoderHistory:
    """The last ``capacity`` encoder readings, in the order received."""

    def __init__(self, capacity: int = 200):
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f"capacity must be an integer >= 1, got {capacity!r}")
        self._readings: deque[EncoderReading] = deque(maxlen=capacity)

    def __len__(self) -> int:
        return len(self._readings)

    def add(self, stamp: Stamp, theta_rad: float, phi_rad: float) -> None:
        """Keep a reading; ValueError for non-finite angles."""
        if not (math.isfinite(theta_rad) and math.isfinite(phi_rad)):
            raise ValueError(f"encoder angles must be finite, got {theta_rad}, {phi_rad}")
        self._readings.append(EncoderReading(tuple(stamp), float(theta_rad), float(phi_rad)))

    def has_after(self, stamp: Stamp) -> bool:
        """Whether a reading stamped at or after ``stamp`` has arrived."""
        return any(r.stamp >= tuple(stamp) for r in self._readings)

    def nearest(self, stamp: Stamp, *, max_gap_s: float) -> EncoderReading:
        """The reading whose stamp is nearest to ``stamp``.

        Raises ValueError when there is none within ``max_gap_s`` seconds
        (the encoders were not being read at the shutter).
        """
        t = _seconds(stamp)
        best = min(self._readings, key=lambda r: abs(_seconds(r.stamp) - t), default=None)
        if best is None:
            raise ValueError("no encoder reading received: is the motor node running?")
        gap = abs(_seconds(best.stamp) - t)
        if gap > max_gap_s:
            raise ValueError(f"the nearest encoder reading is {gap:.3f} s from the shutter "
                             f"(at most {max_gap_s:g} s expected): encoders not being read")
        return best


@dataclass
class LedgerEntry:
    """A capture sent downstream.

    ``view`` is its index in the plan, ``payload`` what is sent again (the
    messages), ``sent_s`` when it was last sent, ``sends`` how often,
    ``angles_rad`` the encoder reading ``(theta, phi)`` that tags it (None if
    not given).
    """

    view: int
    stamp: Stamp
    payload: Any
    sent_s: float
    sends: int = 1
    receipted: bool = False
    given_up: bool = False
    angles_rad: tuple[float, float] | None = None


@dataclass
class CaptureLedger:
    """The captures of one scan, by stamp.

    receipt_timeout_s : float
        A capture without a receipt this long after it was sent is due again.
    max_sends : int
        Most times one capture is sent; after that it is given up (reported,
        kept in the ledger).
    """

    receipt_timeout_s: float
    max_sends: int
    entries: dict[Stamp, LedgerEntry] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.receipt_timeout_s) and self.receipt_timeout_s > 0):
            raise ValueError(f"receipt_timeout_s must be > 0, got {self.receipt_timeout_s}")
        if isinstance(self.max_sends, bool) or not isinstance(self.max_sends, int) \
                or self.max_sends < 1:
            raise ValueError(f"max_sends must be an integer >= 1, got {self.max_sends!r}")

    def add(self, view: int, stamp: Stamp, payload, now_s: float, *,
            angles_rad: tuple[float, float] | None = None) -> LedgerEntry:
        """Record a capture just sent (tagged with ``angles_rad``, radians); ValueError if its
        stamp or its view is already here."""
        stamp = tuple(stamp)
        if stamp in self.entries:
            raise ValueError(f"a capture with stamp {stamp} is already in the ledger")
        if any(e.view == view for e in self.entries.values()):
            raise ValueError(f"view {view} was already captured in this scan")
        entry = LedgerEntry(view, stamp, payload, now_s, angles_rad=angles_rad)
        self.entries[stamp] = entry
        return entry

    def receipt(self, stamp: Stamp) -> bool:
        """Mark the capture at ``stamp`` received downstream (also one given up: it made it
        after all); False if it is not ours."""
        entry = self.entries.get(tuple(stamp))
        if entry is None:
            return False
        entry.receipted, entry.given_up = True, False
        return True

    def due(self, now_s: float) -> tuple[list[LedgerEntry], list[LedgerEntry]]:
        """``(resend, give_up)``: captures to send again now (their ``sends`` and
        ``sent_s`` are updated: the caller sends them), and captures given up now."""
        resend, give_up = [], []
        for entry in self.entries.values():
            if entry.receipted or entry.given_up or now_s - entry.sent_s < self.receipt_timeout_s:
                continue
            if entry.sends >= self.max_sends:
                entry.given_up = True
                give_up.append(entry)
            else:
                entry.sends += 1
                entry.sent_s = now_s
                resend.append(entry)
        return resend, give_up

    def restart_downstream(self, now_s: float) -> list[LedgerEntry]:
        """The receiving side restarted and lost its state: every capture is unreceipted
        and due now, with a fresh allowance of sends. Returns them (the caller sends them)."""
        for entry in self.entries.values():
            entry.receipted = entry.given_up = False
            entry.sends, entry.sent_s = 1, now_s
        return sorted(self.entries.values(), key=lambda e: e.view)

    @property
    def captured(self) -> int:
        return len(self.entries)

    @property
    def receipted(self) -> int:
        return sum(e.receipted for e in self.entries.values())

    @property
    def given_up(self) -> int:
        return sum(e.given_up for e in self.entries.values())

    def views(self) -> set[int]:
        """Plan indices captured so far."""
        return {e.view for e in self.entries.values()}
