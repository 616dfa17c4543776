"""The recorder node's parameters (:data:`PARAMS`) and the check of ``bag_name``."""

from __future__ import annotations

from sfs_ros.cell_logic.bag import STORAGES, bag_folder
from sfs_ros.ros.params import Param, ParameterError

__all__ = ["BAG_NAME", "PARAMS", "check_bag_name"]

#: The name of the next bag, settable at run time.
BAG_NAME = Param("bag_name", "", "Name of the next bag's folder under <output_dir>/bags; "
                 "empty = automatic (bag_<UTC time>, scan_<NNN>_<UTC time>).",
                 constraints="empty, or 1-100 letters, digits, '_', '-', '.'; a bag that "
                             "exists is refused")

#: The recorder node's parameters.
PARAMS: list[Param] = [
    Param("output_dir", "", "Folder whose bags/ sub-folder receives the bags (created if "
          "needed); every file the node writes stays inside it.", read_only=True,
          constraints="required, non-empty"),
    Param("storage", STORAGES[0], "Storage of the bags.", choices=STORAGES, read_only=True),
    BAG_NAME,
    Param("with_scan", False, "Also open a new bag when a scan starts (and keep recording until "
          "recorder/stop, the next scan or shutdown).", read_only=True),
    Param("parameter_nodes", ["carving", "meshing", "segmentation", "scan", "camera"], "Nodes "
          "(names relative to this node's namespace) whose parameters each bag stores.",
          read_only=True),
    Param("parameter_timeout_s", 20.0, "Longest wait for the parameters of all parameter_nodes, "
          "s (they come in milliseconds; a loaded machine can take seconds, and a bag "
          "without them cannot be reconstructed offline).", bounds=(0.1, 600.0),
          read_only=True),
    Param("queue_depth", 100, "Depth of the reliable capture topics; at least the number of "
          "views of a scan.", bounds=(1, 100000), read_only=True),
]


def check_bag_name(output_dir: str, values: dict) -> None:
    """ParameterError naming ``bag_name`` for a name in ``values`` that cannot name a bag's
    folder under ``output_dir``/bags (:func:`~sfs_ros.cell_logic.bag.layout.bag_folder`;
    an empty one is automatic)."""
    if values["bag_name"]:
        try:
            bag_folder(output_dir, values["bag_name"])
        except ValueError as exc:
            raise ParameterError("bag_name", str(exc)) from None
