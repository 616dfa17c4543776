"""What is damaged in a rosbag2 folder's ``metadata.yaml``, in words.

An SQLite bag (``.db3``) is read through its ``metadata.yaml`` (the topics,
their types and the storage files are listed there), so a metadata file of the
wrong shape makes the bag unreadable. :func:`metadata_damage` names the first
field that is missing or of the wrong kind, as a path from the top of the
document (``rosbag2_bagfile_information.duration.nanoseconds``), for the
refusal to say what is wrong rather than the reader's ``KeyError``.
"""

from __future__ import annotations

from pathlib import Path, PurePath

from rosbags.rosbag2 import ReaderError
from rosbags.rosbag2.metadata import parse_qos

from ...core.exchange.errors import ViewError
from ...core.exchange.limits import brief, load_yaml, printable

__all__ = ["metadata_damage"]

_INFO = "rosbag2_bagfile_information"
_STORAGES = ("sqlite3", "mcap")


def _integer(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _mapping(value) -> bool:
    return isinstance(value, dict)


def _list(value) -> bool:
    return isinstance(value, list)


def _string(value) -> bool:
    return isinstance(value, str)


def _field(mapping: dict, key: str, where: str, accepts, expected: str):
    """``mapping[key]``; ValueError naming ``where.key`` unless it is there and
    ``accepts(value)``."""
    path = f"{where}.{key}" if where else key
    if key not in mapping:
        raise ValueError(f"{path} is missing")
    value = mapping[key]
    if not accepts(value):
        raise ValueError(f"{path} is {brief(value, 60)}, expected {expected}")
    return value


def _topic(entry, where: str) -> None:
    if not isinstance(entry, dict):
        raise ValueError(f"{where} is {brief(entry, 60)}, expected a mapping")
    _field(entry, "message_count", where, _integer, "a whole number")
    meta = _field(entry, "topic_metadata", where, _mapping, "a mapping")
    for key in ("name", "type", "serialization_format"):
        _field(meta, key, f"{where}.topic_metadata", _string, "a string")
    try:
        parse_qos(meta.get("offered_qos_profiles", []))
    except (ReaderError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{where}.topic_metadata.offered_qos_profiles cannot be read as "
                         f"QoS profiles ({type(exc).__name__} {printable(str(exc), 60)})") from None


def _check(document, folder: Path) -> None:
    if not isinstance(document, dict):
        raise ValueError(f"the document is {brief(document, 60)}, expected a mapping")
    info = _field(document, _INFO, "", _mapping, "a mapping")
    _field(info, "version", _INFO, lambda v: _integer(v) and 1 <= v <= 9,
           "a whole number 1..9")
    files = _field(info, "relative_file_paths", _INFO,
                   lambda v: _list(v) and all(map(_string, v)),
                   "a list of file names")
    for name in files:
        if not (folder / PurePath(name).name).is_file():
            raise ValueError(f"{_INFO}.relative_file_paths names {brief(name, 60)}, which is "
                             f"not a file in the bag's folder")
    _field(info, "storage_identifier", _INFO, lambda v: v in _STORAGES,
           " or ".join(repr(s) for s in _STORAGES))
    topics = _field(info, "topics_with_message_count", _INFO, _list, "a list")
    for n, entry in enumerate(topics):
        _topic(entry, f"{_INFO}.topics_with_message_count[{n}]")
    duration = _field(info, "duration", _INFO, _mapping, "a mapping")
    _field(duration, "nanoseconds", f"{_INFO}.duration", _integer, "a whole number")
    start = _field(info, "starting_time", _INFO, _mapping, "a mapping")
    _field(start, "nanoseconds_since_epoch", f"{_INFO}.starting_time", _integer,
           "a whole number")
    _field(info, "message_count", _INFO, _integer, "a whole number")
    if "files" in info:
        _field(info, "files", _INFO, _list, "a list")
    for key in ("compression_format", "compression_mode"):
        if key in info:
            _field(info, key, _INFO, _string, "a string")


def metadata_damage(folder: Path) -> str:
    """The first thing wrong with ``folder/metadata.yaml`` for reading the bag, in words
    (``""`` when none is found): a file that is not plain YAML, or a field missing or of
    the wrong kind, named by its path in the document."""
    try:
        document = load_yaml(Path(folder) / "metadata.yaml", "bag metadata")
    except ViewError as exc:
        return str(exc)
    try:
        _check(document, Path(folder))
    except ValueError as exc:
        return str(exc)
    return ""
