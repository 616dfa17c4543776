"""ROS 2 message classes by type name, for code that handles topics of several types."""

from __future__ import annotations

from importlib import import_module

__all__ = ["message_class"]


def message_class(msgtype: str):
    """The rclpy message class of ``"pkg/msg/Name"``; ValueError if it cannot be imported."""
    package, kind, name = (msgtype.split("/") + ["", ""])[:3]
    try:
        return getattr(import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError, ValueError):
        raise ValueError(f"message type {msgtype!r} is not installed") from None
