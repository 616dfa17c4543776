"""Lifecycle manager: brings the cell's managed nodes (motor, camera) to active, in order.

| kind | name | type | notes |
|---|---|---|---|
| cli | ``<node>/get_state``, ``<node>/change_state`` | lifecycle_msgs/srv | of each node of ``nodes`` |
| graph | ``<node>/transition_event`` | lifecycle_msgs/msg/TransitionEvent | its publishers |

The nodes of ``nodes`` (names in this node's namespace) are brought up one after the
other: the next one's transitions start once the one before has appeared and is active. For each: wait
for its ``get_state`` service (INFO once), ``configure`` it if it is unconfigured,
``activate`` it if it is inactive, then say "<node> is active" (INFO). A node is brought
up again whenever a new instance of it appears, known by a new publisher of its
``transition_event`` (a node started again by ``sfs-cell``'s supervisor or the launch
files' respawn); a transition an integrator makes (a deactivate, a cleanup) is left as
it is. A transition the node refuses (``configure`` cannot open the port or the camera:
the node's own WARN says why) is asked again every ``retry_period_s``, said once (WARN).
A call left unanswered for ``call_timeout_s`` (a response lost while the service was
matching) is followed by a new ``get_state``, so no transition is asked twice.

In the mock cell ``nodes`` is ``[camera, motor]``: the mock hardware makes its
controller's port (and its link) before its camera node exists, so once that camera
answers, the motor's port is there. Parameters: :data:`PARAMS`.
"""

from __future__ import annotations

import time

from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.node import Node

from sfs_ros.nodes.entry import run_node
from sfs_ros.process import configure_process
from sfs_ros.ros.params import Param, ParameterError, declare

__all__ = ["LifecycleManagerNode", "PARAMS", "main"]

NODE_NAME = "lifecycle_manager"

PARAMS: list[Param] = [
    Param("nodes", ["motor", "camera"], "The managed nodes to bring to active, in order "
          "(names in this node's namespace).", read_only=True, constraints="at least one"),
    Param("retry_period_s", 2.0, "Period of a refused transition's new attempts, s.",
          bounds=(0.1, 600.0), read_only=True),
    Param("call_timeout_s", 10.0, "A lifecycle call unanswered this long is given up (and "
          "the state asked again), s.", bounds=(0.1, 600.0), read_only=True),
]
#: How often the graph and the calls are looked at, s.
_TICK_S = 0.2
#: The transition that leads on from a primary state towards active.
_NEXT = {State.PRIMARY_STATE_UNCONFIGURED: (Transition.TRANSITION_CONFIGURE, "configure"),
         State.PRIMARY_STATE_INACTIVE: (Transition.TRANSITION_ACTIVATE, "activate")}


class _Managed:
    """One managed node: its clients, the instances seen, and the call under way."""

    def __init__(self, manager: Node, name: str):
        self.name = name
        self.get_state = manager.create_client(GetState, f"{name}/get_state")
        self.change_state = manager.create_client(ChangeState, f"{name}/change_state")
        self.events = f"{manager.get_namespace().rstrip('/')}/{name}/transition_event"
        self.seen: set[bytes] = set()      # GIDs of its transition_event publishers
        self.wanted = False                # to be brought to active
        self.call = None                   # (future, what, asked at) of the call under way
        self.not_before = 0.0              # time.monotonic() of the next attempt
        self.said: set[str] = set()        # INFO / WARN lines said once


class LifecycleManagerNode(Node):
    """Brings the nodes of ``nodes`` to active in order, and again when they restart.

    Raises :class:`ParameterError` at construction for invalid parameters.
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._p = declare(self, PARAMS)
            names = [n.strip() for n in self._p["nodes"]]
            if not names or not all(names):
                raise ParameterError("nodes", f"got {self._p['nodes']}, expected the names of "
                                     "the managed nodes, e.g. [motor, camera]")
        except ParameterError:
            super().destroy_node()
            raise
        self._managed = [_Managed(self, name) for name in names]
        self.create_timer(_TICK_S, self._tick)
        self.get_logger().info(f"bringing {', '.join(names)} to active, in this order")

    def _tick(self) -> None:
        for managed in self._managed:
            self._look(managed)
        for managed in self._managed:      # the first not active; the later ones wait
            if not managed.seen or managed.wanted:
                if managed.wanted:
                    self._step(managed)
                return

    def _look(self, managed: _Managed) -> None:
        """A new instance of the node (a publisher of its transition events not seen
        before) is to be brought up."""
        gids = {bytes(info.endpoint_gid)
                for info in self.get_publishers_info_by_topic(managed.events)}
        if gids - managed.seen:
            managed.wanted, managed.not_before = True, 0.0
        managed.seen |= gids

    def _step(self, managed: _Managed) -> None:
        """The next call towards active, or the answer of the one under way."""
        now = time.monotonic()
        if managed.call is not None:
            future, what, asked = managed.call
            if future.done():
                managed.call = None
                self._answered(managed, what, future.result())
            elif now - asked > self._p["call_timeout_s"]:
                managed.call = None            # lost: ask the state again
            return
        if now < managed.not_before:
            return
        if not managed.get_state.service_is_ready():
            self._once(managed, "waiting", f"waiting for {managed.name}'s lifecycle services")
            return
        managed.call = (managed.get_state.call_async(GetState.Request()), "state", now)

    def _answered(self, managed: _Managed, what: str, answer) -> None:
        if what != "state":
            if not answer.success:
                self._once(managed, f"refused {what}", f"{managed.name} refused {what} (its "
                           f"log says why); asking again every {self._p['retry_period_s']} s",
                           warn=True)
                managed.not_before = time.monotonic() + self._p["retry_period_s"]
            return
        state = answer.current_state
        if state.id == State.PRIMARY_STATE_ACTIVE:
            managed.wanted = False
            managed.said.clear()
            self.get_logger().info(f"{managed.name} is active")
        elif state.id in _NEXT:
            transition, label = _NEXT[state.id]
            request = ChangeState.Request(transition=Transition(id=transition, label=label))
            managed.call = (managed.change_state.call_async(request), label, time.monotonic())
        elif state.id == State.PRIMARY_STATE_FINALIZED:
            managed.wanted = False
            self.get_logger().warning(f"{managed.name} is finalized: start it again to use it")
        # a transition under way: the state is asked again at the next tick

    def _once(self, managed: _Managed, key: str, text: str, *, warn: bool = False) -> None:
        if key in managed.said:
            return
        managed.said.add(key)
        if warn:
            self.get_logger().warning(text)
        else:
            self.get_logger().info(text)


def main(args=None) -> None:
    """Entry point ``sfs-lifecycle-manager`` (``--ros-args -p nodes:=[motor,camera]``)."""
    configure_process()
    run_node("sfs-lifecycle-manager", LifecycleManagerNode, args)


if __name__ == "__main__":
    main()
