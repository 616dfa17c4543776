"""``sfs-cell``: bring up the whole cell, each node a separate process, until Ctrl-C.

    sfs-cell --mock -o out/cell          # simulated hardware
    sfs-cell -o /data/scans              # the real camera and motor controller

The nodes read the YAML files of ``--config`` (default: the installed
``share/sfs_ros/config``); files and meshes go to ``--output-dir``. Then,
from another terminal or a program: ``scan/start``, and ``reconstruct``
once the scan is done (see the README). Ctrl-C (SIGINT) or SIGTERM stops
the nodes, the last started first. A node that ends by itself is started
again after a back-off (0.5 s, doubling up to 30 s); one that ends five times
within two minutes stops the cell with exit status 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .bringup import Cell, cell_nodes, default_config_dir, wait_until_signal

PROG = "sfs-cell"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--mock", action="store_true",
                   help="simulated controller and camera instead of the real hardware")
    p.add_argument("-o", "--output-dir", type=Path, required=True,
                   help="folder of the scans, meshes and reports")
    p.add_argument("--config", type=Path, default=None,
                   help="folder of the YAML parameter files (default: the installed ones)")
    p.add_argument("--namespace", default="", help="ROS namespace of all nodes")
    p.add_argument("--record", action="store_true",
                   help="record every scan as a rosbag2 in OUTPUT_DIR/bags (the recorder "
                        "also takes record/start and record/stop at any time)")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config = args.config or default_config_dir()
        args.output_dir.mkdir(parents=True, exist_ok=True)
        specs = cell_nodes(config, args.output_dir, mock=args.mock, record=args.record)
    except (FileNotFoundError, OSError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    print(f"{PROG}: starting {', '.join(s.name for s in specs)} (config {config}); "
          "Ctrl-C stops", flush=True)
    return wait_until_signal(Cell(specs, namespace=args.namespace).start())


if __name__ == "__main__":
    sys.exit(main())
