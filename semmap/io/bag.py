"""The one rosbags adapter: writing and reading ROS1 ``.bag`` and ROS2 (mcap, sqlite3) bags.

Nothing else in semmap imports :mod:`rosbags`. The writer takes semmap records
and plain numbers and serialises real ROS messages; the reader side gives
:func:`bag_info` (what ``semmap info`` prints) and raw message iteration.
"""

from __future__ import annotations

import heapq
import io
import logging
import mmap
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from ..errors import BagError
from ..geometry import se3_to_translation_quaternion, yaw_to_quaternion
from ..records import CameraIntrinsics, Image, Scan

__all__ = [
    "BagFormat",
    "BAG_FORMATS",
    "BagWriter",
    "TopicInfo",
    "BagInfo",
    "bag_info",
    "open_bag",
    "resolve_bag_path",
    "bag_suffix",
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
            except Exception:  # noqa: BLE001 - already failing; keep the original error
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
        pose: Sequence[float],
        twist: Sequence[float],
        pose_cov_diag: Sequence[float] = (0.0,) * 6,
        twist_cov_diag: Sequence[float] = (0.0,) * 6,
    ) -> None:
        """Write a planar ``nav_msgs/Odometry``: pose (x, y, yaw), twist (vx, vy, wz) in the child frame."""
        typ = "nav_msgs/msg/Odometry"
        t = self._types
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
    raise BagError(f"{p}: folder holds several bags ({names}); name one")


@contextmanager
def open_bag(path: str | Path) -> Iterator[Any]:
    """Open a bag with rosbags' ``AnyReader``; errors become :class:`BagError`."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    p = resolve_bag_path(path)
    try:
        reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        raise BagError(f"{p}: cannot open bag ({exc})") from None
    try:
        yield reader
    finally:
        reader.close()


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


def bag_info(path: str | Path) -> BagInfo:
    """Topics, message types, counts, rates and the time span of a bag.

    Works on ROS1 ``.bag`` and ROS2 sqlite3/mcap bags, including bags written by ROS
    itself. Counts and spans come from reading every message's bag timestamp.
    """
    from rosbags.highlevel import AnyReaderError

    p = resolve_bag_path(path)
    with open_bag(p) as reader:
        names: dict[str, str] = {}
        for conn in reader.connections:
            names.setdefault(conn.topic, conn.msgtype)
        counts = dict.fromkeys(names, 0)
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        try:
            for conn, t_ns, _raw in reader.messages():
                topic = conn.topic
                counts[topic] += 1
                if topic not in first or t_ns < first[topic]:
                    first[topic] = t_ns
                if topic not in last or t_ns > last[topic]:
                    last[topic] = t_ns
        except Exception as exc:  # noqa: BLE001 - rosbags raises a different error per storage
            if isinstance(exc, AnyReaderError | OSError | ValueError | KeyError | EOFError) or (
                type(exc).__module__.startswith("rosbags")
            ):
                raise BagError(f"{p}: bag is unreadable or truncated ({exc})") from None
            raise
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


@dataclass
class ReadStats:
    """Messages read and skipped per topic while streaming a bag."""

    read: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)


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
            end = start - start % mmap.PAGESIZE
            self.mapped.madvise(mmap.MADV_DONTNEED, self._released, end - self._released)
            self._released = end
        return self._view[start:start + size]


def _ros1_records(reader: Any, conns: Sequence[Any]) -> Iterator[tuple[Any, int, bytes | memoryview]] | None:
    """The messages of ``conns`` in an uncompressed ROS1 bag, each read on its own; None for other bags.

    rosbags reads every chunk that holds a wanted message whole, so reading a scan stored beside
    camera images costs the images' bytes as well (a 1.5 MB chunk for a 5 kB scan, and the
    LiDAR, odometry and camera topics are each read by another process). In an uncompressed
    chunk, the bag's index gives each message's offset, so only its own record need be read.
    The bag is mapped into memory where it can be: a message's bytes are then a read-only view
    of the file (a camera frame is not copied on its way to the frame's consumer), and pages read
    past are handed back every few MB, so the process does not hold the whole bag.

    None (rosbags' own path) for compressed chunks (bz2, lz4), for chunks that hold mostly
    wanted bytes (a LiDAR-only bag), and with a rosbags that lays out its parsed index and
    record helpers, which this reads, differently.
    """
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
    except (ImportError, AttributeError, KeyError, TypeError):
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


def _mcap_records(reader: Any, conns: Sequence[Any]) -> Iterator[tuple[Any, int, bytes | memoryview]] | None:
    """The messages of ``conns`` in a ROS2 MCAP bag with uncompressed chunks, each read on its own;
    None for other bags.

    As for ROS1 (:func:`_ros1_records`): rosbags reads every chunk that holds a wanted message
    whole, but each chunk's message index gives the offset of every message of a channel in it,
    so only the wanted records are read (views of the mapped file). The order is rosbags': by log
    time, then by chunk, then as stored. None (rosbags' own path) for compressed chunks or messages,
    several storage files, files without chunk and message indexes, chunks that hold mostly wanted
    bytes, and a rosbags that lays out its parsed index differently.
    """
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
    except (ImportError, AttributeError, KeyError, TypeError):
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

    def records() -> Iterator[tuple[Any, int, bytes | memoryview]]:
        data = _Bytes(bio)
        start_of = {c.chunk_start_offset: c.chunk_start_offset + 9 + 40 + len(c.compression) for c in chunks}
        for log_time, chunk_at, offset, cid in heapq.merge(*(chunk_entries(data, c) for c in chunks)):
            if offset < 0:
                continue
            data.src.seek(start_of[chunk_at] + offset)
            head = data.src.read(9)  # op, record length
            if len(head) != 9 or head[0] != 0x05:
                raise error(f"no message record at chunk {chunk_at} offset {offset}")
            size = int.from_bytes(head[1:9], "little")
            data.src.seek(22, os.SEEK_CUR)  # channel, sequence, log and publish time
            yield wanted[cid], log_time, data.take(size - 22, error)

    return records()


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


def _stream(reader: Any, p: Path, topics: Sequence[str], stats: ReadStats) -> Iterator[tuple[str, int, Any]]:
    from rosbags.highlevel import AnyReaderError

    conns = [c for c in reader.connections if c.topic in set(topics)]
    try:
        records = (_ros1_records(reader, conns) or _mcap_records(reader, conns)) if conns else None
        for conn, t_ns, raw in records if records is not None else reader.messages(connections=conns):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except (AnyReaderError, ValueError, IndexError, KeyError) as exc:
                stats.skipped[conn.topic] = stats.skipped.get(conn.topic, 0) + 1
                log.debug("%s: skipped a message on %s (%s)", p, conn.topic, exc)
                continue
            stats.read[conn.topic] = stats.read.get(conn.topic, 0) + 1
            yield conn.topic, t_ns, msg
    except Exception as exc:  # noqa: BLE001 - storage errors differ per rosbags backend
        if isinstance(exc, AnyReaderError | OSError | EOFError) or type(exc).__module__.startswith("rosbags"):
            raise BagError(f"{p}: bag is unreadable or truncated ({exc})") from None
        raise
