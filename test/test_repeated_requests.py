"""A request sent again gets the answer made (sfs_ros.cell_logic.repeated_requests)."""

import numpy as np
import pytest

from sfs_ros.cell_logic.mesh_options import MeshOptions
from sfs_ros.cell_logic.repeated_requests import RepeatedRequests, request_key


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


BOX = np.array([[-0.05, -0.05, 0.0], [0.05, 0.05, 0.1]])
VIEWS = 29


def test_the_same_request_on_the_same_scan_within_the_window_is_a_repeat():
    clock = Clock()
    repeats = RepeatedRequests(5.0, clock=clock)
    key = request_key(MeshOptions(bounds_m=BOX, colour=True), "/out/scan_001", VIEWS)
    assert repeats.recall(key) is None
    answer = (True, "{}", {"path": "/out/scan_001.ply"})
    repeats.remember(key, answer)
    clock.now += 5.0
    same = request_key(MeshOptions(bounds_m=BOX.copy(), colour=True), "/out/scan_001", VIEWS)
    assert repeats.recall(same) is answer
    clock.now += 0.001
    assert repeats.recall(same) is None          # later than the window: made afresh


@pytest.mark.parametrize("other", [
    request_key(MeshOptions(bounds_m=BOX + 1e-12, colour=True), "/out/scan_001", VIEWS),
    request_key(MeshOptions(bounds_m=BOX, colour=False), "/out/scan_001", VIEWS),
    request_key(MeshOptions(bounds_m=BOX, colour=True, output_name="b.ply"),
                "/out/scan_001", VIEWS),
    request_key(MeshOptions(bounds_m=BOX, colour=True), "/out/scan_002", VIEWS),
    request_key(MeshOptions(bounds_m=BOX, colour=True), "/out/scan_001",
                VIEWS + 1),
])
def test_another_option_box_scan_or_view_is_no_repeat(other):
    repeats = RepeatedRequests(5.0, clock=Clock())
    repeats.remember(request_key(MeshOptions(bounds_m=BOX, colour=True), "/out/scan_001",
                                 VIEWS), (True, "{}", {}))
    assert repeats.recall(other) is None


def test_a_negative_window_is_refused():
    with pytest.raises(ValueError, match="window_s must be >= 0"):
        RepeatedRequests(-1.0)
