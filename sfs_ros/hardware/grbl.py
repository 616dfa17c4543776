"""GRBL 1.1 serial protocol: the subset a two-axis turntable cell uses.

Pure functions, no I/O: format the bytes a host sends, classify and parse the
lines a controller answers. Both :mod:`.driver` (the host) and
:mod:`.simulator` (the controller) use them, so the wire format lives in one
place.

Wire format (GRBL 1.1 ``doc/markdown/interface.md`` and ``realtime_cmds.md``)
---------------------------------------------------------------------------
* Line commands end with ``\\n``; each is answered, in order, by exactly one
  ``ok`` or ``error:N`` line.
* Real-time commands are single bytes, never followed by a newline and never
  answered with ``ok``: ``?`` status report, ``!`` feed hold, ``~`` cycle
  start / resume, ``0x18`` (ctrl-x) soft reset.
* Every controller line ends with ``\\r\\n``. Status reports are enclosed in
  ``<...>``: ``<Idle|MPos:12.000,45.000,0.000|FS:0,0>``; the machine state
  (optionally ``:substate``) comes first, the position second, other fields
  may follow in any order.
* Pushed at any time: ``ALARM:N``, ``[MSG:...]`` feedback, and the welcome
  banner ``Grbl 1.1h ['$' for help]`` after power-up or a soft reset.

Units: this cell configures GRBL so that one "millimetre" is one degree
(``$100``/``$101`` steps per degree), so positions on the wire are degrees and
rates are degrees per minute.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

__all__ = [
    "STATUS_QUERY", "FEED_HOLD", "CYCLE_START", "SOFT_RESET", "REALTIME_COMMANDS",
    "LINE_BUFFER_SIZE", "VERSION", "STATES", "ERROR_CODES", "ALARM_CODES",
    "CRITICAL_ALARMS", "MSG_RESET_TO_CONTINUE", "MSG_UNLOCK", "MSG_UNLOCKED",
    "Ok", "Error", "Alarm", "Welcome", "Feedback", "StatusReport",
    "format_move", "format_line", "format_status_report", "welcome_line",
    "parse_line", "parse_status_report", "error_meaning", "alarm_meaning",
]

#: Real-time command bytes (no newline, no ``ok``).
STATUS_QUERY = b"?"
FEED_HOLD = b"!"
CYCLE_START = b"~"
SOFT_RESET = b"\x18"
REALTIME_COMMANDS = frozenset(STATUS_QUERY + FEED_HOLD + CYCLE_START + SOFT_RESET)

#: GRBL's serial line buffer: longer lines are answered with ``error:11``.
LINE_BUFFER_SIZE = 80
#: Firmware version announced by the simulator's banner.
VERSION = "1.1h"
#: Machine states a GRBL 1.1 status report may start with.
STATES = ("Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep")

#: ``error:N`` codes (GRBL 1.1 ``doc/csv/error_codes_en_US.csv``), short form.
ERROR_CODES = {
    1: "G-code words consist of a letter and a value; letter was not found",
    2: "numeric value format is not valid or missing an expected value",
    3: "'$' system command was not recognized or supported",
    4: "negative value received for an expected positive value",
    5: "homing cycle is not enabled via settings",
    6: "minimum step pulse time must be greater than 3 us",
    7: "EEPROM read failed; restored to default values",
    8: "'$' command cannot be used unless Grbl is Idle",
    9: "G-code locked out during alarm or jog state",
    10: "soft limits cannot be enabled without homing also enabled",
    11: "max characters per line exceeded; line was not executed",
    12: "'$' setting value exceeds the maximum step rate supported",
    13: "safety door detected as opened and door state initiated",
    14: "build info or startup line exceeded EEPROM line length limit",
    15: "jog target exceeds machine travel; command ignored",
    16: "jog command with no '=' or contains prohibited g-code",
    17: "laser mode requires PWM output",
    20: "unsupported or invalid g-code command found in block",
    21: "more than one g-code command from same modal group found in block",
    22: "feed rate has not yet been set or is undefined",
    23: "g-code command in block requires an integer value",
    24: "more than one g-code command that requires axis words found in block",
    25: "repeated g-code word found in block",
    26: "no axis words found in block for g-code command that requires them",
    27: "line number value is invalid",
    28: "g-code command is missing a required value word",
    29: "G59.x work coordinate systems are not supported",
    30: "G53 only allowed with G0 and G1 motion modes",
    31: "axis words found in block when no command or modal state uses them",
    32: "G2 and G3 arcs require at least one in-plane axis word",
    33: "motion command target is invalid",
    34: "arc radius value is invalid",
    35: "G2 and G3 arcs require at least one in-plane offset word",
    36: "unused value words found in block",
    37: "G43.1 dynamic tool length offset is not assigned to the tool length axis",
    38: "tool number greater than max supported value",
}

#: ``ALARM:N`` codes (GRBL 1.1 ``doc/csv/alarm_codes_en_US.csv``), short form.
ALARM_CODES = {
    1: "hard limit triggered; position likely lost, re-homing recommended",
    2: "soft limit: motion target exceeds machine travel; position retained",
    3: "reset while in motion; position likely lost, re-homing recommended",
    4: "probe fail: probe not in the expected initial state",
    5: "probe fail: probe did not contact the workpiece",
    6: "homing fail: the active homing cycle was reset",
    7: "homing fail: safety door was opened during homing",
    8: "homing fail: pull-off travel failed to clear the limit switch",
    9: "homing fail: could not find the limit switch within search distance",
}

#: Alarms after which GRBL blocks everything (even status reports) until a soft
#: reset, and says ``[MSG:Reset to continue]`` (hard and soft limits).
CRITICAL_ALARMS = frozenset({1, 2})
MSG_RESET_TO_CONTINUE = "Reset to continue"
MSG_UNLOCK = "'$H'|'$X' to unlock"
MSG_UNLOCKED = "Caution: Unlocked"


def error_meaning(code: int) -> str:
    """Human-readable meaning of ``error:code``."""
    return ERROR_CODES.get(code, f"unknown error code {code}")


def alarm_meaning(code: int | None) -> str:
    """Human-readable meaning of ``ALARM:code`` (``None``: alarm lock of unknown cause)."""
    if code is None:
        return "controller is in alarm lock (home with $H or unlock with $X)"
    return ALARM_CODES.get(code, f"unknown alarm code {code}")


# --- messages ---------------------------------------------------------------

@dataclass(frozen=True)
class Ok:
    """``ok``: the oldest outstanding line command succeeded."""


@dataclass(frozen=True)
class Error:
    """``error:N``: the oldest outstanding line command was rejected."""
    code: int


@dataclass(frozen=True)
class Alarm:
    """``ALARM:N`` push message."""
    code: int


@dataclass(frozen=True)
class Welcome:
    """Start-up banner ``Grbl X.Xx ['$' for help]`` (power-up or soft reset)."""
    version: str


@dataclass(frozen=True)
class Feedback:
    """Bracketed feedback line ``[KIND:text]``, e.g. ``[MSG:Reset to continue]``."""
    kind: str
    text: str


@dataclass(frozen=True)
class StatusReport:
    """A parsed ``<...>`` real-time status report.

    Attributes
    ----------
    state : str
        One of :data:`STATES`.
    substate : int or None
        ``Hold:0`` -> 0 (hold complete), ``Hold:1`` -> 1 (decelerating), ...
    mpos : (3,) tuple of float or None
        Machine position X, Y, Z (degrees in this cell); ``None`` if the
        report carries ``WPos`` instead.
    wpos : (3,) tuple of float or None
        Work position, if reported instead of ``MPos``.
    feed : float or None
        Current feed rate from ``FS:``/``F:``, units per minute.
    fields : dict of str to str
        Every other ``type:value`` field, raw (``WCO``, ``Ov``, ``Pn``, ...).
    """
    state: str
    substate: int | None
    mpos: tuple[float, float, float] | None
    wpos: tuple[float, float, float] | None = None
    feed: float | None = None
    fields: dict[str, str] = field(default_factory=dict)


Message = Ok | Error | Alarm | Welcome | Feedback | StatusReport

_WELCOME = re.compile(r"Grbl (\S+) \['\$' for help\]")
_ERROR = re.compile(r"error:(\d{1,3})")
_ALARM = re.compile(r"ALARM:(\d{1,3})")
_FEEDBACK = re.compile(r"\[([A-Z][A-Za-z0-9]*):(.*)\]")
# A known message at the very end of a line whose start was corrupted by noise.
_TAIL = re.compile(r"(ok|error:\d{1,3}|ALARM:\d{1,3}|<[^<>]*>)$")


def _floats(text: str, n: int) -> tuple[float, ...]:
    values = tuple(float(v) for v in text.split(","))
    if len(values) < n or not all(math.isfinite(v) for v in values):
        raise ValueError(f"expected {n} finite comma-separated numbers, got {text!r}")
    return values


def parse_status_report(line: str) -> StatusReport:
    """Parse one status report line, with or without the trailing ``\\r\\n``.

    Raises ValueError naming what is malformed (missing chevrons, unknown
    state, missing or non-numeric position).
    """
    text = line.strip()
    if not (text.startswith("<") and text.endswith(">")):
        raise ValueError(f"status report must be enclosed in '<' '>', got {line!r}")
    parts = text[1:-1].split("|")
    state, _, sub = parts[0].partition(":")
    if state not in STATES:
        raise ValueError(f"unknown machine state {parts[0]!r} in {line!r}; "
                         f"expected one of {STATES}")
    try:
        substate = int(sub) if sub else None
    except ValueError:
        raise ValueError(f"substate {sub!r} in {line!r} is not an integer") from None
    if len(parts) < 2:
        raise ValueError(f"status report {line!r} has no position field")
    mpos = wpos = None
    feed = None
    fields: dict[str, str] = {}
    for index, part in enumerate(parts[1:]):
        name, colon, value = part.partition(":")
        if not colon:
            raise ValueError(f"field {part!r} in {line!r} is not of the form type:value")
        try:
            if name == "MPos":
                mpos = _floats(value, 3)[:3]
            elif name == "WPos":
                wpos = _floats(value, 3)[:3]
            elif name in ("FS", "F"):
                feed = _floats(value, 1)[0]
            else:
                fields[name] = value
        except ValueError as exc:
            raise ValueError(f"bad {name} field in status report {line!r}: {exc}") from None
        if index == 0 and mpos is None and wpos is None:
            raise ValueError(f"status report {line!r}: second field must be MPos or WPos")
    return StatusReport(state, substate, mpos, wpos, feed, fields)


def _parse_strict(text: str) -> Message | None:
    if text == "ok":
        return Ok()
    if m := _ERROR.fullmatch(text):
        return Error(int(m.group(1)))
    if m := _ALARM.fullmatch(text):
        return Alarm(int(m.group(1)))
    if text.startswith("<"):
        try:
            return parse_status_report(text)
        except ValueError:
            return None
    if m := _WELCOME.search(text):
        return Welcome(m.group(1))
    if m := _FEEDBACK.fullmatch(text):
        return Feedback(m.group(1), m.group(2))
    return None


def parse_line(line: str | bytes) -> tuple[Message | None, bool]:
    """Classify one controller line.

    Parameters
    ----------
    line : str or bytes
        One line without or with its ``\\r\\n``; bytes that are not ASCII are
        treated as line noise.

    Returns
    -------
    message : Ok, Error, Alarm, Welcome, Feedback, StatusReport or None
        ``None`` for a line that is not part of the protocol (noise).
    salvaged : bool
        True when the line was corrupted at its start and ``message`` was
        recovered from its tail (noise bytes followed by ``ok``, ``error:N``,
        ``ALARM:N`` or a complete ``<...>`` report). Such lines are counted as
        noise by the caller but not lost.
    """
    if isinstance(line, bytes):
        line = line.decode("ascii", errors="replace")
    text = line.strip("\r\n")
    message = _parse_strict(text.strip())
    if message is not None:
        return message, False
    if (m := _TAIL.search(text)) is not None:
        return _parse_strict(m.group(1)), True
    return None, False


# --- formatting ---------------------------------------------------------------

def _fmt(value: float) -> str:
    """GRBL-style fixed 3 decimals, never ``-0.000``."""
    text = f"{value:.3f}"
    return "0.000" if text == "-0.000" else text


def format_line(command: str) -> bytes:
    """Encode a line command: ASCII text plus ``\\n``.

    Raises ValueError for a command containing a newline, a real-time
    character or non-ASCII text, or longer than :data:`LINE_BUFFER_SIZE`.
    """
    if not isinstance(command, str):
        raise ValueError(f"command must be a str, got {type(command).__name__}")
    try:
        data = command.encode("ascii")
    except UnicodeEncodeError:
        raise ValueError(f"command {command!r} is not ASCII") from None
    bad = set(data) & (REALTIME_COMMANDS | {0x0A, 0x0D})
    if bad:
        raise ValueError(f"command {command!r} contains newline or real-time bytes "
                         f"{sorted(bytes([b]) for b in bad)}")
    if len(data) >= LINE_BUFFER_SIZE:
        raise ValueError(f"command {command!r} is {len(data)} characters; GRBL accepts at most "
                         f"{LINE_BUFFER_SIZE - 1}")
    return data + b"\n"


def format_move(x_deg: float, y_deg: float) -> bytes:
    """Absolute rapid move ``G90 G0 X<x> Y<y>\\n``, 3 decimals (degrees in this cell).

    >>> format_move(90, 45)
    b'G90 G0 X90.000 Y45.000\\n'
    """
    for name, value in (("x_deg", x_deg), ("y_deg", y_deg)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")
        if abs(value) >= 1e6:
            raise ValueError(f"{name} = {value!r} is out of range; expected |value| < 1e6 degrees")
    return format_line(f"G90 G0 X{_fmt(x_deg)} Y{_fmt(y_deg)}")


def format_status_report(state: str, mpos: tuple[float, float, float], *,
                         substate: int | None = None, feed: float = 0.0,
                         spindle: float = 0.0, extra: dict[str, str] | None = None) -> bytes:
    """A status report line as GRBL 1.1 prints it with ``$10=1`` (MPos, no buffer field).

    >>> format_status_report("Idle", (12, 45, 0))
    b'<Idle|MPos:12.000,45.000,0.000|FS:0,0>\\r\\n'
    """
    if state not in STATES:
        raise ValueError(f"unknown state {state!r}; expected one of {STATES}")
    head = state if substate is None else f"{state}:{int(substate)}"
    parts = [head, "MPos:" + ",".join(_fmt(v) for v in mpos),
             f"FS:{round(feed):d},{round(spindle):d}"]
    parts += [f"{k}:{v}" for k, v in (extra or {}).items()]
    return ("<" + "|".join(parts) + ">\r\n").encode("ascii")


def welcome_line(version: str = VERSION) -> bytes:
    """The banner GRBL prints after power-up or a soft reset (with its leading ``\\r\\n``)."""
    return f"\r\nGrbl {version} ['$' for help]\r\n".encode("ascii")
