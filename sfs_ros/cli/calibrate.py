"""``sfs-calibrate``: calibrate the cell from photographs of a ChArUco board on the turntable.

    sfs-calibrate INPUT -o OUTDIR [--board 7x5] [--square-m 0.03] [--marker-m 0.022]
                  [--dictionary DICT_5X5_100] [--radial-terms 2] [--max-view-rms-px 1.0]
                  [--apply [--namespace /sfs]]

INPUT is a session folder (``session.yaml`` + ``views.csv`` with
``image,theta_rad,phi_rad`` + ``images/``) of the board standing on the
plate, photographed at a spread of turntable and carriage angles, or a
rosbag2 the recorder made of such a scan (its captured images with their
joint states); its ``rig`` (a bag's: the carving node's) is the
hand-measured start. OUTDIR receives ``rig.yaml`` (the cell's rig
parameters, for ``--params-file``), ``camera_info.yaml`` (ROS
camera_calibration_parsers format) and ``calibration_report.yaml`` (RMS and
per-view residuals, uncertainties, rejected views, fixed parameters).
``--apply`` then sets ``rig.yaml`` on the running cell in ``--namespace``
and keeps it there for restarts (:func:`sfs_ros.ros.rig_apply.apply_rig`).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..core.calibration import (
    BoardSpec,
    calibrate_views,
    camera_info_yaml,
    rig_yaml,
    yaml_document,
)
from ..core.exchange.files import write_atomic_all
from ..process import configure_process
from ..ros.names import NAMESPACE
from ..ros.params_file import check_params_file
from .common import load_input, run_reporting_errors

PROG = "sfs-calibrate"


def _squares(text: str) -> tuple[int, int]:
    try:
        x, y = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not COLUMNSxROWS, e.g. 7x5") from None
    return x, y


def build_parser() -> argparse.ArgumentParser:
    board = BoardSpec()
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("input", type=Path, help="session folder of board photographs with angles, "
                   "or a recorded bag of a board scan")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUTDIR",
                   help="folder for rig.yaml, camera_info.yaml and calibration_report.yaml")
    p.add_argument("--board", type=_squares, default=f"{board.squares_x}x{board.squares_y}",
                   metavar="XxY", help="chessboard squares, columns x rows (default %(default)s)")
    p.add_argument("--square-m", type=float, default=board.square_m,
                   help="square side, metres (default %(default)s)")
    p.add_argument("--marker-m", type=float, default=board.marker_m,
                   help="marker side, metres (default %(default)s)")
    p.add_argument("--dictionary", default=board.dictionary,
                   help="ArUco dictionary (default %(default)s)")
    p.add_argument("--radial-terms", type=int, choices=(2, 3), default=2,
                   help="radial distortion terms: 2 holds k3 at 0 (default), 3 fits it")
    p.add_argument("--max-view-rms-px", type=float, default=1.0,
                   help="reject a view whose corners miss by more than this RMS, pixels "
                        "(default %(default)s)")
    p.add_argument("--camera-name", default="camera", help="camera_name in camera_info.yaml")
    p.add_argument("--apply", action="store_true",
                   help="then set rig.yaml on every node of the running cell that holds the rig "
                        "(between scans) and keep it in the cell's output folder for restarts")
    p.add_argument("--namespace", default=NAMESPACE,
                   help=f"--apply: the cell's ROS namespace (default {NAMESPACE})")
    return p


def run(args) -> dict:
    board = BoardSpec(*args.board, square_m=args.square_m, marker_m=args.marker_m,
                      dictionary=args.dictionary)
    views = load_input(args.input, captures=True)[0]
    fit = calibrate_views(views, board, radial_terms=args.radial_terms,
                          max_view_rms_px=args.max_view_rms_px)
    header = (f"Calibrated by {PROG} from {args.input.name}: {len(fit.view_rms_px)} views, "
              f"{fit.corners} corners, RMS {fit.rms_px:.3f} px")
    report = {"rms_px": fit.rms_px, "corners": fit.corners, "view_rms_px": fit.view_rms_px,
              "rejected": {name: reason for name, reason in fit.rejected},
              "uncertainty": fit.uncertainty, "fixed": fit.fixed,
              "board_pose": {"tilt_x_rad": float(fit.board.tilt_x_rad),
                             "tilt_y_rad": float(fit.board.tilt_y_rad),
                             "offset_m": [float(v) for v in fit.board.offset_m]}}
    _write(args.output, {
        "camera_info.yaml": camera_info_yaml(fit.rig, camera_name=args.camera_name,
                                             header=header),
        "calibration_report.yaml": yaml_document(report, what="calibration_report.yaml"),
        "rig.yaml": rig_yaml(fit.rig, header=header)})
    applied = _apply(args.output / "rig.yaml", args.namespace) if args.apply else None
    return {"fit": fit, "output": args.output, "applied": applied}


def _write(output: Path, files: dict[str, bytes]) -> None:
    """Write ``files`` ({name: text}) into ``output`` (created if needed), each atomically,
    ``rig.yaml`` last, once every text reads back (``rig.yaml`` also by rcl): a link
    in their place is replaced, not followed, and a failure leaves the old files whole."""
    check_params_file(files["rig.yaml"], "rig.yaml")
    output.mkdir(parents=True, exist_ok=True)
    write_atomic_all([(output / name, data) for name, data in files.items()], within=output)


def _apply(path: Path, namespace: str):
    """Set ``path`` on the running cell in ``namespace`` (:func:`apply_rig`); what it did."""
    from ..ros.cell_client import CellClient
    from ..ros.rig_apply import apply_rig

    with CellClient(namespace, name="sfs_calibrate") as cell:
        return apply_rig(cell.node, path)


def main(argv=None) -> int:
    configure_process()
    status, result = run_reporting_errors(PROG, run, build_parser().parse_args(argv))
    if status:
        return status
    fit, rig = result["fit"], result["fit"].rig
    print(f"{len(fit.view_rms_px)} views, {fit.corners} corners: RMS {fit.rms_px:.3f} px; "
          f"f = ({rig.fx:.1f}, {rig.fy:.1f}) px, c = ({rig.K[0, 2]:.1f}, {rig.K[1, 2]:.1f}) px, "
          f"k1 {rig.distortion[0]:.4f}, "
          f"axis at ({1000 * rig.axis_point_m[0]:.2f}, {1000 * rig.axis_point_m[1]:.2f}) mm "
          f"tilted {math.degrees(rig.axis_tilt_y_rad):.3f} deg, zeros theta "
          f"{math.degrees(rig.theta_zero_rad):.3f} deg, phi {math.degrees(rig.phi_zero_rad):.3f} "
          f"deg")
    for name, reason in fit.rejected:
        print(f"rejected {name}: {reason}")
    print(f"wrote {result['output']}/rig.yaml, camera_info.yaml, calibration_report.yaml")
    applied = result["applied"]
    if applied is not None:
        print(f"applied to {', '.join(applied.nodes)} (from their next scan); kept in "
              f"{applied.persisted} for restarts")
    return 0


if __name__ == "__main__":
    sys.exit(main())
