"""``sfs-demo``: a complete simulated scan through the cell's ROS 2 nodes.

Brings up the cell with the mock hardware (:mod:`sfs_ros.cli.bringup`:
mock controller + mock camera, motor, scan, segmentation and reconstruction
nodes, each a separate process), calls ``scan/start``, follows the scan
until every view is stored, calls ``reconstruct``, stops the cell, and
scores the mesh against the true shape of the object the mock camera
rendered. Writes into ``--out``::

    mesh.ply      the coloured mesh (a copy of the one the meshing node wrote)
    mesh.png      a picture of it
    mesh.html     a page that shows it in a browser
    views.png     a contact sheet of the views: mask outline, angles, silhouette IoU
    report.json   the reconstruct answer, the scan's figures, the score vs truth
    cell/         the nodes' output_dir: scan folders, meshes, reports, bags/ (the
                  session recorded as a rosbag2)
    cell.log      every node's output
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from ..core.exchange.export import load_mesh
from ..core.geometry.grid import VoxelGrid
from ..core.pipeline import ReconstructionParams, reconstruct
from ..core.simulation.objects import make_object
from ..core.simulation.synthetic import score_against_truth
from ..process import configure_process
from ..ros.cell_client import CellClient, ScanFailed
from ..ros.services import ServiceError
from .bringup import Cell, cell_nodes, default_config_dir
from .common import StageProgress, load_input

PROG = "sfs-demo"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--config", type=Path, default=None,
                   help="folder of the YAML parameter files (default: the installed ones)")
    p.add_argument("--timeout", type=float, default=1800.0, help="longest scan, seconds")
    return p


def _ros_parameters(path: Path) -> dict:
    return yaml.safe_load(path.read_text())["/**"]["ros__parameters"]


def run(args) -> dict:
    config = args.config or default_config_dir()
    out = args.out
    cell_dir = out / "cell"
    if cell_dir.exists():
        shutil.rmtree(cell_dir)                   # a demo run starts from scan_001
    cell_dir.mkdir(parents=True)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    specs = cell_nodes(config, cell_dir, mock=True, record=True)
    start = time.perf_counter()
    with open(out / "cell.log", "w") as log, Cell(specs, log=log) as cell, \
            CellClient(name="sfs_demo") as client:
        print(f"{PROG}: cell up ({', '.join(s.name for s in specs)}); log in {log.name}",
              file=sys.stderr)
        try:
            client.wait_ready(timeout_s=120.0)
            scan = client.start_scan()
            progress = StageProgress()
            status = client.wait_scan_done(
                scan, timeout_s=args.timeout,
                progress=lambda s: progress("scan", s.count("receipted") / s.count("total")))
            progress.close()
            scan_s = time.perf_counter() - start
            summary = client.reconstruct()
        except (ServiceError, ScanFailed, TimeoutError) as exc:
            ended = cell.exited()
            raise ValueError(f"{exc}" + (f" (nodes ended: {ended})" if ended else "")) from None
    mesh_path = out / f"mesh{Path(summary['path']).suffix}"
    shutil.copyfile(summary["path"], mesh_path)
    for key, name in (("preview_path", "mesh.png"), ("html_path", "mesh.html"),
                      ("contact_sheet_path", "views.png")):
        shutil.copyfile(summary[key], out / name)
    bags = sorted((cell_dir / "bags").glob("*/"))
    mock = _ros_parameters(config / "mock_hardware.yaml")
    own = _ros_parameters(config / "carving.yaml")
    obj = make_object(mock["object"])
    vertices, faces = load_mesh(mesh_path)
    box = [own["bounds_m"][:3], own["bounds_m"][3:]]
    truth = score_against_truth(obj, vertices, faces, VoxelGrid.cube(*box, own["resolution"]))
    replay = _replay(bags[-1], vertices, faces) if bags else None
    report = {"mesh": str(mesh_path), "picture": str(out / "mesh.png"),
              "viewer": str(out / "mesh.html"), "views": str(out / "views.png"),
              "bag": str(bags[-1]) if bags else None, "object": obj.name,
              "n_views": status.count("total"), "scan_seconds": scan_s,
              "total_seconds": time.perf_counter() - start, "scan": status.values,
              "reconstruct": summary, "ground_truth": truth, "bag_replay": replay}
    (out / "report.json").write_text(json.dumps(report, indent=2))
    return report


def _replay(bag: Path, vertices, faces) -> dict:
    """The recorded session reconstructed offline, as ``sfs-reconstruct BAG`` does, against
    the live mesh (read back from its file, float32 coordinates)."""
    views, recorded = load_input(bag)
    result = reconstruct(views, ReconstructionParams(**recorded))
    same = (result.faces.shape == faces.shape and np.array_equal(result.faces, faces)
            and np.allclose(result.vertices, vertices, rtol=0, atol=1e-7))
    return {"bag": str(bag), "views": len(views.views), "same_mesh": bool(same)}


def main(argv=None) -> int:
    configure_process()
    args = build_parser().parse_args(argv)
    try:
        report = run(args)
    except (ValueError, OSError) as exc:
        print(f"\n{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted", file=sys.stderr)
        return 130
    summary, truth = report["reconstruct"], report["ground_truth"]
    print(f"mesh: {report['mesh']} ({summary['n_vertices']} vertices, {summary['n_faces']} "
          f"faces, watertight={summary['watertight']}, coloured from "
          f"{summary['coloured_from_views']} views)")
    print(f"picture: {report['picture']}, viewer: {report['viewer']}, views: {report['views']}, "
          f"session bag: {report['bag']}")
    print(f"scan: {report['n_views']} views through the nodes in {report['scan_seconds']:.1f} s; "
          f"reconstruct {summary['seconds']:.1f} s; {summary['views_used']} views used")
    if report["bag_replay"] is not None:
        replay = report["bag_replay"]
        print(f"the recorded session ({replay['views']} views) reconstructed offline: "
              f"{'the same mesh' if replay['same_mesh'] else 'a DIFFERENT mesh'}")
    print(f"against the true {report['object']}: volume IoU {truth['volume_iou']:.4f}, "
          f"Chamfer {1000 * truth['chamfer_mean_m']:.3f} mm, "
          f"Hausdorff {1000 * truth['hausdorff_m']:.3f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
