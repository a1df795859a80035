"""ROS messages (as rosbags deserialises them) → semmap records.

Field names follow the ROS message definitions; ROS1 and ROS2 differ only where
the definitions do (``CameraInfo.D/K`` vs ``d/k``, ``Header.seq``).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import BagError
from ..geometry import quaternion_to_yaw, se3_from_translation_quaternion
from ..records import CameraIntrinsics, Image, Scan

__all__ = [
    "stamp_ns",
    "scan_from_msg",
    "image_from_msg",
    "compressed_image_from_msg",
    "odometry_from_msg",
    "transforms_from_msg",
    "camera_info_from_msg",
    "LABEL_ENCODINGS",
]

#: encodings a label image may use (see README, "Label images")
LABEL_ENCODINGS = {"mono8", "8UC1", "mono16", "16UC1"}

_CHANNELS = {
    "rgb8": (3, np.uint8), "bgr8": (3, np.uint8), "rgba8": (4, np.uint8), "bgra8": (4, np.uint8),
    "mono8": (1, np.uint8), "8UC1": (1, np.uint8), "mono16": (1, np.uint16), "16UC1": (1, np.uint16),
    "8UC3": (3, np.uint8), "32FC1": (1, np.float32),
}


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header`` stamp as integer nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def scan_from_msg(msg: Any) -> Scan:
    return Scan(
        stamp_ns=stamp_ns(msg.header),
        frame_id=str(msg.header.frame_id).lstrip("/"),
        angle_min=float(msg.angle_min),
        angle_increment=float(msg.angle_increment),
        ranges=np.asarray(msg.ranges, dtype=np.float32),
        range_min=float(msg.range_min),
        range_max=float(msg.range_max),
        time_increment=float(msg.time_increment),
        scan_time=float(msg.scan_time),
        intensities=np.asarray(msg.intensities, dtype=np.float32) if len(msg.intensities) else None,
    )


def image_from_msg(msg: Any, topic: str = "") -> Image:
    """Decode a raw ``sensor_msgs/Image`` (row padding and endianness handled)."""
    enc = str(msg.encoding)
    if enc not in _CHANNELS:
        raise BagError(f"{topic}: unsupported image encoding {enc!r}")
    ch, dtype = _CHANNELS[enc]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    buf = np.asarray(msg.data, dtype=np.uint8)
    row_bytes = w * ch * dt.itemsize
    if step < row_bytes or buf.size < step * h:
        raise BagError(f"{topic}: image data too short for {w}x{h} {enc}")
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


def odometry_from_msg(msg: Any) -> tuple[int, str, str, NDArray[np.float64]]:
    """(stamp, frame_id, child_frame_id, pose (x, y, yaw)) of a ``nav_msgs/Odometry``."""
    p = msg.pose.pose
    q = p.orientation
    yaw = quaternion_to_yaw([q.x, q.y, q.z, q.w])
    return (stamp_ns(msg.header), str(msg.header.frame_id).lstrip("/"), str(msg.child_frame_id).lstrip("/"),
            np.array([p.position.x, p.position.y, yaw], dtype=np.float64))


def transforms_from_msg(msg: Any) -> list[tuple[int, str, str, NDArray[np.float64]]]:
    """(stamp, parent, child, T_parent_child) for each transform of a ``tf2_msgs/TFMessage``."""
    out = []
    for t in msg.transforms:
        tr, q = t.transform.translation, t.transform.rotation
        mat = se3_from_translation_quaternion([tr.x, tr.y, tr.z], [q.x, q.y, q.z, q.w])
        out.append((stamp_ns(t.header), str(t.header.frame_id).lstrip("/"), str(t.child_frame_id).lstrip("/"), mat))
    return out


def camera_info_from_msg(msg: Any) -> CameraIntrinsics:
    """Intrinsics of a ``sensor_msgs/CameraInfo`` (ROS1 ``D/K`` or ROS2 ``d/k``)."""
    k = np.asarray(getattr(msg, "K", None) if hasattr(msg, "K") else msg.k, dtype=np.float64).reshape(3, 3)
    d = np.asarray(getattr(msg, "D", None) if hasattr(msg, "D") else msg.d, dtype=np.float64)
    model = "fisheye" if str(msg.distortion_model) in ("equidistant", "fisheye") else "pinhole"
    if model == "pinhole" and d.size not in (4, 5, 8, 12, 14):
        d = np.zeros(5)
    return CameraIntrinsics(int(msg.width), int(msg.height), k, d, model)  # type: ignore[arg-type]
