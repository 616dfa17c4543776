"""The scan node's parameters made into its plan, progress folder and settings, without a
running node: the parameter each refusal names."""

import math

import pytest

from sfs_ros.nodes.scan_node import PARAMS
from sfs_ros.ros.params import ParameterError
from sfs_ros.ros.scan_params import scan_plan, scan_progress, scan_settings

DEFAULTS = {p.name: p.default for p in PARAMS}


def values(**changes) -> dict:
    return DEFAULTS | changes


def test_the_default_rings_give_the_plan_and_the_settings():
    plan = scan_plan(values())
    assert len(plan) == 3 * 16 + 1                       # three rings of 16 and the top
    settings = scan_settings(values())
    assert settings.settle_tolerance_rad == pytest.approx(math.radians(0.1))
    assert [name for name, _ in settings.prepare] == ["reset", "home", "listeners"]
    assert [name for name, _ in scan_settings(values(), board=True).prepare] == \
        ["home", "listeners"]                            # a board scan keeps the scan open


def test_a_plan_larger_than_the_queue_is_refused_naming_queue_depth():
    with pytest.raises(ParameterError, match="'queue_depth': got 10, expected at least the "
                                             "49 views of the plan"):
        scan_progress(values(queue_depth=10), scan_plan(values()))


def test_progress_is_kept_only_with_a_folder(tmp_path):
    plan = scan_plan(values())
    assert scan_progress(values(), plan) is None
    progress = scan_progress(values(progress_dir=str(tmp_path / "progress")), plan)
    assert progress.folder == tmp_path / "progress"
    (tmp_path / "file").write_text("")
    with pytest.raises(ParameterError, match="'progress_dir': cannot use"):
        scan_progress(values(progress_dir=str(tmp_path / "file" / "below")), plan)


def test_a_bad_plan_file_is_refused_naming_plan_file(tmp_path):
    (tmp_path / "plan.yaml").write_text("views: nonsense\n")
    with pytest.raises(ParameterError, match="'plan_file'"):
        scan_plan(values(plan_file=str(tmp_path / "plan.yaml")))
