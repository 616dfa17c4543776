"""The cell's executors (:mod:`sfs_ros.ros.executor`) build their wait set again when an
entity in it was destroyed meanwhile.

A subscription destroyed from another thread after the executor took its node's lists
cannot be entered into the wait set, and its event handlers then cannot be added to it:
rclpy's executors (9.1.2) raise ``InvalidHandle`` out of ``spin_once`` (a test's
``TfWatch`` closed on a ``CellClient``'s node ended the client's spinning thread that
way). Here a waitable goes through those steps at the executor's own pace: it fails to be
entered and leaves its node's list, as ``Node.destroy_subscription`` makes a
subscription's event handlers do, then fails to be added.
"""

import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.executors import SingleThreadedExecutor as RclpySingleThreadedExecutor
from rclpy.waitable import NumberOfEntities, Waitable

from sfs_ros.ros.executor import DrainingExecutor, SingleThreadedExecutor

from ros_harness import NAMESPACE

#: Seconds bounding a hang (a loaded 2-core machine); never a speed asserted.
DEADLINE_S = 60.0
DESTROYED = "cannot use Destroyable because destruction was requested"


class _DestroyedMeanwhile(Waitable):
    """A waitable destroyed between the executor's taking of its node's lists and its
    entering of it; ``leaves`` its node's list then (as a destroyed subscription's event
    handlers do), or stays there."""

    def __init__(self, node, *, leaves: bool = True):
        super().__init__(node.default_callback_group)
        self.node, self.leaves = node, leaves
        node.add_waitable(self)

    def __enter__(self):
        if self.leaves and self in self.node.waitables:
            self.node.remove_waitable(self)
        raise InvalidHandle(DESTROYED)

    def __exit__(self, *exc):
        pass

    def add_to_wait_set(self, wait_set):
        raise InvalidHandle(DESTROYED)

    def is_ready(self, wait_set):
        return False

    def take_data(self):
        return None

    async def execute(self, taken_data):
        pass

    def get_num_entities(self):
        return NumberOfEntities()


@pytest.fixture()
def node():
    """A node with a timer ticking into ``node.ticks``, in a context of its own."""
    context = Context()
    rclpy.init(context=context)
    made = rclpy.create_node("destroyed_meanwhile", namespace=NAMESPACE, context=context)
    made.ticks = []
    made.create_timer(0.01, lambda: made.ticks.append(time.monotonic()))
    yield made
    made.destroy_node()
    context.try_shutdown()


EXECUTORS = {"single": lambda context: SingleThreadedExecutor(context=context),
             "draining": lambda context: DrainingExecutor(num_threads=2, context=context)}


@pytest.mark.parametrize("kind", EXECUTORS)
def test_a_waitable_destroyed_meanwhile_is_left_out_and_the_spin_goes_on(node, kind):
    destroyed = _DestroyedMeanwhile(node)
    executor = EXECUTORS[kind](node.context)
    executor.add_node(node)
    deadline = time.monotonic() + DEADLINE_S
    try:
        while len(node.ticks) < 3 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
    assert len(node.ticks) >= 3
    assert destroyed not in node.waitables


def test_rclpy_s_own_executor_ends_its_spin_there(node):
    # The reason for the executors above: when rclpy keeps the waitable out of its wait
    # set itself, this fails, and they can go.
    _DestroyedMeanwhile(node)
    _spin_ends_on_the_destroyed(RclpySingleThreadedExecutor(context=node.context), node)


@pytest.mark.parametrize("kind", EXECUTORS)
def test_a_waitable_that_stays_destroyed_on_its_nodes_list_is_an_error(node, kind):
    _DestroyedMeanwhile(node, leaves=False)
    _spin_ends_on_the_destroyed(EXECUTORS[kind](node.context), node)


def _spin_ends_on_the_destroyed(executor, node) -> None:
    """One spin of ``executor`` over ``node`` raises the destroyed waitable's InvalidHandle."""
    executor.add_node(node)
    try:
        with pytest.raises(InvalidHandle, match=DESTROYED):
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
