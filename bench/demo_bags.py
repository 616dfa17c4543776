"""The demo N times in a row: every bag whole, every bag replayed to the same mesh.

Each run is the README's demo (``sfs-demo``: the mock cell as processes, recording, a
49-view scan of the mock mug with the repository's config, then ``reconstruct``), in
a folder of its own under a temporary folder, in a private ROS domain. After each run
the script opens the bag the recorder wrote and checks that it holds the whole scan:
on each of ``capture/image``, ``capture/joint_state``, ``capture/mask`` and
``capture/mask_joint_state`` one message per view (distinct header stamps; a resent
capture recorded twice is counted apart, not as a missing one), the same stamps on all
four. Then the bag is reconstructed offline with ``sfs-reconstruct BAG -o replay.ply``
(another process) and its mesh compared with the one the reconstruction node wrote
during the scan: vertices and faces equal, array for array (the node's mesh carries
colours, the replay's not; the geometry is what is compared).

Run: ``python -m bench.demo_bags [--runs 10] [--keep]``. Prints a line per run and a
summary; exits 1 if any run failed (its folder is kept, with the demo's ``cell.log``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sfs_ros.cell_logic.bag import open_bag
from sfs_ros.cell_logic.bag.layout import STORE
from sfs_ros.core.exchange.export import load_mesh

REPO = Path(__file__).resolve().parent.parent
#: The topics of a view, relative to the cell's namespace: one message each per view.
VIEW_TOPICS = ("capture/image", "capture/joint_state", "capture/mask",
               "capture/mask_joint_state")
#: Longest run of one command, s: only bounds a hang (a demo takes minutes under load).
COMMAND_TIMEOUT_S = 3600.0


def _environment() -> dict:
    """This process's environment in a ROS domain of its own (as test/ros_harness.py
    draws it: from the process id, 1..101), discovery on this machine only, and the
    repository first on the module path (the nodes import the same code)."""
    return dict(os.environ, ROS_DOMAIN_ID=str(1 + os.getpid() % 101),
                ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                PYTHONPATH=os.pathsep.join(filter(None, [str(REPO),
                                                         os.environ.get("PYTHONPATH")])))


def _run(args: list[str], log: Path) -> None:
    """Run ``python -m ...args`` from the repository; its output to ``log``; RuntimeError
    naming the log when it fails."""
    with open(log, "w") as out:
        code = subprocess.run([sys.executable, "-m", *args], cwd=REPO, env=_environment(),
                              stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                              timeout=COMMAND_TIMEOUT_S).returncode
    if code != 0:
        raise RuntimeError(f"{' '.join(args[:1])} exited with {code} (see {log})")


def bag_views(bag_path: Path) -> dict:
    """Per topic of :data:`VIEW_TOPICS`: ``{"messages": n, "stamps": set of (sec, nanosec)}``
    of the bag's messages (an absent topic: none)."""
    bag = open_bag(bag_path)
    found = {}
    for name in VIEW_TOPICS:
        topic = bag.topic(name)
        stamps, messages = set(), 0
        for message in bag.messages([topic] if topic else []):
            header = STORE.deserialize_cdr(message.data, message.msgtype).header
            stamps.add((header.stamp.sec, header.stamp.nanosec))
            messages += 1
        found[name] = {"messages": messages, "stamps": stamps}
    return found


def check_bag(found: dict, views: int) -> list[str]:
    """What is missing from a bag of a ``views``-view scan (``found``: :func:`bag_views`);
    empty when it is whole."""
    problems = [f"{name}: {len(v['stamps'])} views of {views}"
                for name, v in found.items() if len(v["stamps"]) != views]
    first = found[VIEW_TOPICS[0]]["stamps"]
    problems += [f"{name}: stamps differ from {VIEW_TOPICS[0]}'s"
                 for name, v in found.items() if v["stamps"] != first]
    return problems


def same_mesh(a: Path, b: Path) -> bool:
    """Whether two mesh files hold equal vertex and face arrays."""
    (va, fa), (vb, fb) = load_mesh(a), load_mesh(b)
    return va.shape == vb.shape and fa.shape == fb.shape and bool(
        np.array_equal(va, vb) and np.array_equal(fa, fb))


def one_run(folder: Path) -> dict:
    """The demo in ``folder``, then its bag checked and replayed; the run's row."""
    folder.mkdir()
    start = time.monotonic()
    _run(["sfs_ros.cli.demo", "-o", str(folder), "--config", str(REPO / "config")],
         folder / "demo.log")
    demo_s = time.monotonic() - start
    report = json.loads((folder / "report.json").read_text())
    views, bag = report["n_views"], Path(report["bag"])
    found = bag_views(bag)
    problems = check_bag(found, views)
    start = time.monotonic()
    _run(["sfs_ros.cli.reconstruct", str(bag), "-o", str(folder / "replay.ply"), "-q"],
         folder / "replay.log")
    replay_s = time.monotonic() - start
    replayed = same_mesh(Path(report["reconstruct"]["path"]), folder / "replay.ply")
    if not replayed:
        problems.append("the bag's offline reconstruction differs from the live mesh")
    return {"views": views, "problems": problems, "replayed_same": replayed,
            "demo_same": report["bag_replay"]["same_mesh"], "demo_s": demo_s,
            "replay_s": replay_s, "scan_s": report["scan_seconds"],
            "counts": {name: (len(v["stamps"]), v["messages"]) for name, v in found.items()}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10, help="demo runs (default 10)")
    parser.add_argument("--keep", action="store_true",
                        help="keep every run's folder (default: only those that failed)")
    args = parser.parse_args(argv)
    root = Path(tempfile.mkdtemp(prefix="sfs_demo_bags_"))
    print(f"runs in {root}, ROS_DOMAIN_ID {_environment()['ROS_DOMAIN_ID']}", flush=True)
    whole = 0
    for n in range(1, args.runs + 1):
        folder = root / f"run_{n:02d}"
        try:
            row = one_run(folder)
        except (RuntimeError, subprocess.TimeoutExpired, OSError, ValueError) as exc:
            row = {"problems": [f"{type(exc).__name__}: {exc}"]}
        counts = ", ".join(f"{name} {distinct}/{messages}"
                           for name, (distinct, messages) in row.get("counts", {}).items())
        ok = not row["problems"]
        whole += ok
        timing = (f"scan {row['scan_s']:.0f} s, demo {row['demo_s']:.0f} s, "
                  f"replay {row['replay_s']:.0f} s; " if "demo_s" in row else "")
        print(f"run {n:2d}: {'whole' if ok else 'FAILED'}; {timing}views {row.get('views')}; "
              f"views/messages {counts}; replay same mesh: {row.get('replayed_same')} "
              f"(sfs-demo's own check: {row.get('demo_same')})"
              + ("" if ok else f"; {'; '.join(row['problems'])}"), flush=True)
        if ok and not args.keep:
            shutil.rmtree(folder)
    print(f"{whole} of {args.runs} runs whole and replayed to the same mesh"
          + ("" if args.keep or whole < args.runs else f" ({root} removed)"))
    if whole == args.runs and not args.keep:
        root.rmdir()
    return 0 if whole == args.runs else 1


if __name__ == "__main__":
    raise SystemExit(main())
