"""ROS messages (as rosbags deserialises them) → semmap records.

Field names follow the ROS message definitions; ROS1 and ROS2 differ only where
the definitions do (``CameraInfo.D/K`` vs ``d/k``, ``Header.seq``).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import BagError
from ..geometry import quaternion_to_yaw, se3_from_translation_quaternion
from ..records import CameraIntrinsics, Image, Scan
from .topics import COMPRESSED_T, IMAGE_T, INFO_T, ODOM_T, SCAN_T, TF_TYPES

__all__ = [
    "LABEL_ENCODINGS",
    "camera_info_from_msg",
    "compressed_image_from_msg",
    "decode_image",
    "image_from_msg",
    "odometry_from_msg",
    "record_from_msg",
    "scan_from_msg",
    "stamp_ns",
    "transforms_from_msg",
]

log = logging.getLogger(__name__)

#: no 2D LiDAR sees this far: a larger ``range_max`` is a damaged field, and readings beyond are invalid
MAX_RANGE_M = 1000.0
#: no sweep of a 2D LiDAR takes longer (unless its ``scan_time`` says so): a ``time_increment`` that
#: makes the beams span more is a damaged field, taken as unknown (0)
MAX_SWEEP_S = 1.0
#: a planar position or translation farther from its frame's origin than Earth is wide is a damaged field
MAX_COORD_M = 1.3e7

#: encodings a label image may use (see docs/conventions.md, "Label images")
LABEL_ENCODINGS = {"mono8", "8UC1", "mono16", "16UC1"}

_CHANNELS = {
    "rgb8": (3, np.uint8), "bgr8": (3, np.uint8), "rgba8": (4, np.uint8), "bgra8": (4, np.uint8),
    "mono8": (1, np.uint8), "8UC1": (1, np.uint8), "mono16": (1, np.uint16), "16UC1": (1, np.uint16),
    "8UC3": (3, np.uint8), "32FC1": (1, np.float32),
}


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header`` stamp as integer nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


_warned: set[str] = set()


def _damaged(key: str, text: str, *args: object) -> None:
    """Log a damaged field once per kind (a bag with one usually has many)."""
    if key not in _warned:
        _warned.add(key)
        log.warning(text + " (reported once)", *args)


def scan_from_msg(msg: Any, topic: str = "") -> Scan:
    """A ``sensor_msgs/LaserScan`` as a :class:`Scan`, its damaged fields made harmless.

    Readings keep their REP-117 meaning. Fields no LiDAR can report (from a damaged bag) are not
    passed on as they are: a scan whose angles are not finite numbers within a turn has no readings
    (builds count it as a bad scan); a ``range_max`` beyond :data:`MAX_RANGE_M` (or not finite)
    becomes that limit, so readings beyond it are invalid; a ``time_increment`` whose beams would
    span more than the scan period (at least :data:`MAX_SWEEP_S`) and a ``scan_time`` that is not a
    finite, non-negative number become 0 (unknown); intensities that do not pair with the ranges are
    dropped. Each is logged once, naming the topic and the field.
    """
    where = topic or "a LaserScan"
    ranges = np.asarray(msg.ranges, dtype=np.float32)
    n = int(ranges.size)
    angle_min, angle_inc = float(msg.angle_min), float(msg.angle_increment)
    if n and not (math.isfinite(angle_min) and math.isfinite(angle_inc) and abs(angle_min) <= 2 * math.pi
                  and abs(angle_inc) * (n - 1) <= 2 * math.pi + 1e-3):
        _damaged(f"{topic}:angles", "%s: a scan's angles (angle_min %g, angle_increment %g, %d beams) are not "
                 "within a turn; such scans are skipped", where, angle_min, angle_inc, n)
        ranges = ranges[:0]
        n = 0
    range_min, range_max = float(msg.range_min), float(msg.range_max)
    if not (math.isfinite(range_min) and range_min >= 0):
        _damaged(f"{topic}:range_min", "%s: range_min %g is not a distance; taken as 0", where, range_min)
        range_min = 0.0
    if not range_max <= MAX_RANGE_M:  # NaN included
        _damaged(f"{topic}:range_max", "%s: range_max %g m is beyond any 2D LiDAR; readings past %g m are taken "
                 "as invalid", where, range_max, MAX_RANGE_M)
        range_max = MAX_RANGE_M
    scan_time = float(msg.scan_time)
    if not (math.isfinite(scan_time) and scan_time >= 0):
        _damaged(f"{topic}:scan_time", "%s: scan_time %g s is not a time; taken as 0 (unknown)", where, scan_time)
        scan_time = 0.0
    time_inc = float(msg.time_increment)
    if not (math.isfinite(time_inc) and abs(time_inc) * max(n - 1, 0) <= max(MAX_SWEEP_S, scan_time)):
        _damaged(f"{topic}:time_increment", "%s: time_increment %g s would make a sweep of %d beams last longer "
                 "than a scan; taken as 0 (unknown)", where, time_inc, n)
        time_inc = 0.0
    intensities = np.asarray(msg.intensities, dtype=np.float32) if len(msg.intensities) else None
    if intensities is not None and intensities.size != n:
        _damaged(f"{topic}:intensities", "%s: %d intensities for %d ranges; dropped", where, intensities.size, n)
        intensities = None
    return Scan(
        stamp_ns=stamp_ns(msg.header),
        frame_id=str(msg.header.frame_id).lstrip("/"),
        angle_min=angle_min,
        angle_increment=angle_inc,
        ranges=ranges,
        range_min=range_min,
        range_max=range_max,
        time_increment=time_inc,
        scan_time=scan_time,
        intensities=intensities,
    )


def image_from_msg(msg: Any, topic: str = "") -> Image:
    """Decode a raw ``sensor_msgs/Image`` (row padding and endianness handled)."""
    enc = str(msg.encoding)
    if enc not in _CHANNELS:
        raise BagError(f"{topic}: unsupported image encoding {enc!r}")
    ch, dtype = _CHANNELS[enc]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise BagError(f"{topic}: an image of {w}x{h} pixels (height or width 0)")
    buf = np.asarray(msg.data, dtype=np.uint8)
    row_bytes = w * ch * dt.itemsize
    if step < row_bytes:
        raise BagError(f"{topic}: image step {step} is shorter than a row of {w} {enc} pixels ({row_bytes} bytes)")
    if buf.size < step * h:
        raise BagError(f"{topic}: image data ({buf.size} bytes) is shorter than height x step ({h} x {step}) "
                       f"for {w}x{h} {enc}")
    rows = buf[: step * h].reshape(h, step)[:, :row_bytes]
    arr = np.ascontiguousarray(rows).view(dt).reshape(h, w, ch) if ch > 1 else \
        np.ascontiguousarray(rows).view(dt).reshape(h, w)
    arr = arr.astype(dt.newbyteorder("="), copy=False)
    if enc in ("bgr8", "8UC3"):
        arr, enc = arr[:, :, ::-1], "rgb8"
    elif enc == "bgra8":
        arr, enc = arr[:, :, 2::-1], "rgb8"
    elif enc == "rgba8":
        arr, enc = arr[:, :, :3], "rgb8"
    return Image(stamp_ns(msg.header), str(msg.header.frame_id).lstrip("/"), np.ascontiguousarray(arr), enc)


def compressed_image_from_msg(msg: Any, topic: str = "") -> Image:
    """Decode a ``sensor_msgs/CompressedImage`` (JPEG or PNG) to rgb8, or mono for 1-channel PNGs."""
    data = np.asarray(msg.data, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise BagError(f"{topic}: cannot decode compressed image (format {msg.format!r})")
    if img.ndim == 2:
        enc = "mono16" if img.dtype == np.uint16 else "mono8"
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
        enc = "rgb8"
    return Image(stamp_ns(msg.header), str(msg.header.frame_id).lstrip("/"), img, enc)


def decode_image(msg: Any, msgtype: str, topic: str = "") -> Image:
    """The one image decoder: a ``sensor_msgs/Image`` (:func:`image_from_msg`) or
    ``sensor_msgs/CompressedImage`` (:func:`compressed_image_from_msg`) as an :class:`Image`
    (rgb8 for colour, mono8/mono16 (and 32FC1) for one channel); errors are :class:`BagError`."""
    if msgtype == COMPRESSED_T:
        return compressed_image_from_msg(msg, topic)
    if msgtype == IMAGE_T:
        return image_from_msg(msg, topic)
    raise BagError(f"{topic}: {msgtype} is not an image type")


def record_from_msg(msgtype: str, msg: Any, topic: str = "") -> Any:
    """A message of one of the types semmap reads as the semmap record (or plain data) for it:
    :class:`Scan`, :class:`Image`, :func:`odometry_from_msg`'s tuple, :func:`transforms_from_msg`'s
    list, :class:`CameraIntrinsics`."""
    if msgtype == SCAN_T:
        return scan_from_msg(msg, topic)
    if msgtype in (IMAGE_T, COMPRESSED_T):
        return decode_image(msg, msgtype, topic)
    if msgtype == ODOM_T:
        return odometry_from_msg(msg, topic)
    if msgtype in TF_TYPES:  # tf2's, or ROS1's older tf/tfMessage
        return transforms_from_msg(msg, topic)
    if msgtype == INFO_T:
        return camera_info_from_msg(msg)
    raise BagError(f"{topic}: semmap does not read {msgtype} messages")


def _sane(values: list[float]) -> bool:
    return all(math.isfinite(v) and abs(v) <= MAX_COORD_M for v in values)


def odometry_from_msg(msg: Any, topic: str = "") -> tuple[int, str, str, NDArray[np.float64]]:
    """(stamp, frame_id, child_frame_id, pose (x, y, yaw)) of a ``nav_msgs/Odometry``.

    A position that is not finite or farther than :data:`MAX_COORD_M` (a damaged field) gives an
    all-NaN pose, logged once; a quaternion that is not finite gives a NaN yaw.
    """
    p = msg.pose.pose
    q = p.orientation
    yaw = quaternion_to_yaw([q.x, q.y, q.z, q.w])
    pose = np.array([p.position.x, p.position.y, yaw], dtype=np.float64)
    if not _sane([float(p.position.x), float(p.position.y)]):
        _damaged(f"{topic}:position", "%s: an odometry position (%g, %g) is not a place on Earth; "
                 "such poses are not used", topic or "Odometry", float(p.position.x), float(p.position.y))
        pose[:] = np.nan
    return (stamp_ns(msg.header), str(msg.header.frame_id).lstrip("/"), str(msg.child_frame_id).lstrip("/"), pose)


def transforms_from_msg(msg: Any, topic: str = "") -> list[tuple[int, str, str, NDArray[np.float64]]]:
    """(stamp, parent, child, T_parent_child) for each transform of a ``tf2_msgs/TFMessage`` (or of the
    ``tf/tfMessage`` of older ROS1 bags, which has the same fields).

    A transform with a translation that is not finite or farther than :data:`MAX_COORD_M`, or a
    rotation quaternion that is not finite or has (nearly) zero length, is damaged: it is left out,
    logged once naming it and the field.
    """
    out = []
    for t in msg.transforms:
        tr, q = t.transform.translation, t.transform.rotation
        parent, child = str(t.header.frame_id).lstrip("/"), str(t.child_frame_id).lstrip("/")
        trans = [float(tr.x), float(tr.y), float(tr.z)]
        quat = [float(q.x), float(q.y), float(q.z), float(q.w)]
        norm = math.sqrt(sum(v * v for v in quat)) if all(math.isfinite(v) for v in quat) else math.nan
        if not _sane(trans) or not norm > 1e-6:
            field = "translation" if not _sane(trans) else "rotation"
            _damaged(f"{topic}:{parent}:{child}", "%s: the transform %s -> %s has a damaged %s (%s); left out",
                     topic or "TFMessage", parent, child, field, trans if field == "translation" else quat)
            continue
        mat = se3_from_translation_quaternion(trans, quat)
        out.append((stamp_ns(t.header), parent, child, mat))
    return out


def camera_info_from_msg(msg: Any) -> CameraIntrinsics:
    """Intrinsics of a ``sensor_msgs/CameraInfo`` (ROS1 ``D/K`` or ROS2 ``d/k``)."""
    k = np.asarray(getattr(msg, "K", None) if hasattr(msg, "K") else msg.k, dtype=np.float64).reshape(3, 3)
    d = np.asarray(getattr(msg, "D", None) if hasattr(msg, "D") else msg.d, dtype=np.float64)
    model = "fisheye" if str(msg.distortion_model) in ("equidistant", "fisheye") else "pinhole"
    if model == "pinhole" and d.size not in (4, 5, 8, 12, 14):
        d = np.zeros(5)
    return CameraIntrinsics(int(msg.width), int(msg.height), k, d, model)  # type: ignore[arg-type]
