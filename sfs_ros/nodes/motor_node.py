"""Motor node: the turntable and carriage behind a GRBL 1.1 controller.

| kind | name | type | notes |
|---|---|---|---|
| pub | ``joint_states`` | sensor_msgs/JointState | turntable, carriage; rad; encoder read-back |
| pub | ``/diagnostics`` | diagnostic_msgs/DiagnosticArray | 1 Hz and on every fault |
| sub | ``joint_command`` | sensor_msgs/JointState | target positions by joint name, rad |
| srv | ``~/home`` | std_srvs/Trigger | homing cycle; also recovers from an alarm |
| srv | ``~/stop`` | std_srvs/Trigger | stop now, keep the position |

Behaviour
---------
* A managed (lifecycle) node (:mod:`sfs_ros.ros.lifecycle`): ``configure`` opens
  the port (it fails, the node staying unconfigured, when the port cannot be
  opened), ``activate`` starts the polling and serves ``home``, ``stop`` and
  ``joint_command``, ``deactivate`` stops the axes, the polling and those
  interfaces, ``cleanup`` closes the port, ``shutdown`` does all from any state.
  While the node is not active its command interfaces are not there: a caller
  waits for them as for a node not started yet. With ``autostart`` the node brings
  itself up at start-up, trying the port again every ``reconnect_period_s``
  (INFO) until it opens.
* ``joint_states`` is published at ``status_rate_hz`` from a timer that polls
  the controller (``?``) while active; nothing is published while the position
  is unknown (not connected, critical alarm, homing before the first report).
* The alarm lock of a controller just powered up (GRBL with homing enabled:
  state Alarm without an alarm code) is a state, not a fault: diagnostics WARN
  until homed. A status report later than ``status_timeout_s`` is a WARN; the
  controller silent for ``silent_error_s`` is a fault (ERROR, "no answer").
* Moves and homing run one at a time in a worker thread, never in the
  executor. A ``joint_command`` that arrives while a move runs **preempts**
  it: the axes come to a controlled stop (feed hold, no alarm) and the new
  move starts from there; a command that arrives during homing waits for the
  homing to end. Only the latest waiting command is kept.
* A command without both joints, or with a non-finite position, is refused
  with a log line and an ERROR diagnostic; the node carries on.
* ``stop`` drops any waiting command and interrupts the running move: feed
  hold, then a soft reset once stopped, so the position is kept and no alarm
  raised (homing: soft reset, after which the controller wants homing again).
  It succeeds when the axes are at rest, also when an alarm had already
  stopped them (the message says so); it fails when not connected.
* ``home`` waits for the homing cycle (its answer comes when the axes are
  home, or with the reason they are not). A ``home`` that comes while a
  homing is waiting or running joins it (one cycle, the same answer), so a
  caller may send it again when an answer is late. After a limit alarm the
  controller answers nothing but a soft reset: ``home`` then resets first,
  then homes (GRBL accepts ``$H`` in the alarm lock, so no separate unlock is
  needed).
* Faults (timeouts, alarms with a code, stalls, rejected commands, lost
  connection) are logged and reported as ERROR diagnostics until the next
  successful move or homing. A lost connection closes the port; the node tries
  to reopen it every ``reconnect_period_s`` while configured.

The executor is multi-threaded (4 threads): the services and the command
subscription are reentrant (``home`` holds one thread while it waits for the
worker), the polling and reconnect timers mutually exclusive with each other.
Parameters: :data:`PARAMS`; the timeouts may be changed at run time (validated).
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import Future
from functools import partial

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.lifecycle import LifecycleNode
from rclpy.service import Service
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from sfs_ros.hardware.driver import (
    ConnectionLost,
    GrblClient,
    MotionCancelled,
    MotorAlarm,
    MotorError,
    MotorTimeout,
)
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros.convert import angles_from_joint_state, diagnostic_array, health, joint_state
from sfs_ros.ros.lifecycle import AUTOSTART, FAILURE, SUCCESS, bring_up
from sfs_ros.ros.names import DIAGNOSTICS, private, status_name
from sfs_ros.ros.params import Param, ParameterError, declare, validating_callback
from sfs_ros.ros.worker import Hold, JobCancelled, Worker

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
#: The alarm of a controller just powered up with homing enabled: a state, its remedy home.
LOCKED = "alarm lock since power-up: home the axes (motor/home) before moving"


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
        self._client_lock = threading.Lock()
        self._client: GrblClient | None = None
        self._connection_error = ""
        self._fault = ""                   # the last fault, "" after a good move / homing
        self._faults = 0
        self._refused = 0
        self._state = "unknown"
        self._position: tuple[float, float] | None = None
        self._alarm: str = ""
        self._home_on_start = bool(self._p["home_on_start"])
        self._homing_lock = threading.Lock()
        self._homing: Future | None = None  # the homing waiting or running, joined by a home

        # Moves and homing, one at a time; a hold while the axes are being stopped.
        self._worker = Worker("motor-worker", on_error=self._job_failed)

        self._lifecycle = "unconfigured"
        self._answered_at = time.monotonic()   # the controller's last status report
        self._late = ""                    # a status poll went unanswered (WARN)
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
        if not self._open(first=True):
            return FAILURE
        self._timers.append(self.create_timer(self._p["reconnect_period_s"], self._reconnect,
                                              callback_group=self._polling))
        return self._now("inactive")

    def on_activate(self, _state):
        self._answered_at = time.monotonic()
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
        self._close()
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

    def _close(self) -> None:
        with self._client_lock:
            client, self._client = self._client, None
        if client is not None:
            client.close()
        self._state, self._position, self._connection_error = "unknown", None, ""

    # -- connection --------------------------------------------------------------------------

    def _reconnect(self) -> None:
        if self._client is None:
            self._open(first=False)

    def _open(self, *, first: bool) -> bool:
        """Open the port; whether it is open. A port that cannot be opened is a WARN at
        ``configure`` (``first``) and, after a loss, an ERROR once per reason."""
        try:
            client = GrblClient(self._p["port"], baudrate=self._p["baudrate"])
        except (MotorError, ValueError) as exc:
            if first:
                self.get_logger().warning(f"configure failed: {exc}")
            elif str(exc) != self._connection_error:
                self.get_logger().error(f"{exc}; retrying every {self._p['reconnect_period_s']} s")
            self._connection_error = str(exc)
            self._publish_diagnostics()
            return False
        with self._client_lock:
            self._client = client
        self._connection_error = ""
        self._answered_at = time.monotonic()
        self.get_logger().info(f"connected to the motor controller on {self._p['port']}")
        self._publish_diagnostics()
        return True

    def _lost(self, exc: Exception) -> None:
        """The port failed: close it; the reconnect timer reopens it."""
        with self._client_lock:
            client, self._client = self._client, None
        if client is not None:
            client.close()
            self._connection_error = f"connection lost: {exc}"
            self._state, self._position = "disconnected", None
            self.get_logger().error(f"{self._connection_error}; retrying every "
                                    f"{self._p['reconnect_period_s']} s")
            self._publish_diagnostics()

    # -- polling -------------------------------------------------------------------------

    def _poll(self) -> None:
        client = self._client
        if client is None:
            return
        # The reading is stamped when it is asked for: the controller answers within
        # milliseconds, and a stamp taken before the answer can never fall after a loss of
        # the port that the answer preceded (this thread may be held up after reading).
        asked = self.get_clock().now().to_msg()
        try:
            status = client.status(timeout_s=self._p["status_timeout_s"])
        except ConnectionLost as exc:
            self._lost(exc)
            return
        except MotorAlarm as exc:
            self._state, self._position = "Alarm", None
            self._set_alarm(str(exc))
            return
        except MotorTimeout as exc:
            self._unanswered(str(exc))
            return
        except MotorError as exc:
            self._report_fault(str(exc))
            return
        self._answered()
        self._state = status.state
        if status.state == "Alarm":
            code = client.alarm_code
            self._set_alarm(str(MotorAlarm(code)) if code is not None else LOCKED)
        else:
            self._alarm = ""
        if math.isfinite(status.theta_rad) and math.isfinite(status.phi_rad):
            self._position = (status.theta_rad, status.phi_rad)
            self._joints_pub.publish(joint_state(status.theta_rad, status.phi_rad, stamp=asked))

    def _unanswered(self, text: str) -> None:
        """A status poll went unanswered: a WARN, and once the controller has been silent for
        ``silent_error_s`` a fault (ERROR, state "no answer"), each said once."""
        silent_s = time.monotonic() - self._answered_at
        if silent_s >= self._p["silent_error_s"]:
            if self._state != "no answer":
                self._state = "no answer"
                self._report_fault(f"no answer from the motor controller for {silent_s:.1f} s: "
                                   f"{text}")
        elif not self._late:
            self._late = f"a status report came late ({text}); waiting for the next one"
            self.get_logger().warning(self._late)
            self._publish_diagnostics()

    def _answered(self) -> None:
        """A status report came: the controller answers (again)."""
        self._answered_at = time.monotonic()
        if self._state == "no answer":
            self.get_logger().info("the motor controller answers again")
        self._late = ""

    def _set_alarm(self, text: str) -> None:
        """The controller is in alarm: the lock of a controller just powered up is a state
        (INFO; WARN diagnostics until homed), any other alarm a fault (ERROR)."""
        if text != self._alarm:
            self._alarm = text
            if text == LOCKED:
                self.get_logger().info(text)
            else:
                self.get_logger().error(text)
            self._publish_diagnostics()

    # -- commands --------------------------------------------------------------------------

    def _on_command(self, msg: JointState) -> None:
        try:
            target = angles_from_joint_state(msg)
        except ValueError as exc:
            self._refused += 1
            self._report_fault(f"joint_command refused: {exc}")
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
        response.message = error or f"homed; state {self._state}"
        return response

    def _on_stop(self, _request, response):
        hold = self._worker.hold()
        self._worker.cancel_pending("cancelled by stop")
        client = self._client
        try:
            if client is None:
                response.success = False
                response.message = f"not connected: {self._connection_error}"
                return response
            status = client.stop()
        except MotorAlarm as exc:
            response.success, response.message = True, f"axes stopped by an alarm: {exc}"
            return response
        except ConnectionLost as exc:
            self._lost(exc)
            response.success, response.message = False, str(exc)
            return response
        except MotorError as exc:
            self._report_fault(f"stop failed: {exc}")
            response.success, response.message = False, str(exc)
            return response
        finally:
            hold.release()
        response.success = True
        response.message = (f"stopped at theta={status.theta_rad:.4f} rad, "
                            f"phi={status.phi_rad:.4f} rad (state {status.state})")
        self.get_logger().info(response.message)
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

    def _interrupt(self, hold: Hold) -> None:
        """Stop the axes, then release ``hold`` (the worker starts no job until then)."""
        client = self._client
        try:
            if client is not None:
                client.stop()
        except ConnectionLost as exc:
            self._lost(exc)
        except MotorError as exc:          # alarm, timeout: the running job reports it
            self.get_logger().warning(f"could not stop the running move: {exc}")
        finally:
            hold.release()

    # -- worker jobs: the error text, or None when done -------------------------------------

    def _move(self, theta: float, phi: float) -> str | None:
        def move(client: GrblClient) -> None:
            self.get_logger().info(f"moving to theta={theta:.4f} rad, phi={phi:.4f} rad")
            client.move_to(theta, phi, timeout_s=self._param("move_timeout_s"))
        return self._drive("move", move)

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
        return self._drive("home", home)

    def _drive(self, kind: str, motion) -> str | None:
        """Run ``motion(client)``; the error text (reported as a fault), or None."""
        client = self._client
        if client is None:
            error = f"{kind} refused: not connected ({self._connection_error})"
            self._report_fault(error)
            return error
        try:
            motion(client)
        except MotionCancelled as exc:
            self.get_logger().info(str(exc))
            return str(exc)
        except ConnectionLost as exc:
            self._lost(exc)
            return str(exc)
        except MotorTimeout as exc:
            self._report_fault(str(exc))
            if kind == "move":             # the axes may still be moving
                self._interrupt(self._worker.hold())
            return str(exc)
        except MotorError as exc:
            self._report_fault(str(exc))
            return str(exc)
        self._fault = ""
        self._alarm = ""
        self.get_logger().info(f"{kind} done")
        self._publish_diagnostics()
        return None

    def _job_failed(self, kind: str, exc: Exception) -> None:
        self._report_fault(f"{kind} failed: internal error {type(exc).__name__}: {exc}")

    def _param(self, name: str):
        return self.get_parameter(name).value

    # -- diagnostics ----------------------------------------------------------------------

    def _report_fault(self, text: str) -> None:
        self._fault = text
        self._faults += 1
        self.get_logger().error(text)
        self._publish_diagnostics()

    def _level(self, client: GrblClient | None) -> tuple[bytes, str]:
        """The diagnostics' level and message: ERROR for a fault, WARN for what waits on
        someone (a node not active, the alarm lock of power-up, a late report), else OK."""
        if self._lifecycle != _ACTIVE:
            closed = "" if client is not None else " (port closed)"
            return DiagnosticStatus.WARN, (f"the motor node is {self._lifecycle}: activate it "
                                           f"(lifecycle change_state){closed}")
        problem = (self._connection_error or "not connected") if client is None else (
            self._fault or (self._alarm if self._alarm != LOCKED else ""))
        return health(problem, self._alarm or self._late, f"state {self._state}")

    def _publish_diagnostics(self) -> None:
        client = self._client
        level, message = self._level(client)
        values = {
            "lifecycle": self._lifecycle, "port": self._p["port"],
            "connected": client is not None, "state": self._state,
            "alarm": self._alarm, "last_fault": self._fault, "faults": self._faults,
            "refused_commands": self._refused,
            "noise_lines": client.noise_lines if client is not None else "",
            "job": self._worker.current or "",
        }
        if self._position is not None:
            values.update(theta_rad=f"{self._position[0]:.6f}",
                          phi_rad=f"{self._position[1]:.6f}")
        self._diag_pub.publish(diagnostic_array(
            status_name(self, "motor"), level, message, values,
            stamp=self.get_clock().now().to_msg(), hardware_id=self._p["port"]))

    def _release(self) -> None:
        """Stop the worker (and the axes, if moving) and close the port."""
        self._worker.stop(cancel_reason="node shutting down")
        if self._worker.current is not None:
            self._interrupt(self._worker.hold())
        self._worker.join(timeout_s=5.0)
        self._close()

    def destroy_node(self) -> None:
        self._release()
        super().destroy_node()


def main(args=None) -> None:
    """Entry point ``sfs-motor`` (``--ros-args --params-file config/motor.yaml -p port:=...``)."""
    configure_process()
    run_node("sfs-motor", MotorNode, args, threads=4)


if __name__ == "__main__":
    main()
