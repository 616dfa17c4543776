"""``sfs-texture SESSION MESH -o OUT.{glb,obj}``: texture a given mesh from a scan's views.

MESH (.ply, .obj, .stl or .glb, as ``sfs-reconstruct`` writes them: metres, or ``--units
mm``) lies in the object frame of SESSION's views: a reconstruction cleaned up in another
tool, a refined mesh, a CAD model placed as the object stood on the turntable. Each face
takes its colour from the view that sees it best (unhidden by the mesh, frontal, near,
sharp; neighbours from the same view where quality allows), laid out in one atlas with
the views' exposures levelled along the seams: a textured .glb, or .obj with its .mtl and
.png. SESSION is anything ``sfs-reconstruct`` reads; a bag's captured images texture it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..process import configure_process

# The standard library alone at the top, as sfs-reconstruct (:mod:`sfs_ros.process`).
if TYPE_CHECKING:
    from ..core.texture.textured import TexturedMesh

PROG = "sfs-texture"


def build_parser() -> argparse.ArgumentParser:
    from ..core.exchange.export import SUPPORTED_SUFFIXES, TEXTURED_SUFFIXES
    from ..core.settings import MAX_COLOUR_VIEWS
    from .common import accepted_inputs

    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("session", type=Path, help=accepted_inputs())
    p.add_argument("mesh", type=Path,
                   help=f"the mesh to texture ({', '.join(SUPPORTED_SUFFIXES)}), in the "
                        "views' object frame")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help=f"textured mesh, format from the suffix: {' or '.join(TEXTURED_SUFFIXES)} "
                        "(.obj with its .mtl and .png beside it)")
    p.add_argument("--units", choices=("m", "mm"), default="m",
                   help="length unit of MESH and of an .obj output (default m; .glb is metres)")
    p.add_argument("--max-views", type=int, default=MAX_COLOUR_VIEWS, metavar="N",
                   help=f"texture from at most N views spread over the directions "
                        f"(default {MAX_COLOUR_VIEWS})")
    p.add_argument("--html", type=Path, metavar="HTML",
                   help="also write a self-contained HTML page showing the textured mesh")
    return p


def read_mesh(path: Path, units: str):
    """(vertices (n, 3) metres, faces (m, 3)) of the mesh file ``path``; ValueError naming
    the file when it cannot be read as a mesh or has no faces."""
    from ..core.exchange.export import SUPPORTED_SUFFIXES, load_mesh

    if not path.is_file():
        raise ValueError(f"mesh {path} is not a file")
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise ValueError(f"mesh {path} has the suffix {path.suffix!r}; expected one of "
                         f"{', '.join(SUPPORTED_SUFFIXES)}")
    try:
        vertices, faces = load_mesh(path, units=units)
    except Exception as exc:  # noqa: BLE001 - trimesh's readers raise many kinds on bad files
        raise ValueError(f"mesh {path} could not be read as a {path.suffix.lower()} mesh: "
                         f"{type(exc).__name__}: {exc}") from None
    if len(faces) == 0:
        raise ValueError(f"mesh {path} has no faces: a triangle mesh is needed, not a point "
                         "cloud")
    return vertices, faces


def write_textured(textured: TexturedMesh, output: Path, units: str, html: Path | None) -> list:
    """Write the textured mesh (and its viewer); returns the paths written."""
    from ..core.exchange.export import export_textured_mesh
    from ..core.pictures.html_viewer import write_html_viewer

    written = export_textured_mesh(textured, output, units=units)
    if html is not None:
        written.append(write_html_viewer(html, textured.vertices, textured.faces,
                                         vertex_colors=textured.vertex_colours(),
                                         uv=textured.uv, texture=textured.texture,
                                         title=output.name))
    return written


def run(args) -> dict:
    """Texture the mesh from parsed arguments; returns a summary (JSON-ready)."""
    from ..core.exchange.export import TEXTURED_SUFFIXES
    from ..core.texture import texture_from_views
    from .common import check_outputs, input_files, load_input

    suffix = args.output.suffix.lower()
    if suffix not in TEXTURED_SUFFIXES:
        raise ValueError(f"output {args.output} must end in {' or '.join(TEXTURED_SUFFIXES)}: "
                         "the formats that hold a texture")
    if suffix == ".glb" and args.units != "m":
        raise ValueError("a .glb is in metres by specification: --units mm needs an .obj output")
    if args.html is not None and args.html.suffix.lower() not in (".html", ".htm"):
        raise ValueError(f"--html {args.html} must end in .html or .htm")
    if args.max_views < 1:
        raise ValueError(f"--max-views must be >= 1, got {args.max_views}")
    vertices, faces = read_mesh(args.mesh, args.units)
    views, _ = load_input(args.session, captures=True)   # a bag: its images, not its masks
    outputs = {"-o": args.output, "--html": args.html}
    if suffix == ".obj":
        outputs |= {"the texture atlas": args.output.with_suffix(".png"),
                    "the material": args.output.with_suffix(".mtl")}
    check_outputs(outputs, [*input_files(args.session, views), args.mesh])
    start = time.perf_counter()
    textured = texture_from_views(views.views, vertices, faces, max_views=args.max_views)
    seconds = time.perf_counter() - start
    for path in [args.output, args.html]:
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
    written = write_textured(textured, args.output, args.units, args.html)
    return {"output": str(args.output), "files": [str(p) for p in written],
            "texture_s": seconds, **textured.stats}


def summary(report: dict) -> str:
    """A few lines for the terminal."""
    width, height = report["atlas_size"]
    return "\n".join([
        f"textured mesh: {report['output']} ({report['faces']} faces from {report['views']} "
        f"views, {report['unseen_faces']} seen by none)",
        f"atlas: {width} x {height} texels, {100 * report['atlas_use']:.0f} % used, "
        f"{report['charts']} charts, {report['seam_edges']} seam edges",
        f"time: {report['texture_s']:.2f} s ("
        + ", ".join(f"{k} {v:.2f} s" for k, v in report["seconds"].items()) + ")",
        "files: " + ", ".join(report["files"])])


def main(argv=None) -> int:
    configure_process()
    from .common import run_reporting_errors

    status, report = run_reporting_errors(PROG, run, build_parser().parse_args(argv))
    if status:
        return status
    print(summary(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
