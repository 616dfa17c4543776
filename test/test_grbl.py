"""GRBL 1.1 wire format: formatting and parsing, byte for byte (no I/O)."""

import math

import pytest

from sfs_ros.hardware import grbl


def test_move_bytes_are_absolute_rapid_with_three_decimals():
    assert grbl.format_move(90, 45) == b"G90 G0 X90.000 Y45.000\n"
    assert grbl.format_move(math.degrees(math.pi / 2), math.degrees(math.pi / 4)) == \
        b"G90 G0 X90.000 Y45.000\n"
    assert grbl.format_move(-0.0001, 359.99951) == b"G90 G0 X0.000 Y360.000\n"  # no "-0.000"
    assert grbl.format_move(-12.3456, 0) == b"G90 G0 X-12.346 Y0.000\n"


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e7])
def test_move_rejects_non_finite_or_huge(bad):
    with pytest.raises(ValueError, match="x_deg"):
        grbl.format_move(bad, 0)


@pytest.mark.parametrize("bad", ["G0\nX1", "G0 X1?", "$H!", "~", "G0\x18", "é", "G0 X" + "1" * 80])
def test_format_line_rejects_newlines_realtime_bytes_non_ascii_and_overflow(bad):
    with pytest.raises(ValueError):
        grbl.format_line(bad)


def test_status_report_format_is_grbl_1_1():
    assert grbl.format_status_report("Idle", (12, 45, 0)) == \
        b"<Idle|MPos:12.000,45.000,0.000|FS:0,0>\r\n"
    assert grbl.format_status_report("Hold", (1, -2.5, 0), substate=1, feed=1234.4,
                                     extra={"Ov": "100,100,100"}) == \
        b"<Hold:1|MPos:1.000,-2.500,0.000|FS:1234,0|Ov:100,100,100>\r\n"


def test_status_report_round_trip_and_optional_fields():
    report = grbl.parse_status_report(
        "<Run|MPos:12.000,-45.500,0.000|Bf:15,128|FS:500,0|WCO:0.000,1.551,5.664>\r\n")
    assert report.state == "Run" and report.substate is None
    assert report.mpos == (12.0, -45.5, 0.0) and report.wpos is None
    assert report.feed == 500.0
    assert report.fields == {"Bf": "15,128", "WCO": "0.000,1.551,5.664"}
    hold = grbl.parse_status_report("<Hold:0|WPos:-2.500,0.000,11.000|F:0>")
    assert (hold.state, hold.substate, hold.mpos, hold.wpos) == ("Hold", 0, None,
                                                                 (-2.5, 0.0, 11.0))


@pytest.mark.parametrize("bad", [
    "Idle|MPos:0,0,0|FS:0,0",            # no chevrons
    "<Moving|MPos:0,0,0>",               # unknown state
    "<Idle>",                            # no position
    "<Idle|FS:0,0|MPos:0,0,0>",          # position must come second
    "<Idle|MPos:1.0,abc,0>",             # not numbers
    "<Idle|MPos:1.0,2.0>",               # two values
    "<Idle|MPos:nan,0,0>",               # not finite
    "<Hold:x|MPos:0,0,0>",               # substate not an integer
])
def test_malformed_status_reports_raise_value_error(bad):
    with pytest.raises(ValueError):
        grbl.parse_status_report(bad)


@pytest.mark.parametrize("line, expected", [
    (b"ok\r\n", grbl.Ok()),
    (b"error:9\r\n", grbl.Error(9)),
    (b"ALARM:1\r\n", grbl.Alarm(1)),
    (b"Grbl 1.1h ['$' for help]\r\n", grbl.Welcome("1.1h")),
    (b"[MSG:Reset to continue]\r\n", grbl.Feedback("MSG", "Reset to continue")),
    (b"[MSG:'$H'|'$X' to unlock]", grbl.Feedback("MSG", "'$H'|'$X' to unlock")),
    (b"[VER:1.1h.20190830:]", grbl.Feedback("VER", "1.1h.20190830:")),
])
def test_parse_line_classifies_every_message_type(line, expected):
    assert grbl.parse_line(line) == (expected, False)


def test_parse_line_status_report():
    message, salvaged = grbl.parse_line(b"<Idle|MPos:12.000,45.000,0.000|FS:0,0>\r\n")
    assert not salvaged and message.mpos == (12.0, 45.0, 0.0)


@pytest.mark.parametrize("line", [b"\xff\xfe\x00", b"hello", b"okay", b"<Idle|MPos:1,2", b"",
                                  b"error:", b"ALARM:x", b"[MSG:unterminated"])
def test_noise_is_not_a_message(line):
    assert grbl.parse_line(line) == (None, False)


@pytest.mark.parametrize("line, expected", [
    (b"\xff\x13#ok\r\n", grbl.Ok()),
    (b"\x00\x00error:22", grbl.Error(22)),
    (b"junkALARM:2", grbl.Alarm(2)),
])
def test_known_message_at_the_end_of_a_corrupted_line_is_recovered(line, expected):
    assert grbl.parse_line(line) == (expected, True)


def test_corrupted_status_report_is_recovered_from_its_tail():
    message, salvaged = grbl.parse_line(b"\xfe<<Idle|MPos:1.000,2.000,0.000|FS:0,0>")
    assert salvaged and message.mpos == (1.0, 2.0, 0.0)


def test_code_tables_match_grbl_documentation():
    # GRBL 1.1 doc/csv/error_codes_en_US.csv and alarm_codes_en_US.csv.
    assert set(grbl.ERROR_CODES) == set(range(1, 18)) | set(range(20, 39))
    assert set(grbl.ALARM_CODES) == set(range(1, 10))
    assert grbl.CRITICAL_ALARMS == {1, 2}
    assert "hard limit" in grbl.alarm_meaning(1)
    assert "unknown" in grbl.error_meaning(99)


def test_welcome_banner_bytes():
    assert grbl.welcome_line() == b"\r\nGrbl 1.1h ['$' for help]\r\n"
