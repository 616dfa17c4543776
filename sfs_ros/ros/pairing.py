"""Exact pairing of two message streams by header stamp (no ROS imports).

A capture is an image and a joint state published with the *same*
``header.stamp``; they travel on two topics and may arrive in either order.
:class:`StampPairer` holds the unmatched half of each capture until its
partner arrives, and hands out the pair when its second half comes:

* stamps must be identical (``sec``, ``nanosec``): no "nearest" matching,
  which could give a view another view's angles;
* buffers are bounded in count and in bytes: when ``capacity`` items of one
  stream wait, or their sizes add up to more than ``max_bytes``, those that
  have waited longest are evicted (counted, and reported through
  ``on_evict``); an item larger than ``max_bytes`` by itself is given up as it
  comes (reason "too large");
* a stamp may come again (senders deliver at least once, resending what
  was not receipted): a copy of a half that is still waiting replaces it,
  and a capture already paired is paired afresh when its halves come
  again; both count in ``repeated`` (the pairer remembers the last
  ``capacity`` completed stamps for this count). Whoever consumes the
  pairs must tolerate a capture twice (the reconstruction stores each once);
* :meth:`StampPairer.reject` marks a capture bad (one half was malformed):
  its waiting half is dropped, and so is the other half when it comes.

The stamp helpers (:func:`stamp_key`, :func:`format_stamp`, :func:`view_key`) are
:mod:`sfs_ros.cell_logic.message_fields`', named here as well.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any, Callable

from sfs_ros.cell_logic.message_fields import Stamp, format_stamp, stamp_key, view_key

__all__ = ["StampPairer", "format_stamp", "stamp_key", "view_key"]


class StampPairer:
    """Pairs items of stream ``a`` and stream ``b`` that carry identical stamps.

    capacity : int >= 1
        Most items waiting per stream; also how many finished stamps are
        remembered (rejected ones stay rejected, paired ones count as repeats).
    max_bytes : int or None
        Most bytes waiting per stream (the ``nbytes`` given with each item); None:
        no bound.
    on_evict : callable(stream, stamp, item, reason), optional
        Called for every item given up: ``stream`` "a" or "b", ``stamp``
        (sec, nanosec), ``reason`` "evicted" (full buffer), "too large" (over
        ``max_bytes`` alone) or "rejected" (its capture was marked by :meth:`reject`).

    Counters: ``pairs``, ``evicted`` ({"a": n, "b": n}), ``repeated`` (halves
    that came again), ``rejected`` (captures marked by :meth:`reject`),
    ``dropped`` (halves discarded because their capture was rejected).
    """

    def __init__(self, capacity: int, *, max_bytes: int | None = None,
                 on_evict: Callable[[str, Stamp, Any, str], None] | None = None):
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f"capacity must be an integer >= 1, got {capacity!r}")
        self.capacity = capacity
        self.max_bytes = max_bytes
        self._bytes = {"a": 0, "b": 0}
        self._sizes: dict[str, dict[Stamp, int]] = {"a": {}, "b": {}}
        self.repeated = 0
        self._on_evict = on_evict
        self._pending: dict[str, OrderedDict[Stamp, Any]] = {"a": OrderedDict(), "b": OrderedDict()}
        self._finished: OrderedDict[Stamp, str] = OrderedDict()  # stamp -> "paired" / "rejected"
        self.pairs = 0
        self.evicted = {"a": 0, "b": 0}
        self.rejected = 0
        self.dropped = 0

    def add_a(self, stamp, item, nbytes: int = 0) -> tuple[Any, Any] | None:
        """Add an item of stream a (``nbytes`` its size, bytes); ``(item_a, item_b)`` when
        it completes a pair, else None."""
        return self._add("a", "b", stamp_key(stamp), item, nbytes)

    def add_b(self, stamp, item, nbytes: int = 0) -> tuple[Any, Any] | None:
        """Add an item of stream b (``nbytes`` its size, bytes); ``(item_a, item_b)`` when
        it completes a pair, else None."""
        pair = self._add("b", "a", stamp_key(stamp), item, nbytes)
        return None if pair is None else (pair[1], pair[0])

    def reject(self, stamp) -> None:
        """Give up the capture at ``stamp``: drop its waiting half now and its other half later."""
        key = stamp_key(stamp)
        if self._finished.get(key) == "rejected":
            return
        self.rejected += 1
        for stream in ("a", "b"):
            if key in self._pending[stream]:
                self._drop(stream, key, self._pop_pending(stream, key))
        self._finish(key, "rejected")

    def pending_bytes(self, stream: str) -> int:
        """Bytes of the items of ``stream`` ("a" or "b") waiting for a partner."""
        return self._bytes[stream]

    def pending(self, stream: str) -> int:
        """Number of items of ``stream`` ("a" or "b") waiting for a partner."""
        return len(self._pending[stream])

    def _add(self, own: str, other: str, key: Stamp, item, nbytes: int):
        state = self._finished.get(key)
        if state == "rejected":
            self._drop(own, key, item)
            return None
        if state == "paired":                    # the whole capture comes again
            del self._finished[key]
            self.repeated += 1
        elif key in self._pending[own]:          # the newer copy replaces the waiting one
            self._pop_pending(own, key)
            self.repeated += 1
        if key in self._pending[other]:
            partner = self._pop_pending(other, key)
            self._finish(key, "paired")
            self.pairs += 1
            return item, partner
        if self.max_bytes is not None and nbytes > self.max_bytes:
            self._give_up(own, key, item, "too large")
            return None
        self._pending[own][key] = item
        self._sizes[own][key] = nbytes
        self._bytes[own] += nbytes
        while len(self._pending[own]) > self.capacity or (
                self.max_bytes is not None and self._bytes[own] > self.max_bytes):
            old_key = next(iter(self._pending[own]))
            self._give_up(own, old_key, self._pop_pending(own, old_key), "evicted")
        return None

    def _pop_pending(self, stream: str, key: Stamp):
        """Remove the waiting item ``key`` of ``stream``; the item."""
        self._bytes[stream] -= self._sizes[stream].pop(key)
        return self._pending[stream].pop(key)

    def _give_up(self, stream: str, key: Stamp, item, reason: str) -> None:
        self.evicted[stream] += 1
        if self._on_evict is not None:
            self._on_evict(stream, key, item, reason)

    def _drop(self, stream: str, key: Stamp, item) -> None:
        self.dropped += 1
        if self._on_evict is not None:
            self._on_evict(stream, key, item, "rejected")

    def _finish(self, key: Stamp, state: str) -> None:
        self._finished[key] = state
        self._finished.move_to_end(key)
        while len(self._finished) > self.capacity:
            self._finished.popitem(last=False)
