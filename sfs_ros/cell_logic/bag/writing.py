"""Writing a bag: every message in the operating system's hands before the next is taken.

rosbags keeps an MCAP chunk (up to 1 MiB) or an sqlite3 transaction in memory
until the bag is closed, so :class:`BagWriter` closes the chunk (MCAP: one
chunk per message) or commits after each message. A recorder killed mid-write
leaves a storage file without summary and no ``metadata.yaml``, readable up to
its last whole message (:mod:`.salvage`).
"""

from __future__ import annotations

from pathlib import Path

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

from .layout import CAPTURE, DEFAULT, RESULT, STORAGES, STORE

__all__ = ["BagWriter"]


class BagWriter:
    """A rosbag2 being written, each message on disk before the next is taken.

    Parameters
    ----------
    folder : path-like
        The bag folder to create (it must not exist).
    storage : str
        ``"mcap"`` (default) or ``"sqlite3"``.

    Raises ValueError if the folder exists or the storage is unknown.
    """

    def __init__(self, folder, *, storage: str = "mcap"):
        if storage not in STORAGES:
            raise ValueError(f"storage must be one of {STORAGES}, got {storage!r}")
        self.path = Path(folder)
        self.storage = storage
        if self.path.exists():
            raise ValueError(f"bag folder {self.path} exists already; expected a new one")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        try:
            self._writer = Writer(self.path, version=9, storage_plugin=plugin)
            self._writer.open()
        except WriterError as exc:
            raise ValueError(f"cannot create bag {self.path}: {exc}") from None
        #: The storage file, ``<folder>/<name>.mcap`` or ``.db3``.
        self.storage_file = self._writer.storage.path
        if storage == "mcap":
            self._writer.storage.bio.flush()        # magic and header: a readable file
        else:                      # commits reach the OS, not the disk: as MCAP's flushes
            self._writer.storage.conn.execute("PRAGMA synchronous=OFF")
        self._connections: dict = {}
        self.messages = 0       # written so far
        self.bytes = 0          # of message data written so far

    def add_topic(self, topic: str, msgtype: str, *, kind: str = DEFAULT, depth: int = 100) -> None:
        """Declare ``topic`` (absolute name) of ``msgtype`` (e.g. ``"sensor_msgs/msg/Image"``,
        a type rosbags knows) recorded with QoS ``kind`` (:data:`CAPTURE`, :data:`RESULT`,
        :data:`DEFAULT`; capture depth ``depth``)."""
        if topic in self._connections:
            raise ValueError(f"topic {topic} is already in the bag")
        if msgtype not in STORE.types:
            raise ValueError(f"message type {msgtype!r} of {topic} is unknown; expected a "
                             "standard ROS 2 type")
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=STORE, offered_qos_profiles=[_qos(kind, depth)])

    def write(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Write one message: ``data``, its CDR bytes, received at ``log_time_ns``
        (nanoseconds since the epoch) on a topic declared by :meth:`add_topic`."""
        connection = self._connections.get(topic)
        if connection is None:
            raise ValueError(f"topic {topic} was not declared; declare it with add_topic")
        self._writer.write(connection, int(log_time_ns), data)
        storage = self._writer.storage
        if self.storage == "mcap":
            storage.close_chunk()
            storage.bio.flush()
        else:
            storage.conn.commit()
        self.messages += 1
        self.bytes += len(data)

    def close(self) -> None:
        """Write the summary, the index and ``metadata.yaml``."""
        self._writer.close()


def _qos(kind: str, depth: int) -> Qos:
    zero = QosTime(0, 0)     # deadline, lifespan, lease: the defaults (infinite)
    return Qos(QosHistory.KEEP_LAST, {CAPTURE: depth, RESULT: 1}.get(kind, 10),
               QosReliability.RELIABLE,
               QosDurability.TRANSIENT_LOCAL if kind == RESULT else QosDurability.VOLATILE,
               zero, zero, QosLiveliness.AUTOMATIC, zero, False)
