"""The parameters of the cell's nodes, fetched through their parameter services, as the
recorder stores them with each bag (``sfs/parameters``, :mod:`sfs_ros.cell_logic.bag.layout`).

:func:`fetch_parameters` asks every node of its clients for all its parameters within
one deadline, from a thread of the caller's (never the executor's: it waits); a node that
does not answer is named in the document's ``unavailable``. With the carving node's
parameters (and the segmentation node's) the document also holds the ``session`` and
``reconstruction`` sections an offline reconstruction of the bag needs
(:func:`session_parameters`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import asdict

import numpy as np
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from sfs_ros.ros.rig_params import rig_calibration
from sfs_ros.ros.segmentation_params import segmentation_params
from sfs_ros.ros.services import ServiceError

__all__ = ["fetch_parameters", "session_parameters"]


def session_parameters(nodes: dict) -> tuple[dict, dict]:
    """The ``session`` and ``reconstruction`` sections (:mod:`sfs_ros.cell_logic.bag.layout`) of the
    fetched ``{node: {name: value}}``; empty when the carving node's are missing."""
    values = nodes.get("carving")
    if values is None:
        return {}, {}
    session = {"rig": rig_calibration(values).to_dict(),
               "bounds_m": np.reshape(values["bounds_m"], (2, 3)).tolist()}
    if "segmentation" in nodes:
        session["segmentation"] = asdict(segmentation_params(nodes["segmentation"]))
    return session, {"resolution": values["resolution"], "mesher": values["mesher"]}


def fetch_parameters(node: Node, clients: dict[str, AsyncParameterClient],
                     timeout_s: float, *, stopping: threading.Event | None = None,
                     on_answer: Callable[[str], None] | None = None) -> tuple[dict, dict]:
    """``(document, unavailable)``: the parameters of the nodes of ``clients`` (by name)
    fetched within ``timeout_s`` together, in ``node``'s namespace, and why each node
    (or the session sections) is missing. Once ``stopping`` is set (the caller stops), the
    nodes not answered yet are given up at once. ``on_answer(name)`` is called as each
    node's parameters come."""
    deadline = time.monotonic() + timeout_s
    stopping = stopping or threading.Event()
    nodes, unavailable = {}, {}
    for name, client in clients.items():
        try:
            nodes[name] = _parameters_of(node, client, deadline, timeout_s, stopping)
            if on_answer is not None:
                on_answer(name)
        except ServiceError as exc:
            unavailable[name] = str(exc)
        except Exception as exc:  # noqa: BLE001 -- e.g. rclpy shut down meanwhile
            unavailable[name] = f"{type(exc).__name__}: {exc}"
    document = {"namespace": node.get_namespace(), "nodes": nodes, "unavailable": unavailable}
    try:
        session, reconstruction = session_parameters(nodes)
        if session:
            document.update(session=session, reconstruction=reconstruction)
    except (KeyError, ValueError) as exc:
        unavailable["reconstruction"] = f"its parameters do not make a session: {exc}"
    return document, unavailable


def _parameters_of(node: Node, client: AsyncParameterClient, deadline: float,
                   timeout_s: float, stopping: threading.Event) -> dict:
    name = client.remote_node_name
    while not client.services_are_ready():
        _check_running(node, stopping)
        if time.monotonic() > deadline:
            raise ServiceError(f"node {name} offers no parameter services (waited "
                               f"{timeout_s:g} s): is it running?")
        time.sleep(0.05)
    names = list(_answer(node, client.list_parameters(), name, deadline, timeout_s,
                         stopping).result.names)
    values = _answer(node, client.get_parameters(names), name, deadline, timeout_s,
                     stopping).values
    return {n: parameter_value_to_python(v) for n, v in zip(names, values)}


def _answer(node: Node, future, name: str, deadline: float, timeout_s: float,
            stopping: threading.Event):
    answered = threading.Event()
    future.add_done_callback(lambda _f: answered.set())
    while not answered.wait(0.05):
        try:
            _check_running(node, stopping)
        except ServiceError:
            future.cancel()
            raise
        if time.monotonic() > deadline:
            future.cancel()
            raise ServiceError(f"node {name} did not answer its parameter request within "
                               f"{timeout_s:g} s")
    return future.result()


def _check_running(node: Node, stopping: threading.Event) -> None:
    if stopping.is_set() or not node.context.ok():
        raise ServiceError("the recorder stopped before it answered")
