"""``sfs-cell``: bring up the whole cell, each node a separate process, until Ctrl-C.

    sfs-cell --mock -o out/cell          # simulated hardware
    sfs-cell -o /data/scans --port /dev/ttyUSB0 --camera-device /dev/video2
    sfs-cell -o /data/scans --camera-topic /usb_cam/image_raw   # another camera driver
    sfs-cell --mock -o out/desk --camera-topic /usb_cam/image_raw   # a real camera, mock motion
    sfs-cell --mock -o out/cell --only reconstruction,recorder     # this host's part

The nodes read the YAML files of ``--config`` (default: the installed
``share/sfs_ros/config``), then ``--params-file`` (a site's own values);
files and meshes go to ``--output-dir``. The nodes run in the namespace
``/sfs`` (``--namespace``). ``--only`` / ``--without`` start part of the
cell, the rest running on another host in the same ROS domain and namespace
(doc/cell.md, "The reconstruction on another machine"). Then,
from another terminal or a program: ``scan/start``, and ``reconstruct``
once the scan is done (see the README). The motor and camera are managed
(lifecycle) nodes, brought to active in order by the lifecycle manager;
``--manual-lifecycle`` leaves them unconfigured for an integrator's own
launch to configure and activate (their ``change_state`` services,
doc/cell.md). Ctrl-C (SIGINT) or SIGTERM stops
the nodes, the last started first. A node that ends by itself is started
again after a back-off (0.5 s, doubling up to 30 s); one that ends five times
within two minutes stops the cell with exit status 1.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from sfs_ros.process import configure_process
from sfs_ros.ros.names import NAMESPACE

from .bringup import Cell, cell_nodes, default_config_dir, select_nodes, wait_until_signal

PROG = "sfs-cell"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("--mock", action="store_true",
                   help="simulated controller and camera instead of the real hardware")
    p.add_argument("-o", "--output-dir", type=Path, required=True,
                   help="folder of the scans, meshes and reports")
    p.add_argument("--config", type=Path, default=None,
                   help="folder of the YAML parameter files (default: the installed ones)")
    p.add_argument("--namespace", default=NAMESPACE,
                   help=f"ROS namespace of all nodes, absolute (default {NAMESPACE}; "
                        "'' = the root)")
    p.add_argument("--params-file", type=Path, default=None,
                   help="YAML parameters given to every node after its own files (default: "
                        "the config folder's overrides.yaml, which sets nothing)")
    p.add_argument("--port", default=None,
                   help="real hardware: the motor controller's serial port (default: "
                        "motor.yaml's)")
    camera = p.add_mutually_exclusive_group()
    camera.add_argument("--camera-device", default=None,
                        help="real hardware: our camera node's device, e.g. /dev/video2 "
                             "(default: camera.yaml's)")
    camera.add_argument("--camera-topic", default=None,
                        help="take the frames another camera driver streams on this image "
                             "topic (usb_cam, v4l2_camera, GenICam) instead of starting our "
                             "camera node (with --mock: the simulated controller, no mock "
                             "camera)")
    p.add_argument("--record", action="store_true",
                   help="record every scan as a rosbag2 in OUTPUT_DIR/bags (the recorder "
                        "also takes recorder/start and recorder/stop at any time)")
    p.add_argument("--manual-lifecycle", action="store_true",
                   help="start no lifecycle manager: the motor and camera nodes stay "
                        "unconfigured until told through their lifecycle services "
                        "(NODE/change_state)")
    part = p.add_mutually_exclusive_group()
    part.add_argument("--only", type=_names, default=[], metavar="NODE,...",
                      help="start only these nodes (the rest run on another host), e.g. "
                           "reconstruction,recorder")
    part.add_argument("--without", type=_names, default=[], metavar="NODE,...",
                      help="start all nodes but these (they run on another host)")
    return p


def _names(text: str) -> list[str]:
    """A comma-separated list of node names (at least one)."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"no node names in {text!r}")
    return names


#: Discovery ranges in which nodes on other hosts are not found.
_HOST_ONLY_RANGES = ("LOCALHOST", "OFF")


def _elsewhere(left_out: list[str], namespace: str) -> str:
    """What the nodes started here need from the other host's: ``left_out`` running in
    the same domain and namespace, found over the network."""
    domain = os.environ.get("ROS_DOMAIN_ID", "0")
    text = (f"{PROG}: expecting {', '.join(left_out)} on another host (ROS_DOMAIN_ID={domain}, "
            f"namespace /{namespace.strip('/')})")
    found = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper()
    if found in _HOST_ONLY_RANGES:
        text += (f"; ROS_AUTOMATIC_DISCOVERY_RANGE={found} finds no node on another host "
                 "(SUBNET or ROS_STATIC_PEERS does)")
    return text


def main(argv=None) -> int:
    configure_process()     # its nodes inherit the settings
    args = build_parser().parse_args(argv)
    try:
        config = args.config or default_config_dir()
        args.output_dir.mkdir(parents=True, exist_ok=True)
        specs = cell_nodes(config, args.output_dir, mock=args.mock, record=args.record,
                           params_file=args.params_file, port=args.port,
                           camera_device=args.camera_device, camera_topic=args.camera_topic,
                           manual_lifecycle=args.manual_lifecycle)
        chosen = select_nodes(specs, only=args.only, without=args.without)
    except (ValueError, OSError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    left_out = [s.name for s in specs if s not in chosen]
    if left_out:
        print(_elsewhere(left_out, args.namespace), flush=True)
    print(f"{PROG}: starting {', '.join(s.name for s in chosen)} (config {config}); "
          "Ctrl-C stops", flush=True)
    return wait_until_signal(Cell(chosen, namespace=args.namespace).start())


if __name__ == "__main__":
    sys.exit(main())
