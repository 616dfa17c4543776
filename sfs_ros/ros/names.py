"""The cell's ROS names in one place: its namespace, the services of each node, diagnostics.

The cell lives in a namespace (:data:`NAMESPACE` by default, as ``sfs-cell``
and the launch files start it); its topics are relative to it
(``<namespace>/capture/image``, ``<namespace>/joint_states``, ...). Each
node's services are private to the node (``~/home`` of the node ``motor`` is
``<namespace>/motor/home``), so nothing of the cell sits at the root or
under a generic name a robot cell already uses. Only the diagnostics are
absolute (:data:`DIAGNOSTICS`), where the standard aggregator listens; each
status is named ``<node's full name>: <kind>`` (``/sfs/scan: scan``), so a
reader tells cells apart (:func:`sfs_ros.cell_logic.message_fields.status_namespace`).

:data:`SERVICES` maps the short names a program uses
(:class:`sfs_ros.ros.cell_client.CellClient`, the scan node's calls) to the
names relative to the cell's namespace; a node started under another name
is reached by remapping these.
"""

from __future__ import annotations

__all__ = ["NAMESPACE", "DIAGNOSTICS", "CARVING_NODE", "RECORDER_NODE", "SERVICES", "TYPED_SERVICES",
           "SCAN_ACTION", "CALIBRATE_ACTION", "CELL_STATUS", "RECONSTRUCTION_STATUS", "MESHING_STATUS",
           "VIEW_IMAGES", "VIEW_IMAGE_DEPTH", "VIEW_MASKS",
           "CONFIGURATION_ERROR",
           "private", "status_name"]

#: Namespace of the cell when started by ``sfs-cell`` or the launch files.
NAMESPACE = "/sfs"
#: The diagnostics topic of every node: absolute, the standard aggregator's.
DIAGNOSTICS = "/diagnostics"
#: Exit status of a node that refused its configuration (a parameter, a parameters file
#: rcl cannot read): ``sfs-cell`` does not start it again.
CONFIGURATION_ERROR = 2

#: The carving node's name: it holds the scan's views and rig (the scan waits for its
#: subscriptions, a calibration or a driver's intrinsics are set on it).
CARVING_NODE = "carving"
#: The recorder's node name: the scan node knows a restarted recorder by it (and sends it
#: the scan's captures again, so that its new bag holds them).
RECORDER_NODE = "recorder"

#: Short name -> service name relative to the cell's namespace (``<node>/<service>``).
SERVICES: dict[str, str] = {
    "scan/start": "scan/start",
    "scan/cancel": "scan/cancel",
    "scan/resume": "scan/resume",
    "home": "motor/home",
    "stop": "motor/stop",
    "capture": "camera/capture",
    "reset": "carving/reset",
    "reconstruct": "meshing/reconstruct",
    "record/start": "recorder/start",
    "record/stop": "recorder/stop",
}


#: Short name -> typed service (``sfs_ros_interfaces/srv``) relative to the namespace:
#: ``reconstruct_mesh`` (Reconstruct: per-call options, typed answer; ``reconstruct`` is its
#: Trigger alias), ``new_scan`` (NewScan: a reset naming the scan; ``reset`` is its
#: Trigger alias) and ``carve_scan`` (CarveScan: the carving node's hand-over to the
#: meshing node).
TYPED_SERVICES: dict[str, str] = {
    "reconstruct_mesh": "meshing/reconstruct_mesh",
    "new_scan": "carving/new_scan",
    "carve_scan": "carving/carve_scan",
}

#: The scan node's action (``sfs_ros_interfaces/action/Scan``): ``<namespace>/scan``.
SCAN_ACTION = "scan"
#: The calibration node's action (``sfs_ros_interfaces/action/Calibrate``):
#: ``<namespace>/calibrate``.
CALIBRATE_ACTION = "calibrate"
#: The scan node's status (``sfs_ros_interfaces/msg/CellStatus``): ``<namespace>/status``.
CELL_STATUS = "status"
#: The carving node's status (``sfs_ros_interfaces/msg/ReconstructionStatus``: the scan's
#: views), and the meshing node's (the same type: the reconstructions and the last mesh).
RECONSTRUCTION_STATUS = "carving/status"
MESHING_STATUS = "meshing/status"
#: The carving node's colour image of each view as it is stored
#: (``sfs_ros_interfaces/msg/ViewImage``), held by the meshing node.
VIEW_IMAGES = "carving/view_image"
#: The carving node's silhouette of each view with its image (the same type, mono8), held
#: by the meshing node with the image.
VIEW_MASKS = "carving/view_mask"
#: Its depth (reliable, volatile): an image missed by a slow reader comes in the carved
#: scan instead.
VIEW_IMAGE_DEPTH = 8


def private(service: str) -> str:
    """The name a node gives its own service ``<node>/<service>`` of :data:`SERVICES` or
    :data:`TYPED_SERVICES`: ``~/<service>``."""
    return "~/" + {**SERVICES, **TYPED_SERVICES}[service].split("/", 1)[1]


def status_name(node, kind: str) -> str:
    """The diagnostic status name of ``node`` (an rclpy node): ``<full name>: <kind>``."""
    return f"{node.get_fully_qualified_name()}: {kind}"
