"""``sfs-simulate``: a simulated scan written as a session folder, reconstructed in-process.

The quick way to a scan without ROS: renders a known object from a plan of
viewpoints on the upper hemisphere (each image tagged with the actual,
slightly-off angles), writes the scan as a session folder, reconstructs it
like ``sfs-reconstruct`` would, and writes the mesh, a PNG picture of it and
a report scored against the true shape.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..core.exchange.export import MESH_FORMATS, export_mesh
from ..core.exchange.inputs import load_views
from ..core.exchange.session import write_session
from ..core.geometry.rig import RigCalibration
from ..core.pictures.preview import preview_image, write_png
from ..core.pipeline import ReconstructionParams, reconstruct
from ..core.settings import RESOLUTION
from ..core.simulation.objects import (
    ALL_OBJECT_NAMES,
    CONCAVE_OBJECT_NAMES,
    DETAILED_OBJECT_NAMES,
    make_object,
)
from ..core.simulation.plan import ring_plan
from ..core.simulation.synthetic import carving_box, score_against_truth, simulate_scan
from ..process import configure_process
from .common import (
    StageProgress,
    accept_negative_numbers,
    add_mesher_options,
    add_setting,
    mesher_options,
    run_reporting_errors,
)
from .reconstruct import summary

PROG = "sfs-simulate"

#: The simulated camera: 640 x 480 pinhole, 0.6 m from the C-arm centre.
DEMO_RIG = RigCalibration(width=640, height=480, projection="pinhole", fx=1400.0, fy=1400.0,
                          camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))


def build_parser() -> argparse.ArgumentParser:
    from ..core.meshing.meshers import MESHER
    p = accept_negative_numbers(
        argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0]))
    p.add_argument("-o", "--out", type=Path, default=Path("out/simulate"), help="output folder")
    p.add_argument("--object", choices=ALL_OBJECT_NAMES, default="mug",
                   help=f"the object on the turntable; {', '.join(CONCAVE_OBJECT_NAMES)}: "
                        f"concavities no silhouette shows (see --textured and --refine); "
                        f"{', '.join(DETAILED_OBJECT_NAMES)}: thin parts and holes")
    p.add_argument("--textured", action="store_true",
                   help="paint the object with its fine solid colour texture, lit by a lamp "
                        "fixed in the lab (else a smooth pattern, lit from each camera)")
    p.add_argument("--refine", action="store_true",
                   help="refine the hull below itself from the views' colours, as "
                        "sfs-reconstruct does by default (slower; finds concavities in "
                        "textured renders)")
    p.add_argument("--rings", type=float, nargs="+", default=[5.0, 35.0, 65.0], metavar="PHI_DEG",
                   help="carriage elevations of the view rings, degrees")
    p.add_argument("--per-ring", type=int, default=24, help="turntable stops per ring")
    add_setting(p, RESOLUTION, "-r", default=RESOLUTION.cell_default,
                help=RESOLUTION.help(default=f"{RESOLUTION.cell_default}, the cell's"))
    add_setting(p, MESHER, "-m", default=MESHER.default, help=MESHER.help(default=MESHER.default))
    add_mesher_options(p)
    p.add_argument("--format", choices=[s[1:] for s in MESH_FORMATS], default="ply")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-q", "--quiet", action="store_true")
    return p


def run(args) -> dict:
    obj = make_object(args.object)
    plan = ring_plan(args.rings, args.per_ring, top_view=True)
    progress = StageProgress(quiet=args.quiet)
    progress("capture", 0.0)
    captures = simulate_scan(obj, DEMO_RIG, plan, seed=args.seed, textured=args.textured)
    progress("capture", 1.0)
    session = args.out / "session"
    write_session(session, [(c.name, c.image) for c in captures],
                  [(c.theta_rad, c.phi_rad) for c in captures], DEMO_RIG,
                  bounds_m=carving_box(obj))
    views = load_views(session)
    try:
        result = reconstruct(views,
                             ReconstructionParams(resolution=args.resolution, mesher=args.mesher,
                                                  mesher_options=mesher_options(args),
                                                  refine=args.refine),
                             progress=progress)
    finally:
        progress.close()
    mesh_path = export_mesh(result.vertices, result.faces, args.out / f"mesh.{args.format}")
    picture = write_png(args.out / "mesh.png", preview_image(result.vertices, result.faces))
    report = {"output": str(mesh_path), "preview": str(picture), "session": str(session),
              "object": args.object, **result.report,
              "ground_truth": score_against_truth(obj, result.vertices, result.faces, result.grid,
                                                  cameras=[v.camera for v in views.views])}
    (args.out / "report.json").write_text(json.dumps(report, indent=2))
    return report


def main(argv=None) -> int:
    configure_process(keep_freed_memory=True)   # as sfs-reconstruct
    status, report = run_reporting_errors(PROG, run, build_parser().parse_args(argv))
    if status:
        return status
    print(summary(report))
    truth = report["ground_truth"]
    print(f"against the true {report['object']}: volume IoU {truth['volume_iou']:.4f}, "
          f"Chamfer {1000 * truth['chamfer_mean_m']:.3f} mm, "
          f"Hausdorff {1000 * truth['hausdorff_m']:.3f} mm; silhouette IoU against the exact "
          f"silhouettes {truth['exact_silhouette_iou']['mean']:.4f} (worst view "
          f"{truth['exact_silhouette_iou']['min']:.4f}); Chamfer to the true visual hull "
          f"{1000 * truth['chamfer_to_true_hull_m']:.3f} mm")
    print(f"picture: {report['preview']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
