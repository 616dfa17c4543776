"""Soak: many mock scans in a row in one cell; nothing may grow.

The cell runs as ``sfs-cell --mock --record`` (each node a process, a bag per
scan) with a small plan (one ring of 8 views, 64^3, a 320 x 240 camera, fast
axes) so that scans are quick. After a warm-up scan,
every scan is started, followed to the end and reconstructed, and after each
one the script reads, for every node process, its resident memory, open file
descriptors and threads (``/proc``), and the ``/dev/shm`` files the nodes map
or hold open (Fast DDS shared memory). It prints a line per scan and, at the end, the growth of each
figure from the warm-up to the last scan, per scan.

Run: ``python -m bench.soak [--scans 50]``. Growth that is not zero for fds,
threads and ``/dev/shm`` files, or memory rising steadily rather than settling,
is a leak: the growth over the second half of the run is printed apart, as the
steady rate. ``/dev/shm`` counts only the segments the cell's processes map;
Fast DDS maps those of other participants it discovers on the machine too,
so a count that rises and falls back while other ROS programs run is not the
cell's.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import yaml

from sfs_ros.cli.bringup import Cell, cell_nodes

CONFIG = Path(__file__).resolve().parent.parent / "config"
#: Values that differ from the repository's config: a small camera and grid, fast axes.
_CAMERA = {"width": 320, "height": 240, "fx": 700.0, "fy": 700.0}
_SMALL = {"rig.yaml": _CAMERA,
          "mock_hardware.yaml": {"max_speed_deg_s": [720.0, 360.0],
                                 "accel_deg_s2": [7200.0, 3600.0], "homing_speed_deg_s": 600.0},
          "carving.yaml": {"resolution": 64}}


def _small_config(folder: Path) -> Path:
    folder.mkdir()
    for path in CONFIG.glob("*.yaml"):
        data = yaml.safe_load(path.read_text())
        if path.name in _SMALL:
            data["/**"]["ros__parameters"].update(_SMALL[path.name])
        if path.name == "mock_hardware.yaml":      # the mock's world: the same camera
            data["/**"]["ros__parameters"]["world_rig"].update(_CAMERA)
        if path.name == "scan_plan.yaml":
            data = {"rings": {"phi_deg": [35], "per_ring": 8, "top_view": False}}
        (folder / path.name).write_text(yaml.safe_dump(data))
    return folder


def _proc(pid: int) -> dict:
    """Resident memory (MiB), open fds and threads of process ``pid``."""
    status = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text()
                  .splitlines() if ":" in line)
    return {"rss_mib": int(status["VmRSS"].split()[0]) / 1024,
            "fds": len(os.listdir(f"/proc/{pid}/fd")), "threads": int(status["Threads"])}


def _shm(pids: list[int]) -> tuple[int, float]:
    """Files in ``/dev/shm`` that the processes ``pids`` map or hold open: count and MiB
    (only the cell's own, whatever else runs on the machine)."""
    paths = set()
    for pid in pids:
        try:
            maps = Path(f"/proc/{pid}/maps").read_text()
            fds = [os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")]
        except OSError:  # the process ended meanwhile
            continue
        paths.update(line.split(maxsplit=5)[-1] for line in maps.splitlines()
                     if "/dev/shm/" in line)
        paths.update(f for f in fds if f.startswith("/dev/shm/"))
    sizes = [os.stat(p).st_size for p in paths if os.path.exists(p)]
    return len(sizes), sum(sizes) / 2**20


def sample(cell: Cell) -> dict:
    live = {name: p.pid for name, p in cell.processes.items() if p.poll() is None}
    nodes = {name: _proc(pid) for name, pid in live.items()}
    shm_files, shm_mib = _shm(list(live.values()))
    return {"nodes": nodes, "shm_files": shm_files, "shm_mib": shm_mib}


def _table(samples: list[dict]) -> None:
    """Per node, RSS (MiB), fds and threads after the first, the middle and the last scan
    (scan 0 is the warm-up); then /dev/shm."""
    last = len(samples) - 1
    picks = sorted({min(1, last), max(1, last // 2), last})
    print("\n| node | " + " | ".join(f"scan {n}: RSS MiB, fds, threads" for n in picks) + " |")
    print("|---|" + "---|" * len(picks))
    for name in samples[0]["nodes"]:
        cells = []
        for n in picks:
            v = samples[n]["nodes"].get(name)
            cells.append("ended" if v is None
                         else f"{v['rss_mib']:.1f}, {v['fds']}, {v['threads']}")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("| /dev/shm | " + " | ".join(f"{samples[n]['shm_files']} files, "
                                       f"{samples[n]['shm_mib']:.1f} MiB" for n in picks) + " |")


def _growth(samples: list[dict], since: int, label: str) -> None:
    """Per node, what grew from ``samples[since]`` to the last one, in total and per scan."""
    first, last = samples[since], samples[-1]
    scans = max(1, len(samples) - 1 - since)
    print(f"\ngrowth {label} to scan {len(samples) - 1}, per node (total, per scan):")
    for name in first["nodes"]:
        a, b = first["nodes"][name], last["nodes"].get(name)
        if b is None:
            print(f"  {name:15s} ended during the soak")
            continue
        print(f"  {name:15s} rss {b['rss_mib'] - a['rss_mib']:+7.1f} MiB "
              f"({(b['rss_mib'] - a['rss_mib']) / scans:+.2f}/scan), fds {b['fds'] - a['fds']:+d}, "
              f"threads {b['threads'] - a['threads']:+d}")
    print(f"  /dev/shm        files {last['shm_files'] - first['shm_files']:+d}, "
          f"{last['shm_mib'] - first['shm_mib']:+.1f} MiB")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scans", type=int, default=50)
    args = parser.parse_args(argv)
    from sfs_ros.ros.cell_client import CellClient

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    namespace = f"/sfs_soak_{os.getpid()}"
    with tempfile.TemporaryDirectory() as tmp:
        config = _small_config(Path(tmp) / "config")
        output = Path(tmp) / "cell"
        output.mkdir()
        with open(output / "cell.log", "w") as log, \
                Cell(cell_nodes(config, output, mock=True, record=True), namespace=namespace,
                     log=log) as cell, CellClient(namespace, name="soak") as client:
            client.wait_ready(timeout_s=180.0)
            samples = []
            for n in range(args.scans + 1):       # scan 0 warms up
                start = time.monotonic()
                scan = client.start_scan()
                client.wait_scan_done(scan, timeout_s=600.0)
                client.reconstruct()
                samples.append(sample(cell))
                s = samples[-1]
                print(f"scan {n:3d}: {time.monotonic() - start:5.1f} s, "
                      f"rss {sum(v['rss_mib'] for v in s['nodes'].values()):7.1f} MiB, "
                      f"fds {sum(v['fds'] for v in s['nodes'].values()):4d}, "
                      f"threads {sum(v['threads'] for v in s['nodes'].values()):4d}, "
                      f"/dev/shm {s['shm_files']} files {s['shm_mib']:.1f} MiB", flush=True)
    _table(samples)
    middle = len(samples) // 2
    _growth(samples, 0, "from the warm-up scan")
    _growth(samples, middle, f"from scan {middle} (the second half: the steady rate)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
