"""``sfs-ctl``: drive a running cell from the command line, without ros2cli.

    sfs-ctl [--namespace NS] scan [--plan FILE] [--name NAME] [--object board] [--wait]
    sfs-ctl calibrate [--plan FILE] [--apply] [--wait]
    sfs-ctl rig apply FILE
    sfs-ctl cancel | home | status [--follow]
    sfs-ctl reconstruct [--resolution N] [--mesher M] [--output NAME] [--no-colour] [--texture]
                        [--refine] [--wait-pictures]
    sfs-ctl param get NODE NAME | param set NODE NAME VALUE

Through the typed interfaces (:class:`sfs_ros.ros.cell_client.CellClient`): ``scan``
sends a Scan goal (``--wait``: prints each feedback line until the result; Ctrl-C cancels
the goal), ``calibrate`` sends a Calibrate goal to the calibration node (``--wait``: its
feedback lines, then the result; Ctrl-C cancels it), ``rig apply`` sets a calibration's
``rig.yaml`` on every node of the running cell that holds the rig and keeps it for
restarts (:func:`sfs_ros.ros.rig_apply.apply_rig`), ``cancel`` and ``home`` call
``scan/cancel`` and ``motor/home``, ``status`` prints the scan node's CellStatus
(``--follow``: every one until Ctrl-C),
``reconstruct`` calls ``meshing/reconstruct_mesh``, ``param`` gets or sets a
node's parameter through its rcl_interfaces services (VALUE parsed as YAML: ``256``,
``true``, ``[0.1, 0.2]``, ``bracket_07``). Exit status 0 on success, 1 on failure (the
reason on stderr), 2 for a usage error.
"""

from __future__ import annotations

import argparse
import os
import sys

import yaml

from ..process import configure_process
from ..ros.names import NAMESPACE
from ..ros.services import PARAMETER_RESEND_S, ServiceError, call

PROG = "sfs-ctl"
#: How long a command waits for the cell to answer, s (a scan's result: --timeout).
ANSWER_S = 30.0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--namespace", default=NAMESPACE, help="the cell's namespace "
                   "(default %(default)s)")
    sub = p.add_subparsers(dest="command", required=True)
    scan = sub.add_parser("scan", help="start a scan (a Scan goal)")
    scan.add_argument("--plan", default="", help="YAML scan plan file (default: the node's)")
    scan.add_argument("--name", default="", help="the scan's folder and mesh name")
    scan.add_argument("--wait", action="store_true", help="print feedback until the result; "
                      "Ctrl-C cancels the scan")
    scan.add_argument("--object", default="", choices=("", "object", "board"),
                      help="board: a calibration board's scan (default: the object)")
    scan.add_argument("--timeout", type=float, default=3600.0, help="longest scan, s")
    cal = sub.add_parser("calibrate", help="calibrate the cell from the board on the plate "
                         "(a Calibrate goal)")
    cal.add_argument("--plan", default="", help="YAML calibration plan (default: the node's)")
    cal.add_argument("--apply", action="store_true", help="set the calibrated rig on the "
                     "running cell and keep it for restarts")
    cal.add_argument("--wait", action="store_true", help="print feedback until the result; "
                     "Ctrl-C cancels the calibration")
    cal.add_argument("--timeout", type=float, default=3600.0, help="longest calibration, s")
    rig = sub.add_parser("rig", help="the cell's rig")
    rig_what = rig.add_subparsers(dest="action", required=True)
    rig_apply = rig_what.add_parser("apply", help="set a rig.yaml on every node that holds "
                                    "the rig (between scans) and keep it for restarts")
    rig_apply.add_argument("file", help="a rig.yaml (sfs-calibrate's or the Calibrate "
                           "action's)")
    sub.add_parser("cancel", help="cancel the scan (scan/cancel)")
    sub.add_parser("home", help="home the axes (motor/home)")
    status = sub.add_parser("status", help="print the scan node's status")
    status.add_argument("--follow", action="store_true", help="every status until Ctrl-C")
    rec = sub.add_parser("reconstruct", help="mesh the views received")
    rec.add_argument("--resolution", type=int, default=0, help="voxels along the box's "
                     "longest side (default: the node's)")
    rec.add_argument("--mesher", default="", help="a mesher of doc/reference.md "
                     "(default: the node's)")
    rec.add_argument("--output", default="", help="mesh file name in the output folder")
    rec.add_argument("--no-colour", action="store_true", help="no vertex colours")
    rec.add_argument("--texture", action="store_true", help="also a textured model "
                     "(<stem>.textured.glb), made after the answer, which names it")
    rec.add_argument("--refine", action="store_true", help="also the mesh refined below the "
                     "hull from the views' colours (<stem>.refined<suffix>), made after the "
                     "answer, which names it")
    rec.add_argument("--wait-pictures", action="store_true", help="answer once the picture, "
                     "viewer and contact sheet are written too")
    param = sub.add_parser("param", help="get or set a node's parameter")
    what = param.add_subparsers(dest="action", required=True)
    get = what.add_parser("get")
    get.add_argument("node", help="node name, e.g. carving (in the namespace)")
    get.add_argument("name")
    put = what.add_parser("set")
    put.add_argument("node")
    put.add_argument("name")
    put.add_argument("value", help="YAML: 256, true, [0.1, 0.2], a text")
    return p


def _line(status) -> str:
    """One line of a CellStatus or Scan.Feedback."""
    total = getattr(status, "total", None) or getattr(status, "views_total", 0)
    captured = getattr(status, "captured", None)
    captured = status.views_captured if captured is None else captured
    receipted = getattr(status, "receipted", None)
    receipted = status.views_receipted if receipted is None else receipted
    return (f"scan {status.scan} {status.state}: view {status.view} of {total}, {captured} "
            f"captured, {receipted} receipted, theta {status.theta_rad:.4f} phi "
            f"{status.phi_rad:.4f} rad; {status.message}")


def _follow(goal, args, what: str, *, cancel_wait_s: float):
    """The result of an accepted ``goal`` with ``--wait``; None without it (said so), or
    when Ctrl-C cancelled it (the cancellation followed for ``cancel_wait_s``)."""
    from ..ros.cell_client import ScanFailed
    if not args.wait:
        print(f"{what} goal accepted")
        return None
    try:
        return goal.wait(args.timeout)
    except KeyboardInterrupt:
        goal.cancel(ANSWER_S)
        try:
            goal.wait(cancel_wait_s)
        except ScanFailed as exc:
            print(f"{PROG}: {exc}", file=sys.stderr)
        return None


def _scan(client, args) -> int:
    goal = client.send_scan(plan_file=os.path.abspath(args.plan) if args.plan else "",
                            scan_name=args.name, object=args.object,
                            feedback=(lambda f: print(_line(f), flush=True)) if args.wait
                            else None, timeout_s=ANSWER_S)
    result = _follow(goal, args, "scan", cancel_wait_s=ANSWER_S)
    if result is None:
        return 0 if not args.wait else 1
    print(f"scan {result.scan} done: {result.views_captured} of {result.views_total} views "
          f"captured, {result.views_stored} stored in {result.session_dir}, "
          f"{len(result.views_rejected)} rejected")
    for line in result.views_rejected:
        print(f"  rejected: {line}")
    return 0


def _calibrate(client, args) -> int:
    goal = client.send_calibrate(
        plan_file=os.path.abspath(args.plan) if args.plan else "", apply=args.apply,
        feedback=(lambda f: print(f"{f.phase}: {f.views_captured} of {f.views_total} views, "
                                  f"{f.boards_detected} boards detected; {f.message}",
                                  flush=True)) if args.wait else None, timeout_s=ANSWER_S)
    result = _follow(goal, args, "calibrate", cancel_wait_s=ANSWER_S * 4)
    if result is None:
        return 0 if not args.wait else 1
    print(f"calibrated: {result.views_used} views, RMS {result.rms_px:.3f} px; "
          f"{result.rig_file}, report {result.report_file}")
    for line in result.views_rejected:
        print(f"  rejected: {line}")
    if result.applied:
        print(f"applied to {', '.join(result.applied_nodes)}")
    return 0


def _rig(client, args) -> int:
    from ..ros.rig_apply import apply_rig
    applied = apply_rig(client.node, os.path.abspath(args.file), timeout_s=ANSWER_S * 2)
    print(f"applied to {', '.join(applied.nodes)} (from their next scan); kept in "
          f"{applied.persisted} for restarts")
    return 0


def _status(client, args) -> int:
    status = None
    while True:
        status = client.next_status(status, timeout_s=ANSWER_S)
        print(_line(status.msg), flush=True)
        if not args.follow:
            return 0


def _reconstruct(client, args) -> int:
    options = dict(resolution=args.resolution, mesher=args.mesher, output_name=args.output,
                   colour="no" if args.no_colour else "", texture="yes" if args.texture else "",
                   refine="yes" if args.refine else "")
    summary = client.reconstruct(ANSWER_S * 20, pictures=args.wait_pictures, **options)
    print(f"{summary['mesh_path']}: {summary['n_vertices']} vertices, {summary['n_faces']} "
          f"faces, watertight {summary['watertight']}, {summary['views_used']} views used, "
          f"{summary['seconds']:.2f} s")
    if summary["textured_path"]:
        print(f"textured model to follow: {summary['textured_path']}")
    if summary["refined_mesh_path"]:
        print(f"refined mesh to follow: {summary['refined_mesh_path']}")
    return 0


def _param(client, args) -> int:
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.parameter import Parameter

    node = client.node
    prefix = args.node if args.node.startswith("/") else \
        f"{node.get_namespace().rstrip('/')}/{args.node}"
    if args.action == "get":
        answer = call(node.create_client(GetParameters, f"{prefix}/get_parameters"),
                      GetParameters.Request(names=[args.name]), timeout_s=ANSWER_S,
                      resend_after_s=PARAMETER_RESEND_S, keep_resending=True)
        if not answer.values or answer.values[0].type == 0:
            raise ValueError(f"{prefix} has no parameter {args.name!r}")
        print(yaml.safe_dump(Parameter.from_parameter_msg(
            _named(args.name, answer.values[0])).value, default_flow_style=True).strip()
            .removesuffix("...").strip())
        return 0
    try:
        value = yaml.safe_load(args.value)
    except yaml.YAMLError as exc:
        raise ValueError(f"value {args.value!r} is not YAML: {exc}") from None
    try:
        parameter = Parameter(args.name, value=value).to_parameter_msg()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"value {args.value!r} cannot be a parameter: {exc}") from None
    answer = call(node.create_client(SetParameters, f"{prefix}/set_parameters"),
                  SetParameters.Request(parameters=[parameter]), timeout_s=ANSWER_S,
                  resend_after_s=PARAMETER_RESEND_S, keep_resending=True)
    result = answer.results[0]
    if not result.successful:
        raise ValueError(f"{prefix} refused {args.name} = {args.value}: {result.reason}")
    print(f"{prefix} {args.name} = {args.value}")
    return 0


def _named(name: str, value):
    """An rcl_interfaces Parameter message of ``name`` and a ParameterValue."""
    from rcl_interfaces.msg import Parameter as ParameterMsg
    return ParameterMsg(name=name, value=value)


def _trigger(client, service: str) -> int:
    answer = client.call(service, timeout_s=ANSWER_S if service != "home" else ANSWER_S * 10)
    if not answer.success:
        raise ValueError(f"{service}: {answer.message}")
    print(answer.message)
    return 0


def run(args) -> int:
    from ..ros.cell_client import CellClient
    with CellClient(args.namespace, name=f"sfs_ctl_{os.getpid()}") as client:
        if args.command == "scan":
            return _scan(client, args)
        if args.command == "status":
            return _status(client, args)
        if args.command == "reconstruct":
            return _reconstruct(client, args)
        if args.command == "param":
            return _param(client, args)
        if args.command == "calibrate":
            return _calibrate(client, args)
        if args.command == "rig":
            return _rig(client, args)
        return _trigger(client, {"cancel": "scan/cancel", "home": "home"}[args.command])


def main(argv=None) -> int:
    configure_process()
    args = build_parser().parse_args(argv)
    from ..ros.cell_client import ScanFailed
    try:
        return run(args)
    except (ScanFailed, ServiceError, TimeoutError, ValueError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
