"""What the cell's managed (lifecycle) nodes share: the ``autostart`` parameter and the
transitions' answers.

A managed node (:class:`rclpy.lifecycle.LifecycleNode`: the motor and camera nodes) starts
``unconfigured``; ``configure`` opens its hardware, ``activate`` starts its work,
``deactivate`` and ``cleanup`` undo them, ``shutdown`` releases everything from any state
(the services ``<node>/change_state`` and ``<node>/get_state``, lifecycle_msgs). With
``autostart`` (the default, for a node started alone) the node configures and activates
itself at start-up; ``sfs-cell`` and the launch files set it false and bring the nodes up in
order through those services (:mod:`sfs_ros.nodes.lifecycle_manager_node`).
"""

from __future__ import annotations

from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn

from sfs_ros.ros.params import Param

__all__ = ["AUTOSTART", "SUCCESS", "FAILURE", "bring_up"]

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE

#: The parameter of every managed node of the cell.
AUTOSTART = Param("autostart", True, "Configure and activate at start-up; false: stay "
                  "unconfigured until told through the lifecycle services (change_state), as "
                  "sfs-cell's lifecycle manager or an integrator's launch does.",
                  read_only=True)


def bring_up(node: LifecycleNode) -> bool:
    """Configure, then activate ``node`` (the transitions its own services would make);
    whether it is active."""
    return node.trigger_configure() == SUCCESS and node.trigger_activate() == SUCCESS
