"""Scan goals and reconstruction requests checked without ROS: the reasons a bad one gets."""

import math

import numpy as np
import pytest
import yaml

from sfs_ros.cell_logic.mesh_options import mesh_options
from sfs_ros.cell_logic.scan_goal import goal_plan, scan_outcome


def test_no_views_means_the_configured_plan():
    assert goal_plan("", [], [], "", max_views=100) is None


def test_explicit_views_are_kept_in_order():
    plan = goal_plan("", [3.0, 0.5, -1.0], [0.2, 0.4, -math.pi / 2], "bracket_07",
                     max_views=100)
    assert len(plan) == 3
    assert np.allclose(plan.views[:, 0], np.mod([3.0, 0.5, -1.0], 2 * math.pi))
    assert np.allclose(plan.views[:, 1], [0.2, 0.4, -math.pi / 2])


@pytest.mark.parametrize("theta, phi, scan_name, reason", [
    ([0.0, 1.0], [0.3], "", "theta_rad has 2 values and phi_rad 1"),
    ([0.0, math.nan], [0.3, 0.3], "", "view 1 .* is not finite"),
    ([0.0, 1.0], [0.3, 1.6], "", "view 1 has phi 1.6 rad, outside the carriage's range"),
    ([0.0, 0.0], [0.3, 0.3], "", "repeated viewpoint"),
    ([0.0], [0.3], "../up", "scan name '../up' must be"),
])
def test_bad_views_and_names_are_refused_with_the_reason(theta, phi, scan_name, reason):
    with pytest.raises(ValueError, match=reason):
        goal_plan("", theta, phi, scan_name, max_views=100)


def test_too_many_views_and_both_kinds_are_refused(tmp_path):
    with pytest.raises(ValueError, match="3 views, more than the 2"):
        goal_plan("", [0.0, 1.0, 2.0], [0.1, 0.1, 0.1], "", max_views=2)
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({"views": [[0, 20], [90, 20]]}))
    assert len(goal_plan(str(plan), [], [], "", max_views=10)) == 2
    with pytest.raises(ValueError, match="both plan_file and theta_rad"):
        goal_plan(str(plan), [0.0], [0.1], "", max_views=10)
    with pytest.raises(ValueError, match="cannot read scan plan"):
        goal_plan(str(tmp_path / "missing.yaml"), [], [], "", max_views=10)


def test_empty_request_takes_the_node_settings(tmp_path):
    options = mesh_options(tmp_path)
    assert (options.resolution, options.bounds_m, options.mesher, options.colour,
            options.output_name, options.texture, options.refine) == (None,) * 7


@pytest.mark.parametrize("name, reason", [
    ("../x.ply", "has a folder"),
    ("sub/x.ply", "has a folder"),
    ("/tmp/x.ply", "has a folder"),
    ("x.txt", "must end in one of"),
    (".hidden.ply", "hidden component"),
])
def test_output_names_are_confined(tmp_path, name, reason):
    with pytest.raises(ValueError, match=reason):
        mesh_options(tmp_path, output_name=name)


def test_options_are_checked(tmp_path):
    options = mesh_options(tmp_path, resolution=64, bounds_m=[-1, -1, 0, 1, 1, 2],
                           mesher="advancing-front", colour="no", output_name="part.obj",
                           texture="yes", refine="YES")
    assert options.texture is True and options.refine is True
    assert options.resolution == 64 and options.bounds_m.shape == (2, 3)
    assert options.colour is False and options.output_name == "part.obj"
    for kwargs, reason in (({"resolution": 4}, "outside"), ({"bounds_m": [0, 0, 0, 1, 1]},
                                                            "bounds_m"),
                           ({"bounds_m": [1, 0, 0, 0, 1, 1]}, "bounds_m"),
                           ({"mesher": "x"}, "mesher"), ({"colour": "maybe"}, "colour"),
                           ({"texture": "maybe"}, "texture 'maybe'"),
                           ({"refine": "2"}, "refine '2' is not 'yes' or 'no'")):
        with pytest.raises(ValueError, match=reason):
            mesh_options(tmp_path, **kwargs)


def status_values(state, *, scan=2, total=4, receipted=4, lost=0) -> dict:
    return {"scan": scan, "state": state, "total": total, "receipted": receipted,
            "lost_in_transport": lost}


@pytest.mark.parametrize("values, outcome", [
    (status_values("running"), None),                    # still scanning
    (status_values("done", scan=1), None),               # another scan's end
    (status_values("done", receipted=3), None),          # a receipt still to come
    (status_values("done"), True),
    (status_values("done", receipted=3, lost=1), False),  # one lost in transport
    (status_values("paused", receipted=1), False),
    (status_values("cancelled", receipted=0), False),
])
def test_a_goal_ends_once_its_scan_ended_and_every_receipt_came(values, outcome):
    assert scan_outcome(values, 2) is outcome
