"""Salvage: the whole messages of an MCAP file that was cut or never closed.

rosbags reads closed bags only. A recorder killed mid-write leaves an MCAP
file without its summary; :class:`McapRecords` reads such a file record by
record (magic, then records of opcode u8, length u64, body; Schema, Channel and
Message records at the top level or in uncompressed chunks) up to the last
whole record, and says where and how the file ends.
"""

from __future__ import annotations

import mmap
import struct
import zlib
from pathlib import Path

from ...core.exchange.views import ViewError

__all__ = ["McapRecords"]

_MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")


class McapRecords:
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
