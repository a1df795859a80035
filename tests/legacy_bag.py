"""ROS1 bags as 2010-era rosbag (and other writers) laid them out, made from a bag rosbags wrote.

A ROS1 bag (format 2.0, http://wiki.ros.org/Bags/Format/2.0, whose reading rules are those of
ros_comm's ``tools/rosbag/src/rosbag/bag.py``) is the line ``#ROSBAG V2.0`` and then records. A
record is a header (a 4-byte length, then fields ``<4-byte length>name=value``, ``op`` among them)
and its data (a 4-byte length, then the bytes)::

    file header (op 3)        index_pos, conn_count, chunk_count; data: padding to 4096 bytes
    chunk (op 5)              compression, size; data: connection (op 7) and message (op 2) records
    index data (op 4) ...     one per connection in the chunk: ver, conn, count; data: count x
                              (time sec, nsec, offset of the message in the uncompressed chunk)
    ... more chunks, each followed by its index data records ...
    connection (op 7) ...     at index_pos: every connection (conn, topic; data: type, md5sum,
                              message_definition, callerid, latching)
    chunk info (op 6) ...     ver, chunk_pos, start_time, end_time, count; data: count x (conn, msgs)

What a bag of that era differs in, and what this module can reproduce:

* ``index_data_length``: C Turtle's rosbag (before 1.1.15) wrote a wrong data length into every
  index data record. ROS's own reader ignores the field and reads ``count`` entries of 12 bytes
  (``read_connection_index_record``: "skip the record data size"); rosbags asserts it.
* ``field_order``: C++ rosbag keeps header fields in a ``std::map``, so they come sorted by name
  (``conn``, ``count``, ``op``, ``ver``), not in the order rosbags writes them.
* ``pad_index_headers``: a header may carry fields a reader does not know; a reader skips them.
* ``roslib_header``: message definitions named the header ``roslib/Header`` (it moved to
  ``std_msgs/Header`` later; genpy still maps the old name). The md5sums do not change: a message's
  md5sum hashes the md5sum of its header type, not the type's name.
* ``unindexed``: a recording that was never closed has ``index_pos`` 0 and no index at the end.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

OP_MSG, OP_FILE_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
MAGIC = b"#ROSBAG V2.0\n"


@dataclass
class Record:
    """One record: header fields in file order, and the data bytes."""

    fields: list[tuple[bytes, bytes]]
    data: bytes
    pos: int = -1  # where it was read from (-1: made here)
    data_length: int | None = None  # the data length field as written (None: len(data))

    @property
    def op(self) -> int:
        return self.get(b"op")[0]

    def get(self, name: bytes) -> bytes:
        for k, v in self.fields:
            if k == name:
                return v
        raise KeyError(name)

    def set(self, name: bytes, value: bytes) -> None:
        self.fields = [(k, value if k == name else v) for k, v in self.fields]

    def u32(self, name: bytes) -> int:
        return struct.unpack("<I", self.get(name))[0]

    def encode(self) -> bytes:
        head = b"".join(struct.pack("<I", len(k) + 1 + len(v)) + k + b"=" + v for k, v in self.fields)
        length = len(self.data) if self.data_length is None else self.data_length
        return struct.pack("<I", len(head)) + head + struct.pack("<I", length) + self.data


def header_fields(buf: bytes) -> list[tuple[bytes, bytes]]:
    out, i = [], 0
    while i < len(buf):
        (n,) = struct.unpack_from("<I", buf, i)
        name, _, value = buf[i + 4:i + 4 + n].partition(b"=")
        out.append((name, value))
        i += 4 + n
    return out


def read_record(buf: bytes, pos: int, index_entries: bool = True) -> tuple[Record, int]:
    """The record at ``pos`` and the position after it (index data: ``count`` entries, as ROS reads it)."""
    (hlen,) = struct.unpack_from("<I", buf, pos)
    fields = header_fields(buf[pos + 4:pos + 4 + hlen])
    (dlen,) = struct.unpack_from("<I", buf, pos + 4 + hlen)
    start = pos + 8 + hlen
    rec = Record(fields, b"", pos)
    if index_entries and rec.op == OP_INDEX:
        dlen = rec.u32(b"count") * 12
    rec.data = buf[start:start + dlen]
    return rec, start + dlen


def read_bag(path: Path) -> list[Record]:
    """Every top-level record of a bag, the file header first."""
    buf = Path(path).read_bytes()
    assert buf.startswith(MAGIC), path
    pos, out = len(MAGIC), []
    while pos < len(buf):
        rec, pos = read_record(buf, pos)
        out.append(rec)
    return out


def chunk_records(chunk: Record) -> list[Record]:
    """The connection and message records inside a chunk (decompressed)."""
    data = _decompress(chunk)
    pos, out = 0, []
    while pos < len(data):
        rec, pos = read_record(data, pos)
        out.append(rec)
    return out


def _decompress(chunk: Record) -> bytes:
    kind = chunk.get(b"compression")
    if kind == b"none":
        return chunk.data
    if kind == b"bz2":
        return bz2.decompress(chunk.data)
    if kind == b"lz4":
        import lz4.frame

        return lz4.frame.decompress(chunk.data)
    raise ValueError(kind)


def _compress(kind: bytes, data: bytes) -> bytes:
    if kind == b"none":
        return data
    if kind == b"bz2":
        return bz2.compress(data)
    import lz4.frame

    return lz4.frame.compress(data)


def roslib_definition(text: str) -> str:
    """A message definition as 2010-era ROS wrote it: ``Header header`` and ``MSG: roslib/Header``."""
    return text.replace("std_msgs/Header header", "Header header").replace("MSG: std_msgs/Header", "MSG: roslib/Header")


def _legacy_connection(rec: Record, definition: Callable[[str], str]) -> Record:
    """A connection record whose message definition is rewritten (its md5sum stays)."""
    fields = header_fields(rec.data)
    fields = [(k, definition(v.decode()).encode() if k == b"message_definition" else v) for k, v in fields]
    data = b"".join(struct.pack("<I", len(k) + 1 + len(v)) + k + b"=" + v for k, v in fields)
    return Record(rec.fields, data)


def _sorted(rec: Record) -> Record:
    return Record(sorted(rec.fields), rec.data, rec.pos, rec.data_length)


def write_bag(path: Path, records: list[Record], file_header_size: int = 4096) -> None:
    """Write records; chunk positions in chunk infos and index_pos in the file header follow them."""
    moved: dict[int, int] = {}
    out = bytearray(MAGIC)
    header = records[0]
    body = records[1:]
    out += b"\0" * file_header_size  # the file header, written last
    index_pos = 0
    for rec in body:
        if rec.op == OP_CHUNK:
            moved[rec.pos] = len(out)
        if rec.op == OP_CONNECTION and index_pos == 0:
            index_pos = len(out)
        if rec.op == OP_CHUNK_INFO:
            old = struct.unpack("<Q", rec.get(b"chunk_pos"))[0]
            rec = Record(rec.fields, rec.data, rec.pos, rec.data_length)
            rec.set(b"chunk_pos", struct.pack("<Q", moved.get(old, old)))
        out += rec.encode()
    hdr = Record(list(header.fields), b"")
    if struct.unpack("<Q", hdr.get(b"index_pos"))[0] != 0:
        hdr.set(b"index_pos", struct.pack("<Q", index_pos))
    hdr.set(b"conn_count", struct.pack("<I", sum(r.op == OP_CONNECTION for r in body)))
    hdr.set(b"chunk_count", struct.pack("<I", sum(r.op == OP_CHUNK_INFO for r in body)))
    head = hdr.encode()
    hdr.data = b" " * (file_header_size - len(head))
    out[len(MAGIC):len(MAGIC) + file_header_size] = hdr.encode()
    Path(path).write_bytes(bytes(out))


def make_legacy_bag(
    src: Path,
    dst: Path,
    *,
    index_data_length: Callable[[int], int] | None = lambda count: count * 12 + 4,
    field_order: str = "sorted",
    pad_index_headers: bool = False,
    roslib_header: bool = True,
    unindexed: bool = False,
) -> Path:
    """Rewrite the ROS1 bag ``src`` (as rosbags writes it) into ``dst`` the way an old writer laid it out.

    ``index_data_length(count)``: the data length written into each index data record (None: the
    right one, ``count * 12``). ``field_order``: ``"sorted"`` (C++ rosbag's std::map order) or
    ``"as is"``. ``pad_index_headers``: add an unknown ``pad`` field to every index data header.
    ``roslib_header``: message definitions name ``roslib/Header``. ``unindexed``: index_pos 0 and no
    connection or chunk info records at the end (what a recording that was never closed leaves).
    """
    records = read_bag(src)
    out: list[Record] = [records[0]]
    offsets: dict[int, dict[int, int]] = {}  # chunk pos -> old message offset -> new offset
    definition = roslib_definition if roslib_header else (lambda text: text)
    for rec in records[1:]:
        if rec.op == OP_CHUNK:
            inner, new, moved = chunk_records(rec), bytearray(), {}
            old_at = 0
            for r in inner:
                size = len(r.encode())
                if r.op == OP_CONNECTION:
                    r = _legacy_connection(r, definition)
                moved[old_at] = len(new)
                old_at += size
                new += (_sorted(r) if field_order == "sorted" else r).encode()
            offsets[rec.pos] = moved
            chunk = Record(list(rec.fields), _compress(rec.get(b"compression"), bytes(new)), rec.pos)
            chunk.set(b"size", struct.pack("<I", len(new)))
            out.append(_sorted(chunk) if field_order == "sorted" else chunk)
            current = rec.pos
        elif rec.op == OP_INDEX:
            entries = bytearray(rec.data)
            for i in range(0, len(entries), 12):
                (off,) = struct.unpack_from("<I", entries, i + 8)
                struct.pack_into("<I", entries, i + 8, offsets[current][off])
            idx = Record(list(rec.fields), bytes(entries), rec.pos)
            if pad_index_headers:
                idx.fields.append((b"pad", b"    "))
            if index_data_length is not None:
                idx.data_length = index_data_length(rec.u32(b"count"))
            out.append(_sorted(idx) if field_order == "sorted" else idx)
        elif rec.op == OP_CONNECTION:
            if not unindexed:
                conn = _legacy_connection(rec, definition)
                out.append(_sorted(conn) if field_order == "sorted" else conn)
        elif rec.op == OP_CHUNK_INFO:
            if not unindexed:
                out.append(_sorted(rec) if field_order == "sorted" else rec)
        else:
            out.append(rec)
    if unindexed:
        out[0] = Record(list(out[0].fields), b"")
        out[0].set(b"index_pos", struct.pack("<Q", 0))
    if field_order == "sorted":
        out[0] = _sorted(out[0])
    write_bag(dst, out)
    return dst
