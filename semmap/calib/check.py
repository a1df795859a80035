"""``semmap calibrate check``: draw the scan projected into the image, coloured by range.

A person judges the calibration by eye, as in the middle panel of the research's Fig. 3:
with a good ``T_cam_lidar`` the points sit on the walls, legs and furniture they hit; a bad
one shows them sliding off edges, floating above the floor or bending around corners.

Input: an image and a scan (files, or arrays), or a bag and a time (read through :mod:`semmap.io`,
which picks the topics as ``semmap build`` does and decodes the messages into semmap records).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import BagError, ConfigError
from ..geometry import project_points, se3_apply
from ..records import Calibration, Image, Scan
from .scans import ranges_to_points, read_scan_points

__all__ = ["CheckResult", "check_calibration", "draw_scan_on_image", "frame_from_bag", "read_image"]

log = logging.getLogger(__name__)

_LOW = 20  # skip turbo's near-black end so near points stay visible on dark things


@dataclass(frozen=True)
class CheckResult:
    """What ``check`` drew: the picture (BGR), how many scan points landed in the image, and
    (from a bag) the stamps of the image and the scan used."""

    image: NDArray[np.uint8]
    n_points: int
    n_in_image: int
    image_stamp_ns: int | None = None
    scan_stamp_ns: int | None = None
    out: Path | None = None

    @property
    def offset_s(self) -> float | None:
        if self.image_stamp_ns is None or self.scan_stamp_ns is None:
            return None
        return (self.scan_stamp_ns - self.image_stamp_ns) * 1e-9


def read_image(path: str | Path) -> NDArray[np.uint8]:
    """An image file → BGR uint8; errors name the file."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such image file")
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise ConfigError(f"{p}: not an image OpenCV can read")
    return cast("NDArray[np.uint8]", img)  # IMREAD_COLOR gives 8-bit BGR: cv2's stubs carry no dtype


def _colour_bar(width: int, lo: float, hi: float, cmap: int) -> NDArray[np.uint8]:
    bar_h, pad = 14, 6
    panel = np.full((bar_h + 2 * pad + 14, width, 3), 255, np.uint8)
    ramp = np.linspace(_LOW, 255, width - 2 * pad).astype(np.uint8)[None, :]
    colours = cv2.applyColorMap(np.repeat(ramp, bar_h, axis=0), cmap)
    panel[pad:pad + bar_h, pad:width - pad] = colours
    n_ticks = 5
    for k in range(n_ticks):
        x = pad + int(round(k * (width - 2 * pad - 1) / (n_ticks - 1)))
        v = lo + k * (hi - lo) / (n_ticks - 1)
        label = f"{v:.1f} m"
        (tw, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.4, 1)
        tx = int(np.clip(x - tw / 2, 0, width - tw))
        cv2.line(panel, (x, pad + bar_h), (x, pad + bar_h + 3), (0, 0, 0), 1)
        cv2.putText(panel, label, (tx, pad + bar_h + 15), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return panel


def draw_scan_on_image(
    image_bgr: NDArray[np.uint8],
    points_lidar: NDArray[np.float64],
    calibration: Calibration,
    *,
    range_limits: tuple[float, float] | None = None,
    radius: int = 2,
    title: str | None = None,
) -> tuple[NDArray[np.uint8], int]:
    """Project LiDAR points (N, 2|3, LiDAR frame) through ``T_cam_lidar`` and the camera model
    onto the image, coloured by range from the LiDAR (turbo: near blue, far red), with a
    colour bar under the image. Returns the picture and the number of points in the image.
    """
    img = np.asarray(image_bgr)
    if img.ndim == 2:
        img = cast("NDArray[np.uint8]", cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))  # uint8 in, uint8 out
    img = img.copy()
    intr = calibration.intrinsics
    if (img.shape[1], img.shape[0]) != (intr.width, intr.height):
        raise ConfigError(f"image is {img.shape[1]}x{img.shape[0]} but the calibration's camera is "
                          f"{intr.width}x{intr.height}")
    pts = np.asarray(points_lidar, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise ConfigError(f"scan points must be (N, 2) or (N, 3), got shape {pts.shape}")
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    rng = np.linalg.norm(pts, axis=1)
    uv, inside = project_points(intr.K, intr.D, se3_apply(calibration.T_cam_lidar, pts), intr.width,
                                intr.height, intr.model)
    if range_limits is None:
        seen = rng[inside]
        lo, hi = (float(np.percentile(seen, 2)), float(np.percentile(seen, 98))) if seen.size else (0.0, 1.0)
        lo, hi = max(0.0, np.floor(lo * 2) / 2), np.ceil(hi * 2) / 2
        if hi <= lo:
            hi = lo + 0.5
    else:
        lo, hi = range_limits
    cmap = cv2.COLORMAP_TURBO
    idx = np.flatnonzero(inside)
    # far points first, so near ones are drawn on top
    idx = idx[np.argsort(-rng[idx])]
    levels = (_LOW + np.clip((rng[idx] - lo) / (hi - lo), 0, 1) * (255 - _LOW)).astype(np.uint8)
    colours = cv2.applyColorMap(levels[:, None], cmap).reshape(-1, 3) if idx.size else np.zeros((0, 3), np.uint8)
    for i, c in zip(idx, colours):
        centre = (int(round(uv[i, 0])), int(round(uv[i, 1])))
        cv2.circle(img, centre, radius + 1, (0, 0, 0), -1, cv2.LINE_AA)
        cv2.circle(img, centre, radius, tuple(int(v) for v in c), -1, cv2.LINE_AA)
    if title:
        (tw, th), _ = cv2.getTextSize(title, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        cv2.rectangle(img, (0, 0), (min(tw + 8, img.shape[1]), th + 10), (255, 255, 255), -1)
        cv2.putText(img, title, (4, th + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([img, _colour_bar(img.shape[1], lo, hi, cmap)]), int(inside.sum())


# -- bags -------------------------------------------------------------------------------------

def _bgr(image: Image) -> NDArray[np.uint8]:
    """A decoded camera image as BGR uint8 for the picture: grey images (mono16 and float ones
    stretched from their darkest to their brightest pixel) as three equal channels."""
    a = np.asarray(image.data)
    if image.encoding == "rgb8":
        return np.ascontiguousarray(a[:, :, ::-1])
    if a.dtype != np.uint8:
        # OpenCV takes dst=None as "allocate the output"; the stubs of some releases do not (the call goes through
        # Any, so that the type check passes with every release's stubs)
        a = cast(Any, cv2).normalize(np.nan_to_num(a.astype(np.float32)), None, 0, 255,
                                     cv2.NORM_MINMAX).astype(np.uint8)
    return cast("NDArray[np.uint8]", cv2.cvtColor(a, cv2.COLOR_GRAY2BGR))  # uint8 in, uint8 out


def frame_from_bag(bag: str | Path, time_s: float | None = None, *, image_topic: str | None = None,
                   scan_topic: str | None = None
                   ) -> tuple[NDArray[np.uint8], NDArray[np.float64], int, int, str]:
    """The camera image nearest ``time_s`` seconds after the bag's start (default: the middle of
    the bag), and the scan nearest it.

    Returns (BGR image, (N, 3) scan points in the scan's frame, image stamp ns, scan stamp ns,
    scan frame_id). Topics not given are picked as ``semmap build`` picks them
    (:func:`~semmap.io.topics.pick_topics`: image topics named like labels, masks or depth are
    passed over).
    """
    from ..config import TopicsConfig
    from ..io.bag import read_bag
    from ..io.topics import pick_topics
    from ..io.tour import read_tour_manifest

    path, _, manifest = read_tour_manifest(bag)
    with read_bag(path) as src:
        topics = pick_topics(src.types, TopicsConfig(scan=scan_topic, image=image_topic), path, "rgb", manifest,
                             kinds=("scan", "image"), required=("scan", "image"),
                             options={"scan": "--scan-topic", "image": "--image-topic"})
        assert topics.scan and topics.image is not None  # required
        start, end = src.start_ns, src.end_ns
        if time_s is None:
            time_s = (end - start) * 0.5e-9
        target = start + int(round(time_s * 1e9))
        if not start <= target <= end:
            raise BagError(f"{bag}: time {time_s:g} s is outside the bag (0 to {(end - start) / 1e9:.1f} s)")
        found = src.nearest(topics.image, target)  # the image nearest the time asked for (bag time)
        if found is None:
            raise BagError(f"{bag}: no messages on {topics.image}")
        t_img, image = found
        window = 2_000_000_000  # the scan nearest the image (header stamps), within 2 s of it (bag time)
        best: Scan | None = None
        for _, _, scan in src.records([topics.scan], start_ns=t_img - window, stop_ns=t_img + window):
            if best is None or abs(scan.stamp_ns - image.stamp_ns) < abs(best.stamp_ns - image.stamp_ns):
                best = scan
        if best is None:
            raise BagError(f"{bag}: no scan on {topics.scan} within 2 s of the image at {time_s:g} s")
    pts = ranges_to_points(best.ranges, best.angle_min, best.angle_increment, best.range_min, best.range_max)
    return _bgr(image), pts, image.stamp_ns, best.stamp_ns, best.frame_id


def check_calibration(
    calibration: Calibration,
    *,
    image: str | Path | NDArray[np.uint8] | None = None,
    scan: str | Path | NDArray[np.float64] | None = None,
    bag: str | Path | None = None,
    time_s: float | None = None,
    image_topic: str | None = None,
    scan_topic: str | None = None,
    out: str | Path | None = None,
    range_limits: tuple[float, float] | None = None,
    title: str | None = None,
    force: bool = False,
) -> CheckResult:
    """Draw a scan projected into its image with ``calibration``; write it to ``out`` if given.

    Give either ``image`` and ``scan`` (files or arrays) or ``bag`` and ``time_s`` (seconds
    after the bag's start; default: the middle of the bag). An existing ``out`` is replaced
    only with ``force``; that is checked before any work.
    """
    from ..io.atomic import atomic_file, check_output_file

    inputs = [x for x in (image, scan, bag) if isinstance(x, str | Path)]
    if out is not None:
        check_output_file(out, force, inputs, "picture")  # before the work
    img_stamp = scan_stamp = None
    if bag is not None:
        if image is not None or scan is not None:
            raise ConfigError("give either a bag and a time, or an image and a scan, not both")
        img, pts, img_stamp, scan_stamp, frame = frame_from_bag(bag, time_s, image_topic=image_topic,
                                                                scan_topic=scan_topic)
        if frame and frame.lstrip("/") != calibration.lidar_frame.lstrip("/"):
            log.warning("the scan's frame is %r but the calibration's LiDAR frame is %r", frame,
                        calibration.lidar_frame)
    else:
        if image is None or scan is None:
            raise ConfigError("give an image and a scan (or a bag and a time)")
        img = read_image(image) if isinstance(image, str | Path) else np.asarray(image)
        pts = read_scan_points(scan) if isinstance(scan, str | Path) else np.asarray(scan, dtype=np.float64)
    picture, n_in = draw_scan_on_image(img, pts, calibration, range_limits=range_limits, title=title)
    out_path = None
    if out is not None:
        out_path = Path(out)
        with atomic_file(out_path, force, inputs, "picture") as tmp:
            if not cv2.imwrite(str(tmp), picture):
                raise ConfigError(f"{out_path}: cannot write the picture (unknown extension?)")
    if n_in == 0:
        log.warning("no scan point lands in the image: is T_cam_lidar inverted (T_lidar_cam given)?")
    return CheckResult(picture, len(pts), n_in, img_stamp, scan_stamp, out_path)
