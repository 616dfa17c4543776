"""``sfs-reconstruct INPUT -o MESH``: images with cameras in, a mesh out.

INPUT is any input format (:data:`sfs_ros.core.exchange.inputs.INPUT_FORMATS`, the
list in ``doc/reference.md``), a rosbag2 recorded by ``sfs-recorder`` among them (its
recorded masks, rig, box, resolution and mesher, which options override); MESH's suffix
chooses its format (:data:`sfs_ros.core.exchange.export.MESH_FORMATS`). Beside the
mesh it writes ``OUT.report.json``: per-stage timings, views used and
rejected, per-view silhouette IoU and the mesh checks (and with ``--holdout`` and
``--texture`` or ``--colour``, the PSNR of the texture and of the vertex colours in the
held-out views). Where the views carry colour, the hull is refined below itself from the
colours (stage ``refinement``: what was removed, where and on how many views' evidence;
``--no-refine`` skips it; a bag's default is its live mesh, the hull, unless
``--refine``). On request it also
writes a PNG picture of the mesh, an HTML page that shows the mesh in any
browser, and a contact sheet of the views with their mask outlines, angles and
silhouette IoU.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..process import configure_process

# The standard library alone at the top: main() sets the process up before NumPy loads
# (:mod:`sfs_ros.process`), and the help loads no numba, SciPy, OpenCV or trimesh; each
# function imports what it uses.
if TYPE_CHECKING:
    from ..core.exchange.views import ViewSet
    from ..core.result_files import SheetViews
    from ..core.segmentation.segment import SegmentationParams

PROG = "sfs-reconstruct"


def build_parser() -> argparse.ArgumentParser:
    from ..core.exchange.export import MESH_FORMATS
    from ..core.meshing.meshers import MESHER
    from ..core.segmentation.presets import PRESETS
    from ..core.settings import BOUNDS_M, COLOUR, MAX_MEMORY, RESOLUTION
    from .common import accept_negative_numbers, accepted_inputs, add_mesher_options, add_setting

    p = accept_negative_numbers(
        argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0]))
    p.add_argument("input", type=Path, help=accepted_inputs())
    p.add_argument("-o", "--output", type=Path, required=True,
                   help=f"mesh file, format from the suffix: {', '.join(MESH_FORMATS)}")
    size = p.add_mutually_exclusive_group()
    add_setting(size, RESOLUTION, "-r")
    size.add_argument("--voxel-size", type=float, metavar="METRES", help="voxel edge in metres")
    add_setting(p, MAX_MEMORY)
    add_setting(p, MESHER, "-m")
    add_mesher_options(p)
    p.add_argument("--holdout", default="", metavar="VIEWS",
                   help="comma-separated view names or 0-based indices kept out of carving "
                        "and used only to evaluate the mesh")
    add_setting(p, BOUNDS_M, metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"))
    p.add_argument("--max-misses", type=int, default=0, metavar="K",
                   help="keep voxels that fall outside at most K silhouettes (default 0)")
    p.add_argument("--no-consistency-check", action="store_true",
                   help="do not detect and drop views inconsistent with the others")
    p.add_argument("--no-consensus", action="store_true",
                   help="do not re-segment the views with the hull of all views as a prior")
    p.add_argument("--preset", choices=sorted(PRESETS), help="segmentation preset")
    p.add_argument("--threshold", type=float,
                   help="segment by this colour-distance threshold (the threshold method; "
                        "default: the graph cut, no threshold needed)")
    p.add_argument("--ignore-alpha", action="store_true",
                   help="segment the colours of images with an alpha channel (default: alpha is "
                        "the silhouette)")
    p.add_argument("--units", choices=("m", "mm"), default="m", help="units of the mesh file")
    below = p.add_mutually_exclusive_group()
    below.add_argument("--no-refine", action="store_true",
                       help="keep the visual hull: skip the refinement below it (by default "
                            "the hull is carved where the colours of the views show empty "
                            "space, concavities no silhouette shows; views without colour "
                            "skip it)")
    below.add_argument("--refine", action="store_true",
                       help="refine a bag's hull too, from its captured images (a bag's "
                            "default is the live mesh: the hull its carving node made)")
    add_setting(p, COLOUR)
    p.add_argument("--texture", action="store_true",
                   help="texture the mesh from the images (each face from the view that sees "
                        "it best, an atlas, colours levelled along the seams): a textured .glb, "
                        "or .obj with its .mtl and .png; a bag's captured images texture it")
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
    from ..core.segmentation.presets import PRESETS
    from ..core.segmentation.segment import SegmentationParams

    if args.preset is None and args.threshold is None and not args.ignore_alpha:
        return None
    values = dict(PRESETS[args.preset]) if args.preset else dict(stored or {})
    if args.threshold is not None:
        values.update(method="threshold", threshold=args.threshold)
    if args.ignore_alpha:
        values["ignore_alpha"] = True
    return SegmentationParams.from_dict(values)


def _sheet_views(view_set: ViewSet, result) -> SheetViews:
    """Every view of ``view_set``, then those rejected while loading, with the masks the
    pipeline carved with; rejection reasons name the view rather than its image's path."""
    from ..core.exchange.views import read_image
    from ..core.result_files import SheetViews

    reasons = {r["view"]: r["reason"] for r in result.report["views"]["rejected"]}
    images, masks, short = [], [], {}
    for view in view_set.views:
        try:
            image = read_image(view.image_path,
                               expected_size=(view.camera.width, view.camera.height))
        except ValueError:
            image = None
        images.append(image)
        masks.append(result.masks.get(view.name))
        if view.name in reasons:  # the tile names the view: shorter than the image's path
            short[view.name] = reasons[view.name].replace(str(view.image_path), view.name)
    extra = [None] * len(view_set.rejected)
    angles = [None if v.theta_rad is None else (v.theta_rad, v.phi_rad) for v in view_set.views]
    return SheetViews(names=[v.name for v in view_set.views] + [n for n, _ in view_set.rejected],
                      images=images + extra, masks=masks + extra, angles_rad=angles + extra,
                      reasons=short)


def _by_view(captures: ViewSet, view_set: ViewSet) -> dict:
    """{name of a bag's view: path of its captured image} (``captures``: the bag's
    captured images, named by their keys): the bag's views are the recorded masks, named
    as the carving node stored them."""
    from ..core.exchange.session import view_key_of

    paths = {Path(v.name).stem: v.image_path for v in captures.views}
    return {v.name: paths[key] for v in view_set.views if (key := view_key_of(v.name)) in paths}


def run(args) -> dict:
    """Run one reconstruction from parsed arguments; returns the report."""
    from ..core.carving.resolution import parse_memory
    from ..core.exchange.export import MESH_FORMATS, TEXTURED_SUFFIXES
    from ..core.meshing.meshers import MESHER
    from ..core.pipeline import ReconstructionParams, reconstruct
    from ..core.result_files import report_path_for, write_result
    from ..core.texture import texture_reconstruction
    from ..core.texture.evaluation import held_out_colour_psnr
    from .common import StageProgress, check_outputs, input_files, load_input, mesher_options

    suffix = args.output.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise ValueError(f"output {args.output} has an unsupported suffix {suffix!r}; "
                         f"expected one of {', '.join(MESH_FORMATS)}")
    for option, path, suffixes in (("--preview", args.preview, (".png",)),
                                   ("--contact-sheet", args.contact_sheet, (".png",)),
                                   ("--html", args.html, (".html", ".htm"))):
        if path is not None and path.suffix.lower() not in suffixes:
            raise ValueError(f"{option} {path} must end in {' or '.join(suffixes)}: that is "
                             "the format written")
    if args.colour and not MESH_FORMATS[suffix].vertex_colours:
        holders = [s for s, f in MESH_FORMATS.items() if f.vertex_colours]
        raise ValueError(f"--colour needs a format that stores vertex colours "
                         f"({', '.join(holders)}); {MESH_FORMATS[suffix].name} has none")
    if args.texture and suffix not in TEXTURED_SUFFIXES:
        raise ValueError(f"--texture writes {' or '.join(TEXTURED_SUFFIXES)}, not {suffix}: "
                         f"{MESH_FORMATS[suffix].name} holds no texture (use --colour for "
                         "vertex colours)")
    view_set, recorded = load_input(args.input)
    check_outputs({"-o": args.output, "report": report_path_for(args.output),
                   "--preview": args.preview, "--html": args.html,
                   "--contact-sheet": args.contact_sheet,
                   **({"the texture atlas": args.output.with_suffix(".png"),
                       "the material": args.output.with_suffix(".mtl")}
                      if args.texture and suffix == ".obj" else {})},
                  input_files(args.input, view_set))
    # A bag's views are the recorded masks; its captured images colour the mesh (their
    # files live as long as ``captures``).
    refine = args.refine or not (args.no_refine or recorded)
    captures = (load_input(args.input, captures=True)[0]
                if (args.colour or args.texture or args.refine) and recorded else None)
    bag_images = None if captures is None else _by_view(captures, view_set)
    params = ReconstructionParams(
        resolution=recorded.get("resolution") if args.resolution is None else args.resolution,
        voxel_size_m=args.voxel_size,
        max_memory_bytes=None if args.max_memory is None else parse_memory(args.max_memory),
        mesher=args.mesher or recorded.get("mesher", MESHER.default),
        mesher_options=mesher_options(args),
        bounds_m=None if args.bounds is None else (args.bounds[:3], args.bounds[3:]),
        max_misses=args.max_misses, check_consistency=not args.no_consistency_check,
        consensus=not args.no_consensus,
        holdout=_holdout_names(args.holdout, [v.name for v in view_set.views]),
        segmentation=_segmentation(args, view_set.segmentation),
        colour=args.colour, refine=refine)
    progress = StageProgress(quiet=args.quiet)
    try:
        result = reconstruct(view_set, params, progress=progress, images=bag_images)
    finally:
        progress.close()
    textured = None
    if args.texture:
        start = time.perf_counter()
        textured = texture_reconstruction(view_set, result, images=bag_images)
        result.report["timings_s"]["texture"] = time.perf_counter() - start
    if args.texture or args.colour:
        colour_psnr = held_out_colour_psnr(view_set, result, textured, images=bag_images)
        if colour_psnr is not None:
            result.report["held_out_colour_psnr"] = colour_psnr
    written = write_result(
        result, args.output, units=args.units, vertex_colors=result.vertex_colors,
        textured=textured,
        preview=args.preview, html=args.html, contact_sheet=args.contact_sheet,
        sheet_views=None if args.contact_sheet is None else _sheet_views(view_set, result))
    return written.document


def _refinement_line(refinement: dict, seconds: float) -> str:
    """What the refinement below the hull did, in one line (``report["refinement"]``)."""
    from .common import one_line

    if not refinement["applied"]:
        return f"refinement below the hull: skipped, {one_line(refinement['reason'])}"
    box = refinement["removed_box_m"]
    where = ("" if box is None else " within x {:.1f}..{:.1f}, y {:.1f}..{:.1f}, "
             "z {:.1f}..{:.1f} mm".format(*(1e3 * box[end][axis] for axis in range(3)
                                             for end in (0, 1))))
    return (f"refinement below the hull ({seconds:.2f} s): removed "
            f"{100 * refinement['removed_fraction_of_hull']:.1f} % of the hull, "
            f"{refinement['removed_volume_m3'] * 1e6:.1f} cm^3{where}, each voxel on the "
            f"evidence of {refinement['mean_votes_removed']:.1f} views on average")


def summary(report: dict) -> str:
    """A few lines for the terminal."""
    from .common import one_line

    mesh, views, iou = report["mesh"], report["views"], report["silhouette_iou"]
    lines = [f"mesh: {report['output']} ({mesh['n_vertices']} vertices, {mesh['n_faces']} faces, "
             f"watertight={mesh['watertight']}, outward={mesh['outward']})",
             f"views: {len(views['used'])} used, {len(views['held_out'])} held out, "
             f"{len(views['rejected'])} rejected"]
    for r in views["rejected"]:
        lines.append(f"  rejected {one_line(r['view'], 80)}: {one_line(r['reason'])}")
    lines.append(f"agreement with its own masks (not accuracy): silhouette IoU "
                 f"{iou['mean_used']:.4f} over the views carved with"
                 + (f"; leave-one-out: {iou['mean_held_out']:.4f} over held-out views"
                    if iou["mean_held_out"] is not None else ""))
    refinement = report.get("refinement")
    if refinement:
        lines.append(_refinement_line(refinement, report["timings_s"].get("refinement", 0.0)))
    colour = report.get("held_out_colour_psnr")
    if colour is not None:
        shown = [f"{name} {colour[key]:.2f} dB" for name, key in
                 (("texture", "texture_db"), ("vertex colours", "vertex_colours_db"))
                 if colour[key] is not None]
        lines.append(f"colour in {len(colour['views'])} held-out views (PSNR inside their "
                     f"silhouettes): " + ", ".join(shown))
    lines.append("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in report["timings_s"].items()))
    return "\n".join(lines)


def main(argv=None) -> int:
    # The pipeline allocates and frees large arrays stage after stage: kept by malloc, they
    # are not faulted in again each time (doc/changelog.md, 4 December, evening).
    configure_process(keep_freed_memory=True)
    from .common import run_reporting_errors

    status, text = run_reporting_errors(PROG, lambda args: summary(run(args)),
                                        build_parser().parse_args(argv))
    if status:
        return status
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
