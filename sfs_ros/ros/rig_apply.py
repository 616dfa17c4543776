"""Applying a calibration's ``rig.yaml`` to a running cell, and keeping it for restarts.

:func:`read_rig_file` reads the file ``sfs-calibrate`` writes (``/**:
ros__parameters:`` with every rig parameter) and checks it as a
:class:`RigCalibration`. :func:`apply_rig` sets it, all parameters at once
(``SetParametersAtomically``), on every node of the cell that holds the rig:
the nodes in the cell's namespace that declare ``camera_distance_m`` (the
carving node, the camera node, the TF publisher), found through their
``ListParameters`` services. A node that refuses (a scan under way, another
image size) has the reason in the error, and the nodes set before it get
their earlier rig back. Once every node took it, the rig is written
atomically to :data:`sfs_ros.cell_logic.paths.APPLIED_RIG` in the cell's output
folder (the carving node's ``output_dir``), which ``sfs-cell`` gives
those nodes whenever it starts one: a node started again keeps the rig.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import yaml
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from sfs_ros.cell_logic.paths import APPLIED_RIG
from sfs_ros.core.calibration.outputs import yaml_document
from sfs_ros.core.exchange.files import write_atomic
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.ros.names import CARVING_NODE
from sfs_ros.ros.params import ParameterError, check
from sfs_ros.ros.rig_params import RIG_PARAMS, rig_calibration
from sfs_ros.ros.services import PARAMETER_RESEND_S

__all__ = ["AppliedRig", "HOLDER_PARAMETER", "apply_rig", "cell_rig", "read_rig_file"]

#: A node holds the rig if it declares this parameter.
HOLDER_PARAMETER = "camera_distance_m"
#: The node whose ``output_dir`` is the cell's output folder (it holds the rig too).
RECONSTRUCTION_NODE = CARVING_NODE
#: Discovery: the cell's nodes are taken as found once the carving node is and the
#: list of nodes in the namespace has not changed for this long, seconds (a new participant
#: learns of the running ones within a fraction of a second on one machine).
DISCOVERY_QUIET_S = 2.0


@dataclass(frozen=True)
class AppliedRig:
    """What :func:`apply_rig` did: the rig, the nodes that took it (full names) and the
    file that keeps it for restarts."""

    rig: RigCalibration
    nodes: list[str]
    persisted: Path


def read_rig_file(path) -> dict:
    """The rig parameters ``{name: value}`` of a ``rig.yaml`` (``/**: ros__parameters:``
    holding every parameter of :data:`RIG_PARAMS`, of its type and range, and no other),
    checked together as a :class:`RigCalibration`; ValueError naming the file and the field."""
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot be read as YAML: {exc}") from None
    values = (document.get("/**") or {}).get("ros__parameters") \
        if isinstance(document, dict) else None
    if not isinstance(values, dict):
        raise ValueError(f"{path}: expected a ROS parameters file, '/**: ros__parameters:' "
                         "with the rig parameters (as sfs-calibrate writes rig.yaml)")
    names = [p.name for p in RIG_PARAMS]
    missing = [n for n in names if n not in values]
    unknown = sorted(set(values) - set(names))
    if missing or unknown:
        raise ValueError(f"{path}: " + "; ".join(filter(None, [
            f"missing {', '.join(missing)}" if missing else "",
            f"unknown {', '.join(unknown)}" if unknown else ""]))
            + f"; expected exactly the rig parameters {', '.join(names)}")
    for param in RIG_PARAMS:
        reason = check(param, values[param.name])
        if reason is not None:
            raise ValueError(f"{path}: {ParameterError(param.name, reason)}")
    try:
        rig_calibration(values)
    except ParameterError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return {name: values[name] for name in names}


def apply_rig(node: Node, path, namespace: str | None = None, *,
              timeout_s: float = 30.0) -> AppliedRig:
    """Set the rig of ``path`` (:func:`read_rig_file`) on every node of the cell in
    ``namespace`` (default: ``node``'s) that holds the rig, all parameters at once, then
    keep it in the cell's output folder (module docstring).

    ``node`` must be spun by another thread (as :class:`CellClient`'s node is). Raises
    ValueError for a bad file or a node that refuses (the others keep or get back their
    rig, nothing is written), TimeoutError when the cell does not answer within
    ``timeout_s`` seconds.
    """
    values = read_rig_file(path)
    deadline = time.monotonic() + timeout_s
    namespace = "/" + (namespace if namespace is not None else node.get_namespace()).strip("/")
    holders = _holders(node, namespace, deadline)
    names = list(values)
    earlier: list[tuple[AsyncParameterClient, dict]] = []
    for full_name, client in holders.items():
        before = _get(client, names, full_name, deadline)
        refusal = _set(client, values, full_name, deadline)
        if refusal:
            for taken, old in reversed(earlier):
                _set(taken, old, "", deadline)
            raise ValueError(f"{full_name} refused the rig of {path}: {refusal}"
                             + (" (the nodes set before it have their rig back)"
                                if earlier else ""))
        earlier.append((client, before))
    output = _get(holders[_join(namespace, RECONSTRUCTION_NODE)], ["output_dir"],
                  RECONSTRUCTION_NODE, deadline)["output_dir"]
    persisted = write_atomic(Path(output) / APPLIED_RIG, _rig_text(values, path),
                             within=output)
    return AppliedRig(rig_calibration(values), list(holders), persisted)


def cell_rig(node: Node, namespace: str | None = None, *,
             timeout_s: float = 30.0) -> RigCalibration:
    """The rig the cell's carving node in ``namespace`` (default: ``node``'s) holds
    now (the one its next scan is carved with). ``node`` must be spun by another thread.
    TimeoutError when it does not answer within ``timeout_s`` s, ValueError if its values
    make no rig."""
    namespace = "/" + (namespace if namespace is not None else node.get_namespace()).strip("/")
    full_name = _join(namespace, RECONSTRUCTION_NODE)
    client = AsyncParameterClient(node, full_name)
    values = _get(client, [p.name for p in RIG_PARAMS], full_name,
                  time.monotonic() + timeout_s)
    try:
        return rig_calibration({name: list(v) if isinstance(v, (list, tuple))
                                or hasattr(v, "tolist") else v for name, v in values.items()})
    except ParameterError as exc:
        raise ValueError(f"{full_name} holds no valid rig: {exc}") from None


def _join(namespace: str, name: str) -> str:
    return f"{namespace.rstrip('/')}/{name}"


def _holders(node: Node, namespace: str, deadline: float) -> dict[str, AsyncParameterClient]:
    """``{full name: parameter client}`` of the nodes in ``namespace`` that hold the rig,
    the carving node first; waits for discovery (:data:`DISCOVERY_QUIET_S`)."""
    reconstruction = _join(namespace, RECONSTRUCTION_NODE)
    found, quiet_since = set(), time.monotonic()
    while reconstruction not in found or time.monotonic() - quiet_since < DISCOVERY_QUIET_S:
        _check_deadline(deadline, f"no {reconstruction} node: is the cell running in "
                        f"{namespace}?")
        now = {_join(ns, name) for name, ns in node.get_node_names_and_namespaces()
               if ns == namespace}
        if now != found:
            found, quiet_since = now, time.monotonic()
        time.sleep(0.05)
    own = node.get_fully_qualified_name()
    holders = {}
    for full_name in sorted(found, key=lambda n: n != reconstruction):
        if full_name == own:
            continue
        client = AsyncParameterClient(node, full_name)
        listed = _call(client, client.list_parameters, full_name, "list its parameters",
                       deadline)
        if HOLDER_PARAMETER in listed.result.names:
            holders[full_name] = client
    return holders


def _get(client: AsyncParameterClient, names: list[str], full_name: str,
         deadline: float) -> dict:
    answer = _call(client, lambda: client.get_parameters(names), full_name,
                   "get its parameters", deadline)
    return {name: parameter_value_to_python(value) for name, value in
            zip(names, answer.values)}


def _set(client: AsyncParameterClient, values: dict, full_name: str, deadline: float) -> str:
    """Set ``values`` on one node at once; its refusal ("" if it took them)."""
    parameters = [Parameter(name, value=value if isinstance(value, (str, bool, int, float))
                            else list(value)) for name, value in values.items()]
    answer = _call(client, lambda: client.set_parameters_atomically(parameters), full_name,
                   "set the rig", deadline)
    return "" if answer.result.successful else answer.result.reason


def _call(client: AsyncParameterClient, send, full_name: str, what: str, deadline: float):
    """The answer of a parameter service call ``send()`` (returning its future), once the
    node's parameter services are there, by ``deadline``. A call not answered within
    :data:`~sfs_ros.ros.services.PARAMETER_RESEND_S` is sent again (each is idempotent), as
    Fast DDS may drop the answer to a client it has just matched
    (:func:`sfs_ros.ros.services.call`)."""
    while not client.services_are_ready():
        _check_deadline(deadline, f"{full_name} has no parameter services ({what})")
        time.sleep(0.05)
    futures = [send()]
    sent = time.monotonic()
    while not any(f.done() for f in futures):
        _check_deadline(deadline, f"{full_name} did not answer in time ({what})")
        if time.monotonic() - sent > PARAMETER_RESEND_S:
            futures.append(send())
            sent = time.monotonic()
        time.sleep(0.01)
    return next(f for f in futures if f.done()).result()


def _check_deadline(deadline: float, message: str) -> None:
    if time.monotonic() > deadline:
        raise TimeoutError(message)


def _rig_text(values: dict, source) -> bytes:
    """The kept ``rig.yaml``: the rig parameters set, under a line naming their file."""
    header = (f"The rig applied last to the running cell, from {Path(source).resolve()}; "
              "sfs-cell gives it to the nodes that hold the rig at every start.")
    return yaml_document({"/**": {"ros__parameters": values}}, header=header,
                         what=str(APPLIED_RIG))
