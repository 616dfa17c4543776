"""A scanning session as a rosbag2: writing it, reading it back, and the views in it.

Nothing here imports ROS: the pure-Python ``rosbags`` package writes and reads
the bag (rosbag2 metadata, MCAP or sqlite3 storage) and (de)serializes CDR.

Recorded topics (:data:`TOPICS`, names relative to the cell's namespace):

| topic | type | QoS kind |
|---|---|---|
| ``capture/image``, ``capture/mask`` | sensor_msgs/Image | capture |
| ``capture/joint_state``, ``capture/mask_joint_state`` | sensor_msgs/JointState | capture |
| ``capture/stored`` | std_msgs/Header | capture |
| ``joint_states`` | sensor_msgs/JointState | default |
| ``diagnostics`` | diagnostic_msgs/DiagnosticArray | default |
| ``camera_info`` | sensor_msgs/CameraInfo | default |
| ``hull`` | sensor_msgs/PointCloud2 | result |
| ``camera_poses`` | geometry_msgs/PoseArray | result |
| ``mesh``, ``mesh_shape`` | visualization_msgs/Marker, shape_msgs/Mesh | result |
| ``sfs/parameters`` | std_msgs/String | result |

QoS kinds: *capture* = reliable, volatile, keep-last ``depth``; *result* =
reliable, transient-local, depth 1; *default* = reliable, volatile, depth 10.

``sfs/parameters`` holds one JSON document per bag (:func:`parameters_message`),
written by the recorder when it has fetched them at the start: format
``sfs_ros-parameters`` version 1, ``namespace`` (the recorder's), ``nodes``
(every parameter of each node asked, ``{node: {name: value}}``),
``unavailable`` (``{node: reason}`` for those that did not answer) and, from
the reconstruction and segmentation nodes' values, ``session`` (the
``session.yaml`` fields ``rig``, ``bounds_m``, ``segmentation``) and
``reconstruction`` (``resolution``, ``mesher``). A message rather than the
metadata's ``custom_data``: ``metadata.yaml`` is only written when the bag is
closed, and a killed recorder's bag must still say how it was made.

Writing (:class:`BagWriter`): every message is in the operating system's
hands before the next is taken. rosbags keeps an MCAP chunk (up to 1 MiB) or
an sqlite3 transaction in memory until the bag is closed, so the writer
closes the chunk (MCAP: one chunk per message) or commits after each
message. A recorder killed mid-write leaves a storage file without summary
and no ``metadata.yaml``, readable up to its last whole message.

Reading (:func:`open_bag`): a rosbag2 folder, or its ``.mcap`` / ``.db3``
file. rosbags reads closed bags; an MCAP file that rosbags refuses because it
was not closed or was cut is read record by record (magic, then records of
opcode u8, length u64, body; Schema, Channel and Message records at the top
level or in uncompressed chunks) up to the last whole record, with one
warning (``logging``) saying where it ends.

Views (:func:`read_bag`): the masks with their joint states, paired by stamp
and given one by one, in recorded order, to a
:class:`~sfs_ros.cell.live.LiveReconstruction` built from the recorded
reconstruction parameters, exactly as the reconstruction node did; its
session folder (in a temporary folder, removed with the view set) is then
read as any session. A bag holding several scans gives its last (as the
node, the scan node resetting it at each ``scan/start``); a bag with
captures but no masks has its images segmented with the recorded
segmentation parameters first, as the segmentation node did. Unlike the
nodes' bounded buffers, the reader pairs any two halves of a view however far
apart they are in the bag. A recording started after a scan began lacks
that scan's earlier views (``with_scan`` in the recorder starts in time).
"""

from __future__ import annotations

import json
import logging
import math
import mmap
import re
import shutil
import struct
import tempfile
import weakref
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from ..core.geometry.rig import RigCalibration
from ..core.segment import SegmentationParams, segment
from ..core.exchange.session import read_session, write_session
from ..core.exchange.views import ViewError, ViewSet
from ..ros.pairing import stamp_key, view_key   # keyed as the reconstruction node does
from .live import DuplicateViewError, LiveReconstruction
from .paths import confined_path

__all__ = ["CAPTURE", "RESULT", "DEFAULT", "TOPICS", "PARAMETERS_TOPIC", "STORAGES",
           "BAG_SUFFIXES", "bag_folder", "parameters_message", "BagWriter", "BagMessage", "Bag",
           "open_bag", "BagViewSet", "read_bag"]

CAPTURE, RESULT, DEFAULT = "capture", "result", "default"
PARAMETERS_TOPIC = "sfs/parameters"
PARAMETERS_FORMAT = "sfs_ros-parameters"

#: Relative topic name -> (message type, QoS kind).
TOPICS: dict[str, tuple[str, str]] = {
    "capture/image": ("sensor_msgs/msg/Image", CAPTURE),
    "capture/joint_state": ("sensor_msgs/msg/JointState", CAPTURE),
    "capture/mask": ("sensor_msgs/msg/Image", CAPTURE),
    "capture/mask_joint_state": ("sensor_msgs/msg/JointState", CAPTURE),
    "capture/stored": ("std_msgs/msg/Header", CAPTURE),
    "joint_states": ("sensor_msgs/msg/JointState", DEFAULT),
    "diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", DEFAULT),
    "camera_info": ("sensor_msgs/msg/CameraInfo", DEFAULT),
    "hull": ("sensor_msgs/msg/PointCloud2", RESULT),
    "camera_poses": ("geometry_msgs/msg/PoseArray", RESULT),
    "mesh": ("visualization_msgs/msg/Marker", RESULT),
    "mesh_shape": ("shape_msgs/msg/Mesh", RESULT),
    PARAMETERS_TOPIC: ("std_msgs/msg/String", RESULT),
}
STORAGES = ("mcap", "sqlite3")
BAG_SUFFIXES = (".mcap", ".db3")
#: The cell's joints (as ``sfs_ros.ros.convert.JOINT_NAMES``): turntable = theta, carriage = phi.
JOINTS = ("turntable", "carriage")

_STORE = get_typestore(Stores.ROS2_KILTED)
_BAG_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}")
_log = logging.getLogger(__name__)


def bag_folder(output_dir, name: str) -> Path:
    """``<output_dir>/bags/<name>``, confined to ``output_dir`` (which must exist);
    ValueError for a name that is not 1-100 letters, digits, ``_``, ``-`` or ``.``."""
    if not isinstance(name, str) or not _BAG_NAME.fullmatch(name):
        raise ValueError(f"bag name {name!r} must be 1-100 letters, digits, '_', '-' or '.', "
                         "not starting with '.', '_' or '-'")
    return confined_path(output_dir, f"bags/{name}/{name}.mcap", suffixes=(".mcap",)).parent


def parameters_message(document: dict) -> bytes:
    """The CDR bytes of the ``std_msgs/String`` holding ``document`` (JSON) for
    :data:`PARAMETERS_TOPIC`; ``format`` and ``version`` are filled in."""
    text = json.dumps({"format": PARAMETERS_FORMAT, "version": 1, **document})
    return bytes(_STORE.serialize_cdr(_STORE.types["std_msgs/msg/String"](data=text),
                                      "std_msgs/msg/String"))


def _qos(kind: str, depth: int) -> Qos:
    zero = QosTime(0, 0)     # deadline, lifespan, lease: the defaults (infinite)
    return Qos(QosHistory.KEEP_LAST, {CAPTURE: depth, RESULT: 1}.get(kind, 10),
               QosReliability.RELIABLE,
               QosDurability.TRANSIENT_LOCAL if kind == RESULT else QosDurability.VOLATILE,
               zero, zero, QosLiveliness.AUTOMATIC, zero, False)


# ---------------------------------------------------------------- writing

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
        if msgtype not in _STORE.types:
            raise ValueError(f"message type {msgtype!r} of {topic} is unknown; expected a "
                             "standard ROS 2 type")
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=_STORE, offered_qos_profiles=[_qos(kind, depth)])

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


# ---------------------------------------------------------------- reading

@dataclass(frozen=True)
class BagMessage:
    """One recorded message: ``topic`` (absolute name), ``msgtype``, ``log_time_ns`` (when
    the recorder received it, ns since the epoch) and ``data`` (its CDR bytes)."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


_MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")


class _McapRecords:
    """The records of an MCAP file that may have been cut or not closed, read in file order.

    ``channels`` {id: (topic, type)}; ``messages`` [(channel id, log time, data view)];
    ``problem`` is "" when the data section ends properly, else where the file ends.
    """

    def __init__(self, file: Path):
        with open(file, "rb") as f:
            buffer = memoryview(mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)) \
                if file.stat().st_size else memoryview(b"")
        if bytes(buffer[:8]) != _MAGIC:
            why = "is empty or cut before" if len(buffer) < len(_MAGIC) else "has no"
            raise ViewError(f"{file} is not an MCAP file: it {why} the MCAP magic at its start")
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, tuple[str, str]] = {}
        self.messages: list[tuple[int, int, memoryview]] = []
        self.profile = ""
        self._last_whole = len(_MAGIC)
        end = self._walk(buffer, 8, len(buffer), file, top=True)
        self.problem = "" if end is None else (
            f"{file.name} was not closed (recorder killed?) or was cut: it ends {end} after "
            f"byte {self._last_whole} of {len(buffer)}; {len(self.messages)} whole messages "
            "read before that")

    def _walk(self, buffer: memoryview, offset: int, stop: int, file: Path, *, top: bool):
        """Parse records in ``buffer[offset:stop]``; None after DataEnd / Footer, else a
        phrase saying how the records end."""
        while offset < stop:
            if offset + _RECORD.size > stop:
                return "inside a record header"
            op, length = _RECORD.unpack_from(buffer, offset)
            body_start = offset + _RECORD.size
            if body_start + length > stop:
                return f"inside a record of {length} bytes (opcode 0x{op:02x})"
            body = buffer[body_start:body_start + length]
            if op in (0x02, 0x0F) and top:          # Footer, DataEnd
                return None
            try:
                self._record(op, body, file)
            except (struct.error, UnicodeDecodeError, IndexError) as exc:
                return f"in a malformed record (opcode 0x{op:02x}: {exc})"
            offset = body_start + length
            if top:
                self._last_whole = offset
        return "after its last whole record, without the MCAP summary" if top else None

    def _record(self, op: int, body: memoryview, file: Path) -> None:
        if op == 0x01:                               # Header: profile, library
            self.profile = _string(body, 0)[0]
        elif op == 0x03:                             # Schema: id, name, encoding, data
            (schema_id,) = struct.unpack_from("<H", body)
            self.schemas[schema_id] = _string(body, 2)[0]
        elif op == 0x04:                             # Channel: id, schema id, topic, encoding
            channel_id, schema_id = struct.unpack_from("<HH", body)
            topic, _ = _string(body, 4)
            self.channels[channel_id] = (topic, self.schemas.get(schema_id, ""))
        elif op == 0x05:                             # Message: channel, sequence, log time, ...
            channel_id, _, log_time = struct.unpack_from("<HIQ", body)
            self.messages.append((channel_id, log_time, body[22:]))
        elif op == 0x06:                             # Chunk
            _, _, size, crc = struct.unpack_from("<QQQI", body)
            compression, at = _string(body, 28)
            (length,) = struct.unpack_from("<Q", body, at)
            records = body[at + 8:at + 8 + length]
            if compression:
                raise ViewError(f"{file} was not closed and holds {compression}-compressed "
                                "chunks: only uncompressed chunks can be read without the "
                                "MCAP summary")
            if len(records) != size or (crc and zlib.crc32(records) != crc):
                raise struct.error("chunk size or checksum does not match")
            inner = self._walk(records, 0, len(records), file, top=False)
            if inner is not None:
                raise struct.error(f"chunk records end {inner}")


def _string(body: memoryview, offset: int) -> tuple[str, int]:
    (length,) = struct.unpack_from("<I", body, offset)
    end = offset + 4 + length
    if end > len(body):
        raise struct.error("string longer than its record")
    return bytes(body[offset + 4:end]).decode("utf-8"), end


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
                 counts: dict[str, int], *, reader=None, records: _McapRecords | None = None):
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
        with Reader(self._reader_path) as reader:
            connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
            if not connections:
                return
            for connection, log_time, data in reader.messages(connections):
                yield BagMessage(connection.topic, connection.msgtype, log_time, bytes(data))


def _storage_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix in BAG_SUFFIXES and p.is_file())


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
        with Reader(target) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            counts = {t: sum(c.msgcount for c in reader.connections if c.topic == t)
                      for t in topics}
    except (ReaderError, ValueError, struct.error, EOFError, KeyError, IndexError) as exc:
        if len(files) != 1 or files[0].suffix != ".mcap":
            raise ViewError(f"cannot read bag {path}: {exc}") from None
        error = exc
    else:
        return Bag(path, files[0], topics, counts, reader=target)
    records = _McapRecords(files[0])
    if not records.problem:
        raise ViewError(f"cannot read bag {path}: {error}")
    if records.profile != "ros2":
        raise ViewError(f"{files[0]} has MCAP profile {records.profile!r}, expected 'ros2'")
    _log.warning(f"bag {path}: {records.problem}")
    counts: dict[str, int] = {}
    for channel_id, _, _ in records.messages:
        topic = records.channels.get(channel_id, ("",))[0]
        counts[topic] = counts.get(topic, 0) + 1
    return Bag(path, files[0], dict(records.channels.values()), counts, records=records)


# ---------------------------------------------------------------- views

@dataclass
class BagViewSet(ViewSet):
    """The views of a bag (:func:`read_bag`): a :class:`ViewSet` plus the recorded
    reconstruction node's ``resolution`` and ``mesher``."""

    resolution: int | None = None
    mesher: str | None = None


def _decode(message: BagMessage, expected: str):
    if message.msgtype != expected:
        raise ValueError(f"type {message.msgtype}, expected {expected}")
    return _STORE.deserialize_cdr(message.data, message.msgtype)


def _parameters(bag: Bag) -> dict:
    """The last recorded parameters document; ViewError if there is none usable."""
    topic = bag.topic(PARAMETERS_TOPIC)
    documents = list(bag.messages([topic])) if topic else []
    if not documents:
        raise ViewError(f"bag {bag.path} has no {PARAMETERS_TOPIC} message: expected a bag "
                        "recorded by sfs-recorder, which stores the rig calibration there")
    try:
        document = json.loads(_decode(documents[-1], TOPICS[PARAMETERS_TOPIC][0]).data)
    except ValueError as exc:
        raise ViewError(f"bag {bag.path}: {PARAMETERS_TOPIC} is not readable: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != PARAMETERS_FORMAT \
            or document.get("version") != 1:
        raise ViewError(f"bag {bag.path}: {PARAMETERS_TOPIC} is not a {PARAMETERS_FORMAT} "
                        "version 1 document")
    if "session" not in document or "reconstruction" not in document:
        why = document.get("unavailable", {}).get("reconstruction", "not recorded")
        raise ViewError(f"bag {bag.path} has no parameters of the reconstruction node ({why}); "
                        "expected them to place the cameras")
    return document


def _image(msg, encodings: tuple[str, ...]) -> np.ndarray:
    """(H, W, 3) RGB or (H, W) uint8 array of a deserialized ``sensor_msgs/Image``."""
    if msg.encoding not in encodings:
        raise ValueError(f"image encoding is {msg.encoding!r}, expected one of {list(encodings)}")
    channels = 1 if msg.encoding == "mono8" else 3
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if h == 0 or w == 0 or step < w * channels or data.size != h * step:
        raise ValueError(f"image sizes do not add up: {w}x{h} {msg.encoding}, step {step}, "
                         f"{data.size} bytes")
    rows = data.reshape(h, step)[:, :w * channels]
    image = rows if channels == 1 else rows.reshape(h, w, 3)
    return image[:, :, ::-1] if msg.encoding == "bgr8" else image


def _angles(msg) -> tuple[float, float]:
    """``(theta_rad, phi_rad)`` of a deserialized ``sensor_msgs/JointState``."""
    names, positions = list(msg.name), list(msg.position)
    angles = []
    for joint in JOINTS:
        if joint not in names or names.index(joint) >= len(positions):
            raise ValueError(f"joint state has no position of joint {joint!r} (names {names}); "
                             f"expected {list(JOINTS)}")
        value = float(positions[names.index(joint)])
        if not math.isfinite(value):
            raise ValueError(f"joint {joint!r} position is {value}, expected a finite angle")
        angles.append(value)
    return angles[0], angles[1]


class _Views:
    """Feeds the bag's views to a LiveReconstruction as the nodes would; notes rejections."""

    def __init__(self, bag: Bag, document: dict, pair: tuple[str, str], folder: Path, *,
                 captures: bool = False):
        session, recon = document["session"], document["reconstruction"]
        nodes = document.get("nodes", {})
        try:
            calibration = RigCalibration.from_dict(session["rig"])
            self.segmentation = None
            if pair[0] == "capture/image" and not captures:
                self.segmentation = SegmentationParams.from_dict(session["segmentation"]) \
                    if session.get("segmentation") is not None else SegmentationParams()
            self.live = LiveReconstruction(calibration, session["bounds_m"], output_dir=folder,
                                           resolution=recon["resolution"],
                                           mesher=recon["mesher"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ViewError(f"bag {bag.path}: the recorded parameters cannot be used: "
                            f"{type(exc).__name__}: {exc}") from None
        if self.segmentation is not None and session.get("segmentation") is None:
            _log.warning(f"bag {bag.path}: no recorded segmentation parameters; segmenting the "
                         "captures with the defaults")
        self.resets = nodes.get("scan", {}).get("reset_reconstruction", True)
        self.pair = pair
        self.waiting: dict[str, dict] = {pair[0]: {}, pair[1]: {}}   # stamp -> half
        self.bad: set = set()                                         # stamps given up
        self.rejected: dict[str, str] = {}
        self.scans: list[tuple[Path, int]] = []     # scans' session folders and view counts
        self._scan = None
        # With ``captures``: the last scan's images as they were taken, not its masks.
        self.captures: dict[str, tuple[np.ndarray, tuple[float, float]]] | None = \
            {} if captures else None
        self._folder, self._calibration, self._session = folder, calibration, session

    def take(self, name: str, message: BagMessage) -> None:
        if name == "diagnostics":
            self._diagnostics(message)
            return
        try:
            msg = _decode(message, TOPICS[name][0])
            stamp = stamp_key(msg.header.stamp)
        except (ValueError, KeyError, IndexError, struct.error) as exc:
            self.rejected[f"{name} at {message.log_time_ns} ns"] = f"unreadable: {exc}"
            return
        if stamp in self.bad:
            return
        masks = self.segmentation is None and self.captures is None
        try:
            item = _angles(msg) if name == self.pair[1] else _image(
                msg, ("mono8",) if masks else ("rgb8", "bgr8", "mono8"))
        except ValueError as exc:                    # its capture is given up, as the node does
            self.bad.add(stamp)
            for halves in self.waiting.values():
                halves.pop(stamp, None)
            self.rejected[view_key(stamp)] = f"malformed {name}: {exc}"
            return
        other = self.pair[1] if name == self.pair[0] else self.pair[0]
        partner = self.waiting[other].pop(stamp, None)
        if partner is None:
            self.waiting[name][stamp] = item         # a newer copy replaces a waiting one
        elif name == self.pair[0]:
            self._add(stamp, item, partner)
        else:
            self._add(stamp, partner, item)

    def _add(self, stamp, image: np.ndarray, angles: tuple[float, float]) -> None:
        if self.captures is not None:
            rgb = image if image.ndim == 3 else np.repeat(image[:, :, None], 3, axis=2)
            self.captures.setdefault(view_key(stamp), (rgb, angles))    # a resend: kept once
            return
        try:
            mask = image if self.segmentation is None else segment(image, self.segmentation).mask
            self.live.add_view(view_key(stamp), mask, *angles)
        except DuplicateViewError:
            pass                                     # a capture sent again: stored once
        except ValueError as exc:
            self.rejected[view_key(stamp)] = str(exc)

    def _diagnostics(self, message: BagMessage) -> None:
        """A new scan number from the scan node: it reset the reconstruction."""
        try:
            array = _decode(message, TOPICS["diagnostics"][0])
        except (ValueError, KeyError, IndexError, struct.error):
            return
        for status in array.status:
            values = {kv.key: kv.value for kv in status.values}
            if not status.name.endswith(": scan") or "scan" not in values:
                continue
            if self._scan is not None and values["scan"] != self._scan and self.resets:
                if self.live.n_views:
                    self.scans.append((self.live.session_dir, self.live.n_views))
                self.live.reset()
                self.rejected.clear()
                if self.captures is not None:
                    self.captures = {}
            self._scan = values["scan"]

    def finish(self) -> None:
        """Halves still waiting for their partner are rejected views."""
        for name, other in (self.pair, self.pair[::-1]):
            for stamp in self.waiting[name]:
                self.rejected.setdefault(view_key(stamp), f"{name} without {other} of the same "
                                                      "stamp in the bag")
        if self.live.n_views:
            self.scans.append((self.live.session_dir, self.live.n_views))
        if self.captures:
            names = [f"{key}.png" for key in self.captures]
            folder = write_session(self._folder / "captures",
                                   [(n, rgb) for n, (rgb, _) in zip(names, self.captures.values())],
                                   [angles for _, angles in self.captures.values()],
                                   self._calibration, bounds_m=self._session.get("bounds_m"),
                                   segmentation=self._session.get("segmentation"))
            self.scans.append((folder, len(names)))


def _checked(bag: Bag, name: str) -> str | None:
    """The absolute name of relative topic ``name`` if the bag has it with messages;
    ViewError if it has another type than :data:`TOPICS` says."""
    topic = bag.topic(name)
    if topic is None or not bag.counts.get(topic):
        return None
    if bag.topics[topic] != TOPICS[name][0]:
        raise ViewError(f"bag {bag.path}: topic {topic} has type {bag.topics[topic]}, "
                        f"expected {TOPICS[name][0]}")
    return topic


def _view_topics(bag: Bag) -> tuple[str, str]:
    """``(images, joint states)`` relative topics of the views: the masks, else the captures."""
    for images, joints in (("capture/mask", "capture/mask_joint_state"),
                           ("capture/image", "capture/joint_state")):
        topic = _checked(bag, images)
        if topic is None:
            continue
        if _checked(bag, joints) is None:
            raise ViewError(f"bag {bag.path} has {bag.counts[topic]} messages on {topic} but "
                            f"none on {bag.namespace}/{joints}: expected the joint states "
                            "(turntable and carriage angles) under the same stamps")
        return images, joints
    raise ViewError(f"bag {bag.path} holds no views: no messages on capture/mask nor "
                    f"capture/image under namespace '{bag.namespace or '/'}' (topics: "
                    f"{', '.join(sorted(bag.topics)) or 'none'})")


def read_bag(path, *, captures: bool = False) -> BagViewSet:
    """The views of the bag at ``path`` (a rosbag2 folder, or its .mcap / .db3 file), as
    the reconstruction node received them (module docstring); with ``captures``, the
    last scan's captured images with their angles instead (for export to other tools).

    Returns
    -------
    BagViewSet
        ``source="session"`` (read from the session folder the views were stored in);
        ``calibration``, ``bounds_m`` from the recorded reconstruction parameters,
        ``segmentation`` the one that leaves stored masks unchanged; ``rejected``
        holds the views the node would have refused or that the bag lacks a half of;
        ``resolution`` and ``mesher`` the node's.

    Raises
    ------
    ViewError
        One line: not a bag, no recorded parameters, no views, a topic of the wrong
        type, images without their joint-state topic. A bag that ends early gives
        the views read before its end and a warning (logging).
    """
    bag = open_bag(path)
    for topic, msgtype in sorted(bag.topics.items()):
        if msgtype not in _STORE.types:
            _log.warning(f"bag {bag.path}: topic {topic} has type {msgtype}, unknown here: "
                         "skipped")
    document = _parameters(bag)
    pair = ("capture/image", "capture/joint_state") if captures else _view_topics(bag)
    if captures and _checked(bag, pair[0]) is None:
        raise ViewError(f"bag {bag.path} holds no captured images on {pair[0]}")
    names = [*pair, "diagnostics"] if _checked(bag, "diagnostics") else list(pair)
    folder = Path(tempfile.mkdtemp(prefix="sfs_bag_"))
    try:
        views = _Views(bag, document, pair, folder, captures=captures)
        for message in bag.messages([bag.topic(n) for n in names]):
            views.take(bag.relative(message.topic), message)
        views.finish()
        if not views.scans:
            first = next(iter(views.rejected.items()), None)
            detail = f"; first rejected: {first[0]}: {first[1]}" if first else ""
            raise ViewError(f"bag {bag.path} holds no usable view on {pair[0]} with "
                            f"{pair[1]}{detail}")
        session, n_views = views.scans[-1]
        if len(views.scans) > 1:
            earlier = sum(n for _, n in views.scans[:-1])
            _log.warning(f"bag {bag.path} holds {len(views.scans)} scans: using the last "
                         f"({n_views} views), not the {earlier} views of the earlier ones")
        loaded = read_session(session)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    recon = document["reconstruction"]
    view_set = BagViewSet(views=loaded.views, source=loaded.source, bounds_m=loaded.bounds_m,
                          segmentation=loaded.segmentation, calibration=loaded.calibration,
                          rejected=[*views.rejected.items(), *loaded.rejected],
                          resolution=recon["resolution"], mesher=recon["mesher"])
    weakref.finalize(view_set, shutil.rmtree, folder, True)
    return view_set
