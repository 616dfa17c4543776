"""A program's handle on a running cell: scan, follow, reconstruct, through typed interfaces.

What a robot cell's controller (``sfs-demo``, ``sfs-ctl``) does over ROS: send a
``Scan`` goal to the scan node's action (feedback, cancel, result), follow the
scan node's ``CellStatus`` topic, and call the reconstruction's typed ``Reconstruct``
service (``sfs_ros_interfaces``). The std_srvs/Trigger services stay reachable by
their short names (``"reset"``, ``"home"``, ``"scan/start"``, ...), which
:data:`sfs_ros.ros.names.SERVICES` maps to the node's own (``carving/reset``,
``motor/home``, ...) in the cell's namespace (default
:data:`sfs_ros.ros.names.NAMESPACE`). :class:`CellClient` runs its own node in a
private rclpy context, spun by a background thread, so it can be used from plain
synchronous code::

    with CellClient() as cell:
        cell.wait_ready()
        result = cell.scan(feedback=print)          # Scan.Result: session_dir, views_stored
        mesh = cell.reconstruct(resolution=128)     # {"mesh_path": ..., "n_faces": ...}

``calibrate`` sends a ``Calibrate`` goal to the calibration node (a board scan, the fit,
and with ``apply`` the rig set on the running cell).
``start_scan`` / ``wait_scan_done`` (the ``scan/start`` alias and the status topic)
drive a scan without the action, as a scan resumed after a fault is followed.
"""

from __future__ import annotations

import json
import re
import threading
import time
import traceback
from pathlib import Path
from typing import Callable

from std_srvs.srv import Trigger

from sfs_ros.ros import result_qos
from sfs_ros.ros.action_client import RaceFreeActionClient
from sfs_ros.ros.names import (
    CALIBRATE_ACTION,
    CELL_STATUS,
    NAMESPACE,
    SCAN_ACTION,
    SERVICES,
    TYPED_SERVICES,
)
from sfs_ros.ros.services import ServiceError, call
from sfs_ros_interfaces.action import Calibrate, Scan
from sfs_ros_interfaces.msg import CellStatus
from sfs_ros_interfaces.srv import Reconstruct

__all__ = ["CalibrateGoal", "CellClient", "ScanFailed", "ScanGoal", "ScanStatus", "SERVICES", "READY",
           "mesh_summary", "wait_for_pictures", "wait_for_product"]

#: The Trigger services that must answer before :meth:`CellClient.wait_ready` returns
#: (besides the action and the typed service).
READY = ("scan/start", "scan/cancel", "scan/resume", "reconstruct", "reset")


#: Longest wait for the spinning thread to end at :meth:`CellClient.close`, s.
CLOSE_S = 10.0
#: Longest wait of the spinning thread before it looks whether the client is closing, s.
SPIN_POLL_S = 0.1
#: Seconds without an answer after which :meth:`CellClient.reconstruct` sends its request
#: again (then twice as long each time): a request sent to a meshing node just restarted,
#: before it matched the client, is lost; the node answers a repeat with the answer it made
#: (:mod:`sfs_ros.cell_logic.repeated_requests`), not with a second mesh.
RECONSTRUCT_RESEND_S = 2.0
#: How often :func:`wait_for_pictures` reads the report, s.
PICTURE_POLL_S = 0.05
#: States in which a scan is not under way (it waits for ``scan/resume``).
_STOPPED = ("paused", "cancelled")
#: The goal states a result comes with (action_msgs/GoalStatus).
_SUCCEEDED, _CANCELED = 4, 5


class ScanFailed(RuntimeError):
    """The scan was refused, paused on a fault or was cancelled, or the reconstruction
    failed; the text says why. ``result``: the Scan.Result, when the goal ended with one."""

    def __init__(self, message: str, result: Scan.Result | None = None):
        super().__init__(message)
        self.result = result


def mesh_summary(response: Reconstruct.Response) -> dict:
    """A ``Reconstruct`` answer as a dict (JSON-ready): its fields, and ``path`` (the mesh,
    as ``mesh_path``) and ``views_received`` (used + rejected)."""
    summary = {name: getattr(response, name) for name in response.get_fields_and_field_types()}
    summary.update(path=response.mesh_path,
                   views_received=response.views_used + response.views_rejected)
    return summary


def _wait_for_report(report: Path, wanted: dict, timeout_s: float, late: str) -> None:
    """Poll the report file until it names every ``{key: path}`` of ``wanted``;
    TimeoutError saying ``late`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            named = json.loads(report.read_text())
        except (OSError, ValueError):
            named = {}          # replaced just now, or not there: read again
        if all(named.get(key) == path for key, path in wanted.items()):
            return
        if time.monotonic() >= deadline:
            raise TimeoutError(f"{late} within {timeout_s:g} s (the report {report} does "
                               "not name it)")
        time.sleep(PICTURE_POLL_S)


def wait_for_pictures(summary: dict, *, timeout_s: float = 120.0) -> None:
    """Until the report of a reconstruction (``summary``: its ``report_path``,
    ``preview_path``, ``html_path``, ``contact_sheet_path`` and ``path``) names the
    picture, viewer and contact sheet: the node writes them after its answer, then the
    report again. Polls the report file; TimeoutError after ``timeout_s`` (the node's
    diagnostics say why: a full disk, say)."""
    wanted = {"preview": summary["preview_path"], "html": summary["html_path"],
              "contact_sheet": summary["contact_sheet_path"]}
    _wait_for_report(Path(summary["report_path"]), wanted, timeout_s,
                     f"the pictures of {summary['path']} were not written")


def wait_for_product(summary: dict, key: str = "textured_path", *,
                     timeout_s: float = 300.0) -> Path:
    """Until the report of a reconstruction (``summary``: its ``report_path`` and ``key``)
    names the product the answer named under ``key`` (the textured model,
    ``textured_path``, or the refined mesh, ``refined_mesh_path``): the node makes it
    after its answer, then writes the report again. Returns its path; ValueError when the
    answer named none; TimeoutError after ``timeout_s`` (the node's diagnostics say why)."""
    if not summary.get(key):
        raise ValueError(f"the answer names no {key}: not asked for, or it cannot be made "
                         "(the node's diagnostics say why)")
    _wait_for_report(Path(summary["report_path"]), {key: summary[key]}, timeout_s,
                     f"{summary[key]} was not written")
    return Path(summary[key])


class ScanStatus:
    """The scan node's latest ``CellStatus``: ``state``, ``message``, ``values`` (field ->
    value: scan, state, view, total, captured, receipted, theta_rad, phi_rad,
    axes_connected, message) and ``msg`` itself."""

    FIELDS = ("scan", "state", "view", "total", "captured", "receipted", "theta_rad",
              "phi_rad", "axes_connected", "message")

    def __init__(self, msg: CellStatus):
        self.msg = msg
        self.values = {name: getattr(msg, name) for name in self.FIELDS}

    @property
    def state(self) -> str:
        return self.msg.state

    @property
    def message(self) -> str:
        return self.msg.message

    def count(self, key: str) -> int:
        return int(self.values[key])

    @property
    def complete(self) -> bool:
        """Every planned view captured and receipted by the reconstruction."""
        total = self.msg.total
        return self.state == "done" and total > 0 and self.msg.receipted == total


def _wait_future(future, timeout_s: float, what: str):
    """The result of an rclpy future (the node spun elsewhere); TimeoutError naming
    ``what``."""
    done = threading.Event()
    future.add_done_callback(lambda _f: done.set())
    if not done.wait(timeout_s):
        raise TimeoutError(f"{what}: no answer within {timeout_s:g} s")
    return future.result()


class ScanGoal:
    """A ``Scan`` goal (:meth:`CellClient.send_scan`): :meth:`wait` for its result,
    :meth:`cancel` it. ``feedback``: the latest Scan.Feedback (None before one); each is
    also handed to ``on_feedback``, whose exceptions go to ``logger`` (the client node's)."""

    #: What the goal does, in messages.
    WHAT = "scan"

    def __init__(self, on_feedback: Callable[[Scan.Feedback], None] | None, logger):
        self.feedback: Scan.Feedback | None = None
        self._on_feedback = on_feedback
        self._logger = logger
        self._handle = self._result = None

    def feedback_message(self, msg) -> None:
        """The action client's feedback callback: ``on_feedback`` raising is logged (ERROR,
        with its traceback) and the goal goes on."""
        self.feedback = msg.feedback
        if self._on_feedback is not None:
            try:
                self._on_feedback(msg.feedback)
            except Exception:  # noqa: BLE001 -- the caller's bug must not end the client
                self._logger.error(f"the {self.WHAT} goal's feedback callback raised; the "
                                   f"goal goes on:\n{traceback.format_exc()}")

    def accepted(self, handle) -> None:
        """The goal's handle, once the scan node accepted it."""
        self._handle = handle
        self._result = handle.get_result_async()

    def cancel(self, timeout_s: float = 30.0) -> None:
        """Ask the scan node to cancel the goal (it stops the axes; :meth:`wait` then ends
        with ScanFailed, the goal canceled); TimeoutError if it does not answer."""
        _wait_future(self._handle.cancel_goal_async(), timeout_s, "cancel of the scan goal")

    def wait(self, timeout_s: float = 1800.0) -> Scan.Result:
        """The result of a scan that succeeded; ScanFailed with the reason (and the result)
        if it was aborted or canceled; TimeoutError after ``timeout_s``."""
        answer = _wait_future(self._result, timeout_s, f"the {self.WHAT} goal's result")
        result = answer.result
        if answer.status != _SUCCEEDED:
            how = "cancelled" if answer.status == _CANCELED else "failed"
            raise ScanFailed(f"{self.WHAT} {how}: {result.message}", result)
        return result


class CalibrateGoal(ScanGoal):
    """A ``Calibrate`` goal (:meth:`CellClient.send_calibrate`), as :class:`ScanGoal`:
    ``feedback`` the latest Calibrate.Feedback, :meth:`wait` its Calibrate.Result
    (ScanFailed with the reason if it failed or was cancelled)."""

    WHAT = "calibration"


class CellClient:
    """The scan action, the status and the services of a cell in ``namespace`` ("" or "/"
    = the root); call :meth:`close`."""

    def __init__(self, namespace: str = NAMESPACE, *, name: str = "cell_client"):
        import rclpy
        from rclpy.context import Context

        from .executor import DrainingExecutor

        self._context = Context()
        rclpy.init(context=self._context)
        self.node = rclpy.create_node(name, namespace=namespace or "/", context=self._context)
        self._lock = threading.Lock()
        self._scan: ScanStatus | None = None
        self._resumed: int | None = None      # scan resumed, until a report of it running
        self._changed = threading.Condition(self._lock)
        self.node.create_subscription(CellStatus, CELL_STATUS, self._on_status, result_qos())
        self._clients = {n: self.node.create_client(Trigger, name) for n, name in
                         SERVICES.items()}
        self._reconstruct = self.node.create_client(Reconstruct,
                                                    TYPED_SERVICES["reconstruct_mesh"])
        self._action = RaceFreeActionClient(self.node, Scan, SCAN_ACTION)
        self._calibrate = RaceFreeActionClient(self.node, Calibrate, CALIBRATE_ACTION)
        self._executor = DrainingExecutor(num_threads=2, context=self._context)
        self._executor.add_node(self.node)
        self._closing = threading.Event()
        self._spinner = threading.Thread(target=self._spin, daemon=True)
        self._spinner.start()

    def _spin(self) -> None:
        """Spin the client's node until :meth:`close` (which shuts the executor down once
        this has stopped handing it callbacks). A callback that raises is logged, ERROR
        with its traceback, and the spin goes on: the client keeps taking answers. rclpy
        may raise one task's exception at two spins in a row: it is logged once."""
        last = None
        while not self._closing.is_set():
            try:
                self._executor.spin_once(timeout_sec=SPIN_POLL_S)
            except Exception as exc:  # noqa: BLE001 -- one callback must not end the client
                if exc is not last:
                    self.node.get_logger().error(
                        f"a callback raised; the client goes on:\n{traceback.format_exc()}")
                last = exc

    def _on_status(self, msg: CellStatus) -> None:
        with self._changed:
            self._scan = ScanStatus(msg)
            if msg.scan == self._resumed and msg.state not in _STOPPED:
                self._resumed = None
            self._changed.notify_all()

    @property
    def scan(self) -> ScanStatus | None:
        """The scan node's latest progress (None before the first report)."""
        with self._lock:
            return self._scan

    def next_status(self, after: ScanStatus | None, *, timeout_s: float) -> ScanStatus:
        """The first status other than ``after`` (None: the latest, or the first to come);
        TimeoutError after ``timeout_s``."""
        with self._changed:
            if not self._changed.wait_for(lambda: self._scan is not None
                                          and self._scan is not after, timeout_s):
                raise TimeoutError(f"no status from the scan node within {timeout_s:g} s")
            return self._scan

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        """Until the scan action, the typed reconstruct service and the Trigger services
        answer, and the scan node's status says the axes are connected; ServiceError."""
        deadline = time.monotonic() + timeout_s
        while True:
            missing = [SERVICES[n] for n in READY if not self._clients[n].service_is_ready()]
            if not self._action.server_is_ready():
                missing.append(f"the {SCAN_ACTION} action")
            if not self._reconstruct.service_is_ready():
                missing.append(TYPED_SERVICES["reconstruct_mesh"])
            status = self.scan
            if status is None:
                missing.append("the scan node's status")
            elif not status.msg.axes_connected:
                missing.append("encoder readings (a connected motor controller)")
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

    def send_scan(self, *, plan_file: str = "", theta_rad=(), phi_rad=(), scan_name: str = "",
                  object: str = "", feedback: Callable[[Scan.Feedback], None] | None = None,
                  timeout_s: float = 30.0) -> ScanGoal:
        """Send a ``Scan`` goal (all empty: the configured plan, of the object; ``object``
        "board": a calibration board's scan); the accepted goal, or
        ScanFailed when the scan node rejects it (a scan is running). ``feedback`` sees
        every Scan.Feedback (in the client's spinning thread)."""
        goal = ScanGoal(feedback, self.node.get_logger())
        request = Scan.Goal(plan_file=plan_file, theta_rad=[float(v) for v in theta_rad],
                            phi_rad=[float(v) for v in phi_rad], scan_name=scan_name,
                            object=object)
        if not self._action.wait_for_server(timeout_sec=timeout_s):
            raise ServiceError(f"the {SCAN_ACTION} action is not available "
                               f"(waited {timeout_s:g} s): is the scan node running?")
        handle = _wait_future(self._action.send_goal_async(request,
                                                           feedback_callback=goal.feedback_message),
                              timeout_s, "the scan goal")
        if not handle.accepted:
            raise ScanFailed("scan goal rejected: a scan is running (cancel it first)")
        goal.accepted(handle)
        return goal

    def send_calibrate(self, *, plan_file: str = "", apply: bool = False,
                       feedback: Callable[[Calibrate.Feedback], None] | None = None,
                       timeout_s: float = 30.0, **board) -> CalibrateGoal:
        """Send a ``Calibrate`` goal to the calibration node (``plan_file`` "": its plan;
        ``board``: ``columns``, ``rows``, ``square_m``, ``marker_m``, ``dictionary``, each
        left out: its parameter); the accepted goal, or ScanFailed when rejected (a
        calibration is running). ``feedback`` sees every Calibrate.Feedback."""
        goal = CalibrateGoal(feedback, self.node.get_logger())
        request = Calibrate.Goal(plan_file=plan_file, apply=bool(apply), **board)
        if not self._calibrate.wait_for_server(timeout_sec=timeout_s):
            raise ServiceError(f"the {CALIBRATE_ACTION} action is not available (waited "
                               f"{timeout_s:g} s): is the calibration node running?")
        handle = _wait_future(self._calibrate.send_goal_async(
            request, feedback_callback=goal.feedback_message), timeout_s, "the calibrate goal")
        if not handle.accepted:
            raise ScanFailed("calibrate goal rejected: a calibration is running")
        goal.accepted(handle)
        return goal

    def calibrate(self, *, timeout_s: float = 3600.0, **goal) -> Calibrate.Result:
        """Calibrate (:meth:`send_calibrate` with ``goal``) to the end; the result of a
        calibration that succeeded, ScanFailed with the reason otherwise."""
        return self.send_calibrate(**goal).wait(timeout_s)

    def scan_goal(self, *, timeout_s: float = 1800.0, **goal) -> Scan.Result:
        """Scan (:meth:`send_scan` with ``goal``) to the end; the result of a scan that
        succeeded, ScanFailed with the reason otherwise."""
        return self.send_scan(**goal).wait(timeout_s)

    def start_scan(self) -> int:
        """Call ``scan/start`` (the Trigger alias: the scan is followed on the status topic,
        :meth:`wait_scan_done`); the number of the new scan, or ScanFailed with the
        reason."""
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

    def reconstruct(self, timeout_s: float = 600.0, *, pictures: bool = True,
                    **options) -> dict:
        """Call the typed ``reconstruct_mesh``; its answer as :func:`mesh_summary`, or
        ScanFailed with the node's reason.

        ``options``: the request's ``resolution``, ``bounds_m``, ``mesher``, ``colour``
        and ``texture`` ("yes" / "no"), ``output_name`` (each left out: the node's); the
        textured model follows the answer (:func:`wait_for_product`). With ``pictures`` the
        node answers once the picture, viewer and contact sheet are written too; without,
        once the mesh and its report are (:func:`wait_for_pictures` waits for the rest).
        A request without an answer is sent again (:data:`RECONSTRUCT_RESEND_S`) until
        ``timeout_s``."""
        request = Reconstruct.Request(wait_for_pictures=pictures, **options)
        answer = call(self._reconstruct, request, timeout_s=timeout_s,
                      resend_after_s=RECONSTRUCT_RESEND_S, keep_resending=True)
        if not answer.success:
            raise ScanFailed(answer.message)
        return mesh_summary(answer)

    def close(self) -> None:
        self._closing.set()
        self._spinner.join(timeout=CLOSE_S)
        self._executor.shutdown()
        self._action.destroy()
        self._calibrate.destroy()
        self.node.destroy_node()
        self._context.try_shutdown()

    def __enter__(self) -> CellClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
