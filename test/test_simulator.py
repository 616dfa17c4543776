"""The simulated GRBL 1.1 controller, byte for byte through a real pseudo-terminal."""

import math
import time

import pytest
import serial

from sfs_ros.hardware import grbl
from sfs_ros.hardware.simulator import SimulatedGrbl, move_duration_s

from tolerances import HANG_S, ROUND_OFF
from waiting import wait

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
UNLOCK = b"[MSG:'$H'|'$X' to unlock]\r\n"
#: Fast axes so that tests run quickly: 900 deg/s, 18000 deg/s^2 (0.05 s to full speed).
FAST = dict(max_speed_deg_s=(900.0, 900.0), accel_deg_s2=(18000.0, 18000.0),
            homing_speed_deg_s=900.0)


def read_until(port, terminator: bytes, timeout_s: float = HANG_S) -> bytes:
    """Bytes up to and including ``terminator`` (all that came, if it never came within
    ``timeout_s``: a wait for silence passes a short one, any other only bounds a hang)."""
    deadline = time.monotonic() + timeout_s
    data = b""
    while not data.endswith(terminator) and time.monotonic() < deadline:
        data += port.read(1)
    return data


def exchange(port, data: bytes, terminator: bytes = b"\r\n",
             timeout_s: float = HANG_S) -> bytes:
    port.write(data)
    return read_until(port, terminator, timeout_s)


def report(port) -> grbl.StatusReport:
    return grbl.parse_status_report(exchange(port, b"?").decode())


def wait_state(port, state: str, timeout_s: float = HANG_S) -> grbl.StatusReport:
    """Query until the controller reports ``state``; the deadline only bounds a hang."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        r = report(port)
        if (r.state if r.substate is None else f"{r.state}:{r.substate}") == state:
            return r
        time.sleep(0.005)
    raise AssertionError(f"state {state} not reached within {timeout_s} s (last {r})")


@pytest.fixture()
def sim():
    with SimulatedGrbl(encoder_noise_deg=(0.0, 0.0), seed=0, **FAST) as s:
        yield s


@pytest.fixture()
def port(sim):
    with serial.Serial(sim.port, 115200, timeout=0.05) as p:
        yield p


@pytest.fixture()
def idle_port(port):
    """Connected and unlocked (no homing: machine zero where the axes were at power-up)."""
    assert exchange(port, b"$X\n", b"ok\r\n") == b"[MSG:Caution: Unlocked]\r\nok\r\n"
    return port


def test_reset_banner_and_power_up_alarm_lock(port):
    # GRBL with homing enabled starts locked; a soft reset keeps the lock and says so.
    assert exchange(port, b"\x18", UNLOCK) == BANNER + UNLOCK
    assert exchange(port, b"G0 X1\n") == b"error:9\r\n"


def test_status_report_bytes_report_the_encoder(port):
    # Noise off: MPos is exactly machine position + encoder offset (0.03, -0.02) degrees.
    # GRBL sends WCO in the first report after a reset, the overrides in the next.
    assert exchange(port, b"?") == \
        b"<Alarm|MPos:0.030,-0.020,0.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n"
    assert exchange(port, b"?") == b"<Alarm|MPos:0.030,-0.020,0.000|FS:0,0|Ov:100,100,100>\r\n"
    assert exchange(port, b"?") == b"<Alarm|MPos:0.030,-0.020,0.000|FS:0,0>\r\n"


def test_unlock_then_move_and_true_position(sim, idle_port):
    assert exchange(idle_port, b"G90 G0 X90.000 Y45.000\n") == b"ok\r\n"   # queued, not arrived
    r = wait_state(idle_port, "Idle")
    assert r.mpos == pytest.approx((90.03, 44.98, 0.0), abs=1e-9)
    # The true angles are the target: no offset, no noise (only float round-off).
    assert sim.true_position_deg() == pytest.approx((90.0, 45.0), abs=1e-9)
    assert sim.true_position_rad() == pytest.approx((math.pi / 2, math.pi / 4), abs=ROUND_OFF)


@pytest.mark.parametrize("line, answer", [
    (b"hello\n", b"error:2\r\n"),             # H needs a number
    (b"#\n", b"error:1\r\n"),                 # not a letter
    (b"G7\n", b"error:20\r\n"),               # unsupported G code
    (b"M3 S1000\n", b"error:20\r\n"),         # no spindle here
    (b"G0 X1 X2\n", b"error:25\r\n"),         # repeated word
    (b"G0 G1 X1\n", b"error:21\r\n"),         # two motion modes
    (b"G1 X1\n", b"error:22\r\n"),            # no feed rate yet
    (b"G4\n", b"error:28\r\n"),               # dwell without P
    (b"$Q\n", b"error:3\r\n"),                # unknown $ command
    (b"G0 X" + b"1" * 90 + b"\n", b"error:11\r\n"),   # line overflow
    (b"\xff\xfe\x80\n", b"ok\r\n"),           # extended ASCII dropped: empty line
    (b"g0 (comment) x0 ; tail\n", b"ok\r\n"),  # lower case and comments
])
def test_client_garbage_gets_grbl_error_codes(idle_port, line, answer):
    assert exchange(idle_port, line) == answer
    assert report(idle_port).state == "Idle"      # still alive and well


def test_carriage_return_line_feed_is_two_lines(idle_port):
    # GRBL ends a line at '\r' or '\n': "\r\n" is a command plus an empty line, two "ok".
    assert exchange(idle_port, b"G0 X0\r\n", b"ok\r\nok\r\n") == b"ok\r\nok\r\n"


def test_realtime_bytes_are_picked_out_of_a_line(idle_port):
    idle_port.write(b"G0 X")
    assert exchange(idle_port, b"?").startswith(b"<Idle|")
    assert exchange(idle_port, b"10\n") == b"ok\r\n"       # the line was "G0 X10"
    assert wait_state(idle_port, "Idle").mpos[0] == pytest.approx(10.03)


def test_soft_limit_is_a_critical_alarm(sim, idle_port):
    assert exchange(idle_port, b"G0 Y100\n", b"continue]\r\n") == \
        b"ALARM:2\r\n[MSG:Reset to continue]\r\n"
    idle_port.write(b"?G0 Y10\n$X\n")                       # all ignored until a reset
    assert read_until(idle_port, b"\n", timeout_s=0.2) == b""
    assert exchange(idle_port, b"\x18", UNLOCK) == BANNER + UNLOCK
    assert report(idle_port).state == "Alarm"
    assert sim.true_position_deg() == pytest.approx((0.0, 0.0))   # never moved


def test_hard_limit_mid_move(sim, idle_port):
    sim.faults.limit_at_fraction = 0.5
    idle_port.write(b"G0 X90\n")
    assert read_until(idle_port, b"continue]\r\n") == \
        b"ok\r\nALARM:1\r\n[MSG:Reset to continue]\r\n"
    assert sim.true_position_deg()[0] == pytest.approx(45.0)
    assert exchange(idle_port, b"\x18", UNLOCK) == BANNER + UNLOCK


def test_feed_hold_resume_and_reset_in_motion(sim, idle_port):
    assert exchange(idle_port, b"G0 X9000\n") == b"ok\r\n"         # 10 s at 900 deg/s
    wait(lambda: sim.true_position_deg()[0] > 100.0, what="the move past 100 deg")
    idle_port.write(b"!")
    held = wait_state(idle_port, "Hold:0")                         # decelerated (Hold:1) ...
    assert 100.0 < held.mpos[0] < 8900.0
    time.sleep(0.1)                      # (a longer pause on a loaded machine: a stricter test)
    assert report(idle_port).mpos == held.mpos                     # ... and stays put
    idle_port.write(b"~")
    assert report(idle_port).state == "Run"
    # A reset while running loses the position: ALARM:3, then locked.
    assert exchange(idle_port, b"\x18", UNLOCK) == b"ALARM:3\r\n" + BANNER + UNLOCK
    assert report(idle_port).state == "Alarm"


def test_reset_after_completed_hold_keeps_position_without_alarm(idle_port):
    exchange(idle_port, b"G0 X9000\n")                               # 10 s at 900 deg/s
    wait_state(idle_port, "Run")                                   # a hold of a move, not of Idle
    idle_port.write(b"!")
    held = wait_state(idle_port, "Hold:0")
    assert exchange(idle_port, b"\x18", BANNER) == BANNER
    after = report(idle_port)
    assert (after.state, after.mpos) == ("Idle", held.mpos)


def test_move_duration_follows_the_trapezoid(sim, idle_port):
    # Rest to rest over 450 deg at 900 deg/s and 18000 deg/s^2: 0.5 s + 0.05 s. The
    # simulator cannot arrive early (one-sided bound, less one 4 ms simulator tick); how
    # late it is seen depends on the machine's load, so only a hang is bounded.
    expected = move_duration_s(450.0, 900.0, 18000.0)
    assert expected == pytest.approx(0.55)
    t0 = time.monotonic()
    exchange(idle_port, b"G0 X450\n")
    wait(lambda: sim.true_position_deg()[0] >= 450.0, what="arrival at 450 deg",
         timeout=expected + HANG_S, interval_s=0.002)
    assert time.monotonic() - t0 >= expected - 0.004


def test_homing_zeroes_machine_position_and_defers_status():
    with SimulatedGrbl(power_up_true_deg=(200.0, 30.0), encoder_noise_deg=(0.0, 0.0),
                       encoder_offset_deg=(0.0, 0.0), **FAST) as sim, \
            serial.Serial(sim.port, 115200, timeout=0.05) as port:
        assert report(port).mpos == (0.0, 0.0, 0.0)          # machine zero at power-up
        assert sim.true_position_deg() == (200.0, 30.0)
        # Status queries during homing are answered after it, before its "ok".
        sim.faults.homing_hold = True                        # homing goes on until released
        port.write(b"$H\n")
        wait(lambda: sim.state == "Home", what="homing under way")
        port.write(b"?")
        wait(lambda: sim.received().endswith(b"?"), what="the query received while homing")
        sim.faults.homing_hold = False
        answer = read_until(port, b"ok\r\n")
        assert answer == b"<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>\r\nok\r\n"
        # The turntable's index mark is seen once per turn: 200 deg -> nearest 360 deg.
        assert sim.true_position_deg() == pytest.approx((360.0, 0.0))


def test_homing_failure_is_alarm_9(sim, port):
    sim.faults.homing_fails = True   # searches 150 deg at 900 deg/s, finds no switch
    assert exchange(port, b"$H\n", UNLOCK) == b"ALARM:9\r\n" + BANNER + UNLOCK


def test_stall_idle_mode_encoder_shows_the_truth(sim, idle_port):
    sim.faults.stall_axis, sim.faults.stall_fraction = "Y", 0.25
    exchange(idle_port, b"G0 X40 Y80\n")
    r = wait_state(idle_port, "Idle")
    assert sim.machine_position_deg() == (40.0, 80.0)         # GRBL believes it arrived
    assert sim.true_position_deg() == pytest.approx((40.0, 20.0))
    assert r.mpos[:2] == pytest.approx((40.03, 19.98))


def test_stall_run_mode_never_finishes(sim, idle_port):
    sim.faults.stall_axis, sim.faults.stall_mode = "X", "run"
    exchange(idle_port, b"G0 X100\n")
    time.sleep(0.4)               # at least the 0.16 s of a free move (longer: a stricter test)
    r = report(idle_port)
    assert r.state == "Run" and r.mpos[0] == pytest.approx(50.03)


def test_no_answer(sim, idle_port):
    sim.faults.no_answer = True
    idle_port.write(b"?G0 X1\n\x18")
    assert read_until(idle_port, b"\n", timeout_s=0.2) == b""
    sim.faults.no_answer = False
    assert report(idle_port).state == "Idle"


def test_disconnect_makes_the_port_fail(sim, idle_port):
    sim.disconnect()
    with pytest.raises(serial.SerialException):
        idle_port.write(b"?")
        idle_port.read(1)


def test_replug_gives_a_new_port_and_keeps_the_position(sim, idle_port):
    assert exchange(idle_port, b"G0 X12 Y3\n", b"ok\r\n") == b"ok\r\n"
    wait_state(idle_port, "Idle")
    old = sim.port
    sim.disconnect()
    with pytest.raises(RuntimeError, match="disconnect"):
        SimulatedGrbl().replug()                 # never unplugged
    new = sim.replug()
    assert new == sim.port and new != old
    with serial.Serial(new, 115200, timeout=0.05) as port:
        # Noise off: MPos is the kept machine position plus the encoder offset.
        r = report(port)
        assert r.state == "Idle"
        assert r.mpos[:2] == pytest.approx((12.03, 2.98), abs=1e-9)
        assert exchange(port, b"G0 X0\n", b"ok\r\n") == b"ok\r\n"


def test_garbage_and_fragmented_output(sim, idle_port):
    sim.faults.garbage = b"\xff\x00#\r\n"
    sim.faults.fragment_output = True
    assert exchange(idle_port, b"?", b">\r\n") == \
        b"\xff\x00#\r\n<Idle|MPos:0.030,-0.020,0.000|FS:0,0|WCO:0.000,0.000,0.000>\r\n"
    sim.inject_output(b"[MSG:hello]\r\n")
    assert read_until(idle_port, b"]\r\n") == b"[MSG:hello]\r\n"


def test_noise_is_uniform_within_its_bound():
    # Uniform noise of half-width 0.2 deg; 3-decimal printing adds at most 0.0005 deg.
    with SimulatedGrbl(encoder_noise_deg=(0.2, 0.2), encoder_offset_deg=(1.0, -1.0), seed=3,
                       start_locked=False) as sim, \
            serial.Serial(sim.port, 115200, timeout=0.05) as port:
        reports = [report(port).mpos for _ in range(40)]
    xs, ys = [m[0] for m in reports], [m[1] for m in reports]
    assert max(abs(x - 1.0) for x in xs) <= 0.2005
    assert max(abs(y + 1.0) for y in ys) <= 0.2005
    # 40 draws from U(-0.2, 0.2): the spread is wider than 0.1 deg unless p < 1e-10.
    assert max(xs) - min(xs) > 0.1 and max(ys) - min(ys) > 0.1


@pytest.mark.parametrize("kwargs", [dict(max_speed_deg_s=(0, 1)), dict(accel_deg_s2=(1,)),
                                    dict(encoder_noise_deg=(-1, 0)),
                                    dict(soft_limits_deg=(None, (5, -5))),
                                    dict(homing_speed_deg_s=math.nan)])
def test_bad_configuration_is_rejected(kwargs):
    with pytest.raises(ValueError):
        SimulatedGrbl(**kwargs)


@pytest.mark.parametrize("name, value", [("stall_axis", "Z"), ("stall_mode", "sometimes"),
                                         ("stall_fraction", 1.5), ("limit_at_fraction", -0.1)])
def test_bad_fault_settings_are_rejected(sim, name, value):
    with pytest.raises(ValueError, match=name):
        setattr(sim.faults, name, value)
