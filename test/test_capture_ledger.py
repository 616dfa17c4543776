"""The scan node's bookkeeping without ROS: encoder readings by stamp, captures and resends.

Stamps are whole seconds or round fractions whose differences are exact in
floating point where a test depends on equality (ties); times are passed in.
"""

import math

import pytest

from sfs_ros.cell_logic.capture_ledger import CaptureLedger, EncoderHistory, EncoderReading

TIMEOUT_S = 2.0     # receipt timeout of the ledgers below
MAX_SENDS = 3


def history(*stamps, capacity=200) -> EncoderHistory:
    """Readings at ``stamps`` in that order, theta = the stamp's seconds, phi = 0.5."""
    h = EncoderHistory(capacity)
    for stamp in stamps:
        h.add(stamp, float(stamp[0]), 0.5)
    return h


# -- EncoderHistory --------------------------------------------------------------------------

def test_nearest_reading_before_or_after_the_shutter():
    h = history((10, 0), (11, 0))
    # A shutter 0.3 s after the first reading: that one, 0.7 s before the second.
    assert h.nearest((10, 300_000_000), max_gap_s=0.5) == EncoderReading((10, 0), 10.0, 0.5)
    # 0.2 s before the second: the reading after the shutter, not the latest before it.
    assert h.nearest((10, 800_000_000), max_gap_s=0.5).stamp == (11, 0)
    # By stamp, not by arrival: a reading that arrives late still counts.
    h.add((10, 900_000_000), 10.9, 0.5)
    assert h.nearest((10, 800_000_000), max_gap_s=0.5).stamp == (10, 900_000_000)


def test_a_tie_keeps_the_reading_received_first():
    # 1 s either side, exactly: the first received of the two, whichever is older.
    assert history((10, 0), (12, 0)).nearest((11, 0), max_gap_s=1.0).stamp == (10, 0)
    assert history((12, 0), (10, 0)).nearest((11, 0), max_gap_s=1.0).stamp == (12, 0)


def test_a_reading_too_far_from_the_shutter_is_refused():
    h = history((10, 0))
    assert h.nearest((10, 250_000_000), max_gap_s=0.3).stamp == (10, 0)
    with pytest.raises(ValueError, match=r"the nearest encoder reading is 0\.250 s from the "
                                         r"shutter \(at most 0\.1 s expected\): encoders not "
                                         r"being read"):
        h.nearest((10, 250_000_000), max_gap_s=0.1)
    with pytest.raises(ValueError, match=r"is 2\.000 s from the shutter"):
        h.nearest((8, 0), max_gap_s=0.1)                           # before it, too


def test_empty_history_says_no_reading_was_received():
    h = EncoderHistory()
    assert len(h) == 0 and not h.has_after((0, 0))
    with pytest.raises(ValueError, match=r"no encoder reading received: is the motor node "
                                         r"running\?"):
        h.nearest((10, 0), max_gap_s=60.0)


@pytest.mark.parametrize("theta, phi", [(math.nan, 0.0), (0.0, math.inf), (-math.inf, 0.0)])
def test_non_finite_readings_are_refused_and_not_kept(theta, phi):
    h = history((10, 0))
    with pytest.raises(ValueError, match="encoder angles must be finite"):
        h.add((11, 0), theta, phi)
    assert len(h) == 1 and not h.has_after((11, 0))


def test_capacity_drops_the_oldest():
    h = history((10, 0), (11, 0), (12, 0), (13, 0), capacity=3)
    assert len(h) == 3
    # (10, 0) is gone: the nearest to its stamp is now (11, 0), 1 s away.
    assert h.nearest((10, 0), max_gap_s=5.0).stamp == (11, 0)
    with pytest.raises(ValueError, match=r"is 1\.000 s from the shutter"):
        h.nearest((10, 0), max_gap_s=0.5)


def test_has_after_counts_a_reading_at_the_stamp():
    h = history((10, 0), (11, 500))
    assert h.has_after((9, 999_999_999))
    assert h.has_after((11, 500)) and h.has_after([11, 500])     # at the stamp; any sequence
    assert not h.has_after((11, 501))
    assert not h.has_after((12, 0))


@pytest.mark.parametrize("capacity", [0, -1, 2.0, True])
def test_history_capacity_must_be_a_positive_integer(capacity):
    with pytest.raises(ValueError, match="capacity must be an integer >= 1"):
        EncoderHistory(capacity)


# -- CaptureLedger ---------------------------------------------------------------------------

def ledger(n: int = 0, *, now_s: float = 0.0) -> CaptureLedger:
    """A ledger with views 0..n-1 sent at ``now_s``, stamps (100 + view, 0), payload "p<view>"."""
    book = CaptureLedger(TIMEOUT_S, MAX_SENDS)
    for view in range(n):
        book.add(view, (100 + view, 0), f"p{view}", now_s)
    return book


def test_add_and_receipt_counts():
    book = ledger()
    entry = book.add(4, [104, 0], "payload", 1.5)
    assert (entry.view, entry.stamp, entry.payload, entry.sent_s, entry.sends) == \
        (4, (104, 0), "payload", 1.5, 1)
    assert not entry.receipted and not entry.given_up
    book.add(7, (107, 0), "other", 2.0)
    assert (book.captured, book.receipted, book.given_up) == (2, 0, 0)
    assert book.views() == {4, 7}
    assert book.receipt((104, 0)) and entry.receipted
    assert book.receipt((104, 0))                         # a repeated receipt is harmless
    assert not book.receipt((999, 0))                     # not ours
    assert (book.captured, book.receipted, book.given_up) == (2, 1, 0)


def test_a_view_or_a_stamp_is_captured_once():
    book = ledger(2)
    with pytest.raises(ValueError, match=r"view 1 was already captured in this scan"):
        book.add(1, (200, 0), "again", 1.0)
    with pytest.raises(ValueError, match=r"a capture with stamp \(100, 0\) is already in the "
                                         r"ledger"):
        book.add(5, [100, 0], "same stamp", 1.0)
    assert book.captured == 2 and book.views() == {0, 1}


def test_resent_after_the_receipt_timeout_and_not_before():
    book = ledger(1, now_s=10.0)
    assert book.due(10.0 + TIMEOUT_S - 0.001) == ([], [])
    resend, give_up = book.due(10.0 + TIMEOUT_S)               # exactly the timeout: due
    assert [e.view for e in resend] == [0] and give_up == []
    assert (resend[0].sends, resend[0].sent_s) == (2, 10.0 + TIMEOUT_S)
    # The timeout runs again from the resend.
    assert book.due(10.0 + 2 * TIMEOUT_S - 0.001) == ([], [])


def test_given_up_after_max_sends_and_never_sent_again():
    book = ledger(1, now_s=0.0)
    sends = []
    for k in range(1, 10):
        resend, give_up = book.due(k * TIMEOUT_S)
        sends.append((len(resend), len(give_up)))
    # Sent at 0 (1st), resent at T (2nd) and 2T (3rd = MAX_SENDS); given up at 3T; then nothing.
    assert sends == [(1, 0), (1, 0), (0, 1)] + [(0, 0)] * 6
    entry = book.entries[(100, 0)]
    assert entry.sends == MAX_SENDS and entry.given_up and not entry.receipted
    assert (book.captured, book.given_up) == (1, 1)            # kept, reported
    # A receipt that comes after all: stored, no longer counted as lost.
    book.receipt((100, 0))
    assert (book.receipted, book.given_up) == (1, 0)


def test_receipted_captures_are_never_resent():
    book = ledger(3, now_s=0.0)
    book.receipt((101, 0))
    resend, _ = book.due(TIMEOUT_S)
    assert [e.view for e in resend] == [0, 2]
    book.receipt((100, 0))
    resend, give_up = book.due(2 * TIMEOUT_S)
    assert [e.view for e in resend] == [2] and give_up == []
    assert book.entries[(101, 0)].sends == 1


def test_restart_downstream_sends_everything_again_in_view_order():
    book = CaptureLedger(TIMEOUT_S, MAX_SENDS)
    for view in (2, 0, 1):                                     # captured out of view order
        book.add(view, (100 + view, 0), f"p{view}", 0.0)
    book.receipt((100, 0))                                     # receipted
    for k in (1, 2, 3):
        book.due(k * TIMEOUT_S)                                # view 1 and 2: given up at 3T
    book.receipt((101, 0))                                     # late receipt for view 1
    assert book.entries[(102, 0)].given_up

    again = book.restart_downstream(50.0)
    assert [e.view for e in again] == [0, 1, 2]
    assert [e.payload for e in again] == ["p0", "p1", "p2"]
    assert all(e.sends == 1 and e.sent_s == 50.0 and not e.receipted and not e.given_up
               for e in again)
    assert (book.receipted, book.given_up) == (0, 0)
    # A fresh allowance: resent twice more, given up after MAX_SENDS sends from the restart.
    for k in (1, 2):
        resend, give_up = book.due(50.0 + k * TIMEOUT_S)
        assert [e.view for e in resend] == [2, 0, 1] and give_up == []   # ledger order
    resend, give_up = book.due(50.0 + 3 * TIMEOUT_S)
    assert resend == [] and len(give_up) == 3


@pytest.mark.parametrize("timeout_s, max_sends, words", [
    (0.0, 3, "receipt_timeout_s must be > 0"),
    (-1.0, 3, "receipt_timeout_s must be > 0"),
    (math.nan, 3, "receipt_timeout_s must be > 0"),
    (math.inf, 3, "receipt_timeout_s must be > 0"),
    (1.0, 0, "max_sends must be an integer >= 1"),
    (1.0, 2.0, "max_sends must be an integer >= 1"),
    (1.0, True, "max_sends must be an integer >= 1"),
])
def test_ledger_parameters_are_validated(timeout_s, max_sends, words):
    with pytest.raises(ValueError, match=words):
        CaptureLedger(timeout_s, max_sends)
