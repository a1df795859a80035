"""``semmap build``: a recorded tour → a cleaned semantic map folder.

Data flows one way, one scan at a time, so memory does not grow with the tour:

    bag ──► scans, odometry, camera frames (streamed in bag order)
        ──► painter (deskew, sync to the image, project, label → mobility)
        ──► registrar (KISS-ICP + wheel odometry in an EKF)
        ──► semantic grid (log-odds + class evidence)
        ──► cleaning ──► map folder (written atomically)
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .classes import load_class_table
from .config import BuildConfig
from .errors import BagError, SemmapError
from .io.atomic import atomic_dir
from .io.bag import ReadStats, iter_messages, message_count
from .io.messages import compressed_image_from_msg, image_from_msg, odometry_from_msg, scan_from_msg
from .io.tour import COMPRESSED_T, Tour, load_build_config, open_tour
from .paint.motion import OdomTrack
from .paint.painter import Painter
from .records import Image, PaintedScan, Scan, Segmentation
from .segment.base import Segmenter, create_segmenter

__all__ = ["build", "BuildResult"]

log = logging.getLogger(__name__)

ProgressFn = Callable[[int, int], None]


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build` produced."""

    out: Path
    summary: dict[str, Any]
    elapsed_s: float


@dataclass
class _Frame:
    stamp_ns: int
    image: Image
    seg: Segmentation | None = None


@dataclass
class _Timers:
    read: float = 0.0
    paint: float = 0.0
    register: float = 0.0
    fuse: float = 0.0
    clean: float = 0.0
    write: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return {k: round(v, 3) for k, v in self.__dict__.items()}


@dataclass
class _Trace:
    stamps: list[int] = field(default_factory=list)
    poses: list[NDArray[np.float64]] = field(default_factory=list)
    odom: list[NDArray[np.float64] | None] = field(default_factory=list)


class _Pipeline:
    """The streaming core: buffers just enough to pair scans with images and odometry."""

    def __init__(self, tour: Tour, cfg: BuildConfig, segmenter: Segmenter | None, class_names: tuple[str, ...]):
        from .grid import SemanticGrid
        from .register import Registrar

        self.tour = tour
        self.cfg = cfg
        self.segmenter = segmenter
        self.class_names = class_names
        table = load_class_table(cfg.segmentation.classes_file)
        self.painter = Painter(tour.T_base_lidar, tour.calibration, class_names, table, cfg.paint, cfg.sync,
                               cfg.grid.max_free_range)
        self.registrar = Registrar(cfg.registration)
        self.grid = SemanticGrid(cfg.grid, class_names)
        self.odom = OdomTrack(cfg.sync.max_odom_gap) if tour.topics.odometry else None
        self.frames: deque[_Frame] = deque()
        self.pending: deque[tuple[int, Scan]] = deque()  # (bag time, scan)
        self.max_offset_ns = int(cfg.sync.max_image_offset * 1e9)
        self.trace = _Trace()
        self.timers = _Timers()
        self.counts = {"scans": 0, "scans_without_image": 0, "scans_without_odometry": 0, "frames": 0,
                       "odometry": 0, "bad_scans": 0, "bad_frames": 0, "scans_out_of_order": 0}
        self._last_scan_ns: int | None = None
        self.mobility_hits = np.zeros(4, np.int64)
        self.class_hits = np.zeros(len(class_names), np.int64)
        self.last_frame_ns: int | None = None

    # -- inputs -----------------------------------------------------------------------------
    def on_odometry(self, msg: Any) -> None:
        assert self.odom is not None
        stamp, _, _, pose = odometry_from_msg(msg)
        self.odom.add(stamp, pose)
        self.counts["odometry"] += 1

    def on_frame(self, topic: str, msgtype: str, msg: Any) -> None:
        try:
            img = compressed_image_from_msg(msg, topic) if msgtype == COMPRESSED_T else image_from_msg(msg, topic)
        except SemmapError as exc:
            self.counts["bad_frames"] += 1
            log.debug("skipped frame: %s", exc)
            return
        self.frames.append(_Frame(img.stamp_ns, img))
        self.last_frame_ns = max(self.last_frame_ns or img.stamp_ns, img.stamp_ns)
        self.counts["frames"] += 1

    def on_scan(self, t_bag: int, msg: Any) -> None:
        scan = scan_from_msg(msg)
        n = scan.ranges.size
        if n == 0 or not np.isfinite(scan.angle_increment) or scan.angle_increment == 0:
            self.counts["bad_scans"] += 1
            return
        self.pending.append((t_bag, scan))

    # -- processing --------------------------------------------------------------------------
    def _ready(self, t_bag_now: int, scan_bag: int, scan: Scan) -> bool:
        end = scan.stamp_ns + int(scan.time_increment * 1e9 * scan.ranges.size)
        odom_ok = self.odom is None or (self.odom.last_ns is not None and self.odom.last_ns >= end)
        frames_ok = self.tour.topics.frames is None or (
            self.last_frame_ns is not None and self.last_frame_ns >= end + self.max_offset_ns)
        stalled = t_bag_now - scan_bag > 2_000_000_000 or len(self.pending) > 64
        return (odom_ok and frames_ok) or stalled

    def process_ready(self, t_bag_now: int) -> None:
        while self.pending and self._ready(t_bag_now, *self.pending[0]):
            self._process(self.pending.popleft()[1])

    def flush(self) -> None:
        while self.pending:
            self._process(self.pending.popleft()[1])

    def _segmentation(self, scan: Scan) -> Segmentation | None:
        if not self.frames or self.segmenter is None:
            return None
        mid = scan.stamp_ns + int(scan.time_increment * 1e9 * scan.ranges.size / 2)
        best = min(self.frames, key=lambda f: abs(f.stamp_ns - mid))
        if abs(best.stamp_ns - mid) > self.max_offset_ns:
            return None
        if best.seg is None:
            best.seg = self.segmenter.segment(best.image)
        return best.seg

    def _process(self, scan: Scan) -> None:
        if self._last_scan_ns is not None and scan.stamp_ns <= self._last_scan_ns:
            self.counts["scans_out_of_order"] += 1  # repeated or backwards stamps: skipped, counted
            return
        self._last_scan_ns = scan.stamp_ns
        t0 = time.perf_counter()
        seg = self._segmentation(scan)
        painted = self.painter.paint(scan, self.odom, seg)
        t1 = time.perf_counter()
        odom_pose = self.odom.interpolate(painted.stamp_ns) if self.odom is not None else None
        pose = self.registrar.register(painted, odom_pose)
        t2 = time.perf_counter()
        self.grid.integrate(pose, painted)
        t3 = time.perf_counter()
        self.timers.paint += t1 - t0
        self.timers.register += t2 - t1
        self.timers.fuse += t3 - t2
        self.counts["scans"] += 1
        if seg is None:
            self.counts["scans_without_image"] += 1
        if self.odom is not None and odom_pose is None:
            self.counts["scans_without_odometry"] += 1
        self._tally(painted)
        self.trace.stamps.append(painted.stamp_ns)
        self.trace.poses.append(np.asarray(pose, dtype=np.float64))
        self.trace.odom.append(odom_pose)
        # forget what no future scan needs
        keep_from = scan.stamp_ns - 1_000_000_000
        if self.odom is not None:
            self.odom.trim(keep_from)
        while self.frames and self.frames[0].stamp_ns < scan.stamp_ns - self.max_offset_ns - 500_000_000:
            self.frames.popleft()

    def _tally(self, painted: PaintedScan) -> None:
        hit = painted.hit
        self.mobility_hits += np.bincount(painted.mobility[hit], minlength=4)[:4]
        cls = painted.class_id[hit]
        cls = cls[cls >= 0]
        if cls.size:
            self.class_hits += np.bincount(cls, minlength=len(self.class_names))[: len(self.class_names)]


def build(
    tour: str | Path,
    out: str | Path,
    config: str | Path | BuildConfig | None = None,
    calibration: str | Path | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
    overrides: dict[str, Any] | None = None,
) -> BuildResult:
    """Build the cleaned semantic map of a recorded tour into the folder ``out``.

    ``tour`` is a bag or a folder holding one; ``config`` a YAML file or a
    :class:`~semmap.config.BuildConfig`; ``calibration`` overrides the calibration file.
    Nothing appears at ``out`` until the whole map folder is written.
    """
    t_start = time.perf_counter()
    if isinstance(config, BuildConfig):
        cfg, cfg_dir = config, Path.cwd()
    else:
        cfg, cfg_dir = load_build_config(config, overrides)
    tour_path = Path(tour)
    if not tour_path.exists():
        raise BagError(f"{tour_path}: no such file or directory")

    segmenter: Segmenter | None = create_segmenter(cfg.segmentation)
    try:
        tinfo = open_tour(tour_path, cfg, cfg_dir, calibration, consumes=segmenter.consumes)
        # a simulated tour says which class list its label images use
        if (tinfo.manifest.get("label_classes") and "class_list" not in cfg.segmentation.model_fields_set):
            seg_cfg = cfg.segmentation.model_copy(update={"class_list": tinfo.manifest["label_classes"]})
            cfg = cfg.model_copy(update={"segmentation": seg_cfg})
            segmenter.close()
            segmenter = create_segmenter(cfg.segmentation)
        if tinfo.topics.frames is None:
            segmenter.close()
            segmenter = None
            log.warning("%s: no camera topic; building a LiDAR-only map (no classes)", tinfo.bag)
        class_names = segmenter.names if segmenter is not None else ()
        pipe = _Pipeline(tinfo, cfg, segmenter, class_names)
        topics = [t for t in (tinfo.topics.scan, tinfo.topics.odometry, tinfo.topics.frames) if t]
        stats = ReadStats()
        n_scan_msgs = message_count(tinfo.bag, tinfo.topics.scan)
        t_read = time.perf_counter()
        for topic, t_bag, msg in iter_messages(tinfo.bag, topics, stats):
            if topic == tinfo.topics.scan:
                pipe.on_scan(t_bag, msg)
            elif topic == tinfo.topics.odometry:
                pipe.on_odometry(msg)
            else:
                pipe.on_frame(topic, tinfo.types[topic], msg)
            pipe.process_ready(t_bag)
            if progress is not None and topic == tinfo.topics.scan and stats.read.get(topic, 0) % 50 == 0:
                progress(stats.read.get(topic, 0), n_scan_msgs)
        pipe.flush()
        if progress is not None:
            progress(n_scan_msgs, n_scan_msgs)
        loop_s = time.perf_counter() - t_read
        pipe.timers.read = max(0.0, loop_s - pipe.timers.paint - pipe.timers.register - pipe.timers.fuse)
        if pipe.counts["scans"] == 0:
            raise BagError(f"{tinfo.bag}: no usable scans on {tinfo.topics.scan}")
        from .mapfolder.writer import write_map_folder

        with atomic_dir(out, force) as tmp:
            summary = write_map_folder(tmp, tinfo, cfg, pipe, stats, t_start)
    finally:
        if segmenter is not None:
            segmenter.close()
    return BuildResult(Path(out), summary, time.perf_counter() - t_start)
