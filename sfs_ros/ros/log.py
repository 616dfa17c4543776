"""A node's log line at a severity named by a word (``"info"``, ``"warning"``, ``"error"``),
for the cell's objects that log through a callable."""

from __future__ import annotations

__all__ = ["log_at"]


def log_at(logger, level: str, text: str) -> None:
    """Log ``text`` with ``logger`` (an rclpy logger) at ``level``; any other word is info."""
    # One call site per severity: rclpy refuses a site whose severity changes.
    if level == "error":
        logger.error(text)
    elif level == "warning":
        logger.warning(text)
    else:
        logger.info(text)
