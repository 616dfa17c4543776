"""A CellClient closed while status messages pour in leaves nothing behind on stderr.

rclpy's multi-threaded executor, shut down while its spinning thread still hands
callbacks to its pool, destroys its guard condition before the pool has run them: each
then fails ("The following exception was never retrieved: cannot use Destroyable because
destruction was requested", and tracebacks of the spinning thread), printed when the
process collects them. A client of the cell (sfs-ctl, an integrator's script) opens and
closes a CellClient per call, so each close must be clean.

The child floods the client's status topic from a node of its own and opens and closes 20
clients, each once it has had a status: with rclpy's executor and spin(), 30 clients
gave 4 to 6 such lines in each of three runs.
"""

import os
import subprocess
import sys

from ros_harness import NAMESPACE, SOURCE_ROOT

CHILD = f"""
import gc
import threading
import rclpy
from rclpy.context import Context
from sfs_ros.ros import result_qos
from sfs_ros.ros.cell_client import CellClient
from sfs_ros.ros.names import CELL_STATUS
from sfs_ros_interfaces.msg import CellStatus

context = Context()
rclpy.init(context=context)
node = rclpy.create_node("status_flood", namespace="{NAMESPACE}", context=context)
publisher = node.create_publisher(CellStatus, CELL_STATUS, result_qos())
stop = threading.Event()

def flood():
    while not stop.is_set():
        publisher.publish(CellStatus())

flooding = threading.Thread(target=flood)
flooding.start()
for i in range(20):
    client = CellClient("{NAMESPACE}", name=f"closing_client_{{i}}")
    client.next_status(None, timeout_s=60.0)
    client.close()
    gc.collect()
stop.set()
flooding.join()
node.destroy_node()
context.try_shutdown()
print("closed 20 clients")
"""


def test_closing_clients_under_a_flood_of_status_prints_nothing():
    done = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(SOURCE_ROOT)), timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "closed 20 clients"
    assert "never retrieved" not in done.stderr and "Traceback" not in done.stderr, \
        done.stderr
