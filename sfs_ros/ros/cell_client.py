"""A program's handle on a running cell: start a scan, follow it, reconstruct.

What a robot cell's controller (or ``sfs-demo``) does over ROS: call
``scan/start``, follow the scan node's progress on ``/diagnostics``, and call
``reconstruct`` once every view is stored. Services go by their short names
(``"reset"``, ``"home"``, ...), which :data:`sfs_ros.ros.names.SERVICES` maps to
the node's own (``reconstruction/reset``, ``motor/home``, ...) in the cell's
namespace (default :data:`sfs_ros.ros.names.NAMESPACE`); only the statuses
of that namespace's nodes are followed. :class:`CellClient` runs its own
node in a private rclpy context, spun by a background thread, so it can be
used from plain synchronous code::

    with CellClient() as cell:
        cell.wait_ready()
        scan = cell.start_scan()
        cell.wait_scan_done(scan)
        summary = cell.reconstruct()      # {"path": ..., "preview_path": ..., ...}
"""

from __future__ import annotations

import json
import re
import threading
import time
from pathlib import Path
from typing import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from std_srvs.srv import Trigger

from sfs_ros.cell.messages import status_namespace
from sfs_ros.ros.names import DIAGNOSTICS, NAMESPACE, SERVICES
from sfs_ros.ros.services import ServiceError, call

__all__ = ["CellClient", "ScanFailed", "ScanStatus", "SERVICES", "READY", "wait_for_pictures"]

#: The services that must answer before :meth:`CellClient.wait_ready` returns.
READY = ("scan/start", "scan/cancel", "scan/resume", "reconstruct", "reset")


#: How often :func:`wait_for_pictures` reads the report, s.
PICTURE_POLL_S = 0.05
#: States in which a scan is not under way (it waits for ``scan/resume``).
_STOPPED = ("paused", "cancelled")


class ScanFailed(RuntimeError):
    """The scan paused on a fault, or the reconstruction failed; the text says why."""


def wait_for_pictures(summary: dict, *, timeout_s: float = 120.0) -> None:
    """Until the report of a ``reconstruct`` answer (``summary``, its JSON) names the
    picture, viewer and contact sheet the answer gives: the node writes them after its
    answer, then the report again. Polls the report file; TimeoutError after
    ``timeout_s`` (the node's diagnostics say why: a full disk, say)."""
    report = Path(summary["report_path"])
    wanted = {"preview": summary["preview_path"], "html": summary["html_path"],
              "contact_sheet": summary["contact_sheet_path"]}
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            named = json.loads(report.read_text())
        except (OSError, ValueError):
            named = {}          # replaced just now, or not there: read again
        if all(named.get(key) == path for key, path in wanted.items()):
            return
        if time.monotonic() >= deadline:
            raise TimeoutError(f"the pictures of {summary['path']} were not written within "
                               f"{timeout_s:g} s (the report {report} does not name them)")
        time.sleep(PICTURE_POLL_S)


class ScanStatus:
    """The scan node's latest progress: ``level``, ``message`` and ``values`` (str -> str)."""

    def __init__(self, status: DiagnosticStatus):
        self.level = status.level
        self.message = status.message
        self.values = {kv.key: kv.value for kv in status.values}

    @property
    def state(self) -> str:
        return self.values.get("state", "")

    def count(self, key: str) -> int:
        return int(self.values.get(key, "0"))

    @property
    def complete(self) -> bool:
        """Every planned view captured and receipted by the reconstruction."""
        total = self.count("total")
        return self.state == "done" and total > 0 and self.count("receipted") == total


class CellClient:
    """Service calls and scan progress of a cell in ``namespace`` ("" or "/" = the root);
    call :meth:`close`."""

    def __init__(self, namespace: str = NAMESPACE, *, name: str = "cell_client"):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import MultiThreadedExecutor

        self._context = Context()
        rclpy.init(context=self._context)
        self.node = rclpy.create_node(name, namespace=namespace or "/", context=self._context)
        self._lock = threading.Lock()
        self._scan: ScanStatus | None = None
        self._resumed: int | None = None      # scan resumed, until a report of it running
        self._motor_connected = False
        self._changed = threading.Condition(self._lock)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, 50)
        self._clients = {n: self.node.create_client(Trigger, name) for n, name in
                         SERVICES.items()}
        self._executor = MultiThreadedExecutor(num_threads=2, context=self._context)
        self._executor.add_node(self.node)
        self._spinner = threading.Thread(target=self._executor.spin, daemon=True)
        self._spinner.start()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status_namespace(status.name) != self.node.get_namespace():
                continue                     # another cell's, or a robot's
            if status.name.endswith(": scan"):
                with self._changed:
                    self._scan = ScanStatus(status)
                    if self._scan.count("scan") == self._resumed and \
                            self._scan.state not in _STOPPED:
                        self._resumed = None
                    self._changed.notify_all()
            elif status.name.endswith(": motor"):
                self._motor_connected = any(kv.key == "connected" and kv.value == "True"
                                            for kv in status.values)

    @property
    def scan(self) -> ScanStatus | None:
        """The scan node's latest progress (None before the first report)."""
        with self._lock:
            return self._scan

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        """Until every service of the cell answers, the scan node reports and the motor node
        is connected to its controller; ServiceError."""
        deadline = time.monotonic() + timeout_s
        while True:
            missing = [SERVICES[n] for n in READY if not self._clients[n].service_is_ready()]
            if self.scan is None:
                missing.append("scan progress")
            if not self._motor_connected:
                missing.append("a connected motor controller")
            if not missing:
                return
            if time.monotonic() > deadline:
                raise ServiceError(f"the cell is not up after {timeout_s:g} s: "
                                   f"{', '.join(missing)} missing")
            time.sleep(0.1)

    def call(self, service: str, timeout_s: float = 30.0) -> Trigger.Response:
        """Call one of :data:`SERVICES` by its short name (std_srvs/Trigger); the response."""
        return call(self._clients[service], Trigger.Request(), timeout_s=timeout_s)

    def wait_scan(self, scan: int, until: Callable[[ScanStatus], bool], *, timeout_s: float,
                  progress: Callable[[ScanStatus], None] | None = None) -> ScanStatus:
        """Until ``until(status)`` holds for scan number ``scan`` (reports of other scans are
        passed over); ScanFailed if it pauses or is cancelled first, TimeoutError after
        ``timeout_s``. ``progress`` sees every new report of the scan."""
        deadline = time.monotonic() + timeout_s
        seen = None
        while True:
            with self._changed:
                self._changed.wait_for(lambda: self._scan is not seen, timeout=0.5)
                status = seen = self._scan
                resuming = self._resumed == scan
            if status is not None and status.count("scan") == scan:
                if progress is not None:
                    progress(status)
                if until(status):
                    return status
                if status.state in _STOPPED and not resuming:
                    raise ScanFailed(status.message)
            if time.monotonic() > deadline:
                last = status.message if status is not None else "no progress received"
                raise TimeoutError(f"scan {scan} not finished after {timeout_s:g} s "
                                   f"(last: {last})")

    def resume_scan(self) -> None:
        """Call ``scan/resume``; ScanFailed with the reason. Until a report shows the scan
        under way again, :meth:`wait_scan` passes over reports of it stopped (published
        before the resume, they may arrive after its answer)."""
        status = self.scan
        scan = None if status is None else status.count("scan")
        with self._lock:
            self._resumed = scan
        answer = self.call("scan/resume")
        if not answer.success:
            with self._lock:
                self._resumed = None
            raise ScanFailed(f"scan/resume refused: {answer.message}")

    def start_scan(self) -> int:
        """Call ``scan/start``; the number of the new scan, or ScanFailed with the reason."""
        answer = self.call("scan/start")
        found = re.match(r"scan (\d+) started", answer.message)
        if not answer.success or found is None:
            raise ScanFailed(f"scan/start refused: {answer.message}")
        return int(found.group(1))

    def wait_scan_done(self, scan: int, *, timeout_s: float = 1800.0,
                       progress=None) -> ScanStatus:
        """Until scan ``scan`` has every planned view captured and receipted
        (:attr:`ScanStatus.complete`)."""
        return self.wait_scan(scan, lambda s: s.complete, timeout_s=timeout_s,
                              progress=progress)

    def reconstruct(self, timeout_s: float = 600.0, *, pictures: bool = True) -> dict:
        """Call ``reconstruct``; its JSON summary, or ScanFailed with the node's reason.

        The node answers once the mesh and its report are written; with ``pictures``
        this also waits (within ``timeout_s`` in all) until the picture, viewer and
        contact sheet are (:func:`wait_for_pictures`)."""
        deadline = time.monotonic() + timeout_s
        answer = self.call("reconstruct", timeout_s=timeout_s)
        if not answer.success:
            raise ScanFailed(answer.message)
        summary = json.loads(answer.message)
        if pictures:
            wait_for_pictures(summary, timeout_s=max(0.0, deadline - time.monotonic()))
        return summary

    def close(self) -> None:
        self._executor.shutdown()
        self.node.destroy_node()
        self._context.try_shutdown()

    def __enter__(self) -> CellClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
