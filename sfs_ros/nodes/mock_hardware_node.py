"""Mock hardware: a simulated GRBL controller on a pseudo-terminal, and a mock camera.

A drop-in for the cell's hardware: the real motor node opens the simulated
controller's serial port through pyserial, exactly as it opens
``/dev/ttyACM0``; the camera is the real :class:`CameraNode` (same name,
topics, services and parameters) composed into this process with a
:class:`~sfs_ros.hardware.cameras.RenderedSource`, which renders a known
object at the controller's *true* angles (the encoders read those plus an
offset and noise, as real ones do).

| node | kind | name | type | notes |
|---|---|---|---|---|
| mock_hardware | pub | ``mock/port`` | std_msgs/String | the pty path; reliable, transient-local |
| mock_hardware | srv | ``mock/unplug`` | std_srvs/SetBool | true: unplug the cable; false: plug it back |
| mock_hardware | srv | ``mock/hang`` | std_srvs/SetBool | true: the controller stops answering |
| mock_hardware | srv | ``mock/drop_frame`` | std_srvs/Trigger | the next shutter gives no frame |
| camera | | | | as :mod:`sfs_ros.nodes.camera_node` (backend "mock"; managed) |

The controller's pty (and ``port_link``) is made before the camera node exists, so
a lifecycle manager that has seen the camera finds the motor's port there. The
camera is a managed (lifecycle) node: with ``autostart`` false (``sfs-cell``, the
launch files) it waits unconfigured for its transitions; the rendered source is
kept open across ``cleanup`` and closed when the node is destroyed.

``port_link`` (optional) is a stable device name kept pointing at the
current pseudo-terminal, as a udev rule keeps ``/dev/serial/by-id/...``:
give it to the motor node as ``port``. Unplugging removes the link and
closes the pty (the motor node sees a lost connection); plugging back opens a
new pty and restores the link. The controller has its own power: it keeps
its position and state across an unplug. On shutdown (SIGINT) the pty is
closed and the link removed. The link leads through this process's open
descriptor (``/proc/<pid>/fd/<n>``), so after a SIGKILL it leads nowhere
rather than to the next process that gets the same pty number.

Parameters: :data:`PARAMS` (read-only but ``object``) and the camera's. What the
mock camera truly renders through is the mock's own: the simulated cell as
built, ``world_rig.<name>`` for each rig parameter (``world_rig:`` in
``config/mock_hardware.yaml``, the values of ``config/rig.yaml``), as given
(``world`` "perfect") or with the errors of :mod:`sfs_ros.hardware.mock_world`
(``world`` "wrong": the camera sees another cell than the one built). The rig
the cell believes (``config/rig.yaml``, or a calibration's ``rig.yaml``) is
the camera node's: it fills ``camera_info`` and may change between scans,
and never changes what is rendered.
``object`` "board" puts the ChArUco calibration board on the plate
(``config/mock_wrong_world.yaml`` and ``config/calibration_plan.yaml``: a
calibration scan, see ``doc/calibration.md``); ``object`` can be set at run time
(``sfs-ctl param set mock_hardware object board``), as an operator puts the board on the
plate and takes it off again.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from sfs_ros.hardware.cameras import RenderedSource
from sfs_ros.hardware.mock_world import SCENES, WORLDS, mock_scene, world_rig
from sfs_ros.hardware.simulator import SimulatedGrbl
from sfs_ros.nodes.camera_node import CameraNode
from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros import result_qos
from sfs_ros.ros.params import Param, ParameterError, declare, validating_callback
from sfs_ros.ros.rig_params import RIG_PARAMS, rig_calibration

#: Prefix of the parameters of the simulated cell as built (``world_rig.fx``, ...).
WORLD_RIG = "world_rig"

__all__ = ["MockHardwareNode", "PARAMS", "WORLD_RIG", "main", "make_nodes", "world_rig_values"]

NODE_NAME = "mock_hardware"

PARAMS: list[Param] = [
    Param("max_speed_deg_s", [90.0, 45.0], "Maximum speed of the turntable and the carriage, "
          "deg/s.", bounds=(0.001, 100000.0), read_only=True),
    Param("accel_deg_s2", [360.0, 180.0], "Acceleration of the turntable and the carriage, "
          "deg/s^2.", bounds=(0.001, 1.0e6), read_only=True),
    Param("homing_speed_deg_s", 60.0, "Search speed of the homing cycle, deg/s.",
          bounds=(0.001, 100000.0), read_only=True),
    Param("carriage_limits_deg", [-5.0, 95.0], "Soft limits [min, max] of the carriage, deg "
          "(the turntable turns forever).", bounds=(-360.0, 360.0), read_only=True,
          constraints="min < max"),
    Param("encoder_offset_deg", [0.03, -0.02], "Fixed offset of the encoder read-back, deg.",
          bounds=(-10.0, 10.0), read_only=True),
    Param("encoder_noise_deg", [0.01, 0.01], "Half-width of the uniform read-back noise, deg.",
          bounds=(0.0, 10.0), read_only=True),
    Param("start_locked", True, "Start in the alarm lock (home first), like GRBL with homing "
          "enabled.", read_only=True),
    Param("port_link", "", "Symbolic link kept pointing at the controller's pty; empty = none.",
          read_only=True),
    Param("object", "mug", "Known object on the turntable, rendered by the mock camera; "
          "'board' is a 9x7 ChArUco board standing on the plate (sfs-calibrate --board 9x7).",
          choices=SCENES, constraints="settable at run time: another object put on the plate, "
          "rendered from the next frame"),
    Param("world", "perfect", "The cell the mock camera sees: 'perfect' is the rig parameters "
          "as given; 'wrong' adds a tilted, off-centre turntable axis, lens distortion, other "
          "intrinsics, radius, camera mounting and axis zeros (what sfs-calibrate recovers).",
          choices=WORLDS, read_only=True),
    Param("image_noise", 2.0, "Standard deviation of the mock camera's pixel noise, grey "
          "levels.", bounds=(0.0, 100.0), read_only=True),
    Param("background_rgb", [255, 255, 255], "Backdrop colour of the mock camera, 0..255.",
          bounds=(0, 255), read_only=True, constraints="three values"),
    Param("seed", -1, "Seed of the encoder and image noise.", bounds=(-1, 2 ** 31 - 1),
          read_only=True, constraints="-1 = random"),
    Param("camera", True, "Run the mock camera; false: only the simulated controller (a "
          "real camera driver's frames with simulated motion, sfs-cell --mock --camera-topic).",
          read_only=True),
    *(replace(p, name=f"{WORLD_RIG}.{p.name}", read_only=True,
              description=f"The simulated cell as built (before the world's errors): "
                          f"{p.description}") for p in RIG_PARAMS),
]


def world_rig_values(values: dict) -> dict:
    """The rig parameters of the simulated cell as built, ``{name: value}``, from the
    node's parameter values (``world_rig.<name>``)."""
    return {p.name: values[f"{WORLD_RIG}.{p.name}"] for p in RIG_PARAMS}


class MockHardwareNode(Node):
    """Runs a :class:`SimulatedGrbl`, publishes its port and serves the fault switches.

    Raises :class:`ParameterError` at construction for invalid parameters.
    :attr:`camera_source` renders at the simulator's true angles (for the
    camera node); :meth:`destroy_node` closes the pty.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            p = declare(self, PARAMS)
            low, high = p["carriage_limits_deg"]
            if not low < high:
                raise ParameterError("carriage_limits_deg",
                                     f"got {[low, high]}, expected min < max")
            if len(p["background_rgb"]) != 3:
                raise ParameterError("background_rgb", f"got {p['background_rgb']}, expected "
                                     "three values r, g, b")
            try:
                calibration = rig_calibration(world_rig_values(p))
            except ParameterError as err:
                raise ParameterError(f"{WORLD_RIG}.{err.name}", err.reason) from None
            try:
                calibration = world_rig(calibration, p["world"])
            except ValueError as err:
                raise ParameterError("world", f"got {p['world']!r} with this {WORLD_RIG}: "
                                     f"{err}") from None
            link = Path(p["port_link"]) if p["port_link"] else None
            if link is not None and not link.parent.is_dir():
                raise ParameterError("port_link", f"got {p['port_link']!r}: its folder does not "
                                     "exist; expected a path in an existing folder")
        except ParameterError:
            super().destroy_node()         # no simulator started yet
            raise
        seed = None if p["seed"] < 0 else p["seed"]
        self.simulator = SimulatedGrbl(
            max_speed_deg_s=p["max_speed_deg_s"], accel_deg_s2=p["accel_deg_s2"],
            soft_limits_deg=(None, (low, high)), encoder_offset_deg=p["encoder_offset_deg"],
            encoder_noise_deg=p["encoder_noise_deg"],
            homing_speed_deg_s=p["homing_speed_deg_s"], start_locked=p["start_locked"],
            seed=seed).start()
        scene = mock_scene(p["object"], background_rgb=p["background_rgb"])
        self.camera_source = RenderedSource(
            scene, calibration, self.simulator.true_position_rad,
            background_rgb=p["background_rgb"], noise_sigma=p["image_noise"], seed=seed)
        self._link = link
        self._background = p["background_rgb"]
        objects = [q for q in PARAMS if q.name == "object"]
        self.add_on_set_parameters_callback(validating_callback(self, objects, lambda _: None))
        self.add_post_set_parameters_callback(self._on_object)
        self._port_pub = self.create_publisher(String, "mock/port", result_qos())
        self.create_service(SetBool, "mock/unplug", self._on_unplug)
        self.create_service(SetBool, "mock/hang", self._on_hang)
        self.create_service(Trigger, "mock/drop_frame", self._on_drop_frame)
        self._plugged_in()
        self.get_logger().info(f"simulated GRBL controller on {self.simulator.port}"
                               f"{f' (link {self._link})' if self._link else ''}, speeds "
                               f"{p['max_speed_deg_s']} deg/s; mock camera renders the "
                               f"{scene.name} in the {p['world']} world")

    def _on_object(self, parameters: list) -> None:
        """Post-set callback: another object on the plate (``object`` set at run time)."""
        for parameter in parameters:
            if parameter.name == "object":
                self.camera_source.set_scene(mock_scene(parameter.value,
                                                        background_rgb=self._background))
                self.get_logger().info(f"the mock camera now renders the {parameter.value}")

    def _plugged_in(self) -> None:
        port = self.simulator.port
        if self._link is not None:
            tmp = self._link.with_name(f".{self._link.name}.tmp")
            tmp.unlink(missing_ok=True)
            # Through this process's fd: dead with the process, never another's pty.
            tmp.symlink_to(self.simulator.held_port)
            os.replace(tmp, self._link)          # atomic: the link is never missing midway
        self._port_pub.publish(String(data=port))

    def _unlink(self) -> None:
        if self._link is not None and self._link.is_symlink():
            self._link.unlink()

    def _on_unplug(self, request, response):
        if request.data:
            self._unlink()
            self.simulator.disconnect()
            response.message = "cable unplugged: the controller's port is closed"
        else:
            try:
                self.simulator.replug()
            except RuntimeError:
                response.success, response.message = False, "the cable is plugged in already"
                return response
            self._plugged_in()
            response.message = f"cable plugged back in: {self.simulator.port}"
        self.get_logger().warning(response.message)
        response.success = True
        return response

    def _on_hang(self, request, response):
        self.simulator.faults.no_answer = bool(request.data)
        response.success = True
        response.message = ("the controller stops answering" if request.data
                            else "the controller answers again")
        self.get_logger().warning(response.message)
        return response

    def _on_drop_frame(self, _request, response):
        self.camera_source.fail_next(1)
        response.success, response.message = True, "the next shutter gives no frame"
        self.get_logger().warning(response.message)
        return response

    def destroy_node(self) -> None:
        self._unlink()
        self.simulator.close()
        super().destroy_node()


def make_nodes() -> list[Node]:
    """The mock hardware node and the camera node rendering from its simulator (the
    hardware node alone with ``camera`` false)."""
    hardware = MockHardwareNode()
    if not hardware.get_parameter("camera").value:
        return [hardware]
    try:
        camera = CameraNode(source=hardware.camera_source,
                            parameter_overrides=[Parameter("backend", value="mock")])
    except ParameterError:
        hardware.destroy_node()
        raise
    world = hardware.camera_source.calibration
    if camera.size != (world.width, world.height):
        camera.destroy_node()
        hardware.destroy_node()
        raise ParameterError(f"{WORLD_RIG}.width", f"the mock renders {world.width}x"
                             f"{world.height} frames, expected the camera's {camera.size[0]}x"
                             f"{camera.size[1]} (width, height of rig.yaml): give both the "
                             "same size")
    return [hardware, camera]


def main(args=None) -> None:
    """Entry point ``sfs-mock-hardware``.

    ``sfs-mock-hardware --ros-args --params-file config/rig.yaml --params-file
    config/camera.yaml --params-file config/mock_hardware.yaml``
    """
    configure_process()
    run_node("sfs-mock-hardware", make_nodes, args, threads=2)


if __name__ == "__main__":
    main()
