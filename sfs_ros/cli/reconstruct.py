"""``sfs-reconstruct INPUT -o OUT.{ply,obj,stl,glb}``: images with cameras in, a mesh out.

INPUT is a scan session folder (``session.yaml`` + ``views.csv`` + images), a
Middlebury ``*_par.txt`` file, a NeRF-style ``transforms*.json``, or a rosbag2
recorded by ``sfs-recorder`` (its folder or its .mcap / .db3 file: the
recorded masks, rig, box, resolution and mesher, which options override). Beside the
mesh it writes ``OUT.report.json``: per-stage timings, views used and
rejected, per-view silhouette IoU and the mesh checks. On request it also
writes a PNG picture of the mesh, an HTML page that shows the mesh in any
browser, and a contact sheet of the views with their mask outlines, angles and
silhouette IoU.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..core.meshing.colour import vertex_colours
from ..core.pictures.contact_sheet import write_contact_sheet
from ..core.exchange.export import SUPPORTED_SUFFIXES, export_mesh
from ..core.pictures.html_viewer import write_html_viewer
from ..core.pipeline import MESHERS, ReconstructionParams, reconstruct
from ..core.pictures.preview import preview_image, write_png
from ..core.segment import PRESETS, SegmentationParams
from ..core.exchange.views import ViewSet, read_image
from .common import ACCEPTED_INPUTS, StageProgress, load_input, run_reporting_errors

PROG = "sfs-reconstruct"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("input", type=Path, help=ACCEPTED_INPUTS)
    p.add_argument("-o", "--output", type=Path, required=True,
                   help=f"mesh file, format from the suffix: {', '.join(SUPPORTED_SUFFIXES)}")
    size = p.add_mutually_exclusive_group()
    size.add_argument("-r", "--resolution", type=int,
                      help="voxels along the longest side of the bounding box (default: a "
                           "bag's recorded one, else 192)")
    size.add_argument("--voxel-size", type=float, metavar="METRES", help="voxel edge in metres")
    p.add_argument("-m", "--mesher", choices=MESHERS,
                   help="default: a bag's recorded one, else marching-cubes")
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
    p.add_argument("--threshold", type=float,
                   help="segment by this colour-distance threshold (the threshold method; "
                        "default: the graph cut, no threshold needed)")
    p.add_argument("--ignore-alpha", action="store_true",
                   help="segment the colours of images with an alpha channel (default: alpha is "
                        "the silhouette)")
    p.add_argument("--units", choices=("m", "mm"), default="m", help="units of the mesh file")
    p.add_argument("--colour", action="store_true",
                   help="colour the mesh's vertices from the images (the views that see each "
                        "point, blended); a bag's captured images colour it")
    p.add_argument("--preview", type=Path, metavar="PNG", help="also write a PNG picture of the mesh")
    p.add_argument("--html", type=Path, metavar="HTML",
                   help="also write a self-contained HTML page showing the mesh (orbit, zoom)")
    p.add_argument("--contact-sheet", type=Path, metavar="PNG",
                   help="also write a PNG of every view with its mask outline, angles and "
                        "silhouette IoU; bad and rejected views framed in red")
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
    if args.preset is None and args.threshold is None and not args.ignore_alpha:
        return None
    values = dict(PRESETS[args.preset]) if args.preset else dict(stored or {})
    if args.threshold is not None:
        values.update(method="threshold", threshold=args.threshold)
    if args.ignore_alpha:
        values["ignore_alpha"] = True
    return SegmentationParams.from_dict(values)


def _write_contact_sheet(path: Path, view_set: ViewSet, result) -> None:
    """Every view of ``view_set``, then those rejected while loading, with the report's
    silhouette IoU and rejection reasons and the masks the pipeline carved with."""
    report = result.report
    iou = {p["view"]: p["silhouette_iou"] for p in report["silhouette_iou"]["per_view"]}
    reason = {r["view"]: r["reason"] for r in report["views"]["rejected"]}
    images, masks = [], []
    for view in view_set.views:
        try:
            image = read_image(view.image_path,
                               expected_size=(view.camera.width, view.camera.height))
        except ValueError:
            image = None
        images.append(image)
        masks.append(result.masks.get(view.name))
        if view.name in reason:  # the tile names the view: shorter than the image's path
            reason[view.name] = reason[view.name].replace(str(view.image_path), view.name)
    names = [v.name for v in view_set.views] + [name for name, _ in view_set.rejected]
    extra = [None] * len(view_set.rejected)
    angles = [None if v.theta_rad is None else (v.theta_rad, v.phi_rad) for v in view_set.views]
    write_contact_sheet(path, images + extra, masks + extra, names, angles + extra,
                        [iou.get(n) for n in names], rejected=[reason.get(n) for n in names])


def run(args) -> dict:
    """Run one reconstruction from parsed arguments; returns the report."""
    suffix = args.output.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise ValueError(f"output {args.output} has an unsupported suffix {suffix!r}; "
                         f"expected one of {', '.join(SUPPORTED_SUFFIXES)}")
    if args.colour and suffix == ".stl":
        raise ValueError("--colour needs a format that stores vertex colours (.ply, .obj, "
                         ".glb); STL has none")
    view_set, recorded = load_input(args.input)
    # A bag's views are the recorded masks; its captured images colour the mesh.
    bag_images = load_input(args.input, captures=True)[0] if args.colour and recorded else None
    params = ReconstructionParams(
        resolution=args.resolution or recorded.get("resolution", 192),
        voxel_size_m=args.voxel_size, mesher=args.mesher or recorded.get("mesher", MESHERS[0]),
        block=args.block, bounds_m=None if args.bounds is None else (args.bounds[:3], args.bounds[3:]),
        max_misses=args.max_misses, check_consistency=not args.no_consistency_check,
        holdout=_holdout_names(args.holdout, [v.name for v in view_set.views]),
        segmentation=_segmentation(args, view_set.segmentation),
        colour=args.colour and bag_images is None)
    progress = StageProgress(quiet=args.quiet)
    try:
        result = reconstruct(view_set, params, progress=progress)
    finally:
        progress.close()
    colours = result.vertex_colors
    if bag_images is not None:
        colours = vertex_colours(result.vertices, result.faces,
                                 [read_image(v.image_path) for v in bag_images.views],
                                 [v.camera for v in bag_images.views]).colours
    args.output.parent.mkdir(parents=True, exist_ok=True)
    export_mesh(result.vertices, result.faces, args.output, vertex_colors=colours,
                units=args.units)
    report = {"output": str(args.output), "units": args.units, **result.report}
    if args.preview is not None:
        write_png(args.preview, preview_image(result.vertices, result.faces,
                                              vertex_colors=colours))
        report["preview"] = str(args.preview)
    if args.html is not None:
        args.html.parent.mkdir(parents=True, exist_ok=True)
        write_html_viewer(args.html, result.vertices, result.faces, vertex_colors=colours,
                          title=args.output.name)
        report["html"] = str(args.html)
    if args.contact_sheet is not None:
        args.contact_sheet.parent.mkdir(parents=True, exist_ok=True)
        _write_contact_sheet(args.contact_sheet, view_set, result)
        report["contact_sheet"] = str(args.contact_sheet)
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
