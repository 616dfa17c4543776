"""Before a scan's first capture: are the subscriptions that must see it in the graph?

Every node of :data:`LISTENERS` that runs in the scan node's namespace (segmentation,
carving, recorder; a board scan's calibration node and recorder) must have its
subscriptions on the topics it must get, and every subscription to the scan's own
capture topics must be matched to its publishers. The carving node's mask subscriptions
are matched to the segmentation's publishers, not to the scan node's: that they exist is
what it can see. A node not running is not waited for (a scan node alone scans).
"""

from __future__ import annotations

import threading
import time

from rclpy.node import Node

from sfs_ros.cell_logic.scan_sequence import StepFailed
from sfs_ros.ros.names import CARVING_NODE, RECORDER_NODE

__all__ = ["LISTENERS", "missing_listeners", "wait_for_listeners"]

#: How often the graph is looked at while waiting for the capture subscriptions, s.
LISTEN_POLL_S = 0.1
_CAPTURES = ("capture/image", "capture/joint_state")
_MASKS = ("capture/mask", "capture/mask_joint_state")
_BOARD = ("calibration/image", "calibration/joint_state")
#: By the scan's object: the nodes whose subscriptions must be there before its first
#: capture, and the topics of each.
LISTENERS = {
    "object": {"segmentation": _CAPTURES, CARVING_NODE: _MASKS,
               RECORDER_NODE: _CAPTURES + _MASKS},
    "board": {"calibration": _BOARD, RECORDER_NODE: _BOARD},
}


def missing_listeners(node: Node, scan_object: str, publishers) -> list[str]:
    """What keeps the captures of a scan of ``scan_object`` from being seen now: the
    subscriptions of :data:`LISTENERS`' running nodes not in ``node``'s graph, and
    subscriptions to the topics of ``publishers`` (the capture publishers) not yet
    matched (empty: none)."""
    namespace = node.get_namespace()
    running = {name for name, space in node.get_node_names_and_namespaces()
               if space == namespace}
    missing = []
    for listener, topics in LISTENERS[scan_object].items():
        if listener not in running:
            continue
        for topic in topics:
            infos = node.get_subscriptions_info_by_topic(node.resolve_topic_name(topic))
            if not any(i.node_name == listener and i.node_namespace == namespace
                       for i in infos):
                missing.append(f"{listener}'s subscription to {topic}")
    for publisher in publishers:
        known = len(node.get_subscriptions_info_by_topic(publisher.topic_name))
        if publisher.get_subscription_count() < known:
            missing.append(f"a subscription to {publisher.topic_name} still matching")
    return missing


def wait_for_listeners(node: Node, scan_object: str, publishers, timeout_s: float,
                       cancelled: threading.Event) -> None:
    """Until :func:`missing_listeners` is empty (INFO once while waiting) or ``cancelled``
    is set; StepFailed naming what is missing after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    said = False
    while missing := missing_listeners(node, scan_object, publishers):
        if cancelled.is_set():
            return
        if time.monotonic() > deadline:
            raise StepFailed(f"after {timeout_s:g} s the captures would still not be seen: "
                             f"no {', '.join(missing)}")
        if not said:
            said = True
            node.get_logger().info(f"first capture waits for {', '.join(missing)}")
        cancelled.wait(LISTEN_POLL_S)
