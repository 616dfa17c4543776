"""End to end: a 72-view simulated scan through the cell's nodes, stage by stage.

The cell runs as in ``sfs-demo`` (mock hardware with its mock camera, motor,
scan, segmentation, carving and meshing nodes, each a separate process; the
repository's config: 640 x 480 camera, the mock axes' real speeds, 192^3),
with a plan of three rings of 24 views. An observer node in this process
sees each capture on ``capture/image`` and its receipt on ``capture/stored``,
and calls ``reconstruct`` the moment the last receipt arrives.

Stages (sums over the views, seconds): motion (command to settled, scan
node), capture (shutter call to frame in hand: rendering plus the frame's
trip), segmentation (segmentation node), storing and carving
(carving node), transport (capture seen to receipt, minus
segmentation and carving: the two hops and any queueing), meshing (the
``reconstruct`` call: the pipeline again on the stored masks, until the mesh
and its report are written), the latency from the last view (its capture seen
on ``capture/image``) to the mesh (the answer), from its receipt (stored) to
the mesh, and from the last view to the pictures (written after the answer).

The latency from the last view stored is split from the mesh's report: the last
receipt to the ``reconstruct`` call (the observer), the carving node's carve (its
stages), the meshing node's (the answer's ``seconds``: mesh, colour, checks, evaluation,
files) and the hand-over (the rest of the call: the carved scan's message both ways, the
transport, the answers). Beside it, the CPU time (user + system, from ``/proc``, 10 ms
steps) each node's process spent from the last receipt to the answer: on a busy machine
the wall times follow the load, the CPU the work.

Baselines, measured in the same run: the same views rendered, segmented,
carved and meshed in one process by the core pipeline, no ROS (the
``sfs-simulate`` path); and for the split, the cell's own work after the last view in
one process: :meth:`LiveReconstruction.reconstruct` on the masks the cell stored, the
renders as colour images, after a rehearsal. Ratio = baseline / cell. The notes give the
SHA-256 of both mesh files, to compare code on the same views.

Run: ``python -m bench.bench_cell`` (``--quick``: 24 views at 128^3).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

from sfs_ros.cell_logic.live_reconstruction import LiveReconstruction
from sfs_ros.cell_logic.message_fields import status_namespace
from sfs_ros.cell_logic.rehearsal import rehearse
from sfs_ros.cell_logic.scan_plan import ScanPlan
from sfs_ros.cli.bringup import Cell, cell_nodes
from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.synthetic import simulate_scan
from sfs_ros.ros.names import DIAGNOSTICS
from sfs_ros.ros.rig_params import RIG_PARAMS, rig_calibration

from .timing import main

CONFIG = Path(__file__).resolve().parent.parent / "config"
#: The report's stages made by the carving node (the rest by the meshing node).
CARVING_STAGES = ("segmentation", "bounds", "consensus", "fusion", "carving", "refinement",
                  "mesher_input")


def _config(folder: Path, rings: dict, resolution: int) -> dict:
    """The repository's config with the benchmark's plan and grid; the merged parameters."""
    folder.mkdir()
    merged = {}
    for path in CONFIG.glob("*.yaml"):
        data = yaml.safe_load(path.read_text())
        if path.name == "carving.yaml":
            data["/**"]["ros__parameters"]["resolution"] = resolution
        if path.name == "scan_plan.yaml":
            data = {"rings": rings}
        elif path.name != "mock_wrong_world.yaml" and "/**" in data:  # a node's parameters
            merged.update(data["/**"]["ros__parameters"])
        (folder / path.name).write_text(yaml.safe_dump(data))
    return merged


class Observer:
    """Times each capture and its receipt, and reconstructs when the last receipt is in."""

    def __init__(self, client, total: int):
        from sensor_msgs.msg import Image
        from std_msgs.msg import Header

        from sfs_ros.ros import capture_qos

        self.seen, self.receipted = {}, {}
        self.total = total
        self.all_in = threading.Event()
        qos = capture_qos(200)
        client.node.create_subscription(Image, "capture/image", self._on_capture, qos)
        client.node.create_subscription(Header, "capture/stored", self._on_receipt, qos)

    def _on_capture(self, msg) -> None:
        self.seen.setdefault((msg.header.stamp.sec, msg.header.stamp.nanosec), time.monotonic())

    def _on_receipt(self, msg) -> None:
        self.receipted.setdefault((msg.stamp.sec, msg.stamp.nanosec), time.monotonic())
        if len(self.receipted) >= self.total:
            self.all_in.set()

    def in_flight_s(self) -> float:
        """Capture seen to receipt, summed over the views."""
        return sum(self.receipted[s] - t for s, t in self.seen.items() if s in self.receipted)


def _cell_run(config: Path, output: Path, total: int) -> dict:
    from sfs_ros.ros.cell_client import CellClient, wait_for_pictures

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    namespace = f"/sfs_bench_{os.getpid()}"
    with open(output / "cell.log", "w") as log, \
            Cell(cell_nodes(config, output, mock=True), namespace=namespace, log=log) as cell, \
            CellClient(namespace, name="bench_observer") as client:
        observer = Observer(client, total)
        diagnostics = NodeDiagnostics(client)
        client.wait_ready(timeout_s=120.0)
        start = time.monotonic()
        scan = client.start_scan()
        if not observer.all_in.wait(timeout=1800.0):
            raise RuntimeError(f"only {len(observer.receipted)} of {total} views receipted")
        cpu_before = _cpu_by_node(cell)
        called = time.monotonic()
        summary = client.reconstruct(pictures=False)
        end = time.monotonic()
        cpu = {name: s - cpu_before[name] for name, s in _cpu_by_node(cell).items()}
        wait_for_pictures(summary, timeout_s=120.0)
        pictures_end = time.monotonic()
        client.wait_scan_done(scan, timeout_s=30.0)
        motion = diagnostics.value("scan", "motion_s")
        shutter = diagnostics.value("scan", "shutter_s")
        seg = diagnostics.value("segmentation", "segment_s")
        carve = diagnostics.value("carving", "carve_s")
    last_view = max(observer.seen.values())
    stages = json.loads(Path(summary["report_path"]).read_text())["timings_s"]
    carve_s = sum(v for k, v in stages.items() if k in CARVING_STAGES)
    return {"total_s": end - start, "latency_s": end - last_view,
            "stored_to_call_s": called - max(observer.receipted.values()),
            "carve_s": carve_s, "mesh_node_s": summary["seconds"],
            "colour_s": stages.get("colour", 0.0),
            "hand_over_s": end - called - carve_s - summary["seconds"],
            "session": summary["session_dir"],
            "stored_latency_s": end - max(observer.receipted.values()),
            "pictures_latency_s": pictures_end - last_view,
            "motion_s": motion, "capture_s": shutter,
            "segmentation_s": seg, "carving_s": carve,
            "transport_s": observer.in_flight_s() - seg - carve,
            "meshing_s": summary["seconds"], "views_used": summary["views_used"],
            "mesh_sha256": _sha256(summary["path"]),
            "cpu_carving_s": cpu["carving"], "cpu_meshing_s": cpu["meshing"],
            "cpu_cell_s": sum(cpu.values()), "cpu_by_node": cpu}


def _sha256(path: str) -> str:
    """The SHA-256 of the file at ``path``, hex (a mesh's bytes, to compare runs and code)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far, seconds (Linux ``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _cpu_by_node(cell) -> dict[str, float]:
    """{node name: CPU seconds so far} of the cell's processes."""
    return {name: _cpu_s(process.pid) for name, process in cell.processes.items()}


class NodeDiagnostics:
    """The latest diagnostics values of each of the cell's nodes, from one subscription kept
    for the run (destroying a subscription while the client spins races its callbacks)."""

    def __init__(self, client):
        from diagnostic_msgs.msg import DiagnosticArray

        self._namespace = client.node.get_namespace()
        self._values: dict[str, dict[str, str]] = {}
        self._changed = threading.Condition()
        client.node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on, 50)

    def _on(self, msg) -> None:
        with self._changed:
            for status in msg.status:
                if status_namespace(status.name) == self._namespace:
                    node = status.name.rsplit(": ", 1)[-1]
                    self._values.setdefault(node, {}).update(
                        {kv.key: kv.value for kv in status.values})
            self._changed.notify_all()

    def value(self, node: str, key: str, *, timeout_s: float = 5.0) -> float:
        """The latest ``key`` of the ``node``'s diagnostics published after the last call's
        value was read (waits up to ``timeout_s`` for a fresh one)."""
        with self._changed:
            self._values.pop(node, None)
            if not self._changed.wait_for(lambda: key in self._values.get(node, {}),
                                          timeout=timeout_s):
                raise RuntimeError(f"no diagnostics from the {node} node")
            return float(self._values[node][key])


def _cell_in_one_process(session: str, captures: list, rig, params: dict, resolution: int,
                         folder: Path) -> dict:
    """The cell's work after the last view in one process: the masks the cell stored (its
    session folder), with the baseline's renders as the colour images, received by a
    :class:`LiveReconstruction` after a rehearsal (as the nodes have); then its
    ``reconstruct`` timed, the carving and meshing halves of it apart."""
    folder.mkdir()
    rehearse(folder / "rehearsal")
    views = load_views(session).views
    if len(views) != len(captures):
        raise RuntimeError(f"the cell stored {len(views)} views, the plan has {len(captures)}")
    live = LiveReconstruction(rig, np.reshape(params["bounds_m"], (2, 3)), output_dir=folder,
                              resolution=resolution)
    for view, capture in zip(views, captures):
        mask = cv2.imread(str(view.image_path), cv2.IMREAD_GRAYSCALE) > 127
        live.add_view(view.name, mask, view.theta_rad, view.phi_rad)
        live.add_colour_image(view.name, capture.image)
    start, cpu_start = time.perf_counter(), time.process_time()
    summary = live.reconstruct(pictures=False)
    total, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    stages = json.loads(Path(summary["report_path"]).read_text())["timings_s"]
    carve_s = sum(v for k, v in stages.items() if k in CARVING_STAGES)
    return {"total_s": total, "carve_s": carve_s, "mesh_s": summary["seconds"] - carve_s,
            "colour_s": stages.get("colour", 0.0), "cpu_s": cpu,
            "mesh_sha256": _sha256(summary["path"])}


def _baseline(params: dict, plan: ScanPlan, resolution: int, folder: Path) -> dict:
    rig = rig_calibration({p.name: params[p.name] for p in RIG_PARAMS})
    mug = make_object(params["object"])
    start = time.perf_counter()
    captures = simulate_scan(mug, rig, plan.views, seed=0)
    render_s = time.perf_counter() - start
    box = params["bounds_m"]
    write_session(folder, [(c.name, c.image) for c in captures],
                  [(c.theta_rad, c.phi_rad) for c in captures], rig,
                  bounds_m=[box[:3], box[3:]])
    result = reconstruct(load_views(folder), ReconstructionParams(resolution=resolution))
    t = result.report["timings_s"]
    after_segmentation = sum(v for k, v in t.items() if k != "segmentation")
    return {"capture_s": render_s, "segmentation_s": t["segmentation"],
            "carving_s": t["carving"], "meshing_s": after_segmentation,
            "total_s": render_s + sum(t.values()), "captures": captures, "rig": rig}


def run(quick: bool = False) -> list[dict]:
    rings = ({"phi_deg": [20, 50], "per_ring": 12} if quick
             else {"phi_deg": [15, 40, 65], "per_ring": 24})
    resolution = 128 if quick else 192
    plan = ScanPlan.from_dict({"rings": rings})
    n = len(plan)
    with tempfile.TemporaryDirectory(prefix="sfs_bench_cell_") as tmp:
        root = Path(tmp)
        params = _config(root / "config", rings, resolution)
        (root / "output").mkdir()
        cell = _cell_run(root / "config", root / "output", n)
        base = _baseline(params, plan, resolution, root / "baseline")
        one = _cell_in_one_process(cell["session"], base["captures"], base["rig"], params,
                                   resolution, root / "one_process")
    label = f"cell, {n} views of {params['width']}x{params['height']} at {resolution}^3"

    def row(stage, ours, baseline=None):
        return {"name": f"{label}: {stage}", "seconds": ours, "baseline_seconds": baseline,
                "ratio": None if baseline is None else baseline / ours}

    notes = [f"cell: {cell['views_used']} of {n} views used; baselines are the in-process "
             "pipeline on the same views (rendering for capture; everything after "
             "segmentation for meshing and for the latency); the split's baselines are "
             "LiveReconstruction.reconstruct in one process on the masks the cell stored "
             "(the cell's work after the last view, no consensus, no ROS); the CPU rows' "
             "baseline is that call's CPU time (process_time)",
             "CPU from the last receipt to the mesh by process: " + ", ".join(
                 f"{name} {s:.2f} s" for name, s in cell["cpu_by_node"].items()),
             f"mesh SHA-256: cell {cell['mesh_sha256']}, in one process "
             f"{one['mesh_sha256']}",
             f"load average at the end: {os.getloadavg()[0]:.2f}"]
    return [
        row("end to end (start to mesh)", cell["total_s"], base["total_s"]),
        row("motion (move + settle)", cell["motion_s"]),
        row("capture (shutter to frame)", cell["capture_s"], base["capture_s"]),
        row("transport (2 hops + queueing)", cell["transport_s"]),
        row("segmentation", cell["segmentation_s"], base["segmentation_s"]),
        row("storing + carving, incremental", cell["carving_s"], base["carving_s"]),
        row("meshing (reconstruct service)", cell["meshing_s"], base["meshing_s"]),
        row("latency, last view to mesh", cell["latency_s"], base["meshing_s"]),
        row("latency, last view stored to mesh", cell["stored_latency_s"], base["meshing_s"]),
        row("stored to mesh, the same in one process", cell["stored_latency_s"],
            one["total_s"]),
        row(" split: last receipt to the call", cell["stored_to_call_s"]),
        row(" split: carving node's carve", cell["carve_s"], one["carve_s"]),
        row(" split: hand-over", cell["hand_over_s"]),
        row(" split: meshing node", cell["mesh_node_s"], one["mesh_s"]),
        row(" split: meshing node's colour", cell["colour_s"], one["colour_s"]),
        row("CPU from the last receipt to the mesh, carving + meshing nodes",
            cell["cpu_carving_s"] + cell["cpu_meshing_s"], one["cpu_s"]),
        row(" CPU: carving node", cell["cpu_carving_s"]),
        row(" CPU: meshing node", cell["cpu_meshing_s"]),
        row(" CPU: every process of the cell", cell["cpu_cell_s"]),
        {**row("latency, last view to pictures", cell["pictures_latency_s"]), "notes": notes},
    ]


if __name__ == "__main__":
    main(__doc__, run, quick_help="24 views at 128^3")
