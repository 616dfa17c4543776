"""From the ``reconstruct`` answer to the ``mesh`` marker in a subscriber, on the mock mug.

The mock cell (the repository's config: 640 x 480 camera, 192^3 grid) with fast axes
and a 17-view plan scans the mug; an rclpy subscriber in this process takes ``mesh``
(reliable, transient local) and ``mesh_shape``. Then ``reconstruct`` is called and the
seconds from its answer to the marker's arrival are measured, with the marker's
triangles and serialised size, and the full mesh's faces.

Run: ``python -m bench.bench_mesh_message``.
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from pathlib import Path

import rclpy
import yaml
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message
from shape_msgs.msg import Mesh
from visualization_msgs.msg import Marker

from sfs_ros.cli.bringup import Cell, cell_nodes
from sfs_ros.ros import result_qos
from sfs_ros.ros.cell_client import CellClient

CONFIG = Path(__file__).resolve().parent.parent / "config"
NAMESPACE = "/bench_mesh"
FAST = {"meshing.yaml": {"display_triangles": int(os.environ.get("DISPLAY_TRIANGLES", "10000"))},
        "mock_hardware.yaml": {"max_speed_deg_s": [720.0, 360.0],
                               "accel_deg_s2": [7200.0, 3600.0], "homing_speed_deg_s": 600.0}}


def _config(folder: Path) -> Path:
    folder.mkdir()
    for path in CONFIG.glob("*.yaml"):
        data = yaml.safe_load(path.read_text())
        if path.name in FAST:
            data["/**"]["ros__parameters"].update(FAST[path.name])
        (folder / path.name).write_text(yaml.safe_dump(data))
    plan = {"rings": {"phi_deg": [20.0, 55.0], "per_ring": 8, "top_view": True}}
    (folder / "scan_plan.yaml").write_text(yaml.safe_dump(plan))
    return folder


def run() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        config, output = _config(Path(tmp) / "config"), Path(tmp) / "output"
        output.mkdir()
        with open(Path(tmp) / "cell.log", "w") as log:
            cell = Cell(cell_nodes(config, output, mock=True), namespace=NAMESPACE,
                        log=log).start()
            try:
                return _measure()
            finally:
                cell.stop()


def _measure() -> dict:
    rclpy.init()
    node = rclpy.create_node("bench_mesh_observer", namespace=NAMESPACE)
    arrived: list[tuple[float, Marker]] = []
    shapes: list[Mesh] = []
    node.create_subscription(Marker, "mesh", lambda m: arrived.append((time.monotonic(), m)),
                             result_qos())
    node.create_subscription(Mesh, "mesh_shape", shapes.append, result_qos())
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    with CellClient(NAMESPACE, name="bench_mesh_client") as client:
        client.wait_ready(timeout_s=300.0)
        client.wait_scan_done(client.start_scan(), timeout_s=600.0)
        arrived.clear()
        summary = client.reconstruct(pictures=False)
        answered = time.monotonic()
        deadline = answered + 120.0
        while not (arrived and shapes) and time.monotonic() < deadline:
            time.sleep(0.01)
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown()
    at, marker = arrived[0]
    return {"full_faces": summary["n_faces"], "marker_triangles": len(marker.points) // 3,
            "marker_mb": len(serialize_message(marker)) / 1e6,
            "answer_to_marker_s": at - answered}


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key}: {value:.3f}" if isinstance(value, float) else f"{key}: {value}")
