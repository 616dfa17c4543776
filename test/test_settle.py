"""Settle detection on synthetic encoder traces."""

import math

import numpy as np
import pytest

from sfs_ros.cell_logic.settle_detection import SettleDetector

#: Sample period, seconds: a power of two, so sums of periods are exact in floating point.
DT = 1.0 / 32.0
TOL = 0.002  # rad
TARGET = (1.0, 0.5)  # rad


def feed(detector, times, thetas, phis):
    """Feed a trace; return (index, state) of the first final state, or (None, last state)."""
    state = None
    for n, (t, a, b) in enumerate(zip(times, thetas, phis)):
        state = detector.update(t, a, b)
        if state.done:
            return n, state
    return None, state


def reference_settle_index(thetas, phis, samples):
    """The definition, evaluated on whole windows: first index whose last ``samples``
    readings are all within TOL of the target with a spread below TOL on both axes."""
    xy = np.column_stack([thetas, phis])
    for n in range(samples - 1, len(xy)):
        w = xy[n - samples + 1:n + 1]
        if np.all(np.abs(w - TARGET) <= TOL) and np.all(w.max(0) - w.min(0) < TOL):
            return n
    return None


def damped_approach(n, start, decay=4.0, freq_hz=1.5):
    """Underdamped step response from ``start`` to TARGET: (n,) times and both axes.

    ``x(t) = target + (start - target) exp(-decay t) cos(2 pi freq t)``: it
    swings past the target and back, each time less.
    """
    t = np.arange(n) * DT
    envelope = np.exp(-decay * t) * np.cos(2 * np.pi * freq_hz * t)
    return t, *(b + (a - b) * envelope for a, b in zip(start, TARGET))


def test_approach_with_overshoot_settles_when_the_definition_says():
    t, th, ph = damped_approach(400, start=(0.0, 0.2))
    # The trace does swing past the target by more than the tolerance.
    assert th.max() > TARGET[0] + 10 * TOL
    det = SettleDetector(TOL, 5, timeout_s=30.0)
    det.start(0.0, *TARGET)
    n, state = feed(det, t, th, ph)
    assert state.state == "settled" and state.settled and state.done
    assert n == reference_settle_index(th, ph, 5)
    outside = np.flatnonzero((np.abs(th - TARGET[0]) > TOL) | (np.abs(ph - TARGET[1]) > TOL))
    assert n >= outside.max() + 5  # five readings inside the band after the last excursion
    assert state.elapsed_s == pytest.approx(t[n])
    assert "settled" in state.reason and abs(state.error_rad[0]) <= TOL


def test_passing_through_the_target_is_not_settling():
    # Three readings inside the band, but moving 0.6 TOL per reading: spread 1.2 TOL.
    det = SettleDetector(TOL, 3, timeout_s=10.0)
    det.start(0.0, *TARGET)
    for n, offset in enumerate((-0.6 * TOL, 0.0, 0.6 * TOL)):
        state = det.update((n + 1) * DT, TARGET[0] + offset, TARGET[1])
    assert state.state == "moving" and not state.done


def test_both_axes_must_arrive():
    det = SettleDetector(TOL, 3, timeout_s=10.0, stall_s=5.0)
    det.start(0.0, *TARGET)
    for n in range(10):  # theta there, phi still moving 10 TOL per reading
        state = det.update((n + 1) * DT, TARGET[0], TARGET[1] - 0.2 + 10 * TOL * n)
    assert state.state == "moving"


def test_small_noise_settles_after_exactly_samples_readings():
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, TOL / 20, size=(50, 2))
    # 5 readings of sigma TOL/20: spread below ~5 sigma = TOL/4 < TOL, offsets below TOL.
    assert np.all(np.abs(noise) < TOL / 2) and np.ptp(noise[:5], axis=0).max() < TOL
    det = SettleDetector(TOL, 5, timeout_s=10.0)
    det.start(0.0, *TARGET)
    n, state = feed(det, (np.arange(50) + 1) * DT, TARGET[0] + noise[:, 0],
                    TARGET[1] + noise[:, 1])
    assert state.settled and n == 4


def test_noise_larger_than_the_tolerance_times_out_instead_of_settling():
    # Alternating +-0.6 TOL: every reading within tolerance, the spread 1.2 TOL never is.
    det = SettleDetector(TOL, 4, timeout_s=2.0, stall_s=0.5)
    det.start(0.0, *TARGET)
    times = (np.arange(200) + 1) * DT
    jitter = 0.6 * TOL * (-1.0) ** np.arange(200)
    n, state = feed(det, times, TARGET[0] + jitter, np.full(200, TARGET[1]))
    assert state.state == "timeout"
    # The first reading later than timeout_s after the start: t = 2 s + DT.
    assert times[n] == pytest.approx(2.0 + DT)
    assert "not settled within 2 s" in state.reason


def test_stall_far_from_the_target():
    # Moves at 1 rad/s from 0 toward 1 rad, jams at 0.3 rad (t = 0.3 s ~ 9.6 samples).
    stall_s = 0.5
    times = (np.arange(200) + 1) * DT
    theta = np.minimum(times * 1.0, 0.3)
    det = SettleDetector(TOL, 5, timeout_s=10.0, stall_s=stall_s)
    det.start(0.0, *TARGET)
    n, state = feed(det, times, theta, np.full(200, TARGET[1]))
    assert state.state == "stalled"
    first_stuck = np.flatnonzero(theta == 0.3)[0]
    # Stalled at the first reading stall_s after the first stuck one.
    assert times[n] == pytest.approx(times[first_stuck] + stall_s)
    assert state.error_rad[0] == pytest.approx(-0.7)
    assert "stalled" in state.reason and "-0.7000" in state.reason


def test_a_late_start_is_not_a_stall():
    # The controller reacts after 0.4 s (< stall_s = 0.5 s), then moves linearly to the target.
    times = (np.arange(400) + 1) * DT
    theta = np.clip((times - 0.4) * 0.5, 0.0, TARGET[0])
    det = SettleDetector(TOL, 5, timeout_s=10.0, stall_s=0.5)
    det.start(0.0, *TARGET)
    n, state = feed(det, times, theta, np.full(400, TARGET[1]))
    assert state.state == "settled"
    # Linear motion hits the band when theta >= 1 - TOL, at t = 0.4 + 2 (1 - TOL).
    arrive = np.flatnonzero(theta >= TARGET[0] - TOL)[0]
    assert n == arrive + 4


def test_silent_encoder_times_out_on_poll():
    det = SettleDetector(TOL, 3, timeout_s=1.0)
    det.start(10.0, *TARGET)
    assert det.poll(10.5).state == "moving"
    assert det.poll(11.0).state == "moving"  # not *later* than the timeout yet
    state = det.poll(11.0 + DT)
    assert state.state == "timeout" and "no encoder reading" in state.reason
    assert state.error_rad is None and state.elapsed_s == pytest.approx(1.0 + DT)


def test_final_state_is_kept_until_the_next_start():
    det = SettleDetector(TOL, 1, timeout_s=1.0)
    det.start(0.0, *TARGET)
    settled = det.update(DT, *TARGET)
    assert settled.settled
    assert det.update(2 * DT, 0.0, 0.0) is settled  # a later reading does not undo it
    assert det.poll(5.0) is settled
    det.start(5.0, 0.0, 0.0)
    assert det.target == (0.0, 0.0)
    assert det.update(5.0 + DT, 1.0, 1.0).state == "moving"


def test_bad_use_is_refused():
    with pytest.raises(ValueError, match="tolerance_rad must be"):
        SettleDetector(0.0, 3, 1.0)
    with pytest.raises(ValueError, match="samples must be an integer >= 1"):
        SettleDetector(TOL, 0, 1.0)
    with pytest.raises(ValueError, match="timeout_s must be"):
        SettleDetector(TOL, 3, math.inf)
    det = SettleDetector(TOL, 3, 1.0)
    with pytest.raises(ValueError, match="no move started"):
        det.update(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="target must be finite"):
        det.start(0.0, math.nan, 0.0)
    det.start(1.0, *TARGET)
    with pytest.raises(ValueError, match="time went backwards"):
        det.update(0.5, *TARGET)
    with pytest.raises(ValueError, match="encoder readings must be finite"):
        det.update(1.5, math.nan, 0.0)
