"""``sfs-export``: a scan's views and camera poses for other tools.

    sfs-export INPUT [--session DIR] [--colmap DIR] [--nerf FILE]

INPUT is anything ``sfs-reconstruct`` reads (a session folder, a Middlebury
``*_par.txt``, a NeRF ``transforms*.json``, a rosbag2 of a scan). ``--session`` writes a plain
session folder (images + the view table), ``--colmap`` COLMAP's text model
(``cameras.txt``, ``images.txt``, ``points3D.txt``), ``--nerf`` a
``transforms.json`` (:mod:`sfs_ros.core.exchange.pose_export`). With ``--session``
too, the COLMAP and NeRF files refer to the exported images.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..process import configure_process

PROG = "sfs-export"


def build_parser() -> argparse.ArgumentParser:
    from .common import accepted_inputs

    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("input", type=Path, help=accepted_inputs())
    p.add_argument("--session", type=Path, metavar="DIR", help="plain session folder to write")
    p.add_argument("--colmap", type=Path, metavar="DIR", help="COLMAP text model folder")
    p.add_argument("--nerf", type=Path, metavar="FILE", help="transforms.json to write")
    return p


def run(args) -> dict:
    # Here, not at the top: NumPy loads after main() set the process up, and the help loads
    # no writers (SciPy).
    from ..core.exchange.pose_export import export_session, write_colmap, write_nerf_transforms
    from ..core.exchange.session import IMAGES_DIR, read_session
    from .common import check_outputs, input_files, load_input

    if not (args.session or args.colmap or args.nerf):
        raise ValueError("nothing to do: give --session, --colmap and/or --nerf")
    views, _ = load_input(args.input, captures=True)     # a bag: its images, not its masks
    check_outputs({"--session/": args.session, "--colmap/": args.colmap, "--nerf": args.nerf},
                  input_files(args.input, views))
    written = {}
    image_root = None
    if args.session:
        written["session"] = str(export_session(views, args.session))
        views = read_session(args.session)            # the exported images, by their names
        image_root = args.session / IMAGES_DIR
    if args.colmap:
        written["colmap"] = str(write_colmap(views, args.colmap))
    if args.nerf:
        written["nerf"] = str(write_nerf_transforms(views, args.nerf, image_root=image_root))
    return {"views": len(views.views), **written}


def main(argv=None) -> int:
    configure_process()
    from .common import run_reporting_errors

    status, result = run_reporting_errors(PROG, run, build_parser().parse_args(argv))
    if status:
        return status
    print(f"{result.pop('views')} views exported: "
          + ", ".join(f"{k} {v}" for k, v in result.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
