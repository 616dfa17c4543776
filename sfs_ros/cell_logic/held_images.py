"""The colour images and silhouettes a meshing process holds of the scan being received.

The carving node sends each view's colour image and silhouette as it stores the view; the
meshing node keeps those of the newest scan here, so that the carved scan it asks for at
the end can leave them out (the hand-over then carries the hull and the mesher's input).
Whatever is not held (a meshing node started mid-scan, an image dropped on the way, one
given up to the byte limit) comes in the carved scan itself: holding is an optimisation,
never a condition.
"""

from __future__ import annotations

import threading

import numpy as np

from ..core.carving.carve import unpack_bits
from .mesh_files import thumbnail

__all__ = ["HeldImages"]


class HeldImages:
    """Colour images of one scan, ``{view name: (H, W, 3) uint8}``, at most ``max_bytes``,
    and their thumbnails for the contact sheet (:func:`sfs_ros.cell_logic.mesh_files.thumbnail`,
    made as the images come, so that the carved scan need not carry them either).

    Thread-safe: images are added from a subscription while a reconstruction reads them.
    An image of another scan (``session_dir``) replaces those held; past ``max_bytes``
    the oldest images are given up (their thumbnails kept: a few kB each). The views'
    silhouettes are held beside them, packed (:meth:`add_mask`: 38 kB a view of 640 x
    480), as long as the scan's.
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self._lock = threading.Lock()
        self._session = ""
        self._images: dict[str, np.ndarray] = {}
        self._thumbnails: dict[str, np.ndarray] = {}
        self._masks: dict[str, tuple[np.ndarray, tuple]] = {}   # packed, shape

    def _take_up(self, session_dir: str) -> None:
        """Hold the scan ``session_dir`` from now on (another scan's are given up)."""
        if session_dir != self._session:
            self._session, self._images, self._thumbnails, self._masks = \
                session_dir, {}, {}, {}

    def add(self, session_dir: str, name: str, rgb: np.ndarray) -> None:
        """Hold view ``name``'s image of the scan ``session_dir``."""
        small = thumbnail(rgb)
        with self._lock:
            self._take_up(session_dir)
            self._images.pop(name, None)
            self._images[name] = rgb
            self._thumbnails[name] = small
            total = sum(image.nbytes for image in self._images.values())
            while total > self.max_bytes and self._images:
                total -= self._images.pop(next(iter(self._images))).nbytes

    def add_mask(self, session_dir: str, name: str, mask: np.ndarray) -> None:
        """Hold view ``name``'s silhouette ((H, W) bool) of the scan ``session_dir``."""
        packed = np.packbits(mask, axis=None)
        with self._lock:
            self._take_up(session_dir)
            self._masks[name] = (packed, mask.shape)

    def masks(self, session_dir: str, names) -> dict[str, np.ndarray]:
        """{view name: (H, W) bool} of the silhouettes held of the views ``names`` of the
        scan ``session_dir`` (empty for another scan)."""
        with self._lock:
            held = dict(self._masks) if session_dir == self._session else {}
        return {name: unpack_bits(*held[name]) for name in names if name in held}

    def thumbnails(self, session_dir: str) -> dict[str, np.ndarray]:
        """{view name: (h, w, 3) uint8} of the images of the scan ``session_dir`` that came
        (empty for another scan); the dict is the caller's own."""
        with self._lock:
            return dict(self._thumbnails) if session_dir == self._session else {}

    def snapshot(self) -> tuple[str, dict[str, np.ndarray], list[str]]:
        """``(scan folder, {view name: image}, names)`` held now, ``names`` those of the
        views whose silhouette is held too; the dict and list are the caller's own."""
        with self._lock:
            return self._session, dict(self._images), \
                [name for name in self._images if name in self._masks]

    @property
    def n_bytes(self) -> int:
        """Bytes of the images held."""
        with self._lock:
            return sum(image.nbytes for image in self._images.values())
