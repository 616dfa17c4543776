"""Reading a bag: a rosbag2 folder, or its ``.mcap`` / ``.db3`` file, message by message.

:func:`open_bag` reads closed bags with rosbags; an MCAP file that rosbags
refuses because it was not closed or was cut is read by :mod:`.salvage` up to
its last whole message, with one warning (``logging``) saying where it ends.
No record is read or expanded past the limits of :mod:`.bounds`: a bag that
has one is refused, naming the bag and the limit.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from rosbags.rosbag2 import Reader, ReaderError

from ...core.exchange.views import ViewError
from .bounds import RecordTooLarge, check_storage, install
from .layout import BAG_SUFFIXES, TOPICS
from .metadata import metadata_damage
from .salvage import McapRecords

__all__ = ["BagMessage", "Bag", "open_bag"]

_log = logging.getLogger(__name__)
install()   # rosbags expands MCAP chunks within MAX_BAG_RECORD_BYTES (.bounds)


@dataclass(frozen=True)
class BagMessage:
    """One recorded message: ``topic`` (absolute name), ``msgtype``, ``log_time_ns`` (when
    the recorder received it, ns since the epoch) and ``data`` (its CDR bytes)."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


class Bag:
    """A rosbag2 opened for reading (:func:`open_bag`).

    Attributes
    ----------
    path : Path, as given; storage_file : Path, the ``.mcap`` / ``.db3`` file;
    topics : dict, absolute topic name -> message type; counts : dict, name -> messages;
    namespace : str, the cell's namespace (``""`` for the root, else e.g.
        ``"/cell"``), from the names of the cell's topics in the bag;
    problem : str, "" or why the bag ends early (cut, not closed).
    """

    def __init__(self, path: Path, storage_file: Path, topics: dict[str, str],
                 counts: dict[str, int], *, reader=None, records: McapRecords | None = None):
        self.path = path
        self.storage_file = storage_file
        self.topics = topics
        self.counts = counts
        self.problem = records.problem if records is not None else ""
        self._reader_path = reader
        self._records = records
        spaces = {topic[:len(topic) - len(name) - 1] for topic in topics for name in TOPICS
                  if topic == f"/{name}" or topic.endswith(f"/{name}")}
        if len(spaces) > 1:
            raise ViewError(f"bag {path} holds the cell's topics under several namespaces "
                            f"({', '.join(sorted(s or '/' for s in spaces))}); expected one")
        self.namespace = spaces.pop() if spaces else ""

    def relative(self, topic: str) -> str | None:
        """``topic`` relative to :attr:`namespace`, or None if it is not under it."""
        prefix = f"{self.namespace}/"
        return topic[len(prefix):] if topic.startswith(prefix) else None

    def topic(self, name: str) -> str | None:
        """The absolute name of the relative topic ``name`` in this bag, or None."""
        topic = f"{self.namespace}/{name}"
        return topic if topic in self.topics else None

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """The messages in recorded order, of the (absolute) ``topics`` (None: all)."""
        wanted = None if topics is None else set(topics)
        if self._records is not None:
            channels = self._records.channels
            for channel_id, log_time, data in self._records.messages:
                topic, msgtype = channels.get(channel_id, ("", ""))
                if topic and (wanted is None or topic in wanted):
                    yield BagMessage(topic, msgtype, log_time, bytes(data))
            return
        try:
            with Reader(self._reader_path) as reader:
                connections = [c for c in reader.connections
                               if wanted is None or c.topic in wanted]
                if not connections:
                    return
                for connection, log_time, data in reader.messages(connections):
                    yield BagMessage(connection.topic, connection.msgtype, log_time, bytes(data))
        except RecordTooLarge as exc:
            raise ViewError(f"bag {self.path}: {exc}") from None


def _storage_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix in BAG_SUFFIXES and p.is_file())


def _unreadable(path: Path, error: Exception) -> ViewError:
    """The refusal of the bag ``path`` that the reader could not open (``error``): what is
    damaged in its metadata.yaml, which an SQLite bag is read through, if that is why."""
    damage = metadata_damage(path) if path.is_dir() and (path / "metadata.yaml").is_file() \
        else ""
    if damage:
        return ViewError(f"bag {path}: its metadata.yaml is damaged: {damage} (the storage "
                         "file is read through it; ros2 bag reindex writes it again)")
    return ViewError(f"cannot read bag {path}: {type(error).__name__}: {error}")


def open_bag(path) -> Bag:
    """Open the rosbag2 folder (or ``.mcap`` / ``.db3`` file) ``path``.

    Raises ViewError (one line) for what is not a readable bag; warns (logging)
    when an MCAP file ends early, and returns what is whole of it.
    """
    path = Path(path)
    if not path.exists():
        raise ViewError(f"bag {path} does not exist")
    if path.is_dir():
        files = _storage_files(path)
        if not files:
            raise ViewError(f"{path} is not a rosbag2 folder: it holds no "
                            f"{' or '.join(BAG_SUFFIXES)} file")
        if (path / "metadata.yaml").is_file():
            target = path
        elif len(files) == 1:
            target = files[0]          # a bag whose recorder did not close it
        else:
            raise ViewError(f"{path} has no metadata.yaml and several storage files "
                            f"({', '.join(p.name for p in files)}); pass the one to read")
    elif path.suffix in BAG_SUFFIXES:
        files, target = [path], path
    else:
        raise ViewError(f"{path} is not a rosbag2 storage file: expected a folder or a file "
                        f"ending in {' or '.join(BAG_SUFFIXES)}")
    try:
        check_storage(path if path.is_dir() else None, files)
    except RecordTooLarge as exc:
        raise ViewError(f"bag {path}: {exc}") from None
    try:
        with Reader(target) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            counts = {t: sum(c.msgcount for c in reader.connections if c.topic == t)
                      for t in topics}
    except RecordTooLarge as exc:
        raise ViewError(f"bag {path}: {exc}") from None
    except (ReaderError, ValueError, struct.error, EOFError, KeyError, IndexError, TypeError,
            AttributeError) as exc:   # metadata.yaml of an unexpected shape among them
        if len(files) != 1 or files[0].suffix != ".mcap":
            raise _unreadable(path, exc) from None
        error = exc
    else:
        return Bag(path, files[0], topics, counts, reader=target)
    records = McapRecords(files[0])
    if records.profile != "ros2":
        raise ViewError(f"{files[0]} has MCAP profile {records.profile!r}, expected 'ros2'")
    # Whole data but an unreadable summary or metadata.yaml (cut inside it, or damaged):
    # the records hold every message, so read those, as for a file cut earlier.
    problem = records.problem or (f"it cannot be read as a closed bag ({error}); the "
                                  f"records of {files[0].name} are whole and read instead")
    _log.warning(f"bag {path}: {problem}")
    counts: dict[str, int] = {}
    for channel_id, _, _ in records.messages:
        topic = records.channels.get(channel_id, ("",))[0]
        counts[topic] = counts.get(topic, 0) + 1
    return Bag(path, files[0], dict(records.channels.values()), counts, records=records)
