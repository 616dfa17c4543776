"""The scan, view by view, without ROS: move, settle, shutter, tag, send; retries and pauses.

:class:`ScanSequence` runs a plan of viewpoints through a small port
interface (:class:`ScanPorts`) that the scan node implements with topics and
services, and a test with fakes:

* for each view not yet captured, in plan order: command the viewpoint and
  wait until the encoder readings have settled on it
  (:class:`sfs_ros.cell_logic.settle_detection.SettleDetector`); take the view's frame, and
  tag it with the encoder reading whose stamp is nearest to the frame's
  (:class:`EncoderHistory`); record the capture in the :class:`CaptureLedger`
  and send it. The frame is, by ``ScanSettings.trigger``:

  - ``shutter``: release the shutter (``ports.shutter``, our camera node's
    ``capture``) and wait for the frame it announces by its stamp;
  - ``stream``: a camera that streams on its own (any driver publishing
    ``image_raw``): the first frame stamped at or after the moment the axes
    settled plus ``exposure_delay_s`` (``ports.stamp_now``). Frames stamped
    earlier, even those that arrive after the axes settled (a driver's
    latency), were exposed while the axes moved and are passed over;
* a move that does not settle (timeout, stall, no readings) is commanded
  again up to ``move_retries`` times, a shot that brings no frame retaken up
  to ``capture_retries`` times, each retry a WARN; when they are used up the
  scan **pauses** with an ERROR naming the view and the reason;
  :meth:`ScanSequence.resume` goes on from that view (what was captured
  stays captured); :meth:`ScanSequence.cancel` stops the axes and ends the run
  likewise (state ``cancelled``, resumable);
* before the first view the ``prepare`` steps run (reset the reconstruction,
  home the axes); a step that fails pauses the scan;
* delivery (:meth:`ScanSequence.tick`, from a timer): captures without a
  receipt in time are sent again, up to ``max_sends`` sends, then reported
  lost; when a receiver appears that was not there before, every capture is
  sent again;
* with a :class:`sfs_ros.cell_logic.scan_progress.ScanProgress`, every capture is
  written to disk before it is sent, and the scan's number, state and
  receipts with it, so that a restarted node takes up the same scan
  (:meth:`ScanSequence.restore`); a capture that cannot be written (a full
  disk) puts the scan in state ``waiting`` with an ERROR naming the folder
  and the space needed, and it goes on by itself once the write succeeds;
* with ``rehome_before_retry``, a move that failed is retried after the
  ``home`` step (a controller that restarted has lost its position and
  refuses moves until homed).

Threads: :meth:`ScanSequence.run` blocks (a worker thread of the node); the
inputs (:meth:`encoder_reading`, :meth:`frame`, :meth:`receipt`, :meth:`tick`)
and the controls come from other threads. Every wait goes through
``ports.wait_for`` on the sequence's condition and every time through
``ports.now``, so a test drives the whole scan with a simulated clock.

Times are seconds of the ports' monotonic clock, angles radians, stamps
``(sec, nanosec)``.
"""

from __future__ import annotations

import math
import os
import threading
import time
import traceback
from collections import OrderedDict, deque
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import numpy as np

from .capture_ledger import CaptureLedger, EncoderHistory, EncoderReading
from .scan_progress import SavedCapture, SavedScan, ScanProgress
from .settle_detection import SettleDetector

__all__ = ["MonotonicClock", "ScanPorts", "ScanSequence", "ScanSettings", "ScanStatus",
           "StepFailed", "SCAN_STATES", "TRIGGERS"]

Stamp = tuple[int, int]

#: ``idle`` before the first start; ``starting`` (prepare steps), ``running`` and
#: ``waiting`` (for disk space, goes on by itself) while :meth:`ScanSequence.run` works;
#: then ``done``, ``paused`` or ``cancelled``.
SCAN_STATES = ("idle", "starting", "running", "waiting", "paused", "cancelled", "done")
_ACTIVE = ("starting", "running", "waiting")
#: How often a capture that could not be written to disk is tried again, s.
_DISK_RETRY_S = 1.0
#: How often a move's state is judged when no encoder reading comes, s.
_POLL_S = 0.1
#: Camera frames kept by stamp while waiting for the view's one (a second of a 16 Hz stream).
_FRAMES_KEPT = 16
#: How the view's frame is taken (see the module's description).
TRIGGERS = ("shutter", "stream")
#: Encoder readings kept for the move being watched (drained every _POLL_S).
_READINGS_KEPT = 1000


def _disk_problem(view: int, folder, size: int, exc: OSError) -> str:
    """The ERROR of a capture that could not be written: where, why, and the space needed."""
    try:
        stat = os.statvfs(folder)
        free = f" ({stat.f_bavail * stat.f_frsize / 1e6:.1f} MB free now)"
    except OSError:
        free = ""
    return (f"view {view + 1}: cannot keep the capture in {folder}: "
            f"{exc.strerror or exc}; it needs {size / 1e6:.2f} MB free there{free}; "
            "the scan waits and goes on by itself once the write succeeds")


def _format(stamp: Stamp) -> str:
    """``sec.nanosec`` of a stamp, for messages."""
    return f"{stamp[0]}.{stamp[1]:09d}"


def _nanoseconds(stamp: Stamp) -> int:
    return stamp[0] * 1_000_000_000 + stamp[1]


def _checked_views(views_rad) -> np.ndarray:
    """(n, 2) float64 views; ValueError unless a non-empty array of finite angles."""
    views = np.asarray(views_rad, dtype=np.float64)
    if views.ndim != 2 or views.shape[1] != 2 or len(views) == 0 \
            or not np.all(np.isfinite(views)):
        raise ValueError(f"views_rad must be a non-empty (n, 2) array of finite angles, "
                         f"got shape {views.shape}")
    return views


class StepFailed(Exception):
    """A step of the scan failed this time (it may be retried); the text says why."""


class _Cancelled(Exception):
    """cancel() was called."""


class _Fault(Exception):
    """The scan cannot go on (retries used up); the text says why."""


@dataclass(frozen=True)
class ScanSettings:
    """Tolerances, deadlines and retry counts of a scan.

    settle_tolerance_rad, settle_samples, move_timeout_s, stall_s
        Of :class:`SettleDetector` (radians, readings, seconds, seconds).
    move_retries, capture_retries : int
        Moves commanded again / shots retaken before the scan pauses.
    capture_timeout_s : float
        Longest wait for the shutter's answer and for its frame (``stream``: for the
        first frame stamped late enough), s.
    encoder_max_gap_s : float
        Largest time between a frame's stamp and the reading that tags it, s.
    receipt_timeout_s : float, max_sends : int
        Of :class:`CaptureLedger`.
    prepare : tuple of (step, timeout_s)
        Steps run before the first view (``ScanPorts.prepare``), e.g.
        ``(("reset", 10.0), ("home", 120.0))``.
    trigger : str
        One of :data:`TRIGGERS`: ``shutter`` (our camera's ``capture``) or ``stream``.
    exposure_delay_s : float
        ``stream``: the view's frame is stamped at least this long after the axes
        settled (>= 0), s; e.g. a camera's exposure plus the vibration's dying away.
    rehome_before_retry : bool
        Run the ``home`` step of ``prepare`` (when there is one) before commanding a
        failed move again.
    """

    settle_tolerance_rad: float
    settle_samples: int
    move_timeout_s: float
    stall_s: float
    move_retries: int
    capture_timeout_s: float
    capture_retries: int
    encoder_max_gap_s: float
    receipt_timeout_s: float
    max_sends: int
    prepare: tuple[tuple[str, float], ...] = ()
    trigger: str = "shutter"
    exposure_delay_s: float = 0.0
    rehome_before_retry: bool = False

    def __post_init__(self) -> None:
        if self.trigger not in TRIGGERS:
            raise ValueError(f"trigger must be one of {list(TRIGGERS)}, got {self.trigger!r}")
        if not (math.isfinite(self.exposure_delay_s) and self.exposure_delay_s >= 0):
            raise ValueError(f"exposure_delay_s must be a finite number >= 0, got "
                             f"{self.exposure_delay_s!r}")
        for name in ("move_retries", "capture_retries"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
        for name in ("capture_timeout_s", "encoder_max_gap_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        self.settle_detector()           # its own checks, now rather than at the first move

    def settle_detector(self) -> SettleDetector:
        """A fresh detector for one move."""
        return SettleDetector(self.settle_tolerance_rad, self.settle_samples,
                              self.move_timeout_s, stall_s=self.stall_s)


class ScanPorts(Protocol):
    """What the sequence needs from the cell (the scan node's topics and services)."""

    def now(self) -> float:
        """Seconds of a monotonic clock."""

    def wait_for(self, condition: threading.Condition, predicate: Callable[[], bool],
                 timeout_s: float) -> bool:
        """Wait until ``predicate()`` (checked under ``condition``, which is notified when an
        input arrives) or ``timeout_s`` has passed; the predicate's last value."""

    def command_move(self, theta_rad: float, phi_rad: float) -> None:
        """Send the axes toward a viewpoint (returns at once)."""

    def stop_axes(self) -> None:
        """Stop the axes; returns once the motor controller has answered (or after a
        bounded wait)."""

    def prepare(self, step: str, *, timeout_s: float, cancelled: threading.Event) -> None:
        """Run a preparation step (``ScanSettings.prepare``); :class:`StepFailed` saying why
        not. ``cancelled`` set: give up early."""

    def shutter(self, *, timeout_s: float, cancelled: threading.Event) -> Stamp:
        """Release the shutter; the stamp of the frame it took (the frame itself comes
        through :meth:`ScanSequence.frame`), or :class:`StepFailed` saying why not.
        (``trigger`` ``shutter`` only.)"""

    def stamp_now(self) -> Stamp:
        """Now on the clock that stamps the frames and encoder readings (the node's ROS
        clock). (``trigger`` ``stream`` only.)"""

    def make_capture(self, frame: Any, stamp: Stamp, reading: EncoderReading) -> Any:
        """The capture to send (and keep for resending): ``frame`` tagged with ``reading``;
        :class:`StepFailed` for a frame that cannot be read (it is retaken)."""

    def send(self, capture: Any) -> None:
        """Send (or send again) a capture made by :meth:`make_capture`."""

    def log(self, level: str, text: str) -> None:
        """A log line; ``level`` "info", "warning" or "error"."""

    def changed(self) -> None:
        """The state, the view or a problem changed (publish the diagnostics)."""

    def encode_capture(self, capture: Any) -> bytes:
        """A capture as bytes, to keep on disk (used with a :class:`ScanProgress`)."""

    def decode_capture(self, data: bytes) -> Any:
        """The capture of :meth:`encode_capture`'s bytes; ValueError if they are not one."""


class MonotonicClock:
    """``now`` and ``wait_for`` of :class:`ScanPorts` on the machine's clock, for real ports."""

    @staticmethod
    def now() -> float:
        return time.monotonic()

    @staticmethod
    def wait_for(condition: threading.Condition, predicate: Callable[[], bool],
                 timeout_s: float) -> bool:
        with condition:
            return condition.wait_for(predicate, timeout_s)


@dataclass(frozen=True)
class ScanStatus:
    """Where the scan stands, for diagnostics.

    ``values``: scan (number of starts), state, view (1-based), total,
    captured, receipted, resends, move_retries, capture_retries,
    lost_in_transport, malformed, motion_s, shutter_s, trigger (this scan's). ``problem`` (ERROR)
    and ``warning`` (WARN): empty when none; ``summary``: one line.
    """

    values: dict
    problem: str
    warning: str
    summary: str


class ScanSequence:
    """Runs a plan of views through ``ports``; see the module's description.

    Parameters
    ----------
    views_rad : (n, 2) float
        ``(theta, phi)`` of each view, radians, in the order to take them.
    ports : ScanPorts
    settings : ScanSettings
    progress : ScanProgress, optional
        Where the scan's progress and captures are kept on disk.
    """

    def __init__(self, views_rad, ports: ScanPorts, settings: ScanSettings,
                 progress: ScanProgress | None = None):
        self.views_rad = self.plan_views = _checked_views(views_rad)
        self.settings = settings
        self._ports = ports
        self.cancelled = threading.Event()
        self._cv = threading.Condition()    # all state below; notified on every input
        self._history = EncoderHistory()
        self._readings: deque[tuple[float, float]] = deque(maxlen=_READINGS_KEPT)
        self._frames: OrderedDict[Stamp, Any] = OrderedDict()
        self._earliest: Stamp | None = None    # stream: a view waits for a frame this late
        self._receivers: set = set()
        self._ledger = self._new_ledger()
        self._counts = self._new_counts()
        self._state, self._view, self._scan = "idle", 0, 0
        self._problem = self._warning = ""
        self._prepared = False
        self._progress = progress
        self._save_lock = threading.Lock()   # one progress write at a time, the newest last

    def __len__(self) -> int:
        return len(self.views_rad)

    def _new_ledger(self) -> CaptureLedger:
        return CaptureLedger(self.settings.receipt_timeout_s, self.settings.max_sends)

    @staticmethod
    def _new_counts() -> dict:
        return {"resends": 0, "move_retries": 0, "capture_retries": 0, "malformed": 0,
                "motion_s": 0.0, "shutter_s": 0.0}

    # -- inputs (any thread) -----------------------------------------------------------------

    def encoder_reading(self, stamp: Stamp, theta_rad: float, phi_rad: float) -> None:
        """An encoder read-back; ValueError for non-finite angles (nothing kept)."""
        with self._cv:
            self._history.add(stamp, theta_rad, phi_rad)
            self._readings.append((float(theta_rad), float(phi_rad)))
            self._cv.notify_all()

    def frame(self, stamp: Stamp, frame: Any) -> None:
        """A camera frame; the last few are kept by stamp for the shutter that took them
        (``stream``: only while a view waits, and only those stamped late enough, so a
        fast stream of large frames does not pile up)."""
        stamp = tuple(stamp)
        with self._cv:
            if self.settings.trigger == "stream" and (self._earliest is None
                                                      or stamp < self._earliest):
                return
            self._frames[stamp] = frame
            while len(self._frames) > _FRAMES_KEPT:
                self._frames.popitem(last=False)
            self._cv.notify_all()

    def receipt(self, stamp: Stamp) -> bool:
        """The receiver stored the capture at ``stamp``; False if it is not this scan's."""
        with self._cv:
            entry = self._ledger.entries.get(tuple(stamp))
            news = entry is not None and not entry.receipted
            ours = self._ledger.receipt(stamp)
        if news:
            self._save()
        return ours

    def count_malformed(self) -> None:
        """An input was refused (the caller logs why); counted in this scan's diagnostics."""
        with self._cv:
            self._counts["malformed"] += 1

    def tick(self, receivers: set) -> None:
        """Delivery, from a timer: resend what is due, report what is lost; ``receivers`` are
        the ids of the receivers of captures now (the reconstruction's receipt publisher,
        the recorder's subscription); one not seen before means a receiver (re)started:
        every capture is sent again."""
        now = self._ports.now()
        with self._cv:
            came_back = bool(set(receivers) - self._receivers) and self._ledger.captured > 0
            self._receivers |= set(receivers)
            resend = self._ledger.restart_downstream(now) if came_back else []
            more, lost = self._ledger.due(now)
            resend += more
            self._counts["resends"] += len(resend)
        if came_back:
            self._ports.log("warning", f"a new receiver of captures (a restarted "
                                       f"reconstruction or recorder?): sending all "
                                       f"{len(resend)} captures of the scan again")
        elif resend:
            self._ports.log("warning", f"sending {len(resend)} unreceipted capture(s) again: "
                                       f"views {[e.view + 1 for e in resend]}")
        for entry in resend:
            self._ports.send(entry.payload)
        for entry in lost:
            self._set_problem(f"view {entry.view + 1}: capture at stamp "
                              f"{_format(entry.stamp)} was never receipted "
                              f"after {entry.sends} sends (kept, not sent again)")

    # -- controls (any thread): (accepted, message) ------------------------------------------

    @property
    def state(self) -> str:
        """One of :data:`SCAN_STATES`."""
        return self._state

    @property
    def active(self) -> bool:
        """Whether a run is under way (or about to start)."""
        return self._state in _ACTIVE

    def start(self, settings: ScanSettings | None = None,
              views_rad=None) -> tuple[bool, str]:
        """A new scan from the first view (captures of the last one forgotten), with
        ``settings`` from now on if given (a resume keeps them), of the views ``views_rad``
        ((n, 2) radians, this scan only) or else of the plan given at construction; call
        :meth:`run` next when accepted. ValueError for bad ``views_rad``."""
        views = self.plan_views if views_rad is None else _checked_views(views_rad)
        with self._cv:
            if self.active:
                return False, (f"a scan is running (view {self._view + 1} of {len(self)}); "
                               "call scan/cancel first")
            if settings is not None:
                self.settings = settings
            self.views_rad = views
            if self._progress is not None:
                self._progress.plan_rad = views
            self._ledger = self._new_ledger()
            self._counts = self._new_counts()
            self._problem = self._warning = ""
            self._prepared = False
            self._view = 0
            self._scan += 1
            self._begin()
        if self._progress is not None:
            try:
                self._progress.clear_captures()
            except OSError as exc:
                self._ports.log("warning", f"captures of the last scan not deleted: {exc}")
        self._save()
        self._ports.changed()
        return True, f"scan {self._scan} started: {len(self)} views"

    def resume(self) -> tuple[bool, str]:
        """Go on with the views not yet captured; call :meth:`run` next when accepted."""
        with self._cv:
            if self.active:
                return False, "the scan is running"
            if self._state == "idle":
                return False, "no scan to resume: call scan/start"
            if self._ledger.captured == len(self):
                return False, f"all {len(self)} views are captured: nothing to resume"
            self._problem = self._warning = ""
            self._begin()
            to_go = len(self) - self._ledger.captured
        self._ports.changed()
        return True, f"resuming: {to_go} of {len(self)} views to go"

    def cancel(self, *, stop_axes: bool = True) -> tuple[bool, str]:
        """End the run at the next check (state ``cancelled``) and stop the axes (unless
        ``stop_axes`` is False: the node is shutting down); the message says where it
        stood."""
        with self._cv:
            if not self.active:
                return False, f"no scan is running (state {self._state})"
            self.cancelled.set()
            self._cv.notify_all()
            message = (f"cancelled at view {self._view + 1} of {len(self)}, "
                       f"{self._ledger.captured} captured; scan/resume goes on")
        if stop_axes:
            self._ports.stop_axes()
        return True, message

    def _begin(self) -> None:
        self.cancelled.clear()
        self._state = "running" if self._prepared else "starting"

    def restore(self) -> tuple[bool, str]:
        """Take up the scan saved in the progress folder (the node restarted): its number,
        captures (sent again at the next :meth:`tick`) and receipts. ``(go_on, message)``:
        ``go_on`` when it was under way, then call :meth:`run` next."""
        if self._progress is None:
            return False, "no progress folder"
        try:
            saved = self._progress.load()
        except ValueError as exc:
            return False, f"saved progress not taken up: {exc}"
        if saved is None:
            return False, "no saved scan"
        payloads, dropped = [], []
        for capture in saved.captures:
            try:
                payloads.append((capture, self._ports.decode_capture(
                    self._progress.load_capture(capture))))
            except (OSError, ValueError) as exc:
                dropped.append(f"view {capture.view + 1} ({exc})")
        now = self._ports.now()
        with self._cv:
            self._ledger = self._new_ledger()
            for capture, payload in payloads:
                entry = self._ledger.add(capture.view, capture.stamp, payload, now,
                                         angles_rad=(capture.theta_rad, capture.phi_rad))
                entry.receipted = capture.receipted
            self._scan, self._prepared = saved.scan, saved.prepared
            self._view = min(set(range(len(self))) - self._ledger.views(), default=0)
            go_on = saved.state in _ACTIVE and self._ledger.captured < len(self)
            if go_on:
                self._begin()
            elif saved.state in _ACTIVE:
                self._state = "done"
            else:
                self._state = saved.state if saved.state in SCAN_STATES else "paused"
            captured = self._ledger.captured
        message = (f"took up scan {saved.scan} ({saved.state}): {captured} of {len(self)} "
                   f"views captured" + (f"; captures lost from the disk, to be taken again: "
                                        f"{', '.join(dropped)}" if dropped else "")
                   + ("; going on" if go_on else ""))
        self._save()
        self._ports.changed()
        return go_on, message

    def _snapshot(self, extra: SavedCapture | None = None) -> SavedScan:
        """The scan as saved (with ``extra``, a capture about to be added); under the lock."""
        captures = [SavedCapture(e.view, e.stamp, *(e.angles_rad or (math.nan, math.nan)),
                                 e.receipted) for e in self._ledger.entries.values()]
        return SavedScan(scan=self._scan, state=self._state, prepared=self._prepared,
                         captures=tuple(captures + ([extra] if extra else [])))

    def _save(self) -> None:
        """Write the progress (when kept); a WARN when it cannot be written (the next write
        carries what this one missed)."""
        if self._progress is None:
            return
        with self._save_lock:
            with self._cv:
                snapshot = self._snapshot()
            try:
                self._progress.save(snapshot)
            except OSError as exc:
                self._ports.log("warning", f"scan progress not written to "
                                           f"{self._progress.folder}: {exc}")

    # -- the run (a worker thread) -----------------------------------------------------------

    def run(self) -> None:
        """Take the views not yet captured; returns when done, paused or cancelled."""
        try:
            if not self._prepared:
                self._prepare()
                self._prepared = True
            self._set_state("running")
            for view in range(len(self)):
                if view in self._ledger.views():
                    continue
                with self._cv:
                    self._view = view
                    self._warning = ""
                self._ports.changed()
                self._move(view)
                self._capture(view)
            self._set_state("done")
            self._ports.log("info", f"scan done: {len(self)} views captured")
        except _Cancelled:
            self._set_state("cancelled")
            self._ports.log("info", f"scan cancelled at view {self._view + 1}")
        except _Fault as fault:
            theta, phi = np.degrees(self.views_rad[self._view])
            self._set_problem(f"scan paused at view {self._view + 1} of {len(self)} "
                              f"(theta {theta:.2f}, phi {phi:.2f} deg): {fault}; mend it and "
                              "call scan/resume")
            self._set_state("paused")
        except Exception as exc:  # noqa: BLE001 -- a bug must not leave the scan "running"
            self._ports.log("error", traceback.format_exc())
            self._set_problem(f"scan paused at view {self._view + 1}: internal error "
                              f"{type(exc).__name__}: {exc}; call scan/resume")
            self._set_state("paused")

    def _check_cancel(self) -> None:
        if self.cancelled.is_set():
            raise _Cancelled()

    def _prepare(self) -> None:
        for step, timeout_s in self.settings.prepare:
            try:
                self._ports.prepare(step, timeout_s=timeout_s, cancelled=self.cancelled)
            except StepFailed as exc:
                self._check_cancel()
                raise _Fault(str(exc)) from None
            self._check_cancel()

    def _retry(self, counter: str, attempt: int, retries: int, text: str) -> None:
        """Count and report a retry (nothing when the retries are used up)."""
        if attempt < retries:
            with self._cv:
                self._counts[counter] += 1
                self._warning = f"view {self._view + 1}: {text}; retrying"
            self._ports.log("warning", self._warning)
            self._ports.changed()

    def _move(self, view: int) -> None:
        theta, phi = (float(v) for v in self.views_rad[view])
        retries = self.settings.move_retries
        reason = ""
        for attempt in range(retries + 1):
            with self._cv:
                self._readings.clear()           # readings of before this command
            detector = self.settings.settle_detector()
            detector.start(self._ports.now(), theta, phi)
            self._ports.command_move(theta, phi)
            state = detector.poll(self._ports.now())
            while not state.done:
                self._check_cancel()
                self._ports.wait_for(self._cv, lambda: bool(self._readings)
                                     or self.cancelled.is_set(), _POLL_S)
                with self._cv:
                    readings = list(self._readings)
                    self._readings.clear()
                if not readings:
                    state = detector.poll(self._ports.now())
                for reading in readings:
                    state = detector.update(self._ports.now(), *reading)
            with self._cv:
                self._counts["motion_s"] += state.elapsed_s
            if state.settled:
                return
            reason = f"move {state.reason}"
            self._retry("move_retries", attempt, retries, reason)
            if attempt < retries:
                self._rehome()
        raise _Fault(f"{reason} (after {retries + 1} attempts)")

    def _rehome(self) -> None:
        """Home the axes before a move is commanded again (``rehome_before_retry``); a
        failure is only a WARN (the retry then fails in its turn)."""
        steps = dict(self.settings.prepare)
        if not self.settings.rehome_before_retry or "home" not in steps:
            return
        self._ports.log("warning", f"view {self._view + 1}: homing before the move is "
                                   "commanded again")
        try:
            self._ports.prepare("home", timeout_s=steps["home"], cancelled=self.cancelled)
        except StepFailed as exc:
            self._check_cancel()
            self._ports.log("warning", f"homing before the retry failed: {exc}")

    def _keep(self, view: int, stamp: Stamp, capture: Any, reading: EncoderReading) -> None:
        """Write a capture and the progress listing it to disk before it is sent; while the
        disk refuses, the scan is ``waiting`` (ERROR) and the write is tried again."""
        if self._progress is None:
            return
        data = self._ports.encode_capture(capture)
        saved = SavedCapture(view, stamp, reading.theta_rad, reading.phi_rad, False)
        waiting = False
        while True:
            try:
                with self._save_lock:
                    self._progress.save_capture(view, stamp, data)
                    with self._cv:
                        snapshot = self._snapshot(saved)
                    self._progress.save(snapshot)
                break
            except OSError as exc:
                if not waiting:
                    waiting = True
                    self._set_problem(_disk_problem(view, self._progress.folder, len(data),
                                                    exc))
                    self._set_state("waiting")
                self._ports.wait_for(self._cv, self.cancelled.is_set, _DISK_RETRY_S)
                self._check_cancel()
        if waiting:
            with self._cv:
                self._problem = ""
            self._ports.log("info", f"view {view + 1}: capture written to "
                                    f"{self._progress.folder}; the scan goes on")
            self._set_state("running")

    def _capture(self, view: int) -> None:
        retries = self.settings.capture_retries
        reason = ""
        for attempt in range(retries + 1):
            self._check_cancel()
            start = self._ports.now()
            try:
                stamp, frame, reading = self._shoot()
                capture = self._ports.make_capture(frame, stamp, reading)
            except StepFailed as exc:
                self._check_cancel()
                reason = str(exc)
                self._retry("capture_retries", attempt, retries, reason)
                continue
            self._keep(view, stamp, capture, reading)
            with self._cv:
                self._counts["shutter_s"] += self._ports.now() - start
                self._ledger.add(view, stamp, capture, self._ports.now(),
                                 angles_rad=(reading.theta_rad, reading.phi_rad))
            self._ports.send(capture)
            return
        raise _Fault(f"no frame: {reason} (after {retries + 1} attempts)")

    def _shoot(self) -> tuple[Stamp, Any, EncoderReading]:
        """Take the view's frame: ``(stamp, frame, encoder reading)``, or StepFailed saying
        why not."""
        timeout_s = self.settings.capture_timeout_s
        if self.settings.trigger == "stream":
            stamp = self._streamed(timeout_s)
        else:
            stamp = tuple(self._ports.shutter(timeout_s=timeout_s, cancelled=self.cancelled))
            if not self._ports.wait_for(self._cv, lambda: stamp in self._frames
                                        or self.cancelled.is_set(), timeout_s) \
                    or stamp not in self._frames:
                self._check_cancel()
                raise StepFailed(f"frame at stamp {_format(stamp)} announced by the camera "
                                 f"but not received within {timeout_s:g} s")
        gap_s = self.settings.encoder_max_gap_s
        # The first reading after the shutter, if it comes soon, may be nearer than the last.
        self._ports.wait_for(self._cv, lambda: self._history.has_after(stamp), gap_s)
        with self._cv:
            frame = self._frames.pop(stamp)
            try:
                reading = self._history.nearest(stamp, max_gap_s=gap_s)
            except ValueError as exc:
                raise StepFailed(str(exc)) from None
        return stamp, frame, reading

    def _streamed(self, timeout_s: float) -> Stamp:
        """The stamp of the first streamed frame stamped at or after now plus the exposure
        delay (the frame is then in ``_frames``); StepFailed if none comes in time."""
        now_ns = _nanoseconds(tuple(self._ports.stamp_now()))
        earliest = divmod(now_ns + round(self.settings.exposure_delay_s * 1e9), 1_000_000_000)

        def first() -> Stamp | None:
            late = [s for s in self._frames if s >= earliest]
            return min(late) if late else None

        with self._cv:
            self._frames.clear()                 # of an earlier view
            self._earliest = earliest
        try:
            if not self._ports.wait_for(self._cv, lambda: first() is not None
                                        or self.cancelled.is_set(), timeout_s):
                self._check_cancel()
                raise StepFailed(f"no camera frame stamped at or after {_format(earliest)} "
                                 f"(the axes settled, plus {self.settings.exposure_delay_s:g} "
                                 f"s) within {timeout_s:g} s: is the camera streaming on "
                                 "image_raw?")
            self._check_cancel()
            with self._cv:
                return first()
        finally:
            with self._cv:
                self._earliest = None

    # -- state and diagnostics (any thread) --------------------------------------------------

    def _set_state(self, state: str) -> None:
        with self._cv:
            self._state = state
            self._cv.notify_all()
        self._save()
        self._ports.changed()

    def _set_problem(self, text: str) -> None:
        with self._cv:
            self._problem = text
        self._ports.log("error", text)
        self._ports.changed()

    def status(self) -> ScanStatus:
        """The diagnostics of the scan now."""
        with self._cv:
            values = dict(self._counts, motion_s=round(self._counts["motion_s"], 4),
                          shutter_s=round(self._counts["shutter_s"], 4), scan=self._scan,
                          state=self._state, view=self._view + 1, total=len(self),
                          captured=self._ledger.captured, receipted=self._ledger.receipted,
                          lost_in_transport=self._ledger.given_up,
                          trigger=self.settings.trigger)
            problem, warning = self._problem, self._warning
        summary = (f"{values['state']}: {values['captured']} of {values['total']} views "
                   f"captured, {values['receipted']} receipted")
        return ScanStatus(values, problem, warning, summary)
