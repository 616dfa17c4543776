"""The whole mock cell, small and fast, brought up for a test module.

:func:`running_cell` writes the repository's config with a small camera, fast
axes, a 64^3 grid and a 17-view plan, brings every node up with
:class:`sfs_ros.cli.bringup.Cell` in the test run's namespace (see
:mod:`ros_harness`), waits until :class:`CellClient` finds it ready, and on
exit stops the nodes with SIGINT and checks that each exited cleanly.
"""

import os
from contextlib import contextmanager
from pathlib import Path

import yaml

from sfs_ros.cell_logic.scan_plan import ScanPlan
from sfs_ros.cli.bringup import Cell, cell_nodes
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import carving_box
from sfs_ros.ros.cell_client import CellClient

from ros_harness import NAMESPACE, SOURCE_ROOT

CONFIG = Path(__file__).resolve().parent.parent / "config"
RINGS_DEG, PER_RING = [20.0, 55.0], 8
PLAN = ScanPlan.from_rings(RINGS_DEG, PER_RING, True)         # 17 views
RESOLUTION = 64
SCAN_TIMEOUT_S = 180.0

#: The small camera: the cell's rig, and the mock's world built the same.
SMALL_CAMERA = {"width": 320, "height": 240, "fx": 700.0, "fy": 700.0}
#: Values that differ from the repository's config files (a mapping in a value is merged
#: with the file's, as ``world_rig``).
OVERRIDES = {
    "rig.yaml": SMALL_CAMERA,
    "mock_hardware.yaml": {"max_speed_deg_s": [720.0, 360.0], "accel_deg_s2": [7200.0, 3600.0],
                           "homing_speed_deg_s": 600.0, "seed": 7, "world_rig": SMALL_CAMERA},
    "motor.yaml": {"status_rate_hz": 20.0, "reconnect_period_s": 0.5, "move_timeout_s": 5.0},
    "carving.yaml": {"resolution": RESOLUTION, "hull_rate_hz": 1.0,
                     "bounds_m": carving_box(make_object("mug")).ravel().tolist()},
    "scan.yaml": {"settle_samples": 2, "stall_s": 1.5, "move_timeout_s": 4.0, "move_retries": 1,
                  "capture_timeout_s": 3.0, "capture_retries": 1, "receipt_timeout_s": 3.0,
                  # Homing only bounded against a hang: under the load of two full suites
                  # at once the mock's homing call took over 20 s.
                  "home_timeout_s": 120.0},
}


#: Seconds the scan and motor nodes wait for what a fault would withhold (a frame, a move
#: settled, a receipt, a service's answer, the graph matched): bounds a hang only.
HANG_S = 120.0
#: The cell's fault deadlines at :data:`HANG_S`, for the modules that make no fault
#: (:data:`OVERRIDES`' are short, for ``test_cell``'s fault tests): under the load of two
#: test runs at once the shutter's answer has taken longer than 3 s twice in a row, and a
#: scan paused that no fault had stopped.
NO_FAULT = {"scan.yaml": {"move_timeout_s": HANG_S, "stall_s": HANG_S,
                          "capture_timeout_s": HANG_S, "receipt_timeout_s": HANG_S,
                          "service_timeout_s": HANG_S, "listen_timeout_s": HANG_S},
            "motor.yaml": {"move_timeout_s": HANG_S}}


def no_fault(more: dict | None = None) -> dict:
    """:data:`NO_FAULT` with ``more`` (same form) merged into it, file by file."""
    merged = {name: dict(values) for name, values in NO_FAULT.items()}
    for name, values in (more or {}).items():
        merged[name] = {**merged.get(name, {}), **values}
    return merged


def write_config(folder: Path, more: dict | None = None, *, plan: dict | None = None) -> Path:
    """The repository's config with :data:`OVERRIDES`, then ``more`` (same form), and the
    17-view plan (or ``plan``, a plan file's mapping)."""
    folder.mkdir()
    for path in CONFIG.glob("*.yaml"):
        data = yaml.safe_load(path.read_text())
        for changes in (OVERRIDES, more or {}):
            if path.name in changes:
                _merge(data["/**"]["ros__parameters"], changes[path.name])
        (folder / path.name).write_text(yaml.safe_dump(data))
    plan = plan or {"rings": {"phi_deg": RINGS_DEG, "per_ring": PER_RING, "top_view": True}}
    (folder / "scan_plan.yaml").write_text(yaml.safe_dump(plan))
    return folder


def _merge(values: dict, changes: dict) -> None:
    """Update ``values`` with ``changes``, merging a mapping into the mapping it replaces."""
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(values.get(key), dict):
            values[key] = {**values[key], **value}
        else:
            values[key] = value


@contextmanager
def running_cell(root: Path, client_name: str, overrides: dict | None = None, *,
                 plan: dict | None = None, camera_topic: str | None = None):
    """``{"cell": Cell, "client": CellClient, "output": Path, "log": Path}`` of a cell up in
    ``root`` (config: :func:`write_config` with ``overrides`` and ``plan``; ``camera_topic``:
    the frames of a driver on that topic, the mock's camera not started); the nodes are
    stopped (and checked to exit 0) when the block ends."""
    config = write_config(root / "config", overrides, plan=plan)
    output = root / "output"
    output.mkdir()
    log_path = root / "cell.log"
    env = dict(os.environ, PYTHONPATH=str(SOURCE_ROOT))
    with open(log_path, "w") as log:
        cell = Cell(cell_nodes(config, output, mock=True, camera_topic=camera_topic),
                    namespace=NAMESPACE, log=log,
                    env=env).start()
        client = CellClient(NAMESPACE, name=client_name)
        try:
            client.wait_ready(timeout_s=SCAN_TIMEOUT_S)     # six nodes' start-up, loaded
            yield {"cell": cell, "client": client, "output": output, "log": log_path}
        finally:
            client.close()
            codes = cell.stop()
    assert all(code == 0 for code in codes.values()), \
        f"nodes did not stop cleanly: {codes}\n{log_path.read_text()[-5000:]}"
    assert not (output / "ttyMOCK").exists()
