"""The recorder's bag names and its diagnostics' figures, without ROS."""

import pytest

from sfs_ros.cell_logic.bag import new_bag_folder
from sfs_ros.cell_logic.recording_status import RecordingStatus

STAMP = "20261206_041500"


def test_a_bag_is_named_after_its_scan_or_the_request(tmp_path):
    assert new_bag_folder(tmp_path, "", scan=7, rolling=True, stamp=STAMP) == \
        tmp_path / "bags" / f"scan_007_{STAMP}"
    assert new_bag_folder(tmp_path, "", scan=None, rolling=True, stamp=STAMP).name == \
        f"scan_{STAMP}"                              # a capture before its scan's report
    assert new_bag_folder(tmp_path, "", scan=None, rolling=False, stamp=STAMP).name == \
        f"bag_{STAMP}"
    assert new_bag_folder(tmp_path, "mine", scan=7, rolling=True, stamp=STAMP) == \
        tmp_path / "bags" / "mine"


def test_a_bag_name_in_use_gets_the_next_number(tmp_path):
    (tmp_path / "bags" / f"bag_{STAMP}").mkdir(parents=True)
    (tmp_path / "bags" / f"bag_{STAMP}_2").mkdir()
    assert new_bag_folder(tmp_path, "", scan=None, rolling=False, stamp=STAMP).name == \
        f"bag_{STAMP}_3"


@pytest.mark.parametrize("name", ["../out", ".hidden", "a/b", "x" * 101])
def test_a_bad_bag_name_is_refused(tmp_path, name):
    with pytest.raises(ValueError, match="bag name"):
        new_bag_folder(tmp_path, name, scan=None, rolling=False, stamp=STAMP)


def test_the_status_follows_a_bag_from_open_to_close():
    status = RecordingStatus("mcap")
    status.report(problem="an earlier bag failed", warning="late parameters")
    status.opened("/out/bags/b")
    assert status.snapshot() == ({"recording": True, "path": "/out/bags/b", "storage": "mcap",
                                  "messages": 0, "bytes": 0, "write_s": 0.0,
                                  "parameters_from": "", "bags": 0}, "", "")
    status.parameters_came("carving")
    status.parameters_came("meshing")
    assert status.snapshot()[0]["parameters_from"] == "carving,meshing"
    status.wrote(1, 100, 0.25)
    status.wrote(2, 300, 0.125)
    assert status.closed() == 0.375
    values, problem, warning = status.snapshot()
    assert (values["recording"], values["messages"], values["bytes"], values["bags"]) == \
        (False, 2, 300, 1)
    status.report(warning="parameters not stored")
    assert status.snapshot()[1:] == ("", "parameters not stored")
    status.opened("/out/bags/c")
    assert status.snapshot()[0]["parameters_from"] == ""      # of the new bag: none yet
    status.abandoned()
    assert status.snapshot()[0]["recording"] is False and status.path == "/out/bags/c"
