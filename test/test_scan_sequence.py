"""The scan's sequencing (sfs_ros.cell_logic.scan_sequence) with a simulated cell: no processes.

The fake cell is a discrete-event simulation: a clock that only moves when the
sequence waits (to the next scheduled event: an encoder reading, a frame, an
injected fault or control), axes that reach a commanded viewpoint after
``MOVE_S`` unless a fault is switched on, encoders read every ``READ_S`` and a
camera whose frame arrives ``FRAME_S`` after its shutter, or (``stream``) a
camera that streams on its own, as a third-party driver does, a frame every
``STREAM_S`` stamped when exposed and arriving ``LATENCY_S`` later. Each test
runs the sequence in the test's own thread, so every run is deterministic.
"""

import heapq
import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from sfs_ros.cell_logic.scan_sequence import ScanSequence, ScanSettings, StepFailed

VIEWS = np.radians([[0.0, 20.0], [90.0, 20.0], [180.0, 20.0], [270.0, 20.0], [0.0, 90.0]])
MOVE_S = 0.5        # a move takes this long
READ_S = 0.1        # encoder period
FRAME_S = 0.05      # shutter to frame
STREAM_S = 1 / 30   # a streaming camera's frame period
#: Exposure (the frame's stamp) to arrival, streaming: longer than the time from the axes'
#: arrival to their settling (3 readings, 0.2-0.3 s), so frames exposed while they moved are
#: still arriving when they have settled.
LATENCY_S = 0.4
SETTINGS = ScanSettings(settle_tolerance_rad=math.radians(0.1), settle_samples=3,
                        move_timeout_s=5.0, stall_s=2.0, move_retries=2, capture_timeout_s=1.0,
                        capture_retries=2, encoder_max_gap_s=0.5, receipt_timeout_s=10.0,
                        max_sends=3, prepare=(("reset", 10.0), ("home", 60.0)))


def _stamp(t: float) -> tuple[int, int]:
    ns = round(t * 1e9)
    return ns // 1_000_000_000, ns % 1_000_000_000


class FakeCell:
    """The ports of :class:`ScanSequence`, simulated."""

    def __init__(self, settings=SETTINGS):
        self.t = 0.0
        self._events = []               # heap of (time, order, action)
        self._order = itertools.count()
        self.position = (0.0, 0.0)
        self.logs, self.sent, self.commands, self.prepared = [], [], [], []
        self.stops = 0
        self.silent_encoders = False    # no readings (switched by the moves, see silent)
        self.silent = set()             # numbers (1-based) of the moves that get no readings
        self.hung = set()               # numbers of the moves whose axes never start
        self.on_move = {}               # move number -> action run 0.2 s after it
        self.drop_frames = 0            # this many next frames never arrive
        self.failing_steps = set()      # prepare steps that fail
        self.streaming = False          # the stream camera's frames (trigger "stream")
        self.shutters = 0
        self.settled_at = []            # when the sequence asked for the stream's time
        self.seq = ScanSequence(VIEWS, self, settings)
        self.at(READ_S, self._read)
        if settings.trigger == "stream":
            self.streaming = True
            self.at(STREAM_S, self._expose)

    # -- the simulation --------------------------------------------------------------------

    def at(self, delay_s: float, action) -> None:
        heapq.heappush(self._events, (self.t + delay_s, next(self._order), action))

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` pass, running the events due."""
        self.wait_for(None, lambda: False, seconds)

    def _read(self) -> None:
        if not self.silent_encoders:
            theta, phi = self.position
            self.seq.encoder_reading(_stamp(self.t), theta, phi)
        self.at(READ_S, self._read)

    def _arrive(self, target) -> None:
        self.position = target

    def _expose(self) -> None:
        """A streamed frame: what the camera saw now (the axes' position), stamped now,
        delivered LATENCY_S later."""
        if self.streaming:
            stamp, seen = _stamp(self.t), self.position
            self.at(LATENCY_S, lambda: self.seq.frame(stamp, ("streamed", seen)))
        self.at(STREAM_S, self._expose)

    # -- ports -------------------------------------------------------------------------------

    def now(self) -> float:
        return self.t

    def wait_for(self, _condition, predicate, timeout_s: float) -> bool:
        deadline = self.t + timeout_s
        while not predicate():
            if not self._events or self._events[0][0] > deadline:
                self.t = deadline
                return predicate()
            when, _, action = heapq.heappop(self._events)
            self.t = max(self.t, when)
            action()
        return True

    def command_move(self, theta_rad, phi_rad) -> None:
        self.commands.append((theta_rad, phi_rad))
        number = len(self.commands)
        self.silent_encoders = number in self.silent
        if number in self.on_move:
            self.at(0.2, self.on_move[number])
        if number not in self.hung:
            self.at(MOVE_S, lambda: self._arrive((theta_rad, phi_rad)))

    def stop_axes(self) -> None:
        self.stops += 1

    def prepare(self, step, *, timeout_s, cancelled) -> None:
        self.prepared.append(step)
        if step in self.failing_steps:
            raise StepFailed(f"service {step} is not available (waited {timeout_s:g} s)")

    def stamp_now(self):
        self.settled_at.append(self.t)
        return _stamp(self.t)

    def shutter(self, *, timeout_s, cancelled):
        self.shutters += 1
        stamp = _stamp(self.t)
        if self.drop_frames:
            self.drop_frames -= 1
        else:
            self.at(FRAME_S, lambda: self.seq.frame(stamp, f"frame {stamp}"))
        return stamp

    def make_capture(self, frame, stamp, reading):
        return (frame, stamp, reading)

    def send(self, capture) -> None:
        self.sent.append(capture)

    def log(self, level, text) -> None:
        self.logs.append((level, text))

    def changed(self) -> None:
        pass

    # -- checks ------------------------------------------------------------------------------

    def run(self, settings=None):
        ok, message = self.seq.start(settings)
        assert ok, message
        self.seq.run()
        return self.seq.status()

    def resume(self):
        ok, message = self.seq.resume()
        assert ok, message
        self.seq.run()
        return self.seq.status()

    def lines(self, level: str) -> list[str]:
        return [text for lvl, text in self.logs if lvl == level]

    def views_sent(self) -> list[int]:
        """Plan index of each capture sent, by its tag's angles."""
        return [int(np.argmin(np.abs(VIEWS - [r.theta_rad, r.phi_rad]).max(axis=1)))
                for _, _, r in self.sent]

    def receipt_all(self) -> None:
        for _, stamp, _ in self.sent:
            self.seq.receipt(stamp)


def test_a_good_scan_takes_every_view_once_tagged_at_its_viewpoint():
    cell = FakeCell()
    status = cell.run()
    assert status.values["state"] == "done" and status.problem == status.warning == ""
    assert cell.prepared == ["reset", "home"]
    assert cell.commands == [tuple(v) for v in VIEWS]
    assert cell.views_sent() == list(range(len(VIEWS)))
    for (frame, stamp, reading), view in zip(cell.sent, VIEWS):
        assert frame == f"frame {stamp}"
        assert (reading.theta_rad, reading.phi_rad) == tuple(view)
        # the reading nearest the frame's stamp: at most half an encoder period away
        assert abs((reading.stamp[0] + 1e-9 * reading.stamp[1])
                   - (stamp[0] + 1e-9 * stamp[1])) <= READ_S / 2 + 1e-9
    assert status.values["captured"] == len(VIEWS) and status.values["move_retries"] == 0
    assert status.values["motion_s"] > 0 and status.values["shutter_s"] > 0
    assert status.summary == f"done: {len(VIEWS)} of {len(VIEWS)} views captured, 0 receipted"
    assert cell.lines("info") == [f"scan done: {len(VIEWS)} views captured"]
    assert cell.lines("warning") == cell.lines("error") == []


@pytest.mark.parametrize("fault, reason", [
    ("silent", "move timeout: not settled within 5 s, with no encoder reading received"),
    ("hung", "move stalled: the encoders have not moved for 2 s"),
])
def test_a_failed_move_is_commanded_again_with_a_warning_then_succeeds(fault, reason):
    cell = FakeCell()
    getattr(cell, fault).add(1)
    status = cell.run()
    assert status.values["state"] == "done" and status.problem == ""
    assert cell.commands[:2] == [tuple(VIEWS[0])] * 2
    assert status.values["move_retries"] == 1
    [warning] = cell.lines("warning")
    assert warning.startswith(f"view 1: {reason}") and warning.endswith("; retrying")
    assert cell.views_sent() == list(range(len(VIEWS)))


def test_retries_used_up_pause_with_an_error_naming_the_view_and_resume_goes_on():
    cell = FakeCell()
    cell.silent = {3, 4, 5}             # view 3: all three attempts get no reading
    cell.seq.start()
    cell.seq.run()
    paused = cell.seq.status()
    assert paused.values["state"] == "paused"
    assert paused.values["view"] == 3 and paused.values["move_retries"] == 2
    assert cell.views_sent() == [0, 1]
    assert len(cell.lines("warning")) == 2
    [error] = cell.lines("error")
    assert error == paused.problem
    assert error == (f"scan paused at view 3 of {len(VIEWS)} (theta 180.00, phi 20.00 deg): "
                     "move timeout: not settled within 5 s, with no encoder reading received "
                     "(after 3 attempts); mend it and call scan/resume")
    assert cell.seq.resume() == (True, f"resuming: 3 of {len(VIEWS)} views to go")
    cell.seq.run()
    status = cell.seq.status()
    assert status.values["state"] == "done" and status.problem == ""
    assert cell.views_sent() == list(range(len(VIEWS)))       # each view once
    assert cell.prepared == ["reset", "home"]                  # not again on resume
    assert status.values["scan"] == 1


def test_a_preparation_step_that_fails_pauses_before_any_move():
    cell = FakeCell()
    cell.failing_steps = {"home"}
    cell.seq.start()
    assert cell.seq.status().values["state"] == "starting"
    cell.seq.run()
    status = cell.seq.status()
    assert status.values["state"] == "paused" and cell.commands == []
    assert status.problem == (f"scan paused at view 1 of {len(VIEWS)} (theta 0.00, phi 20.00 "
                              "deg): service home is not available (waited 60 s); mend it and "
                              "call scan/resume")
    cell.failing_steps = set()
    cell.resume()
    assert cell.prepared == ["reset", "home", "reset", "home"]
    assert cell.views_sent() == list(range(len(VIEWS)))


def test_cancel_stops_the_axes_and_resume_goes_on():
    cell = FakeCell()
    answers = []
    cell.on_move[2] = lambda: answers.append(cell.seq.cancel())
    cell.seq.start()
    cell.seq.run()
    assert answers == [(True, f"cancelled at view 2 of {len(VIEWS)}, 1 captured; scan/resume "
                              "goes on")]
    assert cell.stops == 1
    assert cell.seq.status().values["state"] == "cancelled"
    assert cell.lines("info") == ["scan cancelled at view 2"]
    assert cell.seq.cancel() == (False, "no scan is running (state cancelled)")
    cell.seq.resume()
    cell.seq.run()
    assert cell.seq.status().values["state"] == "done"
    assert cell.views_sent() == list(range(len(VIEWS)))


def test_cancel_during_preparation_ends_the_run_before_any_move():
    cell = FakeCell()
    cell.prepare = lambda step, **_: cell.seq.cancel() if step == "reset" else None
    cell.seq.start()
    cell.seq.run()
    assert cell.seq.status().values["state"] == "cancelled" and cell.commands == []


def test_a_dropped_frame_is_retaken_with_a_warning():
    cell = FakeCell()
    cell.drop_frames = 1
    status = cell.run()
    assert status.values["state"] == "done" and status.values["capture_retries"] == 1
    [warning] = cell.lines("warning")
    assert warning.startswith("view 1: frame at stamp ")
    assert warning.endswith("announced by the camera but not received within 1 s; retrying")
    assert cell.views_sent() == list(range(len(VIEWS)))


def test_frames_that_never_come_pause_the_scan():
    cell = FakeCell()
    cell.drop_frames = 3
    status = cell.run()
    assert status.values["state"] == "paused" and status.values["capture_retries"] == 2
    assert "no frame: frame at stamp " in status.problem
    assert "(after 3 attempts)" in status.problem
    assert cell.sent == []


def test_controls_refuse_what_does_not_fit_the_state():
    cell = FakeCell()
    assert cell.seq.resume() == (False, "no scan to resume: call scan/start")
    assert cell.seq.cancel() == (False, "no scan is running (state idle)")
    assert cell.seq.start() == (True, f"scan 1 started: {len(VIEWS)} views")
    assert cell.seq.start() == (False, f"a scan is running (view 1 of {len(VIEWS)}); call "
                                       "scan/cancel first")
    assert cell.seq.resume() == (False, "the scan is running")
    cell.seq.run()
    assert cell.seq.resume() == (False, f"all {len(VIEWS)} views are captured: nothing to "
                                        "resume")
    assert cell.seq.start() == (True, f"scan 2 started: {len(VIEWS)} views")
    assert cell.seq.status().values["captured"] == 0


def test_a_capture_without_a_receipt_is_sent_again_then_reported_lost():
    cell = FakeCell()
    cell.seq.tick({"reconstruction"})           # the receiver, there before the scan
    cell.run()
    missing = cell.sent[2]
    for _, stamp, _ in cell.sent:
        if stamp != missing[1]:
            assert cell.seq.receipt(stamp)
    assert not cell.seq.receipt((1, 2))        # not a capture of this scan
    cell.seq.tick({"reconstruction"})
    assert len(cell.sent) == len(VIEWS)         # not due yet
    for sends in range(2, SETTINGS.max_sends + 1):
        cell.advance(SETTINGS.receipt_timeout_s)
        cell.seq.tick({"reconstruction"})
        assert cell.sent[-1] is missing and len(cell.sent) == len(VIEWS) + sends - 1
        assert cell.lines("warning")[-1] == "sending 1 unreceipted capture(s) again: views [3]"
    cell.advance(SETTINGS.receipt_timeout_s)
    cell.seq.tick({"reconstruction"})
    status = cell.seq.status()
    assert len(cell.sent) == len(VIEWS) + SETTINGS.max_sends - 1
    assert status.values["lost_in_transport"] == 1
    assert status.values["resends"] == SETTINGS.max_sends - 1
    assert status.problem.startswith("view 3: capture at stamp ")
    assert status.problem.endswith(f"was never receipted after {SETTINGS.max_sends} sends "
                                   "(kept, not sent again)")
    assert cell.seq.receipt(missing[1])        # it made it after all
    assert cell.seq.status().values["lost_in_transport"] == 0
    assert cell.seq.status().values["receipted"] == len(VIEWS)


def test_every_capture_is_sent_again_when_a_new_receiver_appears():
    cell = FakeCell()
    cell.seq.tick({"reconstruction"})
    cell.run()
    cell.receipt_all()
    cell.seq.tick({"reconstruction"})
    assert len(cell.sent) == len(VIEWS)
    cell.seq.tick({"reconstruction (restarted)"})
    assert cell.sent[len(VIEWS):] == cell.sent[:len(VIEWS)]
    assert cell.lines("warning") == [f"a new receiver of captures (a restarted "
                                     f"reconstruction or recorder?): sending all "
                                     f"{len(VIEWS)} captures of the scan again"]
    status = cell.seq.status()
    assert status.values["receipted"] == 0 and status.values["resends"] == len(VIEWS)
    cell.seq.tick({"reconstruction (restarted)"})     # seen now: nothing more
    assert len(cell.sent) == 2 * len(VIEWS)


def test_a_receiver_seen_before_any_capture_triggers_no_resend():
    cell = FakeCell()
    cell.seq.tick({"reconstruction"})
    cell.seq.start()
    cell.seq.tick({"reconstruction", "recorder"})
    assert cell.sent == [] and cell.logs == []


def test_inputs_are_checked():
    cell = FakeCell()
    with pytest.raises(ValueError, match="must be finite"):
        cell.seq.encoder_reading((1, 0), math.nan, 0.0)
    cell.seq.count_malformed()
    assert cell.seq.status().values["malformed"] == 1
    with pytest.raises(ValueError, match=r"views_rad must be a non-empty \(n, 2\) array"):
        ScanSequence(np.zeros((0, 2)), cell, SETTINGS)
    with pytest.raises(ValueError, match="capture_retries must be an integer >= 0"):
        ScanSettings(**{**SETTINGS.__dict__, "capture_retries": -1})
    with pytest.raises(ValueError, match="samples must be an integer >= 1"):
        ScanSettings(**{**SETTINGS.__dict__, "settle_samples": 0})


STREAM = replace(SETTINGS, trigger="stream")


def _seconds(stamp) -> float:
    return stamp[0] + 1e-9 * stamp[1]


@pytest.mark.parametrize("delay_s", [0.0, 0.25])
def test_a_streaming_camera_gives_the_first_frame_stamped_after_settling_plus_the_delay(
        delay_s):
    cell = FakeCell(replace(STREAM, exposure_delay_s=delay_s))
    status = cell.run()
    assert status.values["state"] == "done" and status.problem == status.warning == ""
    assert cell.shutters == 0                              # no shutter to release
    assert cell.views_sent() == list(range(len(VIEWS)))
    assert len(cell.settled_at) == len(VIEWS)
    for (frame, stamp, reading), view, settled in zip(cell.sent, VIEWS, cell.settled_at):
        kind, seen = frame
        # Exposed at the viewpoint, not on the way: frames stamped before the settling were
        # still arriving then (LATENCY_S) and are passed over.
        assert kind == "streamed" and seen == tuple(view)
        # The first frame at or after settling + delay: within one frame period of it (the
        # stamps are whole nanoseconds, hence 1e-9).
        assert settled + delay_s - 1e-9 <= _seconds(stamp) < settled + delay_s + STREAM_S
        assert (reading.theta_rad, reading.phi_rad) == tuple(view)
        assert abs(_seconds(reading.stamp) - _seconds(stamp)) <= READ_S / 2 + 1e-9


def test_frames_that_never_come_on_the_stream_pause_the_scan_naming_the_topic():
    cell = FakeCell(STREAM)
    cell.streaming = False                                  # the driver publishes nothing
    status = cell.run()
    assert status.values["state"] == "paused" and status.values["captured"] == 0
    assert status.values["capture_retries"] == SETTINGS.capture_retries
    assert "no camera frame stamped at or after" in status.problem
    assert "is the camera streaming on image_raw?" in status.problem
    assert f"after {SETTINGS.capture_retries + 1} attempts" in status.problem
    cell.streaming = True                                   # mended: resume goes on
    assert cell.resume().values["state"] == "done"
    assert cell.views_sent() == list(range(len(VIEWS)))


def test_the_trigger_can_change_between_scans():
    cell = FakeCell(STREAM)
    assert cell.run().values["state"] == "done" and cell.shutters == 0
    status = cell.run(replace(STREAM, trigger="shutter"))
    assert status.values["state"] == "done" and cell.shutters == len(VIEWS)
    assert [frame for frame, _, _ in cell.sent[len(VIEWS):]] == \
        [f"frame {stamp}" for _, stamp, _ in cell.sent[len(VIEWS):]]


def test_stream_settings_are_checked():
    with pytest.raises(ValueError, match=r"trigger must be one of \['shutter', 'stream'\]"):
        replace(SETTINGS, trigger="video")
    with pytest.raises(ValueError, match="exposure_delay_s must be a finite number >= 0"):
        replace(STREAM, exposure_delay_s=-0.1)
