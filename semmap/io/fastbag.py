"""semmap's own reader of healthy bags' records: bounded memory on long bags.

rosbags' ROS1 ``Reader.open`` reads every index data record of the bag into one Python ``IndexData`` per
message, of every topic, and keeps them while it is open: about 180 bytes per bag message (58 MB for a
30-minute tour of 324,000 messages), in every reader a build holds open. A bag whose index is as ROS and
rosbags write it is read here instead from a table of a few numbers per chunk (:class:`Ros1Table`,
made once per bag and process): each chunk's index data records are read again when the stream reaches
the chunk, and only for the connections asked for (:class:`Ros1Reader`, which stands in for rosbags'
reader inside its ``AnyReader``). And where the wanted messages are a small part of uncompressed chunks
(a scan stored beside camera images), each is read on its own, as a view of the mapped file
(:func:`ros1_records`, :func:`mcap_records`).

This reads rosbags' internals (its ROS1 connection reader and record helpers, its parsed ROS1 index, its
MCAP reader's chunk and message indexes), so it is used only with the rosbags versions it was tested
with (:data:`TESTED_ROSBAGS`). Anything it does not understand (a bag not laid out as ROS writes it, a
damaged one, a rosbags that lays out its internals differently) leaves the bag to rosbags' own reader
and the repairs around it in :mod:`semmap.io.bag`, with a log line; anything else it raises (a bug in
semmap, say a ``TypeError``) is raised, never taken for a bag it cannot read.
"""

from __future__ import annotations

import array
import functools
import heapq
import importlib.metadata
import io
import logging
import mmap
import os
import re
import struct
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from .ros1format import (
    MAGIC,
    OP_CHUNK,
    OP_CHUNK_INFO,
    OP_CONNECTION,
    OP_INDEX,
    OP_MSG,
    TIME,
    U32,
    U64,
    Damaged,
    field_int,
    file_header,
    header_fields,
    record_at,
)

__all__ = [
    "TESTED_ROSBAGS",
    "Ros1Reader",
    "Ros1Table",
    "mcap_records",
    "not_understood",
    "reads",
    "ros1_records",
    "ros1_table",
    "usable",
]

log = logging.getLogger(__name__)

#: the rosbags versions this was tested with: from the first, up to (not including) the second
TESTED_ROSBAGS: tuple[tuple[int, ...], tuple[int, ...]] = ((0, 10, 4), (0, 12))


def _version(text: str) -> tuple[int, ...] | None:
    m = re.match(r"(\d+)\.(\d+)(?:\.(\d+))?", text)
    return None if m is None else tuple(int(g) for g in m.groups() if g is not None)


def _rosbags_version() -> str:
    try:
        return importlib.metadata.version("rosbags")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


@functools.cache
def usable() -> bool:
    """Whether the installed rosbags is one this was tested with (:data:`TESTED_ROSBAGS`); when it is not,
    one log line says so and every bag is read through rosbags' own reader."""
    have = _rosbags_version()
    v = _version(have)
    lo, hi = TESTED_ROSBAGS
    if v is not None and lo <= v < hi:
        return True
    log.warning("rosbags %s is not a version semmap's own bag reader was tested with (%s to before %s): bags "
                "are read through rosbags' reader, which holds about 180 bytes per message of a ROS1 bag and "
                "reads whole chunks", have, ".".join(map(str, lo)), ".".join(map(str, hi)))
    return False


@functools.cache
def not_understood() -> tuple[type[BaseException], ...]:
    """What reading a bag's records here raises on a bag it does not understand: damaged, or laid out
    unlike what it reads (rosbags' reader errors, as its own reader raises them; a cut or malformed
    record; a chunk that does not decompress). A ``TypeError``, ``AttributeError`` or ``NameError`` is
    not among them: from here, that is a bug in semmap."""
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    return (_NotPlain, Ros1Error, Ros2Error, struct.error, AssertionError, ValueError, KeyError, OSError, EOFError,
            RuntimeError, MemoryError, OverflowError)


_warned: set[str] = set()


def _falls_back(key: str, text: str, *args: object) -> None:
    """Log, once per process and kind, that a rosbags laid out unlike what this reads leaves bags to it."""
    if key not in _warned:
        _warned.add(key)
        log.warning(text, *args)


def _from_rosbags(what: str, call: Callable[..., Any], *args: Any) -> Any:
    """A call into rosbags' internals; that they are not what this expects is :class:`_NotPlain`."""
    try:
        return call(*args)
    except (AttributeError, KeyError, TypeError) as exc:
        raise _NotPlain(f"rosbags {_rosbags_version()}'s {what} is not what semmap reads ({exc!r})") from None


#: an index data record's first bytes: header length, header (op, ver, conn, count) and data length
_INDEX_HEAD = 4 + 47 + 4
_CHUNK_COMPRESSIONS = ("none", "bz2", "lz4")
#: tables of the last few healthy ROS1 bags, by path and file identity (commands that open a bag again reuse them)
_TABLES: dict[tuple[str, int, int, int, int], Ros1Table] = {}
_TABLES_KEEP = 4


class _NotPlain(Exception):
    """A ROS1 bag's index is not as ROS and rosbags write it: rosbags' own reader takes the bag."""


@dataclass
class Ros1Table:
    """What reading a healthy ROS1 bag needs: its connections, and per chunk (in chunk info order) where
    its data and index data are, its compression, its messages' time span and (connection, count) pairs.
    About 100 bytes per chunk (a chunk holds about 100 messages in semmap's tours); nothing per message."""

    connections: list[Any]  # rosbags' Connections as read from the index, msgcount set, no owner yet
    counts: dict[int, int]  # connection id -> messages
    start_time: int  # as rosbags gives them: the chunk infos' earliest start, latest end + 1 ns
    end_time: int
    data_pos: NDArray[np.int64]  # where the chunk's data starts in the file
    data_size: NDArray[np.int64]  # its length in the file (its index data records follow it)
    compression: NDArray[np.uint8]  # index into _CHUNK_COMPRESSIONS
    t_min: NDArray[np.int64]  # its earliest and latest message (bag time, from its index data)
    t_max: NDArray[np.int64]
    pair_start: NDArray[np.int64]  # chunk c's pairs are [pair_start[c], pair_start[c + 1])
    pair_conn: NDArray[np.uint32]
    pair_count: NDArray[np.uint32]
    conn_at: int  # where the conn and count values are in an index data record's first _INDEX_HEAD bytes
    count_at: int

    def index_bytes(self, c: int) -> int:
        """The length of chunk ``c``'s index data records."""
        p0, p1 = int(self.pair_start[c]), int(self.pair_start[c + 1])
        return _INDEX_HEAD * (p1 - p0) + 12 * int(self.pair_count[p0:p1].sum())


def _plain_fields(buf: bytes, start: int, end: int, names: set[str], what: str) -> dict[str, bytes]:
    """A record header's fields, which must be exactly ``names`` (else :class:`_NotPlain`)."""
    try:
        fields = header_fields(buf, start, end, what)
    except Damaged as exc:
        raise _NotPlain(str(exc)) from None
    if set(fields) != names:
        raise _NotPlain(f"{what} has fields {sorted(fields)}")
    return fields


def _plain_int(fields: dict[str, bytes], name: str, codec: struct.Struct, what: str) -> int:
    try:
        return field_int(fields, name, codec, what)
    except Damaged as exc:
        raise _NotPlain(str(exc)) from None


class _PRead:
    """Reads ranges of a file with ``pread`` (nothing mapped, so nothing stays resident); ``ahead``: read
    up to that many bytes beyond, for the small records read one after the other."""

    def __init__(self, fd: int, size: int) -> None:
        self.fd, self.size = fd, size
        self.buf, self.at = b"", 0

    def __call__(self, pos: int, n: int, ahead: int = 0) -> bytes:
        if pos < 0 or n < 0 or pos + n > self.size:
            raise _NotPlain(f"{n} bytes at byte {pos} are past the end of the file ({self.size} bytes)")
        if self.at <= pos and pos + n <= self.at + len(self.buf):
            return self.buf[pos - self.at:pos - self.at + n]
        data = os.pread(self.fd, min(n + ahead, self.size - pos), pos)
        if len(data) < n:
            raise _NotPlain(f"the file ended while reading byte {pos}")
        self.buf, self.at = data, pos
        return data[:n]


def _scan_ros1(fd: int, size: int) -> Ros1Table:
    """The table of a ROS1 bag whose index is as ROS and rosbags write it; :class:`_NotPlain` otherwise.

    Everything rosbags' ``Reader.open`` checks is checked, more strictly (the exact header fields, every
    index data record against the chunk info of its chunk, every message's offset inside its chunk), so
    that a bag read through the table gives what rosbags would give, and a bag that is not read through
    it is left to rosbags' own reader and the repairs around it, as before.
    """
    try:
        from rosbags.rosbag1.reader import Reader as Reader1
    except ImportError as exc:
        raise _NotPlain(f"rosbags {_rosbags_version()} has no ROS1 Reader where semmap reads it ({exc!r})") from None

    read = _PRead(fd, size)
    head = read(0, min(size, 8192))
    try:
        index_pos, conn_count, chunk_count, _ = file_header(head, len(head))
        fields = record_at(head, len(MAGIC), len(head), "the file header")[0]
    except Damaged as exc:
        raise _NotPlain(str(exc)) from None
    if not set(fields) <= {"op", "index_pos", "conn_count", "chunk_count", "encryptor"}:
        raise _NotPlain(f"the file header has fields {sorted(fields)}")
    if index_pos == 0 or chunk_count == 0 or conn_count == 0 or index_pos >= size:
        raise _NotPlain("not indexed, or no chunks")

    def record(pos: int) -> tuple[int, int, int]:
        """(header length, data length, end) of the index record at ``pos``."""
        (hlen,) = U32.unpack(read(pos, 4, 1 << 20))
        (dlen,) = U32.unpack(read(pos + 4 + hlen, 4, 1 << 20))
        return hlen, dlen, pos + 8 + hlen + dlen

    # the connection records, read by rosbags itself (topic and type names normalised as it does)
    pos = index_pos
    connections = []
    for _ in range(conn_count):
        hlen, dlen, end = record(pos)
        holder = SimpleNamespace(bio=io.BytesIO(read(pos, end - pos)))
        conn = _from_rosbags("Reader.read_connection", Reader1.read_connection, holder)
        if holder.bio.tell() != end - pos:
            raise _NotPlain(f"the connection record at byte {pos} is not what its lengths say")
        connections.append(conn)
        pos = end
    ids = [c.id for c in connections]
    if len(set(ids)) != len(ids):
        raise _NotPlain("two connection records share an id")
    known = set(ids)

    # the chunk infos
    info_names = {"op", "ver", "chunk_pos", "start_time", "end_time", "count"}
    chunk_pos: list[int] = []
    starts: list[int] = []
    ends: list[int] = []
    pair_conn, pair_count = array.array("I"), array.array("I")  # 4 bytes each, not a Python int
    pair_start = array.array("q", [0])
    for _ in range(chunk_count):
        hlen, dlen, end = record(pos)
        what = f"the chunk info record at byte {pos}"
        rec = read(pos, end - pos)
        fields = _plain_fields(rec, 4, 4 + hlen, info_names, what)
        if fields["op"] != bytes([OP_CHUNK_INFO]) or _plain_int(fields, "ver", U32, what) != 1:
            raise _NotPlain(f"{what} is not a chunk info record of version 1")
        count = _plain_int(fields, "count", U32, what)
        if count == 0 or dlen != 8 * count:
            raise _NotPlain(f"{what} counts {count} connections in {dlen} bytes")
        pairs = struct.unpack_from(f"<{2 * count}I", rec, 8 + hlen)
        conns, counts = pairs[0::2], pairs[1::2]
        if len(set(conns)) != count or not known.issuperset(conns) or min(counts) == 0:
            raise _NotPlain(f"{what} counts connections twice, unknown ones or none of their messages")
        chunk_pos.append(_plain_int(fields, "chunk_pos", U64, what))
        starts.append(_plain_int(fields, "start_time", TIME, what))
        ends.append(_plain_int(fields, "end_time", TIME, what))
        pair_conn.extend(conns)
        pair_count.extend(counts)
        pair_start.append(len(pair_conn))
        pos = end
    if len(set(chunk_pos)) != len(chunk_pos):
        raise _NotPlain("two chunk infos name the same chunk")

    # each chunk's header, and its index data records checked against its chunk info
    n = len(chunk_pos)
    data_pos = np.zeros(n, np.int64)
    data_size = np.zeros(n, np.int64)
    compression = np.zeros(n, np.uint8)
    t_min = np.zeros(n, np.int64)
    t_max = np.zeros(n, np.int64)
    layout: tuple[bytes, bytes, bytes] | None = None  # a record's first bytes, but for its conn and count
    conn_at = count_at = lo = hi = 0
    chunk_names = {"op", "compression", "size"}
    for c, at in enumerate(chunk_pos):
        what = f"the chunk at byte {at}"
        (hlen,) = U32.unpack(read(at, 4, 508))
        hdr = read(at, 8 + hlen)
        fields = _plain_fields(hdr, 4, 4 + hlen, chunk_names, what)
        kind = fields["compression"].decode("latin-1")
        if fields["op"] != bytes([OP_CHUNK]) or kind not in _CHUNK_COMPRESSIONS:
            raise _NotPlain(f"{what} is not a chunk, or compressed with {kind!r}")
        unpacked = _plain_int(fields, "size", U32, what)
        (dsize,) = U32.unpack_from(hdr, 4 + hlen)
        if kind == "none" and unpacked != dsize:
            raise _NotPlain(f"{what} is uncompressed, but its size says {unpacked} bytes and its data {dsize}")
        p0, p1 = pair_start[c], pair_start[c + 1]
        expected = dict(zip(pair_conn[p0:p1], pair_count[p0:p1]))
        region = read(at + 8 + hlen + dsize, _INDEX_HEAD * (p1 - p0) + 12 * sum(pair_count[p0:p1]))
        off = 0
        rows = []
        for _ in range(p1 - p0):
            head = region[off:off + _INDEX_HEAD]
            if layout is None:  # the first index data record: its layout is every other's
                what = f"the index data record after {what}"
                fields = _plain_fields(head, 4, _INDEX_HEAD - 4, {"op", "ver", "conn", "count"}, what)
                if U32.unpack_from(head)[0] != 47 or fields["op"] != bytes([OP_INDEX]) or \
                        _plain_int(fields, "ver", U32, what) != 1 or len(fields["conn"]) != 4 or \
                        len(fields["count"]) != 4:
                    raise _NotPlain(f"{what} is not laid out as ROS writes it")
                conn_at = head.index(b"conn=") + 5
                count_at = head.index(b"count=") + 6
                lo, hi = sorted((conn_at, count_at))
                layout = (head[:lo], head[lo + 4:hi], head[hi + 4:_INDEX_HEAD - 4])
            if (head[:lo], head[lo + 4:hi], head[hi + 4:_INDEX_HEAD - 4]) != layout:
                raise _NotPlain(f"an index data record after the chunk at byte {at} is laid out differently")
            (conn,) = U32.unpack_from(head, conn_at)
            (count,) = U32.unpack_from(head, count_at)
            (dlen,) = U32.unpack_from(head, _INDEX_HEAD - 4)
            if expected.pop(conn, None) != count or dlen != 12 * count:
                raise _NotPlain(f"an index data record after the chunk at byte {at} does not match its chunk info")
            rows.append(np.frombuffer(region, dtype="<u4", count=3 * count, offset=off + _INDEX_HEAD))
            off += _INDEX_HEAD + 12 * count
        entries = (np.concatenate(rows) if len(rows) > 1 else rows[0]).reshape(-1, 3)
        if int(entries[:, 2].max()) >= unpacked:
            raise _NotPlain(f"the index of the chunk at byte {at} points past its data")
        times = entries[:, 0].astype(np.int64) * 1_000_000_000 + entries[:, 1]
        data_pos[c], data_size[c] = at + 8 + hlen, dsize
        compression[c] = _CHUNK_COMPRESSIONS.index(kind)
        t_min[c], t_max[c] = times.min(), times.max()
    conn_all = np.frombuffer(pair_conn, dtype=np.uint32).copy()
    count_all = np.frombuffer(pair_count, dtype=np.uint32).copy()
    totals = dict.fromkeys(ids, 0)
    for cid, cnt in zip(pair_conn, pair_count):
        totals[cid] += cnt
    return Ros1Table(
        connections=[_from_rosbags("Connection", lambda c: c._replace(msgcount=totals[c.id], owner=None), c)
                     for c in connections],
        counts=totals,
        start_time=min(starts),
        end_time=max(ends) + 1,
        data_pos=data_pos, data_size=data_size, compression=compression, t_min=t_min, t_max=t_max,
        pair_start=np.frombuffer(pair_start, dtype=np.int64).copy(),
        pair_conn=conn_all, pair_count=count_all, conn_at=conn_at, count_at=count_at,
    )


def ros1_table(p: Path) -> Ros1Table | None:
    """The table of the ROS1 bag ``p`` (:func:`_scan_ros1`), or None when rosbags' own reader is to read
    it (a bag not as ROS writes it, or a rosbags this was not tested with). The last few are kept."""
    if not usable():
        return None
    try:
        st = p.stat()
        key = (str(p.resolve()), st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
    except OSError:
        return None
    table = _TABLES.pop(key, None)
    if table is None:
        try:
            fd = os.open(p, os.O_RDONLY)
        except OSError:
            return None
        try:
            table = _scan_ros1(fd, st.st_size)
        except not_understood() as exc:  # unusual (or damaged): rosbags' path decides; a bug in semmap is raised
            log.info("%s: read through rosbags' reader, not a table of its chunks (%s)", p, exc)
            return None
        finally:
            os.close(fd)
        while len(_TABLES) >= _TABLES_KEEP:
            del _TABLES[next(iter(_TABLES))]
    _TABLES[key] = table
    return table


def _header_fields(buf: Any, start: int, end: int) -> dict[str, bytes]:
    """A record header's fields, read as rosbags reads them (its errors: :class:`ReaderError`, and
    UnicodeDecodeError for a name that is not UTF-8)."""
    from rosbags.rosbag1 import ReaderError

    head = bytes(buf[start:end])
    out: dict[str, bytes] = {}
    pos, length = 0, len(head)
    while pos < length:
        if pos + 4 > length:
            raise ReaderError("Header field size could not be read.")
        (size,) = U32.unpack_from(head, pos)
        pos += 4
        if pos + size > length:
            raise ReaderError("Declared field size is too large for header.")
        name, sep, value = head[pos:pos + size].partition(b"=")
        if not sep:
            raise ReaderError("Header field could not be parsed.")
        out[name.decode()] = value
        pos += size
    return out


def _message_at(buf: Any, pos: int, end: int) -> tuple[int, int, int, int]:
    """(connection, bag time, data start, data length) of the message record at ``pos`` in a chunk's data
    (``buf`` up to ``end``), past any connection records before it; errors as rosbags raises them."""
    from rosbags.rosbag1 import ReaderError

    while True:
        if pos + 4 > end:
            raise ReaderError("Header could not be read from file.")
        (hlen,) = U32.unpack_from(buf, pos)
        start = pos + 4
        if start + hlen > end:
            raise ReaderError("Header could not be read from file.")
        fields = _header_fields(buf, start, start + hlen)
        op = fields.get("op")
        if op is None or len(op) != 1:
            raise ReaderError("Could not read uint8 field 'op'.")
        data = start + hlen + 4
        if op[0] != OP_CONNECTION:
            break
        if data > end:
            raise ReaderError("Could not read uint32.")
        pos = data + U32.unpack_from(buf, start + hlen)[0]
    if op[0] != OP_MSG:
        raise ReaderError("Expected to find message data.")
    if data > end:
        raise ReaderError("Could not read uint32.")
    (dlen,) = U32.unpack_from(buf, start + hlen)
    if data + dlen > end:
        raise ReaderError(f"Got only {max(end - data, 0)} of requested {dlen} bytes.")
    conn, stamp = fields.get("conn"), fields.get("time")
    if conn is None or len(conn) < 4:
        raise ReaderError("Could not read uint32 field 'conn'.")
    if stamp is None or len(stamp) != 8:
        raise ReaderError("Could not read time field 'time'.")
    sec, nsec = TIME.unpack(stamp)
    return U32.unpack_from(conn)[0], sec * 1_000_000_000 + nsec, data, dlen


class Ros1Reader:
    """rosbags' ROS1 ``Reader`` for a healthy bag, without its per-message index.

    It stands in for rosbags' reader inside ``AnyReader`` (which asks it for its connections, opens and
    closes it, and reads messages through it), with the same connections, counts, times and messages in
    the same order. The bag is mapped into memory where it can be. Messages are read chunk by chunk in
    time order: a chunk's index data records are read when the stream reaches it (the chunks whose time
    spans overlap are merged), so a stream holds the entries of a chunk or two, whatever the length of
    the bag; a compressed chunk is decompressed once, when it is reached, and dropped when its last
    wanted message is read; mapped pages read past are handed back every ``_RELEASE_BYTES``.
    """

    def __init__(self, path: Path, table: Ros1Table) -> None:
        self.path = path
        self.table = table
        self.bio: Any = None
        self.connections: list[Any] = []
        self._map: Any = None
        self._view: memoryview | None = None

    # -- what AnyReader and rosbags' users ask of a reader -----------------------------------------------
    def _check_open(self) -> None:
        if not self.bio:
            from rosbags.rosbag1 import ReaderError

            raise ReaderError("Reader is not open.")

    def open(self) -> None:
        from rosbags.rosbag1 import ReaderError

        if self.bio is not None:
            raise ReaderError("Reader is already open.")
        try:
            self.bio = self.path.open("rb")
        except PermissionError:
            raise
        except OSError as err:
            raise ReaderError(f"Could not open file {str(self.path)!r}: {err.strerror}.") from err
        try:
            self._map = mmap.mmap(self.bio.fileno(), 0, access=mmap.ACCESS_READ)
            self._view = memoryview(self._map)
        except (OSError, ValueError):
            self._map = self._view = None
        self.connections = [c._replace(owner=self) for c in self.table.connections]

    def close(self) -> None:
        self._check_open()
        bio, self.bio = self.bio, None
        self.connections = []
        self._map = self._view = None  # unmapped once no message read from it is in use
        bio.close()

    def __enter__(self) -> Ros1Reader:
        self.open()
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        self.close()
        return False

    @property
    def start_time(self) -> int:
        self._check_open()
        return self.table.start_time

    @property
    def end_time(self) -> int:
        self._check_open()
        return self.table.end_time

    @property
    def duration(self) -> int:
        return max(self.end_time - self.start_time, 0)

    @property
    def message_count(self) -> int:
        self._check_open()
        return sum(self.table.counts.get(c.id, 0) for c in self.connections)

    @property
    def topics(self) -> dict[str, Any]:
        from rosbags.interfaces import MessageDefinition, MessageDefinitionFormat, TopicInfo

        self._check_open()
        groups: dict[str, list[Any]] = {}
        for conn in sorted(self.connections, key=lambda x: x.topic):
            groups.setdefault(conn.topic, []).append(conn)
        out = {}
        for topic, conns in groups.items():
            types, defs = {x.msgtype for x in conns}, {x.msgdef for x in conns}
            out[topic] = TopicInfo(
                types.pop() if len(types) == 1 else None,
                defs.pop() if len(defs) == 1 else MessageDefinition(MessageDefinitionFormat.NONE, ""),
                sum(self.table.counts.get(x.id, 0) for x in conns),
                conns,
            )
        return out

    def messages(self, connections: Sequence[Any] = (), start: int | None = None,
                 stop: int | None = None) -> Iterator[tuple[Any, int, bytes]]:
        """``(connection, bag time, bytes)`` as rosbags' reader yields them: in time order, the order of
        ``connections`` among messages of the same time (all connections when empty)."""
        self._check_open()
        yield from self.records(connections or self.connections, start, stop, views=False)  # type: ignore[misc]

    # -- semmap's own use ---------------------------------------------------------------------------------
    def sparse(self, conns: Sequence[Any]) -> bool:
        """Whether ``conns``' messages are worth reading record by record as views of the mapped file: an
        uncompressed bag, mapped, whose chunks holding them are mostly other bytes (``_SPARSE_MIN_BYTES``)."""
        t = self.table
        if self._map is None or t.compression.any():
            return False
        ids = np.array(sorted({c.id for c in conns}), dtype=np.int64)
        hit = np.isin(t.pair_conn, ids)
        wanted = int(t.pair_count[hit].sum())
        chunk_bytes = int(t.data_size[np.logical_or.reduceat(hit, t.pair_start[:-1])].sum())
        return chunk_bytes >= _SPARSE_MIN_BYTES * wanted

    def _read(self, pos: int, n: int) -> bytes:
        from rosbags.rosbag1 import ReaderError

        data = self._map[pos:pos + n] if self._map is not None else os.pread(self.bio.fileno(), n, pos)
        if len(data) != n:
            raise ReaderError(f"Got only {len(data)} of requested {n} bytes.")
        return data

    def _entries(self, c: int, ranks: dict[int, list[int]], start: int | None) -> list[tuple[int, int, int, int, int]]:
        """The wanted messages of chunk ``c`` as ``(time, rank, chunk, position in its index, offset)``,
        sorted: rosbags' order (time, then the connection's place among those asked for, then chunk info
        order, then index order)."""
        from rosbags.rosbag1 import ReaderError

        t = self.table
        p0, p1 = int(t.pair_start[c]), int(t.pair_start[c + 1])
        region = self._read(int(t.data_pos[c] + t.data_size[c]), t.index_bytes(c))
        expected = dict(zip(t.pair_conn[p0:p1].tolist(), t.pair_count[p0:p1].tolist()))
        items: list[tuple[int, int, int, int, int]] = []
        off = 0
        for _ in range(p1 - p0):
            (conn,) = U32.unpack_from(region, off + t.conn_at)
            (count,) = U32.unpack_from(region, off + t.count_at)
            if expected.pop(conn, None) != count:
                raise ReaderError(f"the index data of the chunk at byte {int(t.data_pos[c])} changed while it was read")
            rs = ranks.get(conn)
            if rs:
                rows = np.frombuffer(region, dtype="<u4", count=3 * count, offset=off + _INDEX_HEAD).reshape(-1, 3)
                times = (rows[:, 0].astype(np.int64) * 1_000_000_000 + rows[:, 1]).tolist()
                offsets = rows[:, 2].tolist()
                for r in rs:
                    items.extend(zip(times, [r] * count, [c] * count, range(count), offsets))
            off += _INDEX_HEAD + 12 * count
        if start is not None:
            items = [x for x in items if x[0] >= start]
        items.sort()
        return items

    def _chunk(self, c: int, mapped: Any) -> tuple[Any, int, int]:
        """(buffer, start, end) of chunk ``c``'s records: the mapped file where it is uncompressed, else its
        bytes, decompressed as rosbags decompresses them."""
        from rosbags.rosbag1.reader import decompressors

        t = self.table
        pos, size = int(t.data_pos[c]), int(t.data_size[c])
        kind = _CHUNK_COMPRESSIONS[int(t.compression[c])]
        if kind == "none" and mapped is not None:
            return mapped, pos, pos + size
        data = decompressors[kind](self._read(pos, size))
        return data, 0, len(data)

    def records(self, connections: Sequence[Any], start: int | None = None, stop: int | None = None,
                views: bool = True) -> Iterator[tuple[Any, int, bytes | memoryview]]:
        """The messages of ``connections`` in rosbags' order; each message's bytes a read-only view of the
        mapped file where it is uncompressed and ``views`` is set, else a copy (as rosbags gives them)."""
        t = self.table
        mapped, view = self._map, self._view  # (kept while the stream lasts, even past close())
        ranks: dict[int, list[int]] = {}
        for i, conn in enumerate(connections):
            ranks.setdefault(conn.id, []).append(i)
        connmap = {x.id: x for x in self.connections}
        hit = np.isin(t.pair_conn, np.array(sorted(ranks), dtype=np.int64))
        cand = np.flatnonzero(np.logical_or.reduceat(hit, t.pair_start[:-1]))
        if start is not None:
            cand = cand[t.t_max[cand] >= start]
        if stop is not None:
            cand = cand[t.t_min[cand] < stop]
        cand = cand[np.argsort(t.t_min[cand], kind="stable")]  # by earliest message, then chunk info order
        firsts = t.t_min[cand]
        heap: list[tuple[int, int, int, int, int]] = []
        live: dict[int, list[Any]] = {}  # chunk -> [buffer, start, end, messages still to read]
        released = 0  # mapped pages below this were handed back
        k = 0
        while True:
            # every chunk that may hold a message as early as the next one is loaded before that is read
            while k < len(cand) and (not heap or int(firsts[k]) <= heap[0][0]):
                c = int(cand[k])
                k += 1
                items = self._entries(c, ranks, start)
                if not items:
                    continue
                live[c] = [None, 0, 0, len(items)]  # its data: read when its first message is
                if heap:
                    for item in items:
                        heapq.heappush(heap, item)
                else:
                    heap = items  # a sorted list is a heap
            if not heap:
                return
            stamp, _, c, _, offset = heapq.heappop(heap)
            if stop is not None and stamp >= stop:
                return
            slot = live[c]
            if slot[0] is None:
                slot[:3] = self._chunk(c, mapped)
            buf, base, end = slot[0], slot[1], slot[2]
            conn, when, data, dlen = _message_at(buf, base + offset, end)
            if buf is mapped:
                raw: bytes | memoryview = view[data:data + dlen] if views else buf[data:data + dlen]  # type: ignore[index]
            else:
                raw = buf[data:data + dlen]
            connection = connmap[conn]
            if when != stamp:
                raise AssertionError  # as rosbags' reader asserts it (a bare assert)
            slot[3] -= 1
            if not slot[3]:
                del live[c]
                if mapped is not None and hasattr(mapped, "madvise"):
                    # what no chunk still being read needs, less a trailing window: the message about to be
                    # yielded, and those just before it (a consumer may still hold them), stay mapped
                    floor = min((int(t.data_pos[x]) for x in live), default=int(t.data_pos[c] + t.data_size[c]))
                    floor = min(floor, data) if buf is mapped else floor
                    floor -= _RELEASE_BYTES // 4
                    floor -= floor % mmap.PAGESIZE
                    if floor - released > _RELEASE_BYTES:
                        mapped.madvise(mmap.MADV_DONTNEED, released, floor - released)
                        released = floor
            yield connection, stamp, raw


#: read record by record when whole chunks would cost more than this per wanted message (about where
#: copying the chunk costs what seeking to each message does)
_SPARSE_MIN_BYTES = 64 * 1024
#: mapped bag pages read past are handed back in steps of this many bytes
_RELEASE_BYTES = 16 * 1024 * 1024


class _Bytes:
    """Reads a bag file's records: from the file mapped into memory where it can be (a message's bytes
    are then a read-only view of the file, not a copy), else through its file object. Mapped pages
    read past are handed back every ``_RELEASE_BYTES``, so the process does not hold the whole bag
    resident; a message still in use reads them again from the page cache."""

    def __init__(self, bio: Any) -> None:
        try:
            self.mapped: Any = mmap.mmap(bio.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError, AttributeError, io.UnsupportedOperation):
            self.mapped = None
        self.src = bio if self.mapped is None else self.mapped  # seek, tell and read work on both
        self._view = None if self.mapped is None else memoryview(self.mapped)
        self._released = 0  # mapped pages below this were handed back

    def take(self, size: int, error: type[Exception]) -> bytes | memoryview:
        """The next ``size`` bytes at the current position (the position moves past them)."""
        if self._view is None:
            data = self.src.read(size)
            if len(data) != size:
                raise error(f"Got only {len(data)} of requested {size} bytes.")
            return data
        start = self.src.tell()
        if start + size > len(self._view):
            raise error(f"Got only {len(self._view) - start} of requested {size} bytes.")
        self.src.seek(size, os.SEEK_CUR)
        if start - self._released > _RELEASE_BYTES and hasattr(self.mapped, "madvise"):
            end = start - _RELEASE_BYTES // 4  # the messages just before this one may still be in use
            end -= end % mmap.PAGESIZE
            if end > self._released:
                self.mapped.madvise(mmap.MADV_DONTNEED, self._released, end - self._released)
                self._released = end
        return self._view[start:start + size]


def ros1_records(reader: Any, conns: Sequence[Any]) -> Iterator[tuple[Any, int, bytes | memoryview]] | None:
    """The messages of ``conns`` in an uncompressed ROS1 bag, each read on its own; None for other bags.

    rosbags reads every chunk that holds a wanted message whole, so reading a scan stored beside
    camera images costs the images' bytes as well (a 1.5 MB chunk for a 5 kB scan, and the
    LiDAR, odometry and camera topics are each read by another process). In an uncompressed
    chunk, the bag's index gives each message's offset, so only its own record need be read.
    The bag is mapped into memory where it can be: a message's bytes are then a read-only view
    of the file (a camera frame is not copied on its way to the frame's consumer), and pages read
    past are handed back every few MB, so the process does not hold the whole bag.

    A healthy bag is read by :class:`Ros1Reader` (no per-message index), whose ``records`` this is;
    any other by rosbags' own reader, whose parsed index this reads. None (the reader's own path,
    which copies each message's bytes) for compressed chunks (bz2, lz4), for chunks that hold mostly
    wanted bytes (a LiDAR-only bag), and with a rosbags that lays out its parsed index and record
    helpers, which this reads, differently.
    """
    own = getattr(reader, "readers", None)
    if own and len(own) == 1 and isinstance(own[0], Ros1Reader):  # a healthy bag: no per-message index
        return own[0].records(conns) if own[0].sparse(conns) else None
    if not usable():
        return None
    try:
        from rosbags.rosbag1 import reader as r1

        if getattr(reader, "is2", True) or len(reader.readers) != 1:
            return None
        bag = reader.readers[0]
        plain = r1.decompressors[r1.Compression.NONE.value]
        chunks = bag.chunks
        if not all(c.decompressor is plain for c in chunks.values()):
            return None
        indexes = [bag.indexes[c.id] for c in conns]
        wanted = sum(len(i) for i in indexes)
        chunk_bytes = sum(chunks[pos].datasize for pos in {e.chunk_pos for i in indexes for e in i})
        if chunk_bytes < _SPARSE_MIN_BYTES * wanted:  # the chunks are mostly what is wanted: read them whole
            return None
        connmap = {c.id: c for c in bag.connections}
        bio = bag.bio
        read_header, read_uint32 = r1.Header.read, r1.read_uint32
        connection_op, message_op = int(r1.RecordType.CONNECTION), int(r1.RecordType.MSGDATA)
    except (ImportError, AttributeError, KeyError) as exc:  # rosbags' internals, laid out otherwise
        _falls_back("ros1", "rosbags %s lays out its parsed ROS1 index unlike what semmap reads (%r): ROS1 bags "
                    "rosbags indexes itself are read whole chunk by whole chunk", _rosbags_version(), exc)
        return None

    def records() -> Iterator[tuple[Any, int, bytes | memoryview]]:
        data = _Bytes(bio)
        src = data.src
        for entry in heapq.merge(*indexes):  # time order, as rosbags merges them
            src.seek(chunks[entry.chunk_pos].datapos + entry.offset)
            while True:
                header = read_header(src)
                op = header.get_uint8("op")
                if op != connection_op:
                    break
                src.seek(read_uint32(src), os.SEEK_CUR)  # a connection record before the message
            if op != message_op:
                raise r1.ReaderError(f"expected message data at chunk {entry.chunk_pos} offset {entry.offset}")
            yield connmap[header.get_uint32("conn")], entry.time, data.take(read_uint32(src), r1.ReaderError)

    return records()


def mcap_records(reader: Any, conns: Sequence[Any]) -> Iterator[tuple[Any, int, bytes | memoryview]] | None:
    """The messages of ``conns`` in a ROS2 MCAP bag with uncompressed chunks, each read on its own;
    None for other bags.

    As for ROS1 (:func:`ros1_records`): rosbags reads every chunk that holds a wanted message
    whole, but each chunk's message index gives the offset of every message of a channel in it,
    so only the wanted records are read (views of the mapped file). The order is rosbags': by log
    time, then by chunk, then as stored. None (rosbags' own path) for compressed chunks or messages,
    several storage files, files without chunk and message indexes, chunks that hold mostly wanted
    bytes, and a rosbags that lays out its parsed index differently.
    """
    if not usable():
        return None
    try:
        from rosbags.rosbag2 import storage_mcap as m2

        if not getattr(reader, "is2", False) or len(reader.readers) != 1:
            return None
        bag = reader.readers[0]
        storage = bag.storage
        storages = getattr(storage, "storages", [storage])
        if len(storages) != 1 or not isinstance(storages[0], m2.McapReader) or \
                getattr(bag, "compression_mode", None) == "message":
            return None
        mcap = storages[0]
        # the bag's connections and the file's channels, matched as rosbags matches them
        wanted: dict[int, Any] = {}
        for x in mcap.connections:
            for y in conns:
                if y.topic == x.topic and y.msgtype == x.msgtype and (not x.digest or not y.digest
                                                                        or y.digest == x.digest):
                    wanted[x.id] = y
                    break
        chunks = [c for c in mcap.chunks if any(c.channel_count.get(cid, 0) for cid in wanted)]
        if not chunks or any(c.compression or any(c.channel_count.get(cid, 0) and cid not in c.message_index_offsets
                                                  for cid in wanted) for c in chunks):
            return None
        n_wanted = sum(c.channel_count.get(cid, 0) for c in chunks for cid in wanted)
        if sum(c.uncompressed_size for c in chunks) < _SPARSE_MIN_BYTES * n_wanted:
            return None
        bio = mcap.bio
        error = m2.ReaderError
    except (ImportError, AttributeError, KeyError) as exc:  # rosbags' internals, laid out otherwise
        _falls_back("mcap", "rosbags %s lays out its MCAP reader unlike what semmap reads (%r): MCAP bags are "
                    "read whole chunk by whole chunk", _rosbags_version(), exc)
        return None

    def chunk_entries(data: _Bytes, chunk: Any) -> Iterator[tuple[int, int, int, int]]:
        """(log time, chunk offset, record offset, channel) of the chunk's wanted messages, in order."""
        yield chunk.message_start_time, chunk.chunk_start_offset, -1, -1  # the index is read when needed
        entries: list[tuple[int, int, int, int]] = []
        for cid in wanted:
            if not chunk.channel_count.get(cid, 0):
                continue
            data.src.seek(chunk.message_index_offsets[cid])
            head = data.src.read(15)  # op, record length, channel id, byte length of the entries
            if len(head) != 15 or head[0] != 0x07:
                raise error(f"no message index at offset {chunk.message_index_offsets[cid]}")
            n = int.from_bytes(head[11:15], "little")
            pairs = np.frombuffer(bytes(data.take(n, error)), dtype="<u8").reshape(-1, 2)
            entries.extend((int(t), chunk.chunk_start_offset, int(off), cid) for t, off in pairs.tolist())
        entries.sort()
        yield from entries

    def merged(data: _Bytes) -> Iterator[tuple[int, int, int, int]]:
        """What ``heapq.merge`` of every chunk's entries gives (ties: chunk order), but a chunk's entries
        are made only when the merge reaches its first message, so a stream holds those of a chunk or two
        rather than a generator per chunk of the bag."""
        order = np.lexsort((np.arange(len(chunks)), np.array([c.chunk_start_offset for c in chunks], np.int64),
                            np.array([c.message_start_time for c in chunks], np.int64)))
        heap: list[tuple[tuple[int, int, int, int], int, Iterator[tuple[int, int, int, int]]]] = []
        k = 0
        while True:
            while k < len(order):  # a chunk whose first entry would come before the next one joins
                i = int(order[k])
                first = (chunks[i].message_start_time, chunks[i].chunk_start_offset, -1, -1)
                if heap and (first, i) > heap[0][:2]:
                    break
                entries = chunk_entries(data, chunks[i])
                heapq.heappush(heap, (next(entries), i, entries))
                k += 1
            if not heap:
                return
            value, i, entries = heap[0]
            yield value
            following = next(entries, None)
            if following is None:
                heapq.heappop(heap)
            else:
                heapq.heapreplace(heap, (following, i, entries))

    def records() -> Iterator[tuple[Any, int, bytes | memoryview]]:
        data = _Bytes(bio)
        for log_time, chunk_at, offset, cid in merged(data):
            if offset < 0:
                continue
            data.src.seek(chunk_at + 9 + 40 + offset)  # op, length, 4 numbers, "" (no compression), size
            head = data.src.read(9)  # op, record length
            if len(head) != 9 or head[0] != 0x05:
                raise error(f"no message record at chunk {chunk_at} offset {offset}")
            size = int.from_bytes(head[1:9], "little")
            data.src.seek(22, os.SEEK_CUR)  # channel, sequence, log and publish time
            yield wanted[cid], log_time, data.take(size - 22, error)

    return records()


def reads(reader: Any) -> bool:
    """Whether ``reader`` (rosbags' ``AnyReader``) reads its bag through :class:`Ros1Reader`."""
    own: Sequence[Any] = getattr(reader, "readers", None) or ()
    return len(own) == 1 and isinstance(own[0], Ros1Reader)
