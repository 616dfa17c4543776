"""Motor node: the turntable and carriage behind a GRBL 1.1 controller.

A managed (lifecycle) node wiring ``joint_command``, ``~/home`` and ``~/stop`` to the
controller (:class:`sfs_ros.cell_logic.motor_link.MotorLink`), one move or homing at a time in
a worker thread, and publishing ``joint_states``. What it does, in full:
``doc/nodes.md``; its parameters: ``doc/reference.md`` (generated from :data:`PARAMS`);
its topics and services: ``doc/cell.md``.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future
from functools import partial

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.lifecycle import LifecycleNode
from rclpy.service import Service
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from sfs_ros.cell_logic.motor_link import MotorLink
from sfs_ros.hardware.driver import GrblClient, MotorAlarm
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros.convert import angles_from_joint_state, diagnostic_array, health, joint_state
from sfs_ros.ros.lifecycle import AUTOSTART, FAILURE, SUCCESS, bring_up
from sfs_ros.ros.log import log_at
from sfs_ros.ros.names import DIAGNOSTICS, private, status_name
from sfs_ros.ros.params import Param, ParameterError, declare, validating_callback
from sfs_ros.ros.worker import JobCancelled, JobsOnHold, Worker

__all__ = ["MotorNode", "PARAMS", "main"]

NODE_NAME = "motor"

PARAMS: list[Param] = [
    Param("port", "", "Serial port of the GRBL controller (/dev/ttyACM0, a pty, or a pyserial "
          "URL).", read_only=True, constraints="required, non-empty"),
    Param("baudrate", 115200, "Serial baud rate.", bounds=(1200, 4000000), read_only=True),
    Param("status_rate_hz", 10.0, "Rate of joint_states (one status query each).",
          bounds=(0.5, 50.0), read_only=True),
    Param("move_timeout_s", 30.0, "Deadline of one move, seconds.", bounds=(0.1, 3600.0)),
    Param("home_timeout_s", 60.0, "Deadline of the homing cycle, seconds.",
          bounds=(0.1, 3600.0)),
    Param("home_on_start", False, "Home as soon as the controller is connected.",
          read_only=True),
    Param("reconnect_period_s", 2.0, "Period of the attempts to reopen a lost port, seconds.",
          bounds=(0.1, 600.0), read_only=True),
    Param("status_timeout_s", 0.5, "Longest wait for one status report; a late one is a WARN, "
          "seconds.", bounds=(0.01, 60.0), read_only=True),
    Param("silent_error_s", 2.0, "The controller silent this long is a fault (ERROR, no "
          "answer), seconds.", bounds=(0.1, 600.0), read_only=True),
    AUTOSTART,
]
#: The lifecycle state in which the node takes commands.
_ACTIVE = "active"


def _validate(values: dict) -> None:
    """Cross-field rules beyond types and ranges; raises :class:`ParameterError`."""
    if not values["port"].strip():
        raise ParameterError("port", f"got {values['port']!r}, expected the controller's serial "
                             f"port, e.g. /dev/ttyACM0")


class MotorNode(LifecycleNode):
    """Drives the cell's two axes through :class:`GrblClient`.

    Raises :class:`ParameterError` at construction for invalid parameters.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._p = declare(self, PARAMS)
            _validate(self._p)
        except ParameterError:
            super().destroy_node()         # nothing of ours to release yet
            raise
        self.add_on_set_parameters_callback(validating_callback(self, PARAMS, _validate))
        self._link = MotorLink(self._p["port"], self._p["baudrate"],
                               self._p["reconnect_period_s"],
                               log=partial(log_at, self.get_logger()),
                               changed=self._publish_diagnostics)
        self._home_on_start = bool(self._p["home_on_start"])
        self._homing_lock = threading.Lock()
        self._homing: Future | None = None  # the homing waiting or running, joined by a home

        # Moves and homing, one at a time; a hold while the axes are being stopped.
        self._worker = Worker("motor-worker", on_error=self._job_failed)

        self._lifecycle = "unconfigured"
        self._timers = []                  # reconnecting (configured), polling (active)

        self._joints_pub = self.create_publisher(JointState, "joint_states", 10)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self._reentrant = ReentrantCallbackGroup()
        self._polling = MutuallyExclusiveCallbackGroup()
        self._commands = []                # joint_command, home, stop: while active
        self.create_timer(1.0, self._publish_diagnostics, callback_group=self._reentrant)
        self.get_logger().info(f"motor controller on {self._p['port']}, joint_states at "
                               f"{self._p['status_rate_hz']} Hz when active")
        self._autostart = None
        if self._p["autostart"] and not bring_up(self):
            self.get_logger().info(f"waiting for the port {self._p['port']}: trying again "
                                   f"every {self._p['reconnect_period_s']} s")
            self._autostart = self.create_timer(self._p["reconnect_period_s"],
                                                self._try_autostart)

    # -- lifecycle -----------------------------------------------------------------------------

    def _try_autostart(self) -> None:
        if self._lifecycle == "unconfigured" and bring_up(self):
            self._autostart.cancel()

    def on_configure(self, _state):
        if not self._link.open(first=True):
            return FAILURE
        self._timers.append(self.create_timer(self._p["reconnect_period_s"],
                                              self._link.reconnect,
                                              callback_group=self._polling))
        return self._now("inactive")

    def on_activate(self, _state):
        self._link.expect_reports()
        self._timers.append(self.create_timer(1.0 / self._p["status_rate_hz"], self._poll,
                                              callback_group=self._polling))
        group = self._reentrant
        self._commands = [
            self.create_subscription(JointState, "joint_command", self._on_command, 10,
                                     callback_group=group),
            self.create_service(Trigger, private("home"), self._on_home, callback_group=group),
            self.create_service(Trigger, private("stop"), self._on_stop, callback_group=group)]
        state = self._now(_ACTIVE)
        if self._home_on_start:            # the first activation only
            self._home_on_start = False
            self._join_homing()
        return state

    def on_deactivate(self, _state):
        self._withdraw()
        self._halt()
        self._destroy_timers(keep=1)       # the reconnect timer stays
        return self._now("inactive")

    def on_cleanup(self, _state):
        self._destroy_timers()
        self._link.close()
        return self._now("unconfigured")

    def on_shutdown(self, _state):
        self._withdraw()
        self._destroy_timers()
        self._release()
        return self._now("finalized")

    def _now(self, state: str):
        """Enter lifecycle ``state`` (logged, in the diagnostics); SUCCESS."""
        self._lifecycle = state
        self.get_logger().info(f"motor node {state}")
        self._publish_diagnostics()
        return SUCCESS

    def _withdraw(self) -> None:
        """Take the command interfaces away (``joint_command``, ``home``, ``stop``)."""
        for entity in self._commands:
            if isinstance(entity, Service):
                self.destroy_service(entity)
            else:
                self.destroy_subscription(entity)
        self._commands = []

    def _destroy_timers(self, keep: int = 0) -> None:
        while len(self._timers) > keep:
            self.destroy_timer(self._timers.pop())

    def _halt(self) -> None:
        """Drop waiting commands and stop a running move or homing."""
        self._worker.cancel_pending("node deactivated")
        if self._worker.current is not None:
            self._interrupt(self._worker.hold())

    def _poll(self) -> None:
        """Timer: ``joint_states`` from the controller's status, when the axes' position is
        known."""
        # The reading is stamped when it is asked for: the controller answers within
        # milliseconds, and a stamp taken before the answer can never fall after a loss of
        # the port that the answer preceded (this thread may be held up after reading).
        asked = self.get_clock().now().to_msg()
        position = self._link.poll(self._p["status_timeout_s"], self._p["silent_error_s"])
        if position is not None:
            self._joints_pub.publish(joint_state(*position, stamp=asked))

    # -- commands --------------------------------------------------------------------------

    def _on_command(self, msg: JointState) -> None:
        try:
            target = angles_from_joint_state(msg)
        except ValueError as exc:
            self._link.refused += 1
            self._link.report_fault(f"joint_command refused: {exc}")
            return
        self._submit("move", partial(self._move, *target))

    def _on_home(self, _request, response):
        try:
            error = self._join_homing().result()
        except JobCancelled as exc:       # superseded, stopped, shutting down
            error = str(exc)
        except Exception as exc:  # noqa: BLE001 -- a bug in the job, already reported
            error = f"home failed: internal error {type(exc).__name__}: {exc}"
        response.success = error is None
        response.message = error or f"homed; state {self._link.state}"
        return response

    def _on_stop(self, _request, response):
        hold = self._worker.hold()
        self._worker.cancel_pending("cancelled by stop")
        try:
            response.success, response.message = self._link.stop()
        finally:
            hold.release()
        return response

    def _join_homing(self) -> Future:
        """The future of the homing waiting or running, or of a new one."""
        with self._homing_lock:
            if self._homing is None or self._homing.done():
                self._homing = self._submit("home", self._home)
            else:
                self.get_logger().info("home asked while homing: joining the homing under way")
            return self._homing

    def _submit(self, kind: str, job) -> Future:
        """Queue ``job`` (a move or homing, answering its error or None) in place of a waiting
        one, stopping a running move first; its future."""
        hold = self._worker.hold()         # nothing starts until the preemption is decided
        self._worker.cancel_pending("superseded by a later request")
        future = self._worker.submit(job, name=kind)
        if self._worker.current == "move":
            self._interrupt(hold)
        else:
            hold.release()
        return future

    def _interrupt(self, hold: JobsOnHold) -> None:
        """Stop the axes, then release ``hold`` (the worker starts no job until then)."""
        try:
            self._link.halt()
        finally:
            hold.release()

    # -- worker jobs: the error text, or None when done -------------------------------------

    def _move(self, theta: float, phi: float) -> str | None:
        def move(client: GrblClient) -> None:
            self.get_logger().info(f"moving to theta={theta:.4f} rad, phi={phi:.4f} rad")
            client.move_to(theta, phi, timeout_s=self._param("move_timeout_s"))
        return self._link.drive("move", move,        # the axes may still be moving
                                on_timeout=lambda: self._interrupt(self._worker.hold()))

    def _home(self) -> str | None:
        def home(client: GrblClient) -> None:
            self.get_logger().info("homing")
            try:
                client.status()
            except MotorAlarm as exc:
                if exc.critical:
                    self.get_logger().info("soft reset to clear the alarm before homing")
                    client.reset()
            client.home(timeout_s=self._param("home_timeout_s"))
        return self._link.drive("home", home)

    def _job_failed(self, kind: str, exc: Exception) -> None:
        self._link.report_fault(f"{kind} failed: internal error {type(exc).__name__}: {exc}")

    def _param(self, name: str):
        return self.get_parameter(name).value

    # -- diagnostics ----------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        level, message = health(*self._link.health(self._lifecycle))
        values = self._link.values(self._lifecycle, self._worker.current or "")
        self._diag_pub.publish(diagnostic_array(
            status_name(self, "motor"), level, message, values,
            stamp=self.get_clock().now().to_msg(), hardware_id=self._p["port"]))

    def _release(self) -> None:
        """Stop the worker (and the axes, if moving) and close the port."""
        self._worker.stop(cancel_reason="node shutting down")
        if self._worker.current is not None:
            self._interrupt(self._worker.hold())
        self._worker.join(timeout_s=5.0)
        self._link.close()

    def destroy_node(self) -> None:
        self._release()
        super().destroy_node()


def main(args=None) -> None:
    """Entry point ``sfs-motor`` (``--ros-args --params-file config/motor.yaml -p port:=...``)."""
    configure_process()
    run_node("sfs-motor", MotorNode, args, threads=4)


if __name__ == "__main__":
    main()
