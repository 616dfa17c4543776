"""A program on one host of a cell split over two (run by ``test_two_hosts.py`` with
``ip netns exec``); prints one JSON object a line on stdout.

    python two_hosts_client.py scan NAMESPACE
        CellClient: wait until the cell is ready, start a scan, wait until every view is
        stored, reconstruct; prints {"ready": true}, then {"status": {...},
        "summary": {...}} (the scan node's last status, the reconstruct answer).
    python two_hosts_client.py look NAMESPACE SECONDS [NODE,...]
        A plain node that looks at the ROS graph for SECONDS, or until it has found the
        nodes named; prints {"nodes": [...]}, the nodes it found in NAMESPACE.
"""

import json
import sys
import time

SCAN_TIMEOUT_S = 600.0


def _print(document: dict) -> None:
    print(json.dumps(document), flush=True)


def scan(namespace: str) -> None:
    from sfs_ros.ros.cell_client import CellClient

    with CellClient(namespace, name="two_hosts_client") as cell:
        cell.wait_ready(timeout_s=SCAN_TIMEOUT_S)
        _print({"ready": True})
        status = cell.wait_scan_done(cell.start_scan(), timeout_s=SCAN_TIMEOUT_S)
        summary = cell.reconstruct(timeout_s=SCAN_TIMEOUT_S)
        _print({"status": {k: str(v) for k, v in status.values.items()}, "summary": summary})


def look(namespace: str, seconds: float, wanted: set[str]) -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    node = rclpy.create_node("two_hosts_look", namespace=namespace)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + seconds

    def found() -> list[str]:
        return sorted(name for name, space in node.get_node_names_and_namespaces()
                      if space == namespace and name != node.get_name())

    while time.monotonic() < deadline and not (wanted and wanted <= set(found())):
        executor.spin_once(timeout_sec=0.1)
    _print({"nodes": found()})
    executor.shutdown()
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    command, namespace, *rest = sys.argv[1:]
    if command == "scan":
        scan(namespace)
    else:
        look(namespace, float(rest[0]), set(rest[1].split(",")) if len(rest) > 1 else set())
