"""The one rosbags adapter: writing and reading ROS1 ``.bag`` and ROS2 (mcap, sqlite3) bags.

Nothing outside :mod:`semmap.io` imports :mod:`rosbags` or sees its objects. The writer takes semmap
records and plain numbers and serialises real ROS messages; the reader side gives :func:`bag_info`
(what ``semmap info`` prints), :func:`read_bag` (a bag opened once: its topics, counts, time span, and
its messages as semmap records) and raw message iteration for :mod:`semmap.io`.

A healthy bag is read by semmap's own record reader (:mod:`semmap.io.fastbag`: bounded memory on
long bags, with the rosbags versions it was tested with), anything else by rosbags' reader.

Bags rosbags cannot read are read as ROS's own tools read them where that is possible: a ROS1
bag whose index rosbags rejects (2010-era index records, a recording never closed, an index
that does not lead to the messages) through its index read by ROS's rules or rebuilt from its
chunks as ``rosbag reindex`` would, in memory; ``roslib/Header`` as ``std_msgs/Header``. Whatever
a reading library raises on a damaged bag becomes a :class:`BagError` naming the file and what
is wrong with it.
"""

from __future__ import annotations

import bisect
import contextlib
import io
import logging
import mmap
import os
import struct
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import BagError, SemmapError
from ..geometry import se3_to_translation_quaternion, yaw_to_quaternion
from ..records import CameraIntrinsics, Image, Scan
from . import fastbag
from .ros1format import (
    MAGIC,
    OP_CHUNK,
    OP_CHUNK_INFO,
    OP_CONNECTION,
    OP_FILE_HEADER,
    OP_INDEX,
    OP_MSG,
    TIME,
    U32,
    U64,
    Damaged,
    Truncated,
    field_int,
    file_header,
    header_fields,
    record_at,
    record_op,
)

__all__ = [
    "BAG_FORMATS",
    "BagFormat",
    "BagInfo",
    "BagWriter",
    "OpenBag",
    "ReadStats",
    "TopicInfo",
    "bag_info",
    "bag_suffix",
    "iter_messages",
    "iter_records",
    "message_count",
    "open_bag",
    "read_bag",
    "resolve_bag_path",
    "topic_types",
]

log = logging.getLogger(__name__)

BagFormat = Literal["ros1", "mcap", "sqlite3"]
BAG_FORMATS: tuple[str, ...] = ("ros1", "mcap", "sqlite3")

# ROS1's tf2_msgs/TFMessage definition; older rosbags ROS1 typestores lack it.
_TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"


def bag_suffix(fmt: BagFormat) -> str:
    """File name suffix for a bag of this format (ROS2 bags are directories)."""
    return ".bag" if fmt == "ros1" else ""


def _typestore(fmt: BagFormat) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if fmt == "ros1":
        store = get_typestore(Stores.ROS1_NOETIC)
        if "tf2_msgs/msg/TFMessage" not in store.types:
            store.register(get_types_from_msg(_TF_MESSAGE_MSG, "tf2_msgs/msg/TFMessage"))
        return store
    return get_typestore(Stores.ROS2_HUMBLE)


def _latched_qos() -> list[Any]:
    """QoS offered by a ROS2 ``/tf_static`` publisher: reliable, transient local, depth 1."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    inf = QosTime(9223372036, 854775807)
    return [
        Qos(
            QosHistory.KEEP_LAST,
            1,
            QosReliability.RELIABLE,
            QosDurability.TRANSIENT_LOCAL,
            inf,
            inf,
            QosLiveliness.AUTOMATIC,
            inf,
            False,
        )
    ]


class BagWriter:
    """Write sensor streams as a real ROS1 ``.bag`` or ROS2 bag (mcap or sqlite3).

    Use as a context manager. ``t_ns`` arguments are the bag (receive) time;
    ``stamp_ns`` values go into message headers. On an exception the partial
    bag is left for the caller to delete (semmap writes into a temporary folder).
    """

    def __init__(self, path: str | Path, fmt: BagFormat) -> None:
        if fmt not in BAG_FORMATS:
            raise BagError(f"unknown bag format {fmt!r} (expected one of {', '.join(BAG_FORMATS)})")
        self.path = Path(path)
        self.fmt: BagFormat = fmt
        self._store = _typestore(fmt)
        self._types = self._store.types
        self._connections: dict[str, Any] = {}
        self._seq: dict[str, int] = {}
        self._writer: Any = None

    # -- lifecycle -----------------------------------------------------------------
    def __enter__(self) -> BagWriter:
        if self.fmt == "ros1":
            from rosbags.rosbag1 import Writer as Writer1

            self._writer = Writer1(self.path)
        else:
            from rosbags.rosbag2 import StoragePlugin
            from rosbags.rosbag2 import Writer as Writer2

            plugin = StoragePlugin.MCAP if self.fmt == "mcap" else StoragePlugin.SQLITE3
            self._writer = Writer2(self.path, version=9, storage_plugin=plugin)
        self._writer.open()
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if self._writer is None:
            return
        if exc_type is None:
            self._writer.close()
        else:
            try:
                self._writer.abort()
            except Exception:
                log.debug("aborting bag writer failed", exc_info=True)
        self._writer = None

    # -- plumbing ------------------------------------------------------------------
    def _connection(self, topic: str, msgtype: str, latched: bool = False) -> Any:
        conn = self._connections.get(topic)
        if conn is not None:
            if conn.msgtype != msgtype:
                raise BagError(f"{self.path}: topic {topic} already has type {conn.msgtype}")
            return conn
        if self.fmt == "ros1":
            conn = self._writer.add_connection(
                topic, msgtype, typestore=self._store, callerid="/semmap_sim",
                latching=1 if latched else None,
            )
        else:
            conn = self._writer.add_connection(
                topic, msgtype, typestore=self._store,
                offered_qos_profiles=_latched_qos() if latched else (),
            )
        self._connections[topic] = conn
        self._seq[topic] = 0
        return conn

    def _write(self, topic: str, msgtype: str, t_ns: int, msg: Any, latched: bool = False) -> None:
        conn = self._connection(topic, msgtype, latched)
        if self.fmt == "ros1":
            data = self._store.serialize_ros1(msg, msgtype)
        else:
            data = self._store.serialize_cdr(msg, msgtype)
        self._writer.write(conn, int(t_ns), data)
        self._seq[topic] += 1

    def _time(self, stamp_ns: int) -> Any:
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        return self._types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)

    def _header(self, topic: str, stamp_ns: int, frame_id: str) -> Any:
        header_t = self._types["std_msgs/msg/Header"]
        if self.fmt == "ros1":
            return header_t(seq=self._seq.get(topic, 0), stamp=self._time(stamp_ns), frame_id=frame_id)
        return header_t(stamp=self._time(stamp_ns), frame_id=frame_id)

    # -- message writers -------------------------------------------------------------
    def scan(self, topic: str, t_ns: int, scan: Scan) -> None:
        """Write a ``sensor_msgs/LaserScan``."""
        typ = "sensor_msgs/msg/LaserScan"
        intens = scan.intensities if scan.intensities is not None else np.zeros(0, np.float32)
        msg = self._types[typ](
            header=self._header(topic, scan.stamp_ns, scan.frame_id),
            angle_min=float(scan.angle_min),
            angle_max=float(scan.angle_min + scan.angle_increment * (scan.ranges.size - 1)),
            angle_increment=float(scan.angle_increment),
            time_increment=float(scan.time_increment),
            scan_time=float(scan.scan_time),
            range_min=float(scan.range_min),
            range_max=float(scan.range_max),
            ranges=np.ascontiguousarray(scan.ranges, dtype=np.float32),
            intensities=np.ascontiguousarray(intens, dtype=np.float32),
        )
        self._write(topic, typ, t_ns, msg)

    def image(self, topic: str, t_ns: int, image: Image) -> None:
        """Write a raw ``sensor_msgs/Image`` (rgb8, bgr8, mono8, mono16...), little-endian."""
        typ = "sensor_msgs/msg/Image"
        a = np.ascontiguousarray(image.data)
        if a.dtype.byteorder == ">":
            a = a.astype(a.dtype.newbyteorder("<"))
        h, w = a.shape[:2]
        step = w * (a.shape[2] if a.ndim == 3 else 1) * a.dtype.itemsize
        msg = self._types[typ](
            header=self._header(topic, image.stamp_ns, image.frame_id),
            height=h,
            width=w,
            encoding=image.encoding,
            is_bigendian=0,
            step=step,
            data=a.reshape(-1).view(np.uint8),
        )
        self._write(topic, typ, t_ns, msg)

    def compressed_image(
        self, topic: str, t_ns: int, stamp_ns: int, frame_id: str, fmt: str, data: bytes
    ) -> None:
        """Write a ``sensor_msgs/CompressedImage`` (``fmt`` e.g. ``"rgb8; jpeg compressed bgr8"``)."""
        typ = "sensor_msgs/msg/CompressedImage"
        msg = self._types[typ](
            header=self._header(topic, stamp_ns, frame_id),
            format=fmt,
            data=np.frombuffer(data, dtype=np.uint8),
        )
        self._write(topic, typ, t_ns, msg)

    def camera_info(
        self, topic: str, t_ns: int, stamp_ns: int, frame_id: str, intr: CameraIntrinsics
    ) -> None:
        """Write a ``sensor_msgs/CameraInfo`` (ROS1 ``D/K/R/P``, ROS2 ``d/k/r/p``)."""
        typ = "sensor_msgs/msg/CameraInfo"
        k = intr.K
        p = np.zeros((3, 4))
        p[:, :3] = k
        model = "equidistant" if intr.model == "fisheye" else (
            "rational_polynomial" if intr.D.size >= 8 else "plumb_bob"
        )
        roi = self._types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        arrays = {
            "D": np.asarray(intr.D, dtype=np.float64),
            "K": k.reshape(-1).astype(np.float64),
            "R": np.eye(3).reshape(-1),
            "P": p.reshape(-1),
        }
        if self.fmt != "ros1":
            arrays = {key.lower(): val for key, val in arrays.items()}
        msg = self._types[typ](
            header=self._header(topic, stamp_ns, frame_id),
            height=intr.height,
            width=intr.width,
            distortion_model=model,
            binning_x=0,
            binning_y=0,
            roi=roi,
            **arrays,
        )
        self._write(topic, typ, t_ns, msg)

    def odometry(
        self,
        topic: str,
        t_ns: int,
        stamp_ns: int,
        frame_id: str,
        child_frame_id: str,
        pose: ArrayLike,
        twist: ArrayLike,
        pose_cov_diag: ArrayLike = (0.0,) * 6,
        twist_cov_diag: ArrayLike = (0.0,) * 6,
    ) -> None:
        """Write a planar ``nav_msgs/Odometry``: pose (x, y, yaw), twist (vx, vy, wz) in the child frame."""
        typ = "nav_msgs/msg/Odometry"
        t = self._types
        pose = np.asarray(pose, np.float64)
        twist = np.asarray(twist, np.float64)
        q = yaw_to_quaternion(pose[2])
        pose_msg = t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](
                    x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
                ),
            ),
            covariance=np.diag(np.asarray(pose_cov_diag, dtype=np.float64)).reshape(-1),
        )
        vec = t["geometry_msgs/msg/Vector3"]
        twist_msg = t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=vec(x=float(twist[0]), y=float(twist[1]), z=0.0),
                angular=vec(x=0.0, y=0.0, z=float(twist[2])),
            ),
            covariance=np.diag(np.asarray(twist_cov_diag, dtype=np.float64)).reshape(-1),
        )
        msg = t[typ](
            header=self._header(topic, stamp_ns, frame_id),
            child_frame_id=child_frame_id,
            pose=pose_msg,
            twist=twist_msg,
        )
        self._write(topic, typ, t_ns, msg)

    def transforms(
        self,
        topic: str,
        t_ns: int,
        transforms: Sequence[tuple[int, str, str, NDArray[np.float64]]],
        static: bool = False,
    ) -> None:
        """Write a ``tf2_msgs/TFMessage``; each transform is (stamp_ns, parent, child, T_parent_child)."""
        typ = "tf2_msgs/msg/TFMessage"
        t = self._types
        out = []
        for stamp_ns, parent, child, mat in transforms:
            mat = np.asarray(mat, dtype=np.float64)
            if abs(mat[2, 2] - 1.0) < 1e-12:  # planar: a rotation about z only (fast path)
                trans, q = mat[:3, 3], yaw_to_quaternion(np.arctan2(mat[1, 0], mat[0, 0]))
            else:
                trans, q = se3_to_translation_quaternion(mat)
            out.append(
                t["geometry_msgs/msg/TransformStamped"](
                    header=self._header(topic, stamp_ns, parent),
                    child_frame_id=child,
                    transform=t["geometry_msgs/msg/Transform"](
                        translation=t["geometry_msgs/msg/Vector3"](
                            x=float(trans[0]), y=float(trans[1]), z=float(trans[2])
                        ),
                        rotation=t["geometry_msgs/msg/Quaternion"](
                            x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
                        ),
                    ),
                )
            )
        self._write(topic, typ, t_ns, t[typ](transforms=out), latched=static)


# ---------------------------------------------------------------------------------------
# Reading


def resolve_bag_path(path: str | Path) -> Path:
    """Find the bag a user pointed at: a ``.bag`` file, a ROS2 bag folder, a file
    inside a ROS2 bag folder, or a semmap tour folder holding one bag."""
    p = Path(path)
    if not p.exists():
        raise BagError(f"{p}: no such file or directory")
    if p.is_file():
        if p.suffix == ".bag":
            return p
        if p.suffix in (".mcap", ".db3") and (p.parent / "metadata.yaml").is_file():
            return p.parent
        raise BagError(
            f"{p}: not a bag (expected a ROS1 .bag file or a ROS2 bag folder with metadata.yaml)"
        )
    if (p / "metadata.yaml").is_file():
        return p
    # A folder holding exactly one bag, e.g. what `semmap simulate` writes.
    candidates = sorted(p.glob("*.bag")) + sorted(
        d for d in p.iterdir() if d.is_dir() and (d / "metadata.yaml").is_file()
    )
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise BagError(f"{p}: folder holds no bag (no metadata.yaml and no .bag file)")
    names = ", ".join(c.name for c in candidates)
    # a recording split into files (rosbag record --split): rosbags, which semmap reads with, joins them
    parts = " ".join(c.name for c in candidates)
    raise BagError(f"{p}: folder holds several bags ({names}); name one, or, if they are one recording split "
                   f"into parts, join them in time order with: rosbags-convert --src {parts} --dst joined.bag")


# ---------------------------------------------------------------------------------------
# ROS1 bags whose index rosbags cannot use: read it by ROS's rules, or rebuild it from the chunks
#
# (the record layout: :mod:`semmap.io.ros1format`; the reading rules are those of ROS's own reader,
# ros_comm tools/rosbag/src/rosbag/bag.py)

#: rebuilt indexes of the last few bags, by path and file identity (commands that open a bag again reuse them)
_REBUILT: dict[tuple[str, int, int, int], _Ros1Index] = {}
_REBUILT_KEEP = 4


@dataclass
class _Ros1Chunk:
    """A chunk record: where it is in the file and the messages it holds."""

    pos: int  # the chunk record
    end: int  # the end of its data
    entries: dict[int, list[tuple[int, int]]]  # connection id -> [(time ns, offset in the chunk's data)]


@dataclass
class _Ros1Index:
    """The index of a ROS1 bag as ROS reads it, or rebuilt from its chunks."""

    connections: dict[int, tuple[bytes, list[tuple[bytes, bytes]]]]  # id -> (topic, connection header)
    chunks: list[_Ros1Chunk]
    how: str  # for people: how it was made, and why
    rebuilt: bool = False  # from the chunks (else the bag's own index, read by ROS's rules)


def _connection(fields: dict[str, bytes], buf: Any, start: int, dlen: int, end: int,
                what: str) -> tuple[int, bytes, list[tuple[bytes, bytes]]]:
    """(id, topic, connection header) of a connection record."""
    if start + dlen > end:
        raise Damaged(f"{what} is longer than the data it is in")
    conn = field_int(fields, "conn", U32, what)
    header = header_fields(buf, start, start + dlen, what)
    topic = fields.get("topic", header.get("topic", b""))
    for key, value in (("topic", topic), *((k, header.get(k)) for k in ("type", "md5sum", "message_definition"))):
        if value is None:
            raise Damaged(f"{what} (connection {conn}) has no {key!r}")
        try:
            value.decode()
        except UnicodeDecodeError:
            raise Damaged(f"{what} (connection {conn}) has a {key!r} that is not UTF-8 text") from None
    return conn, topic, [(k.encode("latin-1"), v) for k, v in header.items()]


def _chunk_record(buf: Any, pos: int, size: int, cut: type[Damaged] = Damaged) -> tuple[dict[str, bytes], int, int]:
    """Header fields, data start and data length of the chunk record at ``pos``."""
    what = f"the chunk at byte {pos}"
    fields, start, dlen = record_at(buf, pos, size, what, cut)
    if record_op(fields, what) != OP_CHUNK:
        raise Damaged(f"the record at byte {pos} is not a chunk")
    if dlen == 0:
        raise cut(f"{what} was never finished (its data length is 0)")
    if start + dlen > size:
        raise cut(f"{what} needs {dlen} bytes of data, but the file ends at byte {size}")
    return fields, start, dlen


def _index_data(buf: Any, pos: int, size: int,
                cut: type[Damaged] = Damaged) -> tuple[int, int, int, int, dict[str, bytes]]:
    """(connection, count, entries start, data length as written, header fields) of an index data record.

    The data length is not used, as ROS's reader does not use it (C Turtle's rosbag, before
    1.1.15, wrote a wrong one): the entries are ``count`` x 12 bytes (time sec, nsec, offset).
    """
    what = f"the index data record at byte {pos}"
    fields, start, dlen = record_at(buf, pos, size, what, cut)
    if record_op(fields, what) != OP_INDEX:
        raise Damaged(f"the record at byte {pos} is not index data")
    if field_int(fields, "ver", U32, what) != 1:
        raise Damaged(f"{what} has an unknown version")
    count = field_int(fields, "count", U32, what)
    if start + 12 * count > size:
        raise cut(f"{what} holds {count} entries, but the file ends at byte {size}")
    return field_int(fields, "conn", U32, what), count, start, dlen, fields


def _index_as_ros_reads(buf: Any, size: int, index_pos: int, conn_count: int, chunk_count: int) -> _Ros1Index:
    """The bag's own index, read as ROS's reader reads it: fields in any order, unknown fields
    skipped, the index data records' data length ignored. Raises :class:`Damaged` when it does not
    add up (the chunks are walked then), :class:`Truncated` when the file ends before its index."""
    if index_pos == 0:
        raise Damaged("it is not indexed: its recording was never closed")
    if index_pos >= size:
        raise Truncated(f"bag is truncated: its index should start at byte {index_pos}, but the file ends "
                         f"at byte {size}")
    pos = index_pos
    connections: dict[int, tuple[bytes, list[tuple[bytes, bytes]]]] = {}
    for _ in range(conn_count):
        what = f"the connection record at byte {pos}"
        fields, start, dlen = record_at(buf, pos, size, what)
        if record_op(fields, what) != OP_CONNECTION:
            raise Damaged(f"its index holds {len(connections)} connection records, its file header says {conn_count}")
        conn, topic, header = _connection(fields, buf, start, dlen, size, what)
        connections.setdefault(conn, (topic, header))
        pos = start + dlen
    infos: list[tuple[int, int, dict[int, int]]] = []  # (chunk pos, end time, messages per connection)
    for _ in range(chunk_count):
        what = f"the chunk info record at byte {pos}"
        fields, start, _dlen = record_at(buf, pos, size, what)
        if record_op(fields, what) != OP_CHUNK_INFO or field_int(fields, "ver", U32, what) != 1:
            raise Damaged(f"its index holds {len(infos)} chunk info records, its file header says {chunk_count}")
        count = field_int(fields, "count", U32, what)
        if start + 8 * count > size:
            raise Damaged(f"{what} is cut off")
        pairs = np.frombuffer(buf[start:start + 8 * count], dtype="<u4").reshape(-1, 2)  # (a copy: the map closes)
        infos.append((field_int(fields, "chunk_pos", U64, what), field_int(fields, "end_time", TIME, what),
                      dict(zip(pairs[:, 0].tolist(), pairs[:, 1].tolist()))))
        pos = start + 8 * count
    chunks = []
    quirks: dict[str, str] = {}
    for chunk_pos, end_ns, counts in infos:
        fields, start, dlen = _chunk_record(buf, chunk_pos, size)
        unpacked = field_int(fields, "size", U32, f"the chunk at byte {chunk_pos}")
        entries: dict[int, list[tuple[int, int]]] = {}
        pos = start + dlen
        for _ in range(len(counts)):
            conn, count, at, written, fields = _index_data(buf, pos, size)
            if written != 12 * count:
                quirks["length"] = ("its index data records give a wrong data length (as C Turtle's rosbag, "
                                    "before 1.1.15, wrote them; ROS's reader ignores it)")
            if set(fields) - {"op", "ver", "conn", "count"}:
                quirks["fields"] = "its index data records carry header fields besides op, ver, conn and count"
            rows = np.frombuffer(buf[at:at + 12 * count], dtype="<u4").reshape(-1, 3).astype(np.int64)
            times = rows[:, 0] * 1_000_000_000 + rows[:, 1]
            if conn not in connections or counts.get(conn) != count or conn in entries or \
                    (count and (rows[:, 2].max() >= unpacked or times.max() > end_ns)):
                raise Damaged(f"the index data record at byte {pos} does not match the chunk info of the chunk "
                               f"at byte {chunk_pos}")
            entries[conn] = list(zip(times.tolist(), rows[:, 2].tolist()))
            pos = at + 12 * count
        chunks.append(_Ros1Chunk(chunk_pos, start + dlen, entries))
    return _Ros1Index(connections, chunks, "; ".join(quirks.values()))


def _decompress(buf: Any, start: int, dlen: int, compression: bytes, what: str) -> Any:
    """A chunk's records: its bytes, decompressed."""
    from rosbags.rosbag1.reader import decompressors

    if compression == b"none":
        return buf[start:start + dlen]
    func = decompressors.get(compression.decode("latin-1"))
    if func is None:
        raise Damaged(f"{what} uses compression {compression.decode('latin-1')!r}, which semmap cannot read")
    try:
        return func(bytes(buf[start:start + dlen]))
    except Exception as exc:
        raise Damaged(f"{what} cannot be decompressed ({compression.decode('latin-1')}: {exc})") from None


def _walk_chunk(data: Any, what: str,
                connections: dict[int, tuple[bytes, list[tuple[bytes, bytes]]]]) -> dict[int, list[tuple[int, int]]]:
    """The messages in a chunk's records, as ``rosbag reindex`` finds them; connection records are collected."""
    entries: dict[int, list[tuple[int, int]]] = {}
    at, end = 0, len(data)
    while at < end:
        where = f"the record at offset {at} of {what}"
        fields, start, dlen = record_at(data, at, end, where)
        if start + dlen > end:
            raise Damaged(f"{where} is longer than its chunk")
        op = record_op(fields, where)
        if op == OP_CONNECTION:
            conn, topic, header = _connection(fields, data, start, dlen, end, where)
            connections.setdefault(conn, (topic, header))
        elif op == OP_MSG:
            conn = field_int(fields, "conn", U32, where)
            entries.setdefault(conn, []).append((field_int(fields, "time", TIME, where), at))
        at = start + dlen
    return entries


def _is_record(buf: Any, pos: int, size: int) -> bool:
    """Whether a record of a known kind starts at ``pos`` (or the file ends there)."""
    if pos == size:
        return True
    try:
        return record_op(record_at(buf, pos, size, "")[0], "") in (OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION)
    except Damaged:
        return False


def _index_from_chunks(buf: Any, size: int, first: int, index_pos: int, why: str) -> _Ros1Index:
    """The index rebuilt by walking the chunks, as ``rosbag reindex`` does.

    Records between chunks are skipped: index data by its ``count`` (or by its data length when only
    that leads to the next record), the rest by their data length; connection records are collected
    wherever they are (``rosbag record --split`` once wrote some only at the end). What follows the
    last chunk of a closed bag (at ``index_pos``) is its old index, not needed: damage there ends the
    walk. A bag that was never closed (``index_pos`` 0) keeps its complete chunks and loses an
    unfinished last one, as with ``rosbag reindex``; a closed bag that ends early is truncated.
    """
    connections: dict[int, tuple[bytes, list[tuple[bytes, bytes]]]] = {}
    chunks: list[_Ros1Chunk] = []
    dropped = cut = ""
    pos = first
    while pos < size:
        try:
            what = f"the record at byte {pos}"
            fields, start, dlen = record_at(buf, pos, size, what, Truncated)
            op = record_op(fields, what)
            if op == OP_CHUNK:
                what = f"the chunk at byte {pos}"
                fields, start, dlen = _chunk_record(buf, pos, size, Truncated)
                data = _decompress(buf, start, dlen, fields.get("compression", b"none"), what)
                entries = _walk_chunk(data, what, connections)
                if entries:
                    chunks.append(_Ros1Chunk(pos, start + dlen, entries))
                nxt = start + dlen
            elif op == OP_INDEX:
                _, count, at, dlen, _ = _index_data(buf, pos, size, Truncated)
                nxt = at + 12 * count
                if not _is_record(buf, nxt, size) and at + dlen <= size and _is_record(buf, at + dlen, size):
                    nxt = at + dlen
            elif op == OP_CONNECTION:
                conn, topic, header = _connection(fields, buf, start, dlen, size,
                                                  f"the connection record at byte {pos}")
                connections.setdefault(conn, (topic, header))
                nxt = start + dlen
            elif op in (OP_MSG, OP_FILE_HEADER):
                raise Damaged(f"{what} (op {op}) is out of place")
            else:  # chunk info, or a kind of record this reader does not know: skipped, as ROS does
                nxt = start + dlen
            if nxt > size:
                raise Truncated(f"{what} is cut off (the file ends at byte {size})")
            pos = nxt
        except Damaged as exc:
            if chunks and first < index_pos <= pos:  # in the old index, after the last chunk
                why = f"{why}; its old index is damaged too ({exc})"
                break
            if index_pos == 0 and isinstance(exc, Truncated):
                cut = str(exc)
                dropped = f"; dropped its unfinished end from byte {pos}: {cut}"
                break
            raise Truncated(f"bag is truncated: {exc}") if isinstance(exc, Truncated) else \
                Damaged(f"bag is damaged: {exc}") from None
    if dropped and not chunks:
        raise Truncated(f"bag is truncated: it was never closed, and no chunk in it is complete ({cut})")
    for chunk in chunks:
        for conn in chunk.entries:
            if conn not in connections:
                raise Damaged(f"bag is damaged: the chunk at byte {chunk.pos} holds messages of connection {conn}, "
                               f"which no connection record defines")
    return _Ros1Index(connections, chunks, f"rebuilt its index from its chunks, as `rosbag reindex` would "
                                           f"({why}{dropped})", rebuilt=True)


def _ros1_index(p: Path, why: str, trust_index: bool = True) -> _Ros1Index:
    """The index of the ROS1 bag ``p``, whose own index rosbags could not use (``why``): its own index
    read by ROS's rules where that adds up (``trust_index``), else rebuilt from its chunks.
    :class:`BagError` when the bag is damaged beyond that. The last few are kept."""
    try:
        st = p.stat()
        if st.st_size == 0:
            raise BagError(f"{p}: the file is empty, not a bag")
        with p.open("rb") as f:
            buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except OSError as exc:
        raise BagError(f"{p}: cannot read the bag ({exc.strerror or exc})") from None
    key = (str(p.resolve()), st.st_size, st.st_mtime_ns, st.st_ino)
    cached = _REBUILT.get(key)
    if cached is not None and (trust_index or cached.rebuilt):
        buf.close()
        return cached
    try:
        index_pos, conn_count, chunk_count, first = file_header(buf, st.st_size)
        index = None
        if trust_index:
            try:
                index = _index_as_ros_reads(buf, st.st_size, index_pos, conn_count, chunk_count)
            except Truncated:
                raise
            except Damaged as exc:
                why = str(exc)
        if index is None:
            index = _index_from_chunks(buf, st.st_size, first, index_pos, why)
        notes = [index.how] if index.rebuilt else [f"read its own index as ROS's reader does: {index.how}"] \
            if index.how else []
        if any(b"roslib/Header" in v for _, header in index.connections.values() for _, v in header):
            notes.append("its message definitions name roslib/Header, read as std_msgs/Header (as genpy does)")
        index.how = "; ".join(notes) or f"read its own index as ROS's reader does ({why})"
    except Damaged as exc:
        msg = str(exc)
        raise BagError(f"{p}: {msg if msg.startswith(('bag ', 'not ')) else 'bag is damaged: ' + msg}") from None
    finally:
        buf.close()
    _REBUILT.pop(key, None)
    while len(_REBUILT) >= _REBUILT_KEEP:
        del _REBUILT[next(iter(_REBUILT))]
    _REBUILT[key] = index
    return index


def _record_bytes(fields: list[tuple[bytes, bytes]], data: bytes) -> bytes:
    head = b"".join(U32.pack(len(k) + 1 + len(v)) + k + b"=" + v for k, v in fields)
    return U32.pack(len(head)) + head + U32.pack(len(data)) + data


def _modern_definition(header: list[tuple[bytes, bytes]]) -> list[tuple[bytes, bytes]]:
    """A connection header whose types name ``std_msgs/Header`` where it says ``roslib/Header`` (ROS
    before 1.2; genpy maps it the same way, and the md5sums are the same)."""
    return [(k, v.replace(b"roslib/Header", b"std_msgs/Header") if k in (b"message_definition", b"type") else v)
            for k, v in header]


def _time_bytes(ns: int) -> bytes:
    return TIME.pack(*divmod(ns, 1_000_000_000))


def _view_parts(index: _Ros1Index) -> list[bytes | tuple[int, int]]:
    """The bag as rosbags reads it: its chunks (ranges of the file, unchanged) each followed by
    index data records, then the connection and chunk info records, behind a file header."""
    chunk_part: list[bytes | tuple[int, int]] = []
    chunk_at: list[int] = []
    header_len = len(_record_bytes([(b"op", bytes([OP_FILE_HEADER])), (b"index_pos", bytes(8)),
                                    (b"conn_count", bytes(4)), (b"chunk_count", bytes(4))], b""))
    at = len(MAGIC) + header_len
    for chunk in index.chunks:
        chunk_at.append(at)
        chunk_part.append((chunk.pos, chunk.end - chunk.pos))
        at += chunk.end - chunk.pos
        for conn, entries in sorted(chunk.entries.items()):
            rows = np.array([(t // 1_000_000_000, t % 1_000_000_000, off) for t, off in entries], dtype="<u4")
            rec = _record_bytes([(b"op", bytes([OP_INDEX])), (b"ver", U32.pack(1)), (b"conn", U32.pack(conn)),
                                 (b"count", U32.pack(len(entries)))], rows.tobytes())
            chunk_part.append(rec)
            at += len(rec)
    tail = bytearray()
    for conn, (topic, header) in sorted(index.connections.items()):
        data = b"".join(U32.pack(len(k) + 1 + len(v)) + k + b"=" + v for k, v in _modern_definition(header))
        tail += _record_bytes([(b"op", bytes([OP_CONNECTION])), (b"conn", U32.pack(conn)), (b"topic", topic)], data)
    for chunk, pos in zip(index.chunks, chunk_at):
        times = [t for entries in chunk.entries.values() for t, _ in entries]
        pairs = b"".join(U32.pack(c) + U32.pack(len(e)) for c, e in sorted(chunk.entries.items()))
        tail += _record_bytes([(b"op", bytes([OP_CHUNK_INFO])), (b"ver", U32.pack(1)), (b"chunk_pos", U64.pack(pos)),
                               (b"start_time", _time_bytes(min(times))), (b"end_time", _time_bytes(max(times))),
                               (b"count", U32.pack(len(chunk.entries)))], pairs)
    file_header = _record_bytes([(b"op", bytes([OP_FILE_HEADER])), (b"index_pos", U64.pack(at)),
                                 (b"conn_count", U32.pack(len(index.connections))),
                                 (b"chunk_count", U32.pack(len(index.chunks)))], b"")
    return [MAGIC + file_header, *chunk_part, bytes(tail)]


class _SplicedFile(io.RawIOBase):
    """A read-only file made of ranges of a real file and bytes held in memory."""

    def __init__(self, path: Path, parts: Sequence[bytes | tuple[int, int]]) -> None:
        super().__init__()
        self._fd = os.open(path, os.O_RDONLY)
        self._parts: list[tuple[int, bytes | tuple[int, int]]] = []
        at = 0
        for part in parts:
            size = len(part) if isinstance(part, bytes) else part[1]
            if size > 0:
                self._parts.append((at, part))
                at += size
        self._starts = [s for s, _ in self._parts]
        self._size = at
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._pos, os.SEEK_END: self._size}[whence]
        if base + offset < 0:
            raise OSError(22, "negative seek position")
        self._pos = base + offset
        return self._pos

    def readinto(self, b: Any) -> int:
        out = memoryview(b).cast("B")
        done = 0
        while done < len(out) and self._pos < self._size:
            i = bisect.bisect_right(self._starts, self._pos) - 1
            start, part = self._parts[i]
            inside = self._pos - start
            if isinstance(part, bytes):
                chunk = part[inside:inside + len(out) - done]
            else:
                chunk = os.pread(self._fd, min(part[1] - inside, len(out) - done), part[0] + inside)
                if not chunk:
                    raise OSError(5, "the bag changed while it was read")
            out[done:done + len(chunk)] = chunk
            done += len(chunk)
            self._pos += len(chunk)
        return done

    def close(self) -> None:
        if not self.closed:
            os.close(self._fd)
        super().close()


class _RebuiltBagPath:
    """A ROS1 bag seen through a rebuilt index, for rosbags' reader (its ``RPath`` protocol): its
    chunks are read from the bag itself; nothing is written anywhere."""

    suffix = ".bag"

    def __init__(self, path: Path, index: _Ros1Index) -> None:
        self.path = path
        self.name, self.stem = path.name, path.stem
        self.rebuilt = index.rebuilt
        self._parts = _view_parts(index)

    def exists(self) -> bool:
        return True

    def is_dir(self) -> bool:
        return False

    def open(self, mode: str = "rb", *args: Any, **kwargs: Any) -> io.BufferedReader:
        if mode != "rb":
            raise OSError(f"{self.path}: a rebuilt view of a bag opens read-only")
        return io.BufferedReader(_SplicedFile(self.path, self._parts), buffer_size=64 * 1024)

    def stat(self, *, follow_symlinks: bool = True) -> os.stat_result:
        st = self.path.stat()
        size = sum(len(part) if isinstance(part, bytes) else part[1] for part in self._parts)
        return os.stat_result((st.st_mode, st.st_ino, st.st_dev, st.st_nlink, st.st_uid, st.st_gid, size,
                               int(st.st_atime), int(st.st_mtime), int(st.st_ctime)))

    def read_text(self, encoding: str | None = None) -> str:
        raise OSError(f"{self.path}: a bag is not text")

    def __truediv__(self, key: object) -> Path:
        return self.path / str(key)

    def __str__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"_RebuiltBagPath({str(self.path)!r})"


def _describe(exc: BaseException) -> str:
    """What an exception from a bag reading library says is wrong with the bag, in words (one line)."""
    text = " ".join(str(exc).split())
    if len(text) > 240:
        text = text[:240] + "..."
    if type(exc).__name__ == "TypesysError":
        return f"a message definition in it cannot be parsed ({text})"
    if isinstance(exc, AssertionError):
        return "its records do not match its index" + (f" ({text})" if text else "")
    if isinstance(exc, UnicodeDecodeError):
        return "a name or message definition in it is not UTF-8 text"
    if isinstance(exc, struct.error):
        return f"a record in it is cut short or malformed ({text})"
    if isinstance(exc, IndexError):
        return "a record in it points past the end of its data" + (f" ({text})" if text else "")
    if isinstance(exc, KeyError):
        return f"it refers to a connection, channel or schema it does not define ({text})"
    if isinstance(exc, MemoryError | OverflowError):
        return "a record in it claims an impossible size"
    if type(exc).__module__.split(".")[0] in ("zlib", "zstandard", "lz4", "_bz2", "bz2", "_lzma"):
        return f"a compressed chunk in it cannot be decompressed ({text or type(exc).__name__})"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return text or f"it cannot be read ({type(exc).__name__})"


def _is_ros1(p: Path) -> bool:
    return p.is_file() and p.suffix == ".bag"


def _index_adds_up(reader: Any) -> bool:
    """Whether a ROS1 bag's index data holds as many messages as its chunk infos count."""
    try:
        bag = reader.readers[0]
        counted: dict[int, int] = {}
        for info in bag.chunk_infos:
            for conn, n in info.connection_counts.items():
                counted[conn] = counted.get(conn, 0) + n
        return all(len(bag.indexes.get(c.id, ())) == counted.get(c.id, 0) for c in bag.connections)
    except (AttributeError, IndexError, TypeError):  # a rosbags that lays out its index differently
        return True


def _open_rebuilt(p: Path, why: str, trust_index: bool = True) -> Any:
    """rosbags' reader on a ROS1 bag whose own index it could not use (``why``), through the index as ROS
    reads it or rebuilt from the chunks (:func:`_ros1_index`); roslib/Header is read as std_msgs/Header."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    index = _ros1_index(p, why, trust_index)
    log.info("%s: %s", p, index.how)
    try:
        reader = AnyReader([_RebuiltBagPath(p, index)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))  # type: ignore[list-item]
        reader.open()
    except Exception as exc:
        if not index.rebuilt:  # the connection records inside the chunks may be whole where the index's are not
            log.debug("%s: cannot read it through its own index either (%r)", p, exc)
            return _open_rebuilt(p, f"reading through its own index failed: {_describe(exc)}", trust_index=False)
        raise BagError(f"{p}: cannot open bag ({_describe(exc)})") from None
    return reader


def _open_reader(p: Path) -> Any:
    """rosbags' ``AnyReader`` on the bag ``p``, opened; :class:`BagError` when it cannot be read.

    A ROS1 bag whose index is as ROS writes it is read through :class:`~semmap.io.fastbag.Ros1Reader` (no
    per-message index); any other goes through rosbags' own reader, and the repairs around it.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    table = fastbag.ros1_table(p) if _is_ros1(p) else None
    try:
        reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        if table is not None:
            reader.readers = [fastbag.Ros1Reader(p, table)]  # type: ignore[assignment]  # duck-typed
        reader.open()
    except Exception as exc:
        if not _is_ros1(p):
            raise BagError(f"{p}: cannot open bag ({_describe(exc)})") from None
        log.debug("%s: rosbags cannot open it (%r); reading it as ROS does", p, exc)
        return _open_rebuilt(p, f"rosbags could not: {_describe(exc)}")
    if _is_ros1(p) and table is None and not _index_adds_up(reader):
        reader.close()
        return _open_rebuilt(p, "its index data and chunk infos count different messages", trust_index=False)
    return reader


def _rebuilt_index_note(path: str | Path) -> str | None:
    """How semmap reads a ROS1 bag whose own index rosbags cannot use (None for any other bag)."""
    p = resolve_bag_path(path)
    if not _is_ros1(p):
        return None
    st = p.stat()
    index = _REBUILT.get((str(p.resolve()), st.st_size, st.st_mtime_ns, st.st_ino))
    return None if index is None else index.how


@contextmanager
def open_bag(path: str | Path) -> Iterator[Any]:
    """Open a bag with rosbags' ``AnyReader``; errors become :class:`BagError`.

    A ROS1 bag whose index rosbags cannot use (a 2010-era bag with wrong index data lengths, a bag
    never closed, a damaged index) is read through its index as ROS's own reader reads it, or
    through an index rebuilt from its chunks as ``rosbag reindex`` would (in memory; nothing is
    written). Message definitions naming ``roslib/Header`` are read as ``std_msgs/Header``.
    """
    p = resolve_bag_path(path)
    reader = _open_reader(p)
    try:
        yield reader
    finally:
        try:
            reader.close()
        except Exception:
            log.debug("closing %s failed", p, exc_info=True)


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: type, message count, time span (bag time) and mean rate."""

    name: str
    msgtype: str
    count: int
    first_ns: int | None
    last_ns: int | None

    @property
    def rate_hz(self) -> float | None:
        if self.count < 2 or self.first_ns is None or self.last_ns is None:
            return None
        span = (self.last_ns - self.first_ns) * 1e-9
        return (self.count - 1) / span if span > 0 else None

    def as_dict(self) -> dict[str, Any]:
        return {
            "topic": self.name,
            "type": self.msgtype,
            "count": self.count,
            "rate_hz": None if self.rate_hz is None else round(self.rate_hz, 4),
            "first_ns": self.first_ns,
            "last_ns": self.last_ns,
        }


@dataclass(frozen=True)
class BagInfo:
    """What ``semmap info`` reports about a bag."""

    path: Path
    storage: str
    size_bytes: int
    start_ns: int | None
    end_ns: int | None
    message_count: int
    topics: tuple[TopicInfo, ...] = field(default_factory=tuple)
    #: how a ROS1 bag whose own index rosbags cannot use was read (None: through its own index)
    index_note: str | None = None

    @property
    def duration_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) * 1e-9

    def topic(self, name: str) -> TopicInfo:
        for t in self.topics:
            if t.name == name:
                return t
        raise KeyError(name)

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "storage": self.storage,
            "size_bytes": self.size_bytes,
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "duration_s": round(self.duration_s, 6),
            "message_count": self.message_count,
            "topics": [t.as_dict() for t in self.topics],
            **({"index_note": self.index_note} if self.index_note else {}),
        }


def _storage_name(p: Path) -> str:
    if p.is_file():
        return "ros1"
    if any(p.glob("*.mcap")):
        return "ros2 (mcap)"
    if any(p.glob("*.db3")):
        return "ros2 (sqlite3)"
    return "ros2"


def _size(p: Path) -> int:
    if p.is_file():
        return p.stat().st_size
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())


def _rebuilt_from_chunks(reader: Any) -> bool:
    """Whether ``reader`` reads a ROS1 bag through an index rebuilt from its chunks."""
    paths: Sequence[Any] = getattr(reader, "paths", ())
    return bool(paths) and isinstance(paths[0], _RebuiltBagPath) and paths[0].rebuilt


def _unreadable(p: Path, exc: BaseException) -> BagError:
    return BagError(f"{p}: bag is unreadable or truncated ({_describe(exc)})")


def _summary(reader: Any) -> tuple[dict[str, str], dict[str, int], dict[str, int], dict[str, int]]:
    """Topic types, message counts and first and last bag times, from reading every message's record."""
    names: dict[str, str] = {}
    for conn in reader.connections:
        names.setdefault(conn.topic, conn.msgtype)
    counts = dict.fromkeys(names, 0)
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for conn, t_ns, _raw in reader.messages():
        topic = conn.topic
        counts[topic] += 1
        if topic not in first or t_ns < first[topic]:
            first[topic] = t_ns
        if topic not in last or t_ns > last[topic]:
            last[topic] = t_ns
    return names, counts, first, last


def bag_info(path: str | Path) -> BagInfo:
    """Topics, message types, counts, rates and the time span of a bag.

    Works on ROS1 ``.bag`` and ROS2 sqlite3/mcap bags, including bags written by ROS
    itself. Counts and spans come from reading every message's bag timestamp. A ROS1 bag whose
    index does not lead to its messages is read through an index rebuilt from its chunks.
    """
    p = resolve_bag_path(path)
    failure: Exception | None = None
    with open_bag(p) as reader:
        try:
            names, counts, first, last = _summary(reader)
        except Exception as exc:
            failure = exc
            if not _is_ros1(p) or _rebuilt_from_chunks(reader):
                raise _unreadable(p, exc) from None
    if failure is not None:
        log.debug("%s: reading through its index failed (%r); rebuilding it from the chunks", p, failure)
        reader = _open_rebuilt(p, f"reading through its own index failed: {_describe(failure)}", trust_index=False)
        try:
            names, counts, first, last = _summary(reader)
        except Exception as exc:
            raise _unreadable(p, exc) from None
        finally:
            reader.close()
    topics = tuple(
        TopicInfo(n, names[n], counts[n], first.get(n), last.get(n)) for n in sorted(names)
    )
    total = sum(counts.values())
    return BagInfo(
        path=p,
        storage=_storage_name(p),
        size_bytes=_size(p),
        start_ns=min(first.values()) if first else None,
        end_ns=max(last.values()) if last else None,
        message_count=total,
        topics=topics,
        index_note=_rebuilt_index_note(p),
    )


def topic_types(path: str | Path) -> dict[str, str]:
    """Topic → message type (``sensor_msgs/msg/LaserScan`` style), without reading messages."""
    with open_bag(path) as reader:
        out: dict[str, str] = {}
        for conn in reader.connections:
            out.setdefault(conn.topic, conn.msgtype)
        return out


def message_count(path: str | Path, topic: str, reader: Any = None) -> int:
    """Messages on ``topic`` as the bag's index counts them (0 if the storage does not say).

    ``reader``: the bag already opened with :func:`open_bag` (else it is opened here).
    """
    if reader is not None:
        return sum(max(c.msgcount, 0) for c in reader.connections if c.topic == topic)
    with open_bag(path) as opened:
        return message_count(path, topic, opened)


class OpenBag:
    """A bag opened once (:func:`read_bag`): its topics and their types, message counts, time span,
    and streams of its messages, each read from the same opened reader (for a ROS1 bag, one table
    of its chunks, or one index rosbags parsed)."""

    def __init__(self, path: str | Path, stack: contextlib.ExitStack) -> None:
        self._given = path
        self._stack = stack
        self._path: Path | None = None
        self._opened: Any = None
        self._closed = False
        self._types: dict[str, str] | None = None

    @property
    def path(self) -> Path:
        """The bag file or ROS2 bag folder."""
        if self._path is None:
            self._path = resolve_bag_path(self._given)
        return self._path

    @property
    def _reader(self) -> Any:
        if self._opened is None:
            if self._closed:
                raise BagError(f"{self.path}: the bag was closed")
            self._opened = self._stack.enter_context(open_bag(self.path))
        return self._opened

    def close(self) -> None:
        """Close the bag now (else when :func:`read_bag`'s block ends)."""
        self._closed = True
        self._opened = None
        self._stack.close()

    @property
    def types(self) -> dict[str, str]:
        """Topic -> message type (``sensor_msgs/msg/LaserScan`` style)."""
        if self._types is None:
            self._types = {}
            for conn in self._reader.connections:
                self._types.setdefault(conn.topic, conn.msgtype)
        return self._types

    @property
    def start_ns(self) -> int:
        """The bag time of its first message (as the storage's index gives it)."""
        return int(self._reader.start_time)

    @property
    def end_ns(self) -> int:
        """The bag time just after its last message (as the storage's index gives it)."""
        return int(self._reader.end_time)

    def count(self, topic: str) -> int:
        """Messages on ``topic`` as the bag's index counts them (0 if the storage does not say)."""
        return message_count(self.path, topic, self._reader)

    def messages(self, topics: Sequence[str], stats: ReadStats | None = None) -> Iterator[tuple[str, int, Any]]:
        """``(topic, bag time, message)`` of ``topics`` in bag-time order (:func:`iter_messages`); the
        messages are rosbags' objects, for :mod:`semmap.io` (elsewhere, :meth:`records`)."""
        return iter_messages(self.path, topics, stats, self._reader)

    def first(self, topic: str) -> Any:
        """The first message on ``topic`` (rosbags' object); :class:`BagError` when there is none."""
        for _, _, msg in self.messages([topic]):
            return msg
        raise BagError(f"{self.path}: topic {topic} has no messages")

    def records(self, topics: Sequence[str], stats: ReadStats | None = None, start_ns: int | None = None,
                stop_ns: int | None = None, skip: Callable[[str, SemmapError], None] | None = None,
                ) -> Iterator[tuple[str, int, Any]]:
        """``(topic, bag time, record)`` of ``topics`` in bag-time order, each message as the semmap record
        for its type (:func:`~semmap.io.messages.record_from_msg`), from bag time ``start_ns`` (messages
        before it are not decoded) to ``stop_ns`` (both included). ``skip``: a message that cannot be
        decoded is handed to it (topic, error) and left out; without it, the error is raised."""
        from .messages import record_from_msg

        for topic, t_ns, msg in self.messages(topics, stats):
            if start_ns is not None and t_ns < start_ns:
                continue
            if stop_ns is not None and t_ns > stop_ns:
                return
            try:
                record = record_from_msg(self.types[topic], msg, topic)
            except SemmapError as exc:
                if skip is None:
                    raise
                skip(topic, exc)
                continue
            yield topic, t_ns, record

    def nearest(self, topic: str, t_ns: int) -> tuple[int, Any] | None:
        """``(bag time, record)`` of the message on ``topic`` nearest bag time ``t_ns`` (only that one is
        decoded); None when the topic has no messages."""
        from .messages import record_from_msg

        best: tuple[int, Any] | None = None
        for _, t_msg, msg in self.messages([topic]):
            if best is None or abs(t_msg - t_ns) < abs(best[0] - t_ns):
                best = (t_msg, msg)
            elif t_msg > t_ns:
                break
        return None if best is None else (best[0], record_from_msg(self.types[topic], best[1], topic))

    def nearest_stamp(self, topic: str, stamp_ns: int, within_ns: int, until_ns: int) -> Any:
        """The record of the message on ``topic`` whose header stamp is nearest ``stamp_ns`` and within
        ``within_ns`` of it (only that one is decoded), read up to bag time ``until_ns``; None if none is."""
        from .messages import record_from_msg
        from .messages import stamp_ns as header_stamp

        best, best_dt = None, within_ns + 1
        for _, t_msg, msg in self.messages([topic]):
            dt = abs(header_stamp(msg.header) - stamp_ns)
            if dt < best_dt:
                best, best_dt = msg, dt
            if t_msg > until_ns:
                break
        return None if best is None else record_from_msg(self.types[topic], best, topic)


@contextmanager
def read_bag(path: str | Path, lazy: bool = False) -> Iterator[OpenBag]:
    """The bag at ``path`` (or in the tour folder ``path``) opened once, as an :class:`OpenBag`, and
    closed when the block ends; errors become :class:`BagError` naming the file. ``lazy``: the bag is
    found and opened when first used (its errors come when the work that needs it starts)."""
    with contextlib.ExitStack() as stack:
        bag = OpenBag(path, stack)
        if not lazy:
            bag.types  # noqa: B018 - opens it
        yield bag


def iter_records(path: str | Path, topics: Sequence[str],
                 stats: ReadStats | None = None) -> Iterator[tuple[str, int, Any]]:
    """``(topic, bag time, record)`` of ``topics`` of the bag at ``path`` (:meth:`OpenBag.records`), opened
    for as long as the stream lasts."""
    with read_bag(path) as bag:
        yield from bag.records(topics, stats)


@dataclass
class ReadStats:
    """Messages read and skipped per topic while streaming a bag."""

    read: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)


def iter_messages(path: str | Path, topics: Sequence[str], stats: ReadStats | None = None,
                  reader: Any = None) -> Iterator[tuple[str, int, Any]]:
    """Stream ``(topic, bag_time_ns, message)`` for the given topics in bag-time order.

    Messages are deserialised one at a time, so memory does not grow with the bag.
    A message that fails to deserialise is skipped and counted in ``stats.skipped``.
    ``reader``: the bag already opened with :func:`open_bag` (else it is opened here).
    """
    stats = stats if stats is not None else ReadStats()
    p = resolve_bag_path(path)
    if reader is not None:
        yield from _stream(reader, p, topics, stats)
        return
    with open_bag(p) as opened:
        yield from _stream(opened, p, topics, stats)


def _deserialize(reader: Any, p: Path, conn: Any, raw: Any, stats: ReadStats) -> Any:
    """The message, or None (counted in ``stats.skipped``) when its bytes do not fit its type."""
    try:
        msg = reader.deserialize(raw, conn.msgtype)
    except Exception as exc:
        stats.skipped[conn.topic] = stats.skipped.get(conn.topic, 0) + 1
        log.debug("%s: skipped a message on %s (%s)", p, conn.topic, _describe(exc))
        return None
    stats.read[conn.topic] = stats.read.get(conn.topic, 0) + 1
    return msg


def _stream(reader: Any, p: Path, topics: Sequence[str], stats: ReadStats) -> Iterator[tuple[str, int, Any]]:
    wanted = set(topics)
    conns = [c for c in reader.connections if c.topic in wanted]
    if not conns:
        return
    last: int | None = None  # bag time of the last record read, and how many records were read at that time
    at_last = 0
    fast = False  # read by semmap's own reader (:mod:`semmap.io.fastbag`)
    try:
        records = fastbag.ros1_records(reader, conns) or fastbag.mcap_records(reader, conns)
        fast = records is not None or fastbag.reads(reader)
        for conn, t_ns, raw in records if records is not None else reader.messages(connections=conns):
            last, at_last = (t_ns, at_last + 1) if t_ns == last else (t_ns, 1)
            msg = _deserialize(reader, p, conn, raw, stats)
            if msg is not None:
                yield conn.topic, t_ns, msg
        return
    except SemmapError:
        raise
    except Exception as exc:
        if fast and not isinstance(exc, fastbag.not_understood()):
            raise  # a bug in semmap's own reader, not a bag it cannot read: never hidden behind the fallback
        failure = exc
    if not _is_ros1(p) or _rebuilt_from_chunks(reader):
        raise _unreadable(p, failure)
    # a ROS1 bag whose index does not lead to its messages: go on through an index rebuilt from its chunks
    (log.info if fast else log.debug)("%s: reading through its index failed (%r); rebuilding it from the chunks "
                                      "and reading it through rosbags' reader", p, failure)
    rebuilt = _open_rebuilt(p, f"reading through its own index failed: {_describe(failure)}", trust_index=False)
    try:
        conns = [c for c in rebuilt.connections if c.topic in wanted]
        for conn, t_ns, raw in rebuilt.messages(connections=conns) if conns else ():  # (none: rosbags reads all)
            if last is not None and (t_ns < last or (t_ns == last and at_last > 0)):
                at_last -= t_ns == last  # read before the failure
                continue
            msg = _deserialize(rebuilt, p, conn, raw, stats)
            if msg is not None:
                yield conn.topic, t_ns, msg
    except SemmapError:
        raise
    except Exception as exc:
        raise _unreadable(p, exc) from None
    finally:
        rebuilt.close()
