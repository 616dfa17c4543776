"""Exact stamp pairing: every capture paired exactly once, whatever the arrival order."""

import numpy as np
import pytest

from sfs_ros.ros.pairing import StampPairer, stamp_key


class FakeTime:
    def __init__(self, sec, nanosec):
        self.sec, self.nanosec = sec, nanosec


def test_stamp_key_accepts_messages_and_pairs():
    assert stamp_key(FakeTime(12, 345)) == (12, 345)
    assert stamp_key((12, 345)) == (12, 345)
    for bad in (12.5, (1, 2, 3), (1, 1_000_000_000), (1.5, 0), "1.2"):
        with pytest.raises(ValueError):
            stamp_key(bad)


def test_shuffled_streams_pair_exactly_once():
    rng = np.random.default_rng(3)
    n = 200
    stamps = [(1000 + i // 3, (i % 3) * 1000) for i in range(n)]  # several per second
    events = [("a", s) for s in stamps] + [("b", s) for s in stamps]
    order = rng.permutation(len(events))
    pairer = StampPairer(n)
    pairs = []
    for k in order:
        side, s = events[k]
        add = pairer.add_a if side == "a" else pairer.add_b
        result = add(FakeTime(*s), (side, s))
        if result is not None:
            pairs.append(result)
    # Each pair is (item of a, item of b) with the same stamp, each stamp once.
    assert sorted(a[1] for a, _ in pairs) == sorted(stamps)
    assert all(a == ("a", b[1]) and b[0] == "b" for a, b in pairs)
    assert pairer.pairs == n and pairer.pending("a") == pairer.pending("b") == 0


def test_stamps_differing_by_one_nanosecond_do_not_pair():
    pairer = StampPairer(4)
    assert pairer.add_a((5, 1), "image") is None
    assert pairer.add_b((5, 2), "joints") is None
    assert pairer.add_b((5, 1), "joints") == ("image", "joints")


def test_full_buffer_evicts_the_longest_waiting():
    evicted = []
    pairer = StampPairer(3, on_evict=lambda *args: evicted.append(args))
    for i in range(5):
        pairer.add_a((i, 0), f"img{i}")
    assert evicted == [("a", (0, 0), "img0", "evicted"), ("a", (1, 0), "img1", "evicted")]
    assert pairer.evicted == {"a": 2, "b": 0} and pairer.pending("a") == 3
    assert pairer.add_b((0, 0), "late joints") is None  # its image is gone: waits in b
    assert pairer.add_b((4, 0), "joints4") == ("img4", "joints4")


def test_a_half_sent_again_while_waiting_replaces_the_waiting_copy():
    pairer = StampPairer(8)
    pairer.add_a((1, 0), "first")
    assert pairer.add_a((1, 0), "again") is None
    assert pairer.pending("a") == 1
    assert pairer.add_b((1, 0), "joints") == ("again", "joints")
    assert pairer.repeated == 1 and pairer.pairs == 1


def test_a_capture_sent_again_after_pairing_is_paired_afresh():
    pairer = StampPairer(8)
    assert pairer.add_a((1, 0), "image") is None
    assert pairer.add_b((1, 0), "joints") == ("image", "joints")
    # Sent again (not receipted downstream): paired afresh, in either order, counted once.
    assert pairer.add_b((1, 0), "joints again") is None
    assert pairer.add_a((1, 0), "image again") == ("image again", "joints again")
    assert pairer.repeated == 1 and pairer.pairs == 2


def test_rejected_capture_drops_both_halves():
    dropped = []
    pairer = StampPairer(8, on_evict=lambda *args: dropped.append(args))
    pairer.add_a((2, 0), "image")
    pairer.reject((2, 0))            # its joint state was malformed
    assert pairer.pending("a") == 0
    pairer.reject((3, 0))            # a malformed image, partner not yet here
    assert pairer.add_b((3, 0), "joints") is None
    assert pairer.pending("b") == 0
    assert [d[1:] for d in dropped] == [((2, 0), "image", "rejected"),
                                        ((3, 0), "joints", "rejected")]
    assert pairer.rejected == 2 and pairer.dropped == 2 and pairer.pairs == 0


def test_rejected_stamps_are_remembered_for_capacity_captures():
    pairer = StampPairer(2)
    for i in range(3):
        pairer.reject((i, 0))
    # (0, 0) has been forgotten (3 captures rejected, capacity 2): accepted as new.
    assert pairer.add_a((0, 0), "new") is None and pairer.pending("a") == 1
    assert pairer.add_a((2, 0), "still rejected") is None and pairer.pending("a") == 1
    assert pairer.dropped == 1


@pytest.mark.parametrize("capacity", [0, -1, 2.0, True])
def test_capacity_must_be_a_positive_integer(capacity):
    with pytest.raises(ValueError, match="capacity"):
        StampPairer(capacity)


def test_stamps_read_and_key_with_nine_digit_nanoseconds():
    from sfs_ros.ros.pairing import format_stamp, view_key
    assert format_stamp((12, 3400)) == "12.000003400"
    assert view_key((12, 3400)) == "12_000003400"
