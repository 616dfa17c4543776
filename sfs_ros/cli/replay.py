"""``sfs-replay BAG``: publish a recorded bag back onto its topics, at its recorded pace.

BAG is a rosbag2 folder or its .mcap / .db3 file (one that ends early plays
what is whole of it). Every message goes out as its recorded serialized bytes
(rclpy publishers take bytes), so stamps and contents are the recording's; the
n-th message is published (t_n - t_0) / RATE seconds after the first, t being
the time the recorder received it. QoS as the cell's: capture topics reliable,
volatile, keep-last ``--queue-depth``; results (mesh, hull, ...) reliable,
transient-local, depth 1; the others reliable, depth 10. Topics are those of
the bag under its recorded namespace, moved to ``--namespace`` if given.
Before playing, it waits up to ``--wait-s`` for every topic to have a
subscriber; at the end, for every reliable message to be acknowledged.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..process import configure_process

PROG = "sfs-replay"
#: Longest wait for the subscribers to acknowledge the last messages, s.
ACK_TIMEOUT_S = 10.0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("bag", type=Path, help="rosbag2 folder, or its .mcap / .db3 file")
    p.add_argument("--rate", type=float, default=1.0, metavar="R",
                   help="R x the recorded pace (default 1; 2 = twice as fast)")
    p.add_argument("--topics", nargs="+", metavar="TOPIC",
                   help="only these topics, relative to the recorded namespace "
                        "(e.g. capture/image capture/joint_state; default: all)")
    p.add_argument("--namespace", metavar="NS",
                   help="publish under this namespace instead of the recorded one")
    p.add_argument("--queue-depth", type=int, default=100, metavar="N",
                   help="depth of the capture topics (default 100, >= views per scan)")
    p.add_argument("--wait-s", type=float, default=5.0, metavar="S",
                   help="wait up to S seconds for each topic's first subscriber (default 5)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    return p


def _namespace(text: str) -> str:
    """``"/ns"`` (or ``""`` for the root) from ``ns``, ``/ns`` or ``/``."""
    text = text.strip().strip("/")
    return f"/{text}" if text else ""


def _plan(bag, args) -> dict[str, tuple[str, str, str]]:
    """Recorded topic -> (topic to publish on, message type, QoS kind)."""
    from ..cell_logic.bag import DEFAULT, TOPICS

    namespace = bag.namespace if args.namespace is None else _namespace(args.namespace)
    names = {bag.relative(t) or t: t for t in bag.topics}
    chosen = args.topics or list(names)
    unknown = [n for n in chosen if n not in names]
    if unknown:
        raise ValueError(f"topic(s) {', '.join(unknown)} not in the bag; it has "
                         f"{', '.join(sorted(names))}")
    plan = {}
    for name in chosen:
        topic = names[name]
        target = f"{namespace}/{name}" if bag.relative(topic) is not None else topic
        plan[topic] = (target, bag.topics[topic], TOPICS.get(name, ("", DEFAULT))[1])
    return plan


def run(args) -> dict:
    """Play the bag; ``{"messages", "topics", "seconds", "skipped"}``."""
    # Here, not at the top: the help loads neither rclpy nor the bag reader.
    import rclpy
    from rclpy.duration import Duration
    from rclpy.signals import SignalHandlerOptions

    from ..cell_logic.bag import CAPTURE, RESULT, open_bag
    from ..ros import capture_qos, result_qos
    from ..ros.message_types import message_class

    if not args.rate > 0:
        raise ValueError(f"--rate must be > 0, got {args.rate}")
    if args.queue_depth < 1:
        raise ValueError(f"--queue-depth must be >= 1, got {args.queue_depth}")
    bag = open_bag(args.bag)
    plan = _plan(bag, args)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)   # Ctrl-C: KeyboardInterrupt
    try:
        node = rclpy.create_node("replay")
        publishers, skipped = {}, []
        for topic, (target, msgtype, kind) in plan.items():
            try:
                cls = message_class(msgtype)
            except ValueError as exc:
                skipped.append(f"{topic}: {exc}")
                continue
            qos = capture_qos(args.queue_depth) if kind == CAPTURE \
                else result_qos() if kind == RESULT else 10
            publishers[topic] = node.create_publisher(cls, target, qos)
        for text in skipped:
            print(f"{PROG}: skipping {text}", file=sys.stderr)
        deadline = time.monotonic() + args.wait_s
        while time.monotonic() < deadline and \
                not all(p.get_subscription_count() for p in publishers.values()):
            time.sleep(0.05)
        lonely = sorted(p.topic_name for p in publishers.values() if not p.get_subscription_count())
        if lonely and not args.quiet:
            print(f"{PROG}: no subscriber on {', '.join(lonely)}; playing anyway", file=sys.stderr)
        count, first, start = 0, None, time.monotonic()
        for message in bag.messages(publishers):
            publisher = publishers[message.topic]
            first = message.log_time_ns if first is None else first
            delay = start + (message.log_time_ns - first) / 1e9 / args.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            publisher.publish(message.data)
            count += 1
        seconds = time.monotonic() - start
        for publisher in publishers.values():
            publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return {"messages": count, "topics": len(publishers), "seconds": seconds,
            "skipped": skipped}


def main(argv=None) -> int:
    configure_process()
    from .common import run_reporting_errors

    args = build_parser().parse_args(argv)
    status, summary = run_reporting_errors(PROG, run, args)
    if status:
        return status
    if not args.quiet:
        print(f"published {summary['messages']} messages on {summary['topics']} topics in "
              f"{summary['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
