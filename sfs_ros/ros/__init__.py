"""ROS 2 plumbing of the cell: message conversions, stamp pairing, parameters, QoS.

:mod:`sfs_ros.ros.pairing` imports nothing from ROS (usable and testable
without rclpy), so this package imports rclpy only inside the QoS helpers.

QoS of the cell:

* :func:`capture_qos` -- captures, masks and their joint states feed carving
  and must not be dropped: reliable, keep-last ``depth`` (at least the scan
  plan's size), volatile (a node that starts late does not receive old views;
  volatile subscribers also match transient-local publishers);
* :func:`result_qos` -- final results (mesh, hull): reliable, transient-local,
  depth 1, so that a viewer started afterwards still gets the last one.
"""

__all__ = ["capture_qos", "result_qos"]


def capture_qos(depth: int = 100):
    """Reliable, volatile, keep-last ``depth`` ``rclpy.qos.QoSProfile`` for captures and masks."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def result_qos():
    """Reliable, transient-local, depth-1 ``rclpy.qos.QoSProfile`` (late joiners get the last)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
