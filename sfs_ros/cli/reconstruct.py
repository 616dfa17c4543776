"""``sfs-reconstruct INPUT -o OUT.{ply,obj,stl,glb}``: images with cameras in, a mesh out.

INPUT is a scan session folder (``session.yaml`` + ``views.csv`` + images), a
Middlebury ``*_par.txt`` file, or a NeRF-style ``transforms*.json``. Beside the
mesh it writes ``OUT.report.json``: per-stage timings, views used and
rejected, per-view silhouette IoU and the mesh checks.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..core.export import SUPPORTED_SUFFIXES, export_mesh
from ..core.inputs import load_views
from ..core.pipeline import MESHERS, ReconstructionParams, reconstruct
from ..core.preview import preview_image, write_png
from ..core.segment import PRESETS, SegmentationParams
from .common import StageProgress, run_reporting_errors

PROG = "sfs-reconstruct"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("input", type=Path, help="session folder, Middlebury *_par.txt or transforms*.json")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help=f"mesh file, format from the suffix: {', '.join(SUPPORTED_SUFFIXES)}")
    size = p.add_mutually_exclusive_group()
    size.add_argument("-r", "--resolution", type=int, default=192,
                      help="voxels along the longest side of the bounding box (default 192)")
    size.add_argument("--voxel-size", type=float, metavar="METRES", help="voxel edge in metres")
    p.add_argument("-m", "--mesher", choices=MESHERS, default="marching-cubes")
    p.add_argument("--block", type=int, default=2, metavar="M",
                   help="cloud of points: one point per MxMxM block (advancing front; default 2)")
    p.add_argument("--holdout", default="", metavar="VIEWS",
                   help="comma-separated view names or 0-based indices kept out of carving "
                        "and used only to evaluate the mesh")
    p.add_argument("--bounds", type=float, nargs=6, metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="carving box in metres (default: the input's, else estimated)")
    p.add_argument("--max-misses", type=int, default=0, metavar="K",
                   help="keep voxels that fall outside at most K silhouettes (default 0)")
    p.add_argument("--no-consistency-check", action="store_true",
                   help="do not detect and drop views inconsistent with the others")
    p.add_argument("--preset", choices=sorted(PRESETS), help="segmentation preset")
    p.add_argument("--threshold", type=float, help="segmentation threshold (default automatic)")
    p.add_argument("--units", choices=("m", "mm"), default="m", help="units of the mesh file")
    p.add_argument("--preview", type=Path, metavar="PNG", help="also write a PNG picture of the mesh")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    return p


def _holdout_names(spec: str, names: list[str]) -> tuple[str, ...]:
    chosen = []
    for item in filter(None, (s.strip() for s in spec.split(","))):
        if item.isdigit():
            index = int(item)
            if index >= len(names):
                raise ValueError(f"--holdout index {index} is out of range: the input has "
                                 f"{len(names)} views (0..{len(names) - 1})")
            chosen.append(names[index])
        elif item in names:
            chosen.append(item)
        else:
            raise ValueError(f"--holdout view {item!r} is not in the input")
    return tuple(chosen)


def _segmentation(args, stored: dict | None) -> SegmentationParams | None:
    if args.preset is None and args.threshold is None:
        return None
    values = dict(PRESETS[args.preset]) if args.preset else dict(stored or {})
    if args.threshold is not None:
        values["threshold"] = args.threshold
    return SegmentationParams.from_dict(values)


def run(args) -> dict:
    """Run one reconstruction from parsed arguments; returns the report."""
    suffix = args.output.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise ValueError(f"output {args.output} has an unsupported suffix {suffix!r}; "
                         f"expected one of {', '.join(SUPPORTED_SUFFIXES)}")
    view_set = load_views(args.input)
    params = ReconstructionParams(
        resolution=args.resolution, voxel_size_m=args.voxel_size, mesher=args.mesher,
        block=args.block, bounds_m=None if args.bounds is None else (args.bounds[:3], args.bounds[3:]),
        max_misses=args.max_misses, check_consistency=not args.no_consistency_check,
        holdout=_holdout_names(args.holdout, [v.name for v in view_set.views]),
        segmentation=_segmentation(args, view_set.segmentation))
    progress = StageProgress(quiet=args.quiet)
    try:
        result = reconstruct(view_set, params, progress=progress)
    finally:
        progress.close()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    export_mesh(result.vertices, result.faces, args.output, units=args.units)
    report = {"output": str(args.output), "units": args.units, **result.report}
    if args.preview is not None:
        write_png(args.preview, preview_image(result.vertices, result.faces))
        report["preview"] = str(args.preview)
    report_path = args.output.with_name(args.output.stem + ".report.json")
    report_path.write_text(json.dumps(report, indent=2))
    return report


def summary(report: dict) -> str:
    """A few lines for the terminal."""
    mesh, views, iou = report["mesh"], report["views"], report["silhouette_iou"]
    lines = [f"mesh: {report['output']} ({mesh['n_vertices']} vertices, {mesh['n_faces']} faces, "
             f"watertight={mesh['watertight']}, outward={mesh['outward']})",
             f"views: {len(views['used'])} used, {len(views['held_out'])} held out, "
             f"{len(views['rejected'])} rejected"]
    for r in views["rejected"]:
        lines.append(f"  rejected {r['view']}: {r['reason']}")
    lines.append(f"silhouette IoU: mean {iou['mean_used']:.4f} over used views"
                 + (f", {iou['mean_held_out']:.4f} over held-out views"
                    if iou["mean_held_out"] is not None else ""))
    lines.append("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in report["timings_s"].items()))
    return "\n".join(lines)


def main(argv=None) -> int:
    status, report = run_reporting_errors(PROG, run, build_parser().parse_args(argv))
    if status:
        return status
    print(summary(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
