"""The record layout of ROS1 bags (format 2.0), as ROS's own reader reads it.

A ROS1 bag is the line ``#ROSBAG V2.0`` and then records: a header (a 4-byte length, then fields
``<4-byte length>name=value``, ``op`` among them) and data (a 4-byte length, then the bytes). The
file header (op 3) gives ``index_pos``; chunks (op 5) hold connection (op 7) and message (op 2)
records, and each is followed by one index data record (op 4) per connection in it; at
``index_pos`` come the connection records and one chunk info record (op 6) per chunk. The reading
rules are those of ROS's own reader (ros_comm tools/rosbag/src/rosbag/bag.py).

Shared by the repairs of :mod:`semmap.io.bag` and the fast reader of :mod:`semmap.io.fastbag`;
nothing here imports rosbags.
"""

from __future__ import annotations

import re
import struct
from typing import Any

__all__ = [
    "MAGIC",
    "OP_CHUNK",
    "OP_CHUNK_INFO",
    "OP_CONNECTION",
    "OP_FILE_HEADER",
    "OP_INDEX",
    "OP_MSG",
    "TIME",
    "U32",
    "U64",
    "Damaged",
    "Truncated",
    "field_int",
    "file_header",
    "header_fields",
    "record_at",
    "record_op",
]

MAGIC = b"#ROSBAG V2.0\n"
#: record ops
OP_MSG, OP_FILE_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
U32, U64, TIME = struct.Struct("<I"), struct.Struct("<Q"), struct.Struct("<II")


class Damaged(Exception):
    """What is wrong with a ROS1 bag, and where (becomes a :class:`BagError` naming the file)."""


class Truncated(Damaged):
    """The file ends inside a record."""


def header_fields(buf: Any, start: int, end: int, what: str) -> dict[str, bytes]:
    """The ``name=value`` fields of a record header (a repeated name: the last, as ROS reads it); unknown
    fields are kept, and ignored."""
    out: dict[str, bytes] = {}
    pos = start
    while pos < end:
        if pos + 4 > end:
            raise Damaged(f"{what} has a malformed header")
        (size,) = U32.unpack_from(buf, pos)
        pos += 4
        if pos + size > end:
            raise Damaged(f"{what} has a header field longer than its header")
        name, sep, value = bytes(buf[pos:pos + size]).partition(b"=")
        if not sep:
            raise Damaged(f"{what} has a header field without '='")
        out[name.decode("latin-1")] = value
        pos += size
    return out


def record_at(buf: Any, pos: int, end: int, what: str,
              cut: type[Damaged] = Damaged) -> tuple[dict[str, bytes], int, int]:
    """Header fields, data start and data length (as written) of the record at ``pos`` (before ``end``)."""
    if pos + 4 > end:
        raise cut(f"{what} is cut off (at byte {end})")
    (hlen,) = U32.unpack_from(buf, pos)
    if pos + 8 + hlen > end:
        raise cut(f"{what} has a {hlen}-byte header, but the data ends at byte {end}")
    fields = header_fields(buf, pos + 4, pos + 4 + hlen, what)
    (dlen,) = U32.unpack_from(buf, pos + 4 + hlen)
    return fields, pos + 8 + hlen, dlen


def field_int(fields: dict[str, bytes], name: str, codec: struct.Struct, what: str) -> int:
    value = fields.get(name)
    if value is None or len(value) != codec.size:
        raise Damaged(f"{what} has no valid {name!r} field")
    parts = codec.unpack(value)
    return parts[0] if len(parts) == 1 else parts[0] * 1_000_000_000 + parts[1]


def record_op(fields: dict[str, bytes], what: str) -> int:
    value = fields.get("op")
    if value is None or len(value) != 1:
        raise Damaged(f"{what} has no valid 'op' field")
    return value[0]


def file_header(buf: Any, size: int) -> tuple[int, int, int, int]:
    """(index_pos, conn_count, chunk_count, position of the first record after the file header)."""
    if bytes(buf[:len(MAGIC)]) != MAGIC:
        version = re.match(rb"#ROSBAG V(\d+\.\d+)\n", bytes(buf[:32]))
        if version:
            raise Damaged(f"bag format {version.group(1).decode()} is not supported (only 2.0)")
        raise Damaged("not a ROS1 bag (it does not start with '#ROSBAG V2.0')")
    what = "the file header"
    fields, start, dlen = record_at(buf, len(MAGIC), size, what, Truncated)
    if record_op(fields, what) != OP_FILE_HEADER:
        raise Damaged(f"{what} is not a file header record")
    if fields.get("encryptor"):
        raise Damaged(f"the bag is encrypted ({fields['encryptor'].decode('latin-1')}), which semmap cannot read")
    return (field_int(fields, "index_pos", U64, what), field_int(fields, "conn_count", U32, what),
            field_int(fields, "chunk_count", U32, what), start + dlen)
