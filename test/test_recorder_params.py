"""The recorder node's ``bag_name`` checked without a running node."""

import pytest

from sfs_ros.ros.params import ParameterError
from sfs_ros.ros.recorder_params import check_bag_name


@pytest.mark.parametrize("name", ["", "session_1", "mug-2.b"])
def test_an_empty_or_plain_bag_name_is_taken(tmp_path, name):
    check_bag_name(str(tmp_path), {"bag_name": name})


@pytest.mark.parametrize("name", ["../outside", "a/b", ".hidden", "x" * 101])
def test_a_bag_name_that_is_no_folder_name_is_refused_by_name(tmp_path, name):
    with pytest.raises(ParameterError, match="must be 1-100 letters") as refused:
        check_bag_name(str(tmp_path), {"bag_name": name})
    assert refused.value.name == "bag_name"
