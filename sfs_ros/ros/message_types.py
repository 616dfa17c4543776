"""ROS 2 message classes by type name, for code that handles topics of several types.

A type name comes from outside (a bag's channel, a topic list), so it never
chooses what is imported: only messages (``pkg/msg/Name``) of the packages in
:data:`MESSAGE_PACKAGES` are resolved, and only by their exact module
``pkg.msg``.
"""

from __future__ import annotations

import re
from importlib import import_module

__all__ = ["MESSAGE_PACKAGES", "message_class"]

#: The message packages whose types may be resolved: the cell's own and the ROS 2
#: packages its topics and services use.
MESSAGE_PACKAGES = frozenset({
    "action_msgs", "builtin_interfaces", "diagnostic_msgs", "geometry_msgs",
    "lifecycle_msgs", "rcl_interfaces", "rosgraph_msgs", "sensor_msgs", "sfs_ros_interfaces",
    "shape_msgs", "std_msgs", "tf2_msgs", "unique_identifier_msgs", "visualization_msgs",
})
_TYPE = re.compile(r"([a-z][a-z0-9_]*)/msg/([A-Z][A-Za-z0-9]*)")


def message_class(msgtype: str):
    """The rclpy message class of ``"pkg/msg/Name"``; ValueError, naming the type, for a
    name of another form, a package not in :data:`MESSAGE_PACKAGES` or a type that is not
    installed (nothing is imported then)."""
    match = _TYPE.fullmatch(msgtype) if isinstance(msgtype, str) else None
    if match is None:
        raise ValueError(f"message type {msgtype!r} is not of the form package/msg/Name")
    package, name = match.groups()
    if package not in MESSAGE_PACKAGES:
        raise ValueError(f"message type {msgtype!r} is not of a known message package "
                         f"({', '.join(sorted(MESSAGE_PACKAGES))})")
    try:
        cls = getattr(import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError):
        raise ValueError(f"message type {msgtype!r} is not installed") from None
    if not isinstance(cls, type) or not hasattr(cls, "_TYPE_SUPPORT"):
        raise ValueError(f"message type {msgtype!r} is not a message")
    return cls
