"""The body every node's ``main()`` shares (:mod:`sfs_ros.nodes.entry`): a node asked for
its threads' stacks (SIGUSR1) writes them and runs on, and still stops cleanly on SIGINT."""

import re
import signal

from ros_harness import STARTUP_TIMEOUT_S, NodeProcess
from waiting import wait

#: A node with nothing to do until its managed nodes appear (none will); it says which it
#: waits for once it is built, its stop signals already handled.
MODULE = "sfs_ros.nodes.lifecycle_manager_node"


def test_a_node_asked_for_its_stacks_writes_them_and_runs_on():
    process = NodeProcess(MODULE, parameters={"nodes": ["nobody"]})
    wait(lambda: "bringing nobody to active" in process.output(), what="the node to start",
         timeout=STARTUP_TIMEOUT_S)
    process.process.send_signal(signal.SIGUSR1)
    # The main thread's stack, written from its innermost call out, down to run_node.
    wait(lambda: re.search(r'sfs_ros/nodes/entry\.py", line \d+ in run_node', process.output()),
         what="the node's stacks down to run_node", timeout=STARTUP_TIMEOUT_S)
    assert "Current thread" in process.output()
    assert process.alive()
    code, output = process.stop_and_read()
    assert code == 0, output
    assert "Traceback" not in output, output
