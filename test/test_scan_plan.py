"""Scan plans: formats, validation, and an ordering that shortens the motion."""

from pathlib import Path

import numpy as np
import pytest

from sfs_ros.cell_logic.scan_plan import ScanPlan, load_plan, travel_deg
from sfs_ros.core.simulation.plan import ring_plan

EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "scan_plan.yaml"


def as_set(views_rad, decimals=9):
    """Viewpoints as a set of rounded (theta mod 2 pi, phi) pairs, for order-free comparison."""
    v = np.asarray(views_rad)
    return {(round(t % (2 * np.pi), decimals), round(p, decimals)) for t, p in v}


def write(tmp_path, text):
    path = tmp_path / "plan.yaml"
    path.write_text(text)
    return path


def test_rings_hold_the_same_viewpoints_as_ring_plan():
    plan = ScanPlan.from_rings([15, 40, 65], 16, True)
    reference = ring_plan([15, 40, 65], 16)  # without the top view: its angle is moved
    assert len(plan) == 49 and plan.views.shape == (49, 2) and plan.views.dtype == np.float64
    assert as_set(reference) <= as_set(plan.views)
    top = plan.views[np.isclose(plan.views[:, 1], np.pi / 2)]
    assert len(top) == 1
    assert plan.names == tuple(f"view_{n:03d}" for n in range(49))
    assert plan.duplicates == ()


def test_ordering_goes_ring_by_ring_alternating_direction():
    deg = ScanPlan.from_rings([15, 40, 65], 16, True).views_deg
    assert np.all(np.diff(deg[:, 1]) >= 0)  # elevations only go up
    for ring, direction in zip((15, 40, 65), (1, -1, 1)):
        theta = deg[deg[:, 1] == ring, 0]
        assert np.all(np.sign(np.diff(theta)) == direction)
    # The top view is taken where the turntable already is.
    assert deg[-1, 1] == 90 and deg[-1, 0] == deg[-2, 0]


def test_ordering_shortens_turntable_travel():
    ordered = ScanPlan.from_rings([15, 40, 65], 16, True)
    naive = ScanPlan.from_rings([15, 40, 65], 16, True, reorder=False)
    assert as_set(naive.views[:-1]) == as_set(ordered.views[:-1])
    # Naive: each ring sweeps 337.5 deg upward, then swings back to start the next
    # (337.5 -> 11.25, 348.75 -> 0); the top view at theta = 0 swings back again.
    assert naive.travel_deg() == pytest.approx((3 * 337.5 + 326.25 + 348.75 + 337.5, 75.0))
    # Ordered: three sweeps of 337.5 deg joined by two half steps of 11.25 deg:
    # 1035 deg instead of 2025, 49 % less turntable motion; the carriage is the same.
    assert ordered.travel_deg() == pytest.approx((3 * 337.5 + 2 * 11.25, 75.0))


def test_explicit_views_are_reordered_by_ring():
    plan = ScanPlan.from_views([[90, 30], [0, 10], [270, 30], [180, 10], [-90, 10]])
    # Lowest ring first, ascending; the next ring starts at its end nearest to 270.
    np.testing.assert_allclose(plan.views_deg, [[0, 10], [180, 10], [270, 10], [270, 30],
                                                [90, 30]])
    assert plan.travel_deg() == pytest.approx((270 + 180, 20))
    kept = ScanPlan.from_views([[90, 30], [0, 10]], reorder=False)
    np.testing.assert_allclose(kept.views_deg, [[90, 30], [0, 10]])


def test_travel_is_measured_without_wrapping():
    assert travel_deg(np.radians([[0, 0], [350, 10], [10, 0]])) == pytest.approx((690, 20))


def test_duplicates_are_flagged():
    with pytest.raises(ValueError, match=r"1 repeated viewpoint.*views 0 and 1"):
        ScanPlan.from_views([[10, 20], [370, 20]], reorder=False)
    # Straight down, the turntable angle only rotates the image: the same view.
    with pytest.raises(ValueError, match="repeated viewpoint"):
        ScanPlan.from_views([[0, 90], [45, 90]])
    plan = ScanPlan.from_views([[10, 20], [370, 20], [0, 20]], reorder=False,
                               allow_duplicates=True)
    assert plan.duplicates == ((0, 1),)
    # A 90 degree ring is one view repeated.
    with pytest.raises(ValueError, match="repeated viewpoint"):
        ScanPlan.from_rings([30, 90], 4)


@pytest.mark.parametrize("views, problem", [
    ([[0, 91]], r"phi 91.0 deg, outside the carriage range \[-90, 90\]"),
    ([[0, -90.5]], "outside the carriage range"),
    ([[float("nan"), 10]], "not finite"),
    ([[0, float("inf")]], "not finite"),
    ([], "non-empty list"),
    ([[0, 1, 2]], "pairs"),
    ([["a", 1]], "pairs of numbers"),
])
def test_bad_views_are_refused(views, problem):
    with pytest.raises(ValueError, match=problem):
        ScanPlan.from_views(views)


def test_yaml_views_and_rings(tmp_path):
    plan = load_plan(write(tmp_path, "views:\n  - [0, 20]\n  - [90, 20]\n  - [0, 90]\n"))
    np.testing.assert_allclose(plan.views_deg, [[0, 20], [90, 20], [90, 90]])
    rings = load_plan(write(tmp_path, "rings:\n  phi_deg: [10, 50]\n  per_ring: 8\n"
                                      "  top_view: false\n  stagger: false\nreorder: false\n"))
    np.testing.assert_allclose(rings.views, ring_plan([10, 50], 8, stagger=False))


def test_example_plan_file_loads():
    plan = load_plan(EXAMPLE)
    assert len(plan) == 49
    assert plan.travel_deg()[0] == pytest.approx(3 * 337.5 + 2 * 11.25)


@pytest.mark.parametrize("text, problem", [
    ("views: [[0, 20]]\nspeed: 3\n", r"unknown keys \['speed'\] in the scan plan"),
    ("rings: {phi_deg: [10], per_ring: 4, tilt: 1}\n", r"unknown keys \['tilt'\] in 'rings'"),
    ("views: [[0, 20]]\nrings: {phi_deg: [10], per_ring: 4}\n", "exactly one of"),
    ("reorder: true\n", "exactly one of"),
    ("rings: {per_ring: 4}\n", r"needs \['phi_deg'\]"),
    ("rings: {phi_deg: [10, 95], per_ring: 4}\n", r"in \[-90, 90\]"),
    ("rings: {phi_deg: ['10'], per_ring: 4}\n", r"in \[-90, 90\]"),
    ("rings: {phi_deg: [10, 10], per_ring: 4}\n", "elevation twice"),
    ("rings: {phi_deg: [10], per_ring: 0}\n", "per_ring must be an integer >= 1"),
    ("rings: {phi_deg: [10], per_ring: 2.5}\n", "per_ring must be an integer"),
    ("rings: {phi_deg: [10], per_ring: 4, top_view: 'yes'}\n", "top_view must be true or false"),
    ("rings: {phi_deg: [10], per_ring: 4}\nallow_duplicates: true\n", "explicit 'views' only"),
    ("views: [[0, 20]]\nreorder: 1\n", "reorder must be true or false"),
    ("- [0, 20]\n", "must be a mapping"),
    ("views: [[0, 20]\n", "not valid YAML"),
])
def test_bad_plan_files_name_the_file_and_the_problem(tmp_path, text, problem):
    path = write(tmp_path, text)
    with pytest.raises(ValueError, match=problem) as err:
        load_plan(path)
    assert str(path) in str(err.value)


def test_missing_plan_file(tmp_path):
    with pytest.raises(ValueError, match="cannot read scan plan"):
        load_plan(tmp_path / "nope.yaml")
