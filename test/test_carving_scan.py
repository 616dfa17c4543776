"""The carving node's scan without ROS: what becomes of each view, the memory refusal, the
views a full disk refuses, the views of earlier scans and the hull's schedule."""

import math

import numpy as np
import pytest

from sfs_ros.cell_logic.carving_scan import (
    CarvingScan,
    EarlierViews,
    HullSchedule,
    grid_refusal,
    memory_budget,
    reset_refusal,
)
from sfs_ros.cell_logic.live_reconstruction import OPEN_MARKER, LiveReconstruction
from sfs_ros.cell_logic.message_fields import view_key
from sfs_ros.core.carving.resolution import default_memory_budget
from sfs_ros.core.geometry.rig import RigCalibration

from small_disk import fill, small_disk

#: A small orthographic rig: 80 x 60 pixels, 400 px per metre (a 0.2 m x 0.15 m field).
RIG = RigCalibration(width=80, height=60, fx=400.0, fy=400.0)
BOX = np.array([[-0.05, -0.05, 0.0], [0.05, 0.05, 0.1]])
BUDGET = 1 << 30


def disc() -> np.ndarray:
    """A disc of radius 10 px at the image centre: the silhouette of a round object."""
    rows, cols = np.mgrid[:RIG.height, :RIG.width]
    return (rows - RIG.height / 2) ** 2 + (cols - RIG.width / 2) ** 2 <= 100


#: The per-scan settings the scans of :func:`make_scan` are made with (compared only).
SETTINGS = ("box", 16)


def make_scan(tmp_path, folder="out") -> CarvingScan:
    return CarvingScan(LiveReconstruction(RIG, BOX, output_dir=tmp_path / folder, resolution=16),
                       BUDGET, settings=SETTINGS)


def no_new_reconstruction() -> LiveReconstruction:
    raise AssertionError("the settings did not change: the reconstruction is reset, not made")


def test_a_view_is_carved_receipted_and_counted(tmp_path):
    scan = make_scan(tmp_path)
    scan.health.report("an earlier problem")
    outcome = scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    assert (outcome.kind, outcome.text, outcome.receipted, outcome.stored) == \
        ("carved", "", True, True)
    counts, problem, warning, rejected = scan.health.snapshot()
    assert counts["carved"] == counts["scan_views"] == 1 and counts["carve_s"] >= 0.0
    assert (problem, warning, rejected) == ("", "", [])      # a good view ends the problem
    assert len(scan.cameras) == 1 and scan.live.n_views == 1


def test_an_empty_mask_is_stored_with_a_warning(tmp_path):
    scan = make_scan(tmp_path)
    outcome = scan.add_view((5, 0), "camera", np.zeros((RIG.height, RIG.width), bool), 0.0, 0.3)
    assert outcome.kind == "empty" and outcome.stored and outcome.receipted
    assert outcome.text == "view at stamp 5.000000000: empty mask: no object to carve with"
    counts, _, warning, _ = scan.health.snapshot()
    assert counts["empty"] == 1 and warning == outcome.text


def test_a_view_sent_again_is_receipted_not_stored_twice(tmp_path):
    scan = make_scan(tmp_path)
    scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    outcome = scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    assert outcome.kind == "repeat" and outcome.receipted and not outcome.stored
    assert scan.live.n_views == 1 and scan.health.snapshot()[0]["repeats"] == 1


def test_an_unusable_view_is_rejected_named_and_receipted(tmp_path):
    scan = make_scan(tmp_path)
    outcome = scan.add_view((5, 7), "camera", np.ones((3, 3), bool), 0.25, 0.5)
    assert outcome.kind == "rejected" and outcome.receipted and not outcome.stored
    assert outcome.text.startswith("view at stamp 5.000000007 rejected: ")
    counts, _, _, rejected = scan.health.snapshot()
    assert counts["rejected"] == 1 and scan.live.n_views == 0
    assert rejected == [f"view at stamp 5.000000007 (theta 0.25 rad, phi 0.5 rad): "
                        f"{outcome.text.split('rejected: ', 1)[1]}"]


def test_a_late_copy_of_an_earlier_scans_view_is_not_stored_in_the_next(tmp_path):
    scan = make_scan(tmp_path)
    scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    first = scan.live.session_dir
    assert scan.new_scan(None, SETTINGS, no_new_reconstruction) is False
    assert scan.cameras == [] and scan.health.snapshot()[0]["scan_views"] == 0
    outcome = scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    assert outcome.kind == "stale" and outcome.receipted and not outcome.stored
    assert scan.live.n_views == 0 and scan.live.session_dir is None
    scan.add_view((6, 0), "camera", disc(), math.pi / 2, 0.3)
    assert scan.live.session_dir != first and scan.live.n_views == 1


def test_new_settings_make_a_new_reconstruction_and_end_the_old_scan(tmp_path):
    scan = make_scan(tmp_path)
    scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    old, first = scan.live, scan.live.session_dir
    assert (first / OPEN_MARKER).exists()
    assert scan.new_scan("named", ("box", 20),
                         lambda: LiveReconstruction(RIG, BOX, output_dir=tmp_path / "out",
                                                    resolution=20, scan_name="named"))
    assert scan.live is not old and scan.live.grid.shape[0] == 20
    assert scan.settings == ("box", 20)
    assert not (first / OPEN_MARKER).exists()
    assert scan.add_view((5, 0), "camera", disc(), 0.0, 0.3).kind == "stale"


def test_a_taken_scan_name_changes_nothing(tmp_path):
    scan = make_scan(tmp_path)
    scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    with pytest.raises(ValueError, match="scan_001"):
        scan.new_scan("scan_001", SETTINGS, no_new_reconstruction)
    assert scan.live.n_views == 1 and "5_000000000" not in scan.earlier


def test_a_scan_without_a_reconstruction_gets_one_at_its_first_new_scan(tmp_path):
    scan = CarvingScan(None, BUDGET, "refused: too big", SETTINGS)
    assert scan.working_memory_reserve() == 0
    assert scan.new_scan(None, SETTINGS, lambda: LiveReconstruction(
        RIG, BOX, output_dir=tmp_path / "out", resolution=16))
    assert scan.live is not None and scan.refusal == ""
    assert 0 < scan.working_memory_reserve() == min(scan.live.working_memory_bytes, BUDGET)


def test_a_reset_is_refused_while_the_scan_node_takes_views_or_for_a_grid_too_big():
    assert reset_refusal(None, BOX, 16, BUDGET) == ""
    assert reset_refusal((3, "running"), BOX, 16, BUDGET) == (
        "reset refused: the scan node reports scan 3 running; its views go to the scan open "
        "now (cancel it first: scan/cancel, then reset)")
    assert reset_refusal(None, BOX, 2048, 64 << 20) == grid_refusal(BOX, 2048, 64 << 20) != ""


def test_a_colour_image_is_kept_for_its_view_or_refused_with_its_stamp(tmp_path):
    scan = make_scan(tmp_path)
    scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    image = np.full((RIG.height, RIG.width, 3), 200, np.uint8)
    assert scan.add_colour_image((5, 0), image) == ""
    assert scan.live.colour_image(view_key((5, 0))) is not None
    problem = scan.add_colour_image((6, 0), image[:10])
    assert problem.startswith("captured image at stamp 6.000000000 not kept for colour: ")
    assert "the rig's size" in problem


def test_earlier_views_keep_the_most_recent():
    earlier = EarlierViews(kept=3)
    earlier.remember(["a", "b"])
    earlier.remember(["c", "d"])
    assert len(earlier) == 3 and "a" not in earlier and all(k in earlier for k in "bcd")


def test_without_a_reconstruction_a_view_is_refused_without_a_receipt():
    scan = CarvingScan(None, BUDGET, "refused: too big")
    assert scan.health.snapshot()[1] == "refused: too big"
    outcome = scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
    assert (outcome.kind, outcome.receipted) == ("refused", False)
    assert outcome.text == "view at stamp 5.000000000 not received: refused: too big"


def test_a_view_the_disk_refuses_is_kept_and_stored_once_there_is_space(tmp_path):
    mount_point = tmp_path / "disk"
    mount_point.mkdir()
    with small_disk(mount_point, "1m"):
        scan = make_scan(mount_point)
        scan.add_view((5, 0), "camera", disc(), 0.0, 0.3)
        fill(mount_point / "filler")
        outcome = scan.add_view((6, 0), "camera", disc(), 1.0, 0.3)
        assert outcome.kind == "unstored" and not outcome.receipted
        assert outcome.text.startswith(f"view at stamp 6.000000000 not stored in "
                                       f"{scan.live.session_dir}: ")
        assert "MB free" in outcome.text and outcome.text.endswith(
            "1 view(s) kept in memory without a receipt, stored as soon as a write succeeds")
        assert list(scan.unstored) == [view_key((6, 0))] and scan.live.n_views == 1
        offered = []

        def add(*args):
            offered.append(args[0])
            scan.add_view(*args)
        scan.store_unstored(add)                 # still full: kept
        assert offered == [(6, 0)] and list(scan.unstored) == [view_key((6, 0))]
        (mount_point / "filler").unlink()
        scan.store_unstored(add)
        assert scan.unstored == {} and scan.live.n_views == 2


def test_grid_refusal_names_the_resolution_and_the_budget():
    assert grid_refusal(BOX, 64, BUDGET) == ""
    refusal = grid_refusal(BOX, 2048, 64 << 20)
    assert refusal.startswith("refused: resolution 2048 is more than this machine may hold")
    assert "0.06 GiB" in refusal


def test_memory_budget_parses_a_size_or_takes_the_default():
    assert memory_budget("512M") == 512 << 20
    assert memory_budget("  ") == default_memory_budget()
    with pytest.raises(ValueError):
        memory_budget("lots")


def test_the_hull_is_due_after_a_change_when_idle_or_after_the_period():
    hull = HullSchedule(0.5)
    assert not hull.due(0, 10.0)               # nothing changed
    hull.changed = True
    assert hull.due(0, 10.0) and hull.due(3, 10.0)   # never published: the period is over
    hull.published(10.0)
    hull.changed = True
    assert not hull.due(3, 10.2)               # jobs wait, within the period
    assert hull.due(0, 10.2) and hull.due(3, 10.5)
