"""Every node's parameters are all in its config file, and the files start the node.

``config/*.yaml`` are what ``sfs-cell`` and the launch files give the nodes;
a parameter missing there is one a user does not see, a stale one a typo
the node silently ignores.
"""

from pathlib import Path

import pytest
import yaml

from sfs_ros.nodes import (
    calibration_node,
    camera_node,
    carving_node,
    meshing_node,
    mock_hardware_node,
    motor_node,
    recorder_node,
    scan_node,
    segmentation_node,
)
from sfs_ros.ros.rig_params import RIG_PARAMS

CONFIG = Path(__file__).resolve().parent.parent / "config"
RIG_NAMES = {p.name for p in RIG_PARAMS}

# (module, its config file): the rig parameters live in rig.yaml, the rest in the node's file.
NODES = [(camera_node, "camera.yaml"), (mock_hardware_node, "mock_hardware.yaml"),
         (motor_node, "motor.yaml"), (carving_node, "carving.yaml"),
         (meshing_node, "meshing.yaml"),
         (recorder_node, "recorder.yaml"), (scan_node, "scan.yaml"),
         (calibration_node, "calibration.yaml")]


def _values(name: str) -> dict:
    return yaml.safe_load((CONFIG / name).read_text())["/**"]["ros__parameters"]


def _flat(values: dict, prefix: str = "") -> dict:
    """``{name: value}`` with nested mappings as ROS names them (``world_rig.fx``)."""
    flat = {}
    for key, value in values.items():
        if isinstance(value, dict):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def test_rig_file_holds_exactly_the_rig_parameters():
    assert set(_values("rig.yaml")) == RIG_NAMES


@pytest.mark.parametrize("module, name", NODES, ids=[n for _, n in NODES])
def test_config_file_lists_every_parameter_of_its_node(module, name):
    own = {p.name for p in module.PARAMS} - RIG_NAMES
    assert set(_flat(_values(name))) == own


def test_the_mock_is_built_as_rig_yaml_says():
    # The mock's world (what it renders) is its own; by default the cell it simulates is the
    # one config/rig.yaml describes.
    assert _values("mock_hardware.yaml")["world_rig"] == _values("rig.yaml")


def test_segmentation_file_names_every_parameter():
    # Its segmentation parameters are commented out (the preset gives their defaults);
    # each still appears, with the built-in default.
    # The rig's image size comes from rig.yaml, as for every node that needs the rig.
    text = (CONFIG / "segmentation.yaml").read_text()
    for param in segmentation_node.PARAMS:
        assert (f" {param.name}:" in text) != (param.name in RIG_NAMES), param.name


def test_the_default_site_params_file_sets_nothing():
    # sfs-cell and the launch files give it to every node last: a site's own values go in a
    # file that replaces it, so by default it must change nothing.
    assert _values("overrides.yaml") == {}


def test_the_cell_benchmark_reads_the_config_folder(tmp_path):
    # bench.bench_cell runs the cell on a copy of this folder with its own plan and grid.
    from bench.bench_cell import _config

    merged = _config(tmp_path / "config", {"phi_deg": [30], "per_ring": 4}, 64)
    assert RIG_NAMES <= set(merged) and merged["resolution"] == 64
    assert {p.name for p in (tmp_path / "config").iterdir()} == \
        {p.name for p in CONFIG.glob("*.yaml")}
    plan = yaml.safe_load((tmp_path / "config" / "scan_plan.yaml").read_text())
    assert plan == {"rings": {"phi_deg": [30], "per_ring": 4}}
