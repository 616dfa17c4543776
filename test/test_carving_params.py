"""The carving node's parameters made into its scan, without a running node: the memory
refusal, the parameter each refusal names, the checks of a carving request."""

from types import SimpleNamespace

import pytest

from sfs_ros.nodes.carving_node import PARAMS
from sfs_ros.ros.carving_params import (
    carve_options,
    check_scan_settings,
    open_scan,
    scan_bounds,
)
from sfs_ros.ros.params import ParameterError

DEFAULTS = {p.name: p.default for p in PARAMS}
#: A budget no grid of the default box at resolution 2048 fits in (2048^3 voxels).
SMALL = "64M"


def values(tmp_path, **changes) -> dict:
    return DEFAULTS | {"output_dir": str(tmp_path / "out"), "resolution": 16} | changes


def request(**fields):
    return SimpleNamespace(**({"resolution": 0, "bounds_m": [], "mesher": "", "colour": ""}
                              | fields))


def test_the_default_parameters_open_a_scan(tmp_path):
    scan = open_scan(values(tmp_path))
    assert scan.refusal == "" and scan.live is not None
    assert scan.live.grid.shape[0] == 16 and (tmp_path / "out").is_dir()


def test_a_grid_beyond_the_budget_opens_a_scan_without_a_reconstruction(tmp_path):
    scan = open_scan(values(tmp_path, resolution=2048, max_memory=SMALL))
    assert scan.live is None
    assert scan.refusal.startswith("refused: resolution 2048 is more than this machine may hold")
    assert scan.health.snapshot()[1] == scan.refusal          # an ERROR until a reset


@pytest.mark.parametrize("changes, name", [
    ({"output_dir": " "}, "output_dir"),
    ({"max_memory": "lots"}, "max_memory"),
    ({"bounds_m": [0.0, 0.0, 0.0, 0.1, 0.1]}, "bounds_m"),
    ({"bounds_m": [0.1, 0.0, 0.0, 0.0, 0.1, 0.1]}, "bounds_m"),
])
def test_parameters_that_cannot_make_a_scan_name_themselves(tmp_path, changes, name):
    with pytest.raises(ParameterError) as refused:
        open_scan(values(tmp_path, **changes))
    assert refused.value.name == name


def test_per_scan_settings_are_checked_when_set(tmp_path):
    check_scan_settings(values(tmp_path), 1 << 30)
    with pytest.raises(ParameterError, match="'resolution': refused: resolution 2048"):
        check_scan_settings(values(tmp_path, resolution=2048), 64 << 20)
    (tmp_path / "out" / "taken").mkdir(parents=True)
    with pytest.raises(ParameterError) as refused:
        check_scan_settings(values(tmp_path, scan_name="taken"), 1 << 30)
    assert refused.value.name == "scan_name"


def test_a_carving_request_is_refused_with_the_reason(tmp_path):
    own = values(tmp_path)
    assert carve_options(request(), own, 1 << 30).resolution is None   # the node's own
    assert carve_options(request(resolution=32), own, 1 << 30).resolution == 32
    with pytest.raises(ValueError, match="^request refused: .*mesher"):
        carve_options(request(mesher="clay"), own, 1 << 30)
    with pytest.raises(ValueError, match="^request refused: resolution 2048 is more than"):
        carve_options(request(resolution=2048), own, 64 << 20)
    # The node's own grid is never refused at request time: it was checked when set.
    assert carve_options(request(resolution=16), own, 1).resolution == 16
    assert scan_bounds(own).shape == (2, 3)
