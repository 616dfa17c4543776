"""Recorder node: a scanning session as a rosbag2 (MCAP, or sqlite3 on request).

It subscribes to the cell's topics from start-up (their serialized bytes) and writes
them, in one worker thread, into a bag (:class:`sfs_ros.cell_logic.bag.writing.BagWriter`)
opened on ``~/record/start`` or (``with_scan``) with each scan, with the parameters of the
cell's nodes (:mod:`sfs_ros.ros.parameter_fetch`). What it does, in full:
``doc/nodes.md``; its parameters: ``doc/reference.md`` (generated from :data:`PARAMS`);
its topics and services: ``doc/cell.md``; the bag's layout: :mod:`sfs_ros.cell_logic.bag.layout`.
"""

from __future__ import annotations

import json
import threading
import time
import traceback
from concurrent.futures import Future
from functools import partial

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.parameter_client import AsyncParameterClient
from rclpy.serialization import deserialize_message
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.bag import (
    CAPTURE,
    PARAMETERS_TOPIC,
    RECORDER_TOPICS,
    RESULT,
    SCAN_TOPIC,
    TOPICS,
    BagWriter,
    new_bag_folder,
    parameters_message,
    scan_message,
)
from sfs_ros.cell_logic.message_fields import scan_report
from sfs_ros.cell_logic.recording_status import RecordingStatus
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import capture_qos, result_qos
from sfs_ros.ros.convert import diagnostic_array, health
from sfs_ros.ros.message_types import message_class
from sfs_ros.ros.names import DIAGNOSTICS, RECORDER_NODE, private, status_name
from sfs_ros.ros.parameter_fetch import fetch_parameters
from sfs_ros.ros.params import declare, output_folder, validating_callback
from sfs_ros.ros.recorder_params import BAG_NAME, PARAMS, check_bag_name
from sfs_ros.ros.worker import Worker

__all__ = ["RecorderNode", "PARAMS", "main"]

NODE_NAME = RECORDER_NODE

class RecorderNode(Node):
    """Records the cell's topics into rosbag2 bags on request or with each scan.

    Raises :class:`ParameterError` at construction for invalid parameters.
    ``destroy_node`` writes what is queued and closes the bag.
    """

    def __init__(self, **kwargs):
        self._worker = None   # started last; a node refused at start-up has none to stop
        self._stopping = threading.Event()     # set as the node stops: a fetch gives up
        super().__init__(NODE_NAME, **kwargs)
        p = self._p = declare(self, PARAMS)
        bags = output_folder(p["output_dir"], "the bags", "bags")
        check_bag_name(p["output_dir"], {"bag_name": p["bag_name"]})
        self.add_on_set_parameters_callback(validating_callback(
            self, [BAG_NAME], partial(check_bag_name, p["output_dir"])))

        self._status = RecordingStatus(p["storage"])
        self._last_ns = 0
        self._scan_seen = None
        self._bag_scan: int | None = None     # the scan the open bag holds, if known
        self._bag: BagWriter | None = None           # worker thread only
        self._fetched: Future | None = None
        self._started = 0.0

        inputs = MutuallyExclusiveCallbackGroup()     # in order: strictly increasing log times
        services = MutuallyExclusiveCallbackGroup()
        clients = ReentrantCallbackGroup()
        self._topics: dict[str, tuple[str, str]] = {}  # absolute name -> (type, kind)
        for name, (msgtype, kind) in TOPICS.items():
            if name in RECORDER_TOPICS:
                continue
            # Deep queues everywhere: the diagnostics of six nodes come in bursts (at a
            # scan's start above all), and a keep-last queue of 10 would drop some.
            qos = capture_qos(p["queue_depth"]) if kind == CAPTURE \
                else result_qos() if kind == RESULT else p["queue_depth"]
            # The bag keeps every topic under the cell's namespace; the diagnostics come
            # from the absolute topic they are published on.
            topic = self.resolve_topic_name(name)
            source = DIAGNOSTICS if name == "diagnostics" else name
            self.create_subscription(message_class(msgtype), source,
                                     partial(self._on_message, topic), qos,
                                     callback_group=inputs, raw=True)
            self._topics[topic] = (msgtype, kind)
        self._diagnostics_topic = self.resolve_topic_name("diagnostics")
        self._parameters_topic = self.resolve_topic_name(PARAMETERS_TOPIC)
        self._scan_topic = self.resolve_topic_name(SCAN_TOPIC)
        self._bag_scan_written: int | None = None    # the last sfs/scan record in the bag
        self._parameter_clients = {n: AsyncParameterClient(self, n, callback_group=clients)
                                   for n in p["parameter_nodes"]}
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.create_service(Trigger, private("record/start"), self._on_start,
                            callback_group=services)
        self.create_service(Trigger, private("record/stop"), self._on_stop,
                            callback_group=services)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=inputs)
        self._worker = Worker("recorder", on_error=self._job_failed)
        self.get_logger().info(
            f"recording into {bags} ({p['storage']}"
            f"{', a bag per scan' if p['with_scan'] else ''}): call recorder/start")

    def destroy_node(self) -> None:
        """Write what is queued, close the bag, stop the worker, then destroy the node. A
        fetch of parameters still waiting (a node that does not answer) gives up at once:
        the bag is closed with what came."""
        self._stopping.set()
        if self._worker is not None:
            self._worker.submit(self._close, name="close")
            self._worker.stop()
            self._worker.join()
        super().destroy_node()

    # -- inputs (executor) -------------------------------------------------------------------

    def _on_message(self, topic: str, data: bytes) -> None:
        # 2 ns apart at least: room for an sfs/scan record just before a diagnostics message
        now = max(self.get_clock().now().nanoseconds, self._last_ns + 2)
        self._last_ns = now
        if self._p["with_scan"] and topic == self._diagnostics_topic:
            self._watch_scan(data)
        self._submit("message", self._record, topic, now, data)

    def _watch_scan(self, data: bytes) -> None:
        """Queue a new bag when the scan node reports a new scan starting."""
        report = scan_report(deserialize_message(data, DiagnosticArray), self.get_namespace())
        # "starting" is a moment (reset, homing): a report of the scan in any later
        # state opens its bag too, if that moment was missed.
        if report is not None and report[0] != self._scan_seen \
                and report[1] in ("starting", "running"):
            self._scan_seen = report[0]
            self._submit("scan", self._scan_started, report[0])

    def _on_start(self, _request, response):
        return self._request(self._submit("start", self._open, None, rolling=False), response)

    def _on_stop(self, _request, response):
        return self._request(self._submit("stop", self._stop), response)

    @staticmethod
    def _request(answer: Future, response):
        """Answer a service with the ``(success, message)`` of a worker job."""
        try:
            response.success, response.message = answer.result()
        except Exception as exc:  # noqa: BLE001 -- the worker reported it and closed the bag
            response.success, response.message = False, f"{type(exc).__name__}: {exc}"
        return response

    def _submit(self, name: str, job, *args, **kwargs) -> Future:
        """Queue ``job(*args, **kwargs)`` for the worker; its future."""
        return self._worker.submit(partial(job, *args, **kwargs), name=name)

    # -- worker thread -----------------------------------------------------------------------

    def _job_failed(self, _name: str, exc: Exception) -> None:
        """A job failed (disk full, a bug): report it and close the bag; keep serving."""
        if not isinstance(exc, OSError):
            self.get_logger().error("".join(traceback.format_exception(exc)))
        what = "write failed" if isinstance(exc, OSError) else \
            f"internal error {type(exc).__name__}"
        self._report_problem(f"bag {self._status.path}: {what}: {exc}; bag closed")
        self._abandon()

    def _record(self, topic: str, log_ns: int, data: bytes) -> None:
        """Write a received message (with ``with_scan``, a capture opens a bag if none is)."""
        if self._bag is None and self._p["with_scan"] and self._topics[topic][1] == CAPTURE:
            self._open(None, rolling=True)    # a capture before its scan's report
        self._write(topic, log_ns, data)

    def _scan_started(self, scan: int) -> None:
        """The scan node reported scan ``scan``: the bag its first capture opened is that
        scan's, else a new bag opens."""
        if self._bag is not None and self._bag_scan is None:
            self._bag_scan = scan
        elif self._bag is None or self._bag_scan != scan:
            self._open(scan, rolling=True)

    def _stop(self) -> tuple[bool, str]:
        return self._close() if self._bag is not None \
            else (False, "not recording: call recorder/start first")

    def _open(self, scan: int | None, *, rolling: bool) -> tuple[bool, str]:
        """Open a bag (closing the one open when ``rolling``): ``scan_NNN_<time>`` for scan
        NNN, ``scan_<time>`` for a scan not yet reported, ``bag_<time>`` on request."""
        if self._bag is not None:
            if not rolling:
                return False, (f"already recording to {self._bag.path}; call recorder/stop "
                               "first")
            self._close()
        name = self.get_parameter("bag_name").value
        try:
            folder = new_bag_folder(self._p["output_dir"], name, scan=scan, rolling=rolling,
                                    stamp=time.strftime("%Y%m%d_%H%M%S", time.gmtime()))
            bag = BagWriter(folder, storage=self._p["storage"])
        except ValueError as exc:
            text = f"cannot start recording: {exc}"
            if name:
                text += "; set bag_name to a new name (or empty for an automatic one)"
            self._report_problem(text)
            return False, text
        for topic, (msgtype, kind) in [*self._topics.items(),
                                       (self._parameters_topic, TOPICS[PARAMETERS_TOPIC]),
                                       (self._scan_topic, TOPICS[SCAN_TOPIC])]:
            bag.add_topic(topic, msgtype, kind=kind, depth=self._p["queue_depth"])
        self._bag, self._bag_scan, self._started = bag, scan, time.monotonic()
        self._bag_scan_written = None
        self._fetched = Future()
        self._status.opened(bag.path)
        threading.Thread(target=self._fetch, args=(self._fetched,), daemon=True).start()
        self.get_logger().info(f"recording to {bag.path}")
        self._publish_diagnostics()
        return True, json.dumps({"path": str(bag.path), "storage": bag.storage})

    def _write(self, topic: str, log_ns: int, data: bytes) -> None:
        if self._bag is None:
            return
        if topic == self._diagnostics_topic:
            self._write_scan(log_ns, data)
        start = time.perf_counter()
        self._bag.write(topic, log_ns, data)
        self._status.wrote(self._bag.messages, self._bag.bytes, time.perf_counter() - start)

    def _write_scan(self, log_ns: int, diagnostics: bytes) -> None:
        """Before a diagnostics message that reports a scan new to this bag, an ``sfs/scan``
        record of its number (one ns earlier: log times stay strictly increasing)."""
        report = scan_report(deserialize_message(diagnostics, DiagnosticArray),
                             self.get_namespace())
        if report is None or report[0] == self._bag_scan_written:
            return
        self._bag_scan_written = report[0]
        self._write(self._scan_topic, log_ns - 1, scan_message(report[0]))

    def _write_parameters(self, *, wait: bool = False) -> None:
        """Write the fetched parameters once they are in (``wait``: up to the timeout)."""
        fetched = self._fetched
        if self._bag is None or fetched is None or not (wait or fetched.done()):
            return
        self._fetched = None
        try:
            document = fetched.result(timeout=self._p["parameter_timeout_s"] + 1.0)
        except TimeoutError:
            self._report_warning("the parameters did not arrive before the bag closed")
            return
        self._write(self._parameters_topic,
                    max(self.get_clock().now().nanoseconds, self._last_ns + 1),
                    parameters_message(document))

    def _close(self) -> tuple[bool, str]:
        if self._bag is None:
            return False, "not recording"
        self._write_parameters(wait=True)
        bag, self._bag = self._bag, None
        bag.close()
        seconds = time.monotonic() - self._started
        write_s = self._status.closed()
        self.get_logger().info(f"bag {bag.path} closed: {bag.messages} messages, "
                               f"{bag.bytes / 1e6:.1f} MB in {seconds:.1f} s")
        self._publish_diagnostics()
        return True, json.dumps({"path": str(bag.path), "messages": bag.messages,
                                 "bytes": bag.bytes, "seconds": round(seconds, 3),
                                 "write_s": round(write_s, 4)})

    def _abandon(self) -> None:
        """After a failed write: close what can be closed, record nothing more in this bag."""
        bag, self._bag, self._fetched = self._bag, None, None
        self._status.abandoned()
        if bag is not None:
            try:
                bag.close()
            except Exception as exc:  # noqa: BLE001 -- the file keeps its whole messages
                self.get_logger().error(f"bag {bag.path} could not be closed: {exc}")

    # -- parameters (a thread per bag) -------------------------------------------------------

    def _fetch(self, result: Future) -> None:
        document, unavailable = fetch_parameters(self, self._parameter_clients,
                                                 self._p["parameter_timeout_s"],
                                                 stopping=self._stopping,
                                                 on_answer=self._status.parameters_came)
        if unavailable:
            self._report_warning("parameters not stored: " + "; ".join(
                f"{n}: {why}" for n, why in unavailable.items()))
        result.set_result(document)
        self._worker.submit(self._write_parameters, name="parameters")

    # -- diagnostics (any thread) ------------------------------------------------------------

    def _report_problem(self, text: str) -> None:
        self._status.report(problem=text)
        self.get_logger().error(text)
        self._publish_diagnostics()

    def _report_warning(self, text: str) -> None:
        self._status.report(warning=text)
        self.get_logger().warning(text)

    def _publish_diagnostics(self) -> None:
        if not self.context.ok():          # closing the bag after SIGINT shut rclpy down
            return
        values, problem, warning = self._status.snapshot()
        level, message = health(problem, warning, f"recording to {values['path']}"
                                if values["recording"] else "idle")
        self._diag_pub.publish(diagnostic_array(status_name(self, "recorder"), level, message,
                                                values, stamp=self.get_clock().now().to_msg()))


def main(args=None) -> None:
    """Entry point ``sfs-recorder``
    (``--ros-args --params-file config/recorder.yaml``, with ``output_dir`` set)."""
    configure_process()
    run_node("sfs-recorder", RecorderNode, args, threads=4)


if __name__ == "__main__":
    main()
