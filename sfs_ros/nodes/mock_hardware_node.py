"""Mock hardware node: a simulated GRBL controller on a pseudo-terminal, for the real motor node.

| kind | name | type | notes |
|---|---|---|---|
| pub | ``mock/port`` | std_msgs/String | the pty path (``/dev/pts/N``); reliable, transient-local |

The controller (:class:`sfs_ros.hardware.simulator.SimulatedGrbl`) answers on
the pseudo-terminal from its own thread; the motor node opens the published
path as it would open ``/dev/ttyACM0``. The path is also logged at start-up.
Speeds, accelerations, encoder offset and noise are parameters (defaults: a
turntable at 90 deg/s, a carriage at 45 deg/s). On shutdown (SIGINT) the
simulator thread stops and the pseudo-terminal is closed, which a connected
motor node sees as an unplugged cable.
"""

from __future__ import annotations

from rclpy.node import Node
from std_msgs.msg import String

from sfs_ros.hardware.simulator import SimulatedGrbl
from sfs_ros.nodes.entry import run_node
from sfs_ros.ros import result_qos
from sfs_ros.ros.params import Param, ParameterError, declare

__all__ = ["MockHardwareNode", "PARAMS", "main"]

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
    Param("seed", -1, "Seed of the encoder noise.", bounds=(-1, 2 ** 31 - 1), read_only=True,
          constraints="-1 = random"),
]


class MockHardwareNode(Node):
    """Runs a :class:`SimulatedGrbl` and publishes its port; call :meth:`destroy_node` to close it.

    Raises :class:`ParameterError` at construction for invalid parameters.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            p = declare(self, PARAMS)
            low, high = p["carriage_limits_deg"]
            if not low < high:
                raise ParameterError("carriage_limits_deg",
                                     f"got {[low, high]}, expected min < max")
        except ParameterError:
            super().destroy_node()         # no simulator started yet
            raise
        self.simulator = SimulatedGrbl(
            max_speed_deg_s=p["max_speed_deg_s"], accel_deg_s2=p["accel_deg_s2"],
            soft_limits_deg=(None, (low, high)), encoder_offset_deg=p["encoder_offset_deg"],
            encoder_noise_deg=p["encoder_noise_deg"],
            homing_speed_deg_s=p["homing_speed_deg_s"], start_locked=p["start_locked"],
            seed=None if p["seed"] < 0 else p["seed"]).start()
        self.get_logger().info(f"simulated GRBL controller on {self.simulator.port} "
                               f"(speeds {p['max_speed_deg_s']} deg/s)")
        self._port_pub = self.create_publisher(String, "mock/port", result_qos())
        self._port_pub.publish(String(data=self.simulator.port))

    def destroy_node(self) -> None:
        self.simulator.close()
        super().destroy_node()


def main(args=None) -> None:
    """Entry point ``sfs-mock-hardware``.

    ``sfs-mock-hardware --ros-args --params-file config/mock_hardware.yaml``
    """
    run_node("sfs-mock-hardware", MockHardwareNode, args)


if __name__ == "__main__":
    main()
