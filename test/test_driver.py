"""GrblClient through real pseudo-terminals: against the simulator and a scripted controller."""

import math
import os
import threading
import time
import tty

import pytest

from sfs_ros.hardware.driver import (
    CommandRejected,
    ConnectionLost,
    GrblClient,
    MotionCancelled,
    MotorAlarm,
    MotorError,
    MotorStalled,
    MotorTimeout,
    Status,
)
from sfs_ros.hardware.simulator import SimulatedGrbl, move_duration_s

from tolerances import (
    ENCODER_NOISE_DEG,
    ENCODER_OFFSET_DEG,
    HANG_S,
    PRINT_ROUNDING_DEG,
    READBACK_TOL_RAD,
    ROUND_OFF,
)
from waiting import wait

#: Fast axes so that tests run quickly: 900 deg/s, 18000 deg/s^2 (0.05 s to full speed).
FAST = dict(max_speed_deg_s=(900.0, 900.0), accel_deg_s2=(18000.0, 18000.0),
            homing_speed_deg_s=900.0)
#: Short timeout of the calls that are meant to time out.
TIMEOUT_S = 0.3
#: A turntable move that lasts 10 s at 900 deg/s: still under way whenever a test
#: stops it or looks at it, however late a loaded machine lets the test run.
LONG_MOVE_DEG = 9000.0


@pytest.fixture()
def sim():
    with SimulatedGrbl(encoder_offset_deg=ENCODER_OFFSET_DEG,
                       encoder_noise_deg=ENCODER_NOISE_DEG, seed=1,
                       **FAST) as s:
        yield s


@pytest.fixture()
def client(sim):
    with GrblClient(sim.port, timeout_s=HANG_S, poll_interval_s=0.01,
                    stall_timeout_s=0.3) as c:
        yield c


@pytest.fixture()
def homed(sim, client):
    client.home(timeout_s=HANG_S)
    sim.clear_received()
    return client


def test_move_bytes_and_arrival(sim, homed):
    status = homed.move_to(math.pi / 2, math.pi / 4, timeout_s=HANG_S)
    sent = sim.received()
    # Exactly one line command; everything else is single-byte status queries.
    assert sent.replace(b"?", b"") == b"G90 G0 X90.000 Y45.000\n"
    assert sent.startswith(b"G90 G0 X90.000 Y45.000\n")
    assert status.state == "Idle"
    assert status.theta_rad == pytest.approx(math.pi / 2, abs=READBACK_TOL_RAD[0])
    assert status.phi_rad == pytest.approx(math.pi / 4, abs=READBACK_TOL_RAD[1])
    # The truth is the target itself (float round-off only).
    assert sim.true_position_rad() == pytest.approx((math.pi / 2, math.pi / 4), abs=ROUND_OFF)


def test_status_sends_one_byte_and_parses_the_encoder(sim, homed):
    status = homed.status()
    assert sim.received() == b"?"
    assert isinstance(status, Status) and status.state == "Idle"


def test_encoder_offset_and_noise_visible_but_bounded(homed):
    readings = [homed.status() for _ in range(30)]
    theta, phi = [s.theta_rad for s in readings], [s.phi_rad for s in readings]
    # Homed at zero: read-back = offset + U(-noise, noise), printed with 3 decimals.
    for values, offset, noise in ((theta, ENCODER_OFFSET_DEG[0], ENCODER_NOISE_DEG[0]),
                                  (phi, ENCODER_OFFSET_DEG[1], ENCODER_NOISE_DEG[1])):
        assert max(abs(math.degrees(v) - offset) for v in values) <= \
            noise + PRINT_ROUNDING_DEG + 1e-9
        assert len(set(values)) > 1          # noise is there (30 equal draws: p ~ 1e-40)


def test_move_duration(homed):
    # 450 deg rest to rest at 900 deg/s, 18000 deg/s^2: 0.5 s cruise-dominated + 0.05 s.
    # Arrival cannot be seen early (one-sided, less one 4 ms simulator tick); how late it
    # is seen depends on the machine's load, so only a hang is bounded.
    expected = move_duration_s(450.0, 900.0, 18000.0)
    t0 = time.monotonic()
    homed.move_to(math.radians(450.0), 0.0, timeout_s=HANG_S)
    elapsed = time.monotonic() - t0
    assert expected - 0.004 <= elapsed <= expected + HANG_S


def test_power_up_lock_then_home(sim, client):
    with pytest.raises(MotorAlarm) as info:
        client.move_to(0.1, 0.1, timeout_s=HANG_S)
    assert info.value.code is None and "home()" in str(info.value)
    assert client.status().state == "Alarm"
    assert client.home(timeout_s=HANG_S).state == "Idle"
    assert client.move_to(0.1, 0.1, timeout_s=HANG_S).state == "Idle"


def test_status_during_homing_is_reported_as_home(sim, client):
    client.unlock()
    client.move_to(math.radians(170.0), math.radians(80.0), timeout_s=HANG_S)
    sim.faults.homing_hold = True                      # homing goes on until released
    seen = []
    worker = threading.Thread(target=lambda: seen.append(client.home(timeout_s=HANG_S)))
    worker.start()
    try:
        wait(lambda: sim.state == "Home", what="the simulator homing", timeout=HANG_S)
        # Each query must get the port from the thread that loops reading it for $H's answer.
        assert {client.status(timeout_s=HANG_S).state for _ in range(100)} == {"Home"}
    finally:
        sim.faults.homing_hold = False
        worker.join(HANG_S)
    assert seen and seen[0].state == "Idle"
    assert sim.true_position_deg() == pytest.approx((0.0, 0.0))


def test_soft_limit_alarm_and_recovery(sim, homed):
    with pytest.raises(MotorAlarm) as info:
        homed.move_to(0.0, math.radians(100.0), timeout_s=HANG_S)      # phi limit is 95 deg
    assert info.value.code == 2 and info.value.critical
    with pytest.raises(MotorAlarm):                      # locked until reset: no answers
        homed.status()
    assert homed.reset().state == "Alarm"
    assert homed.unlock().state == "Idle"
    assert homed.move_to(0.0, math.radians(90.0), timeout_s=HANG_S).state == "Idle"


def test_limit_switch_mid_move_then_reset_unlock_home(sim, homed):
    sim.faults.limit_at_fraction = 0.5
    with pytest.raises(MotorAlarm) as info:
        homed.move_to(math.radians(180.0), 0.0, timeout_s=HANG_S)
    assert info.value.code == 1 and "hard limit" in info.value.meaning
    assert sim.true_position_deg()[0] == pytest.approx(90.0)
    assert homed.reset().state == "Alarm"
    assert homed.unlock().state == "Idle"
    assert homed.home(timeout_s=HANG_S).state == "Idle"
    assert homed.alarm_code is None
    assert homed.move_to(math.radians(30.0), math.radians(10.0), timeout_s=HANG_S).state == "Idle"
    assert sim.true_position_deg() == pytest.approx((30.0, 10.0))


def test_stall_reported_idle_short_of_target(sim, homed):
    sim.faults.stall_axis, sim.faults.stall_fraction = "Y", 0.5
    with pytest.raises(MotorStalled, match="short of the target"):
        homed.move_to(0.0, math.radians(60.0), timeout_s=HANG_S)
    assert sim.true_position_deg()[1] == pytest.approx(30.0)


def test_stall_stuck_in_run(sim, homed):
    sim.faults.stall_axis, sim.faults.stall_mode = "X", "run"
    t0 = time.monotonic()
    with pytest.raises(MotorStalled, match="no progress"):
        homed.move_to(math.radians(90.0), 0.0, timeout_s=HANG_S)
    # Detected after stall_timeout_s (0.3 s) without progress (a MotorTimeout at the
    # move's own deadline would not match above); never sooner.
    assert time.monotonic() - t0 >= 0.3


def test_no_answer_times_out_in_time(sim, homed):
    sim.faults.no_answer = True
    t0 = time.monotonic()
    with pytest.raises(MotorTimeout, match="no status report"):
        homed.status(timeout_s=TIMEOUT_S)
    assert TIMEOUT_S <= time.monotonic() - t0 <= TIMEOUT_S + HANG_S
    t0 = time.monotonic()
    with pytest.raises(MotorTimeout, match="no answer"):
        homed.move_to(0.1, 0.1, timeout_s=0.3)
    assert 0.3 <= time.monotonic() - t0 <= 0.3 + HANG_S
    # The unanswered command blocks the next one (its late "ok" would be taken for the
    # next command's) until a reset resynchronises.
    sim.faults.no_answer = False
    with pytest.raises(MotorTimeout, match="reset"):
        homed.move_to(0.1, 0.1, timeout_s=0.3)
    homed.reset()
    assert homed.move_to(0.1, 0.1, timeout_s=HANG_S).state == "Idle"


def test_slow_move_times_out(homed):
    t0 = time.monotonic()
    with pytest.raises(MotorTimeout, match="not finished"):
        homed.move_to(math.radians(LONG_MOVE_DEG), 0.0, timeout_s=0.2)
    assert 0.2 <= time.monotonic() - t0 <= 0.2 + HANG_S
    homed.stop()


def _long_move_in_background(sim, client) -> tuple[threading.Thread, list]:
    """A long turntable move started in another thread, past 50 degrees; the thread and
    the list that receives the MotorError it ends with."""
    errors = []

    def move():
        try:
            client.move_to(math.radians(LONG_MOVE_DEG), 0.0, timeout_s=HANG_S)
        except MotorError as exc:
            errors.append(exc)

    worker = threading.Thread(target=move)
    worker.start()
    wait(lambda: sim.true_position_deg()[0] > 50.0, what="the move under way", timeout=HANG_S)
    return worker, errors


def test_disconnect_mid_move(sim, homed):
    worker, errors = _long_move_in_background(sim, homed)
    sim.disconnect()
    worker.join(HANG_S)
    assert len(errors) == 1 and isinstance(errors[0], ConnectionLost)
    with pytest.raises(ConnectionLost):
        homed.status()


def test_stop_interrupts_a_move_from_another_thread(sim, homed):
    worker, errors = _long_move_in_background(sim, homed)
    status = homed.stop()
    worker.join(HANG_S)
    assert len(errors) == 1 and isinstance(errors[0], MotionCancelled)
    assert status.state == "Idle"                      # hold, then reset: no alarm
    theta = sim.true_position_deg()[0]
    assert 50.0 < theta < LONG_MOVE_DEG - 50.0
    assert math.degrees(homed.status().theta_rad) == pytest.approx(theta, abs=0.05)
    assert homed.move_to(0.0, 0.0, timeout_s=HANG_S).state == "Idle"


def test_two_stops_at_once_both_succeed(sim, homed):
    # A stop service call and a preempting command can stop the same move together: the
    # first stop's soft reset clears the other's hold, which then finds the axes Idle.
    moving, errors = _long_move_in_background(sim, homed)
    results = []
    stops = [threading.Thread(target=lambda: results.append(homed.stop())) for _ in range(2)]
    for t in stops:
        t.start()
    for t in stops + [moving]:
        t.join(HANG_S)
    assert [r.state for r in results] == ["Idle", "Idle"]
    assert len(errors) == 1 and isinstance(errors[0], MotionCancelled)
    assert sim.state == "Idle"


def test_status_polling_from_another_thread_during_a_move(homed):
    seen, errors = [], []
    done = threading.Event()

    def poll():
        while True:
            last = done.is_set()             # the last poll comes after the move: Idle
            try:
                seen.append(homed.status())
            except MotorError as exc:
                errors.append(exc)
            if last:
                return
            time.sleep(0.005)

    poller = threading.Thread(target=poll)
    poller.start()
    try:
        # 2 s under way: the poller gets a turn during it however loaded the machine.
        homed.move_to(math.radians(1800.0), math.radians(45.0), timeout_s=HANG_S)
    finally:
        done.set()
        poller.join(HANG_S)
    assert not errors
    assert {s.state for s in seen} >= {"Run", "Idle"}


def test_garbage_and_split_lines_from_the_controller(sim, homed):
    sim.faults.garbage = b"\xfe\x01@#\r\n"              # a noise line before every message
    sim.faults.fragment_output = True                   # lines arrive a few bytes at a time
    sim.inject_output(b"[MSG:hello]\r\n\x00\x01")
    assert homed.move_to(math.radians(20.0), math.radians(10.0), timeout_s=HANG_S).state == "Idle"
    assert homed.noise_lines >= 3                        # at least: ok, one report, the final one
    assert "hello" in homed.messages
    sim.faults.garbage = b"\xff\x13"                    # noise glued to the start of each line
    assert homed.status().state == "Idle"
    assert homed.salvaged_lines >= 1


def test_unsolicited_alarm_while_idle(sim, homed):
    sim.trigger_limit()
    with pytest.raises(MotorAlarm) as info:
        homed.status()
    assert info.value.code == 1 and info.value.critical
    homed.reset()
    homed.home(timeout_s=HANG_S)
    assert homed.status().state == "Idle"


def test_closed_client_refuses_to_work(homed):
    homed.close()
    homed.close()
    with pytest.raises(ConnectionLost):
        homed.status()


def test_unopenable_port():
    with pytest.raises(ConnectionLost, match="cannot open"):
        GrblClient("/nonexistent/tty")


@pytest.mark.parametrize("theta", [math.nan, math.inf, "1"])
def test_bad_targets_are_rejected(homed, theta):
    with pytest.raises(ValueError, match="theta_rad"):
        homed.move_to(theta, 0.0, timeout_s=HANG_S)


def test_bad_options_are_rejected(sim):
    with pytest.raises(ValueError, match="timeout_s"):
        GrblClient(sim.port, timeout_s=0)


class ScriptedController:
    """A bare pseudo-terminal whose answers to ``?`` a test writes byte by byte."""

    def __init__(self, chunks):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.chunks = chunks
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        os.read(self.master, 1)              # the client's "?"
        for chunk in self.chunks:
            os.write(self.master, chunk)
            time.sleep(0.02)                 # the client sees each piece in a separate read

    def close(self):
        self.thread.join(1.0)
        os.close(self.master)
        os.close(self.slave)


def test_status_report_split_across_writes_with_interleaved_noise():
    controller = ScriptedController([b"\x00\xff garbage\r\nok\r\n<Idle|MPo", b"s:90.000,45",
                                     b".000,0.000|F", b"S:0,0>\r", b"\n"])
    try:
        with GrblClient(controller.port, timeout_s=HANG_S) as client:
            status = client.status()
            assert status == Status("Idle", math.pi / 2, math.pi / 4)
            # The garbage line and the "ok" that answers no command are counted as noise.
            assert client.noise_lines == 2
    finally:
        controller.close()


def test_error_answer_is_command_rejected(homed):
    with pytest.raises(MotorTimeout):
        homed.move_to(math.radians(LONG_MOVE_DEG), 0.0, timeout_s=0.1)   # still running after
    with pytest.raises(CommandRejected) as info:
        homed.home(timeout_s=HANG_S)                                    # "$H" while running
    assert info.value.code == 8 and "Idle" in info.value.meaning
    homed.stop()


def test_build_info(homed):
    assert homed.build_info().startswith("1.1h.")
