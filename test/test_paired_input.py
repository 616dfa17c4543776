"""The paired input of the segmentation and reconstruction nodes, without a running ROS graph.

The node is replaced by a recorder of its subscriptions (the thing under test is the
pairing and error reporting, not rclpy); the messages are real ROS messages.
"""

import pytest
from sensor_msgs.msg import Image, JointState

from sfs_ros.ros.convert import angles_from_joint_state, joint_state
from sfs_ros.ros.paired_input import PairedInput, Stream


class SubscriptionRecorder:
    """Stands in for the node: keeps each subscription's callback by topic."""

    def __init__(self):
        self.callbacks = {}
        self.qos = {}

    def create_subscription(self, msg_type, topic, callback, qos, *, callback_group=None):
        self.callbacks[topic] = callback
        self.qos[topic] = (msg_type, qos, callback_group)


def _image(sec, nanosec=0, encoding="mono8"):
    msg = Image(height=1, width=2, encoding=encoding, step=2, data=[0, 255])
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.header.frame_id = "camera"
    return msg


def _decode(msg):
    if msg.encoding != "mono8":
        raise ValueError(f"encoding {msg.encoding!r}, expected mono8")
    return msg.header.frame_id


@pytest.fixture
def wiring():
    node, pairs, problems = SubscriptionRecorder(), [], []
    paired = PairedInput(node, Stream(Image, "capture/mask", "mask", _decode),
                         Stream(JointState, "capture/mask_joint_state", "joint state",
                                angles_from_joint_state),
                         2, 7, unit="view", on_pair=lambda *p: pairs.append(p),
                         on_problem=lambda kind, text: problems.append((kind, text)),
                         callback_group="group")
    return node, paired, pairs, problems


def test_subscribes_both_topics_and_pairs_either_order(wiring):
    node, paired, pairs, problems = wiring
    assert node.qos == {"capture/mask": (Image, 7, "group"),
                        "capture/mask_joint_state": (JointState, 7, "group")}
    node.callbacks["capture/mask"](_image(1))
    assert paired.pending("first") == 1 and pairs == []
    node.callbacks["capture/mask_joint_state"](joint_state(0.5, 0.25, stamp=(1, 0)))
    node.callbacks["capture/mask_joint_state"](joint_state(1.0, 0.75, stamp=(2, 5)))
    node.callbacks["capture/mask"](_image(2, 5))
    assert pairs == [((1, 0), "camera", (0.5, 0.25)), ((2, 5), "camera", (1.0, 0.75))]
    assert problems == [] and paired.pending("first") == paired.pending("second") == 0


def test_a_malformed_half_drops_its_capture_and_its_partner(wiring):
    node, paired, pairs, problems = wiring
    node.callbacks["capture/mask_joint_state"](joint_state(0.5, 0.25, stamp=(3, 0)))
    node.callbacks["capture/mask"](_image(3, encoding="rgb8"))
    assert pairs == [] and paired.pending("second") == 0
    assert [kind for kind, _ in problems] == ["unpaired_dropped", "malformed"]
    assert problems[0][1] == "joint state at stamp 3.000000000 dropped: its partner was malformed"
    assert problems[1][1] == ("malformed mask at stamp 3.000000000 dropped with its view: "
                              "encoding 'rgb8', expected mono8")
    # A good copy of the rejected mask still pairs with nothing.
    node.callbacks["capture/mask"](_image(3))
    assert pairs == [] and paired.pending("first") == 0


def test_a_bad_stamp_and_a_bad_joint_state_are_reported_not_raised(wiring):
    node, _, pairs, problems = wiring
    bad = joint_state(0.5, 0.25, stamp=(4, 0))
    bad.name = ["turntable"]
    bad.position = [0.5]
    node.callbacks["capture/mask_joint_state"](bad)

    class NoStamp:
        class header:          # noqa: N801 -- mimics a message's attribute
            stamp = "yesterday"
    node.callbacks["capture/mask"](NoStamp())
    assert pairs == []
    assert [kind for kind, _ in problems] == ["malformed", "malformed"]
    assert problems[0][1].startswith("malformed joint state at stamp 4.000000000 dropped with "
                                     "its view: ")
    assert problems[1][1].startswith("malformed mask dropped: stamp must be")


def test_unpaired_halves_are_evicted_beyond_the_depth(wiring):
    node, paired, _, problems = wiring
    for sec in (10, 11, 12):
        node.callbacks["capture/mask"](_image(sec))
    assert paired.pending("first") == 2
    assert problems == [("unpaired_dropped", "mask at stamp 10.000000000 dropped: no partner "
                                             "arrived before the buffer filled")]


def test_the_node_can_give_up_a_capture_after_pairing_it(wiring):
    node, paired, pairs, problems = wiring
    paired.malformed((5, 0), "image", ValueError("too small to segment"))
    node.callbacks["capture/mask"](_image(5))
    assert pairs == []
    assert problems[0] == ("malformed", "malformed image at stamp 5.000000000 dropped with its "
                                        "view: too small to segment")
    assert problems[1][0] == "unpaired_dropped"
