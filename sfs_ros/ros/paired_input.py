"""Two subscriptions whose messages pair up by header stamp: one capture each pair.

The segmentation node pairs (image, joint state), the carving node
(mask, joint state); both the same way, here:

* each message is decoded by its stream's ``decode`` (ValueError = malformed);
* a message whose stamp is bad is dropped (its partner, with the same bad
  stamp, will be too); one whose content is bad gives up its whole capture
  (:meth:`StampPairer.reject`: the partner is dropped too, waiting or to come);
* a half whose partner never comes is dropped once the buffer is full, in
  count (``depth``) or in bytes (``max_bytes``, the messages' ``data``); one
  larger than ``max_bytes`` by itself is dropped as it comes;
* every drop is reported through ``on_problem(kind, text)``, ``kind``
  ``"malformed"`` or ``"unpaired_dropped"`` (the nodes' diagnostics counters),
  and the node carries on;
* each complete pair goes to ``on_pair(stamp, first, second)`` with the
  decoded items.

No ROS import: the node passed in makes the subscriptions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from sfs_ros.core.exchange.limits import MAX_WAITING_BYTES
from sfs_ros.ros.pairing import Stamp, StampPairer, format_stamp, stamp_key

__all__ = ["PairedInput", "Stream"]


@dataclass(frozen=True)
class Stream:
    """One half of a capture.

    msg_type : type
        Message class (with a ``header``).
    topic : str
        Topic name (relative).
    what : str
        The half's name in messages ("image", "mask", "joint state").
    decode : callable(msg) -> item
        The item handed to ``on_pair``; ValueError saying what is wrong with the message.
    """

    msg_type: type
    topic: str
    what: str
    decode: Callable[[Any], Any]


class PairedInput:
    """Subscribes ``first`` and ``second`` on ``node`` and pairs them by exact stamp.

    Parameters
    ----------
    node : rclpy.node.Node
        Makes the subscriptions (``create_subscription``).
    first, second : Stream
        The two halves; pairs are handed out as ``(first item, second item)``.
    depth : int
        Buffer of unpaired halves per stream (:class:`StampPairer` capacity).
    max_bytes : int, keyword-only
        Bytes of unpaired halves per stream (the length of their ``data``), at most
        (default :data:`~sfs_ros.core.exchange.limits.MAX_WAITING_BYTES`).
    qos : QoSProfile or int
        Of both subscriptions.
    unit : str, keyword-only
        What a pair is called in messages ("capture", "view").
    on_pair : callable(stamp, first_item, second_item), keyword-only
        Called (in the subscription's thread) with each complete pair.
    on_problem : callable(kind, text), keyword-only
        Called with each dropped message: ``kind`` "malformed" or "unpaired_dropped".
    callback_group : optional, keyword-only
        Of both subscriptions.
    """

    def __init__(self, node, first: Stream, second: Stream, depth: int, qos, *, unit: str,
                 max_bytes: int = MAX_WAITING_BYTES, on_pair: Callable[[Stamp, Any, Any], None],
                 on_problem: Callable[[str, str], None], callback_group=None):
        self._streams = {"a": first, "b": second}
        self._unit = unit
        self._on_pair = on_pair
        self._on_problem = on_problem
        self.pairer = StampPairer(depth, max_bytes=max_bytes, on_evict=self._given_up)
        for add, stream in ((self.pairer.add_a, first), (self.pairer.add_b, second)):
            node.create_subscription(
                stream.msg_type, stream.topic,
                lambda msg, add=add, stream=stream: self._receive(msg, add, stream), qos,
                callback_group=callback_group)

    def pending(self, which: str) -> int:
        """Halves of ``which`` ("first" or "second") waiting for their partner."""
        return self.pairer.pending({"first": "a", "second": "b"}[which])

    def _receive(self, msg, add, stream: Stream) -> None:
        try:
            stamp = stamp_key(msg.header.stamp)
        except ValueError as exc:
            self._on_problem("malformed", f"malformed {stream.what} dropped: {exc}")
            return
        try:
            item = stream.decode(msg)
        except ValueError as exc:
            self.malformed(stamp, stream.what, exc)
            return
        pair = add(stamp, item, len(getattr(msg, "data", b"")))
        if pair is not None:
            self._on_pair(stamp, *pair)

    def malformed(self, stamp: Stamp, what: str, exc: Exception) -> None:
        """Give up the capture at ``stamp`` because its ``what`` (e.g. "image") is malformed
        (``exc`` says how): its halves are dropped, waiting or to come."""
        self.pairer.reject(stamp)
        self._on_problem("malformed", f"malformed {what} at stamp {format_stamp(stamp)} "
                                      f"dropped with its {self._unit}: {exc}")

    def _given_up(self, stream: str, stamp: Stamp, _item, reason: str) -> None:
        why = {"evicted": "no partner arrived before the buffer filled",
               "too large": f"larger than the {self.pairer.max_bytes >> 20} MiB its buffer "
                            "holds"}.get(reason, "its partner was malformed")
        self._on_problem("unpaired_dropped", f"{self._streams[stream].what} at stamp "
                                             f"{format_stamp(stamp)} dropped: {why}")
