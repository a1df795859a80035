"""``semmap build``: a recorded tour → a cleaned semantic map folder.

Data flows one way, one scan at a time, so memory does not grow with the tour:

    bag ─► scans + odometry ───────────────┐   (this process)
    bag ─► camera frames ─► segmenter ─────┤   (frame worker process; raw label images: this process)
                                           ▼
           painter (deskew, sync to the image, project, label → mobility)   (this process)
                                           ▼
           registrar (KISS-ICP + wheel odometry in an EKF)   (registration worker)
                                           ▼
           semantic grid (log-odds + class evidence)         (fusion worker)
                                           ▼
           cleaning ─► map folder (written atomically)
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
from .config import BuildConfig, merge_overrides
from .errors import BagError
from .io.atomic import atomic_dir
from .io.bag import ReadStats, iter_messages, message_count, open_bag
from .io.messages import odometry_from_msg, scan_from_msg
from .io.tour import IMAGE_T, Tour, load_build_config, open_tour
from .paint.motion import OdomTrack
from .paint.painter import Painter
from .records import PaintedScan, Scan, Segmentation
from .segment.base import backend_consumes
from .workers import FrameWorker, InProcessFrames, InProcessMapper, MapperResult, MapperWorkers

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
class _Timers:
    read: float = 0.0
    paint: float = 0.0
    hand_over: float = 0.0  # giving scans to the mapping stages, and waiting for them at the end
    clean: float = 0.0
    write: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return {k: round(v, 3) for k, v in self.__dict__.items()}


@dataclass
class _Trace:
    stamps: list[int] = field(default_factory=list)
    odom: list[NDArray[np.float64] | None] = field(default_factory=list)
    poses: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # filled at the end


class _Pipeline:
    """The streaming core: buffers just enough to pair scans with images and odometry."""

    def __init__(self, tour: Tour, cfg: BuildConfig, class_names: tuple[str, ...], frames: Any, mapper: Any):
        self.tour = tour
        self.cfg = cfg
        self.class_names = class_names
        self.frame_source = frames
        self.mapper = mapper
        self.result: MapperResult | None = None
        table = load_class_table(cfg.segmentation.classes_file)
        self.painter = Painter(tour.T_base_lidar, tour.calibration, class_names, table, cfg.paint, cfg.sync,
                               cfg.grid.max_free_range)
        self.odom = OdomTrack(cfg.sync.max_odom_gap) if tour.topics.odometry else None
        self.segs: deque[Segmentation] = deque()
        self.frames_done = frames is None
        self.pending: deque[tuple[int, Scan]] = deque()  # (bag time, scan)
        self.max_offset_ns = int(cfg.sync.max_image_offset * 1e9)
        self.trace = _Trace()
        self.timers = _Timers()
        self.counts = {"scans": 0, "scans_without_image": 0, "scans_without_odometry": 0, "odometry": 0,
                       "bad_scans": 0, "scans_out_of_order": 0}
        self._last_scan_ns: int | None = None
        self.cpu_s: dict[str, float] = {}  # CPU time of the streaming loop, per process
        self.mobility_hits = np.zeros(4, np.int64)
        self.class_hits = np.zeros(len(class_names), np.int64)

    # -- inputs -----------------------------------------------------------------------------
    def on_odometry(self, msg: Any) -> None:
        assert self.odom is not None
        stamp, _, _, pose = odometry_from_msg(msg)
        self.odom.add(stamp, pose)
        self.counts["odometry"] += 1

    def on_scan(self, t_bag: int, msg: Any) -> None:
        scan = scan_from_msg(msg)
        n = scan.ranges.size
        if n == 0 or not np.isfinite(scan.angle_increment) or scan.angle_increment == 0:
            self.counts["bad_scans"] += 1
            return
        self.pending.append((t_bag, scan))

    # -- processing --------------------------------------------------------------------------
    @staticmethod
    def _end_ns(scan: Scan) -> int:
        return scan.stamp_ns + int(scan.time_increment * 1e9 * scan.ranges.size)

    def _ready(self, t_bag_now: int, scan_bag: int, scan: Scan) -> bool:
        # odometry must reach past the sweep and the latest image it may be paired with (motion compensation)
        need = self._end_ns(scan) + self.max_offset_ns
        odom_ok = self.odom is None or (self.odom.last_ns is not None and self.odom.last_ns >= need)
        stalled = t_bag_now - scan_bag > 2_000_000_000 or len(self.pending) > 64
        return odom_ok or stalled

    def process_ready(self, t_bag_now: int) -> None:
        while self.pending and self._ready(t_bag_now, *self.pending[0]):
            self._process(self.pending.popleft()[1])

    def flush(self) -> None:
        while self.pending:
            self._process(self.pending.popleft()[1])

    def _segmentation(self, scan: Scan) -> Segmentation | None:
        """The segmentation nearest the scan's middle, pulling frames only as far as needed."""
        mid = scan.stamp_ns + (self._end_ns(scan) - scan.stamp_ns) // 2
        while not self.frames_done and (not self.segs or self.segs[-1].stamp_ns < mid + self.max_offset_ns):
            seg = self.frame_source.next()
            if seg is None:
                self.frames_done = True
            else:
                self.segs.append(seg)
        while len(self.segs) > 1 and self.segs[0].stamp_ns < mid - self.max_offset_ns - 500_000_000:
            self.frame_source.release(self.segs.popleft())
        if not self.segs:
            return None
        best = min(self.segs, key=lambda s: abs(s.stamp_ns - mid))
        return best if abs(best.stamp_ns - mid) <= self.max_offset_ns else None

    def _process(self, scan: Scan) -> None:
        if self._last_scan_ns is not None and scan.stamp_ns <= self._last_scan_ns:
            self.counts["scans_out_of_order"] += 1  # repeated or backwards stamps: skipped, counted
            return
        self._last_scan_ns = scan.stamp_ns
        t0 = time.perf_counter()
        self._handle(scan, self._segmentation(scan), t0)
        if self.odom is not None:
            self.odom.trim(scan.stamp_ns - 1_000_000_000)  # forget what no future scan needs

    def _handle(self, scan: Scan, seg: Segmentation | None, t0: float) -> None:
        """Paint a scan paired with its segmentation and hand it to the mapper."""
        try:
            painted = self.painter.paint(scan, self.odom, seg)
        except BagError as exc:  # a label image that does not fit the calibration
            raise BagError(f"{self.tour.bag}: {self.tour.topics.frames}: {exc}") from None
        odom_pose = self.painter.last_odom_pose
        t1 = time.perf_counter()
        self.mapper.push(painted, odom_pose)
        self.timers.paint += t1 - t0
        self.timers.hand_over += time.perf_counter() - t1  # the mapper times its own work
        self.counts["scans"] += 1
        if seg is None:
            self.counts["scans_without_image"] += 1
        if self.odom is not None and odom_pose is None:
            self.counts["scans_without_odometry"] += 1
        self._tally(painted)
        self.trace.stamps.append(painted.stamp_ns)
        self.trace.odom.append(odom_pose)

    def _tally(self, painted: PaintedScan) -> None:
        hit = painted.hit
        self.mobility_hits += np.bincount(painted.mobility[hit], minlength=4)[:4]
        cls = painted.class_id[hit]
        cls = cls[cls >= 0]
        if cls.size:
            self.class_hits += np.bincount(cls, minlength=len(self.class_names))[: len(self.class_names)]

    @property
    def frame_counts(self) -> dict[str, int]:
        return dict(self.frame_source.counts) if self.frame_source is not None else {"frames": 0, "bad_frames": 0}


def _frames_are_light(cfg: BuildConfig, msgtype: str) -> bool:
    """Raw label images recorded in the bag: nothing to decode or infer, so they are read in the mapping
    process. A worker process would cost more than it saves: each frame copied into shared memory and
    handed over, against a view of the bag's bytes here (the office tour builds faster this way from
    ROS1 and from MCAP alike)."""
    return backend_consumes(cfg.segmentation) == "labels" and msgtype == IMAGE_T


def open_build_tour(tour: str | Path, config: str | Path | BuildConfig | None = None,
                    calibration: str | Path | None = None,
                    overrides: dict[str, Any] | None = None) -> tuple[Tour, BuildConfig]:
    """The effective config and the opened tour, as ``semmap build`` sees them (also ``semmap paint``).

    A simulated tour's manifest names the class list of its label images; it applies unless
    the config sets ``segmentation.class_list``.
    """
    if isinstance(config, BuildConfig):
        cfg, cfg_dir = config, Path.cwd()
        if overrides:
            cfg, _ = load_build_config(None, merge_overrides(config.model_dump(exclude_unset=True), overrides))
    else:
        cfg, cfg_dir = load_build_config(config, overrides)
    tour_path = Path(tour)
    if not tour_path.exists():
        raise BagError(f"{tour_path}: no such file or directory")
    tinfo = open_tour(tour_path, cfg, cfg_dir, calibration, consumes=backend_consumes(cfg.segmentation))
    if tinfo.manifest.get("label_classes") and "class_list" not in cfg.segmentation.model_fields_set:
        seg_cfg = cfg.segmentation.model_copy(update={"class_list": tinfo.manifest["label_classes"]})
        cfg = cfg.model_copy(update={"segmentation": seg_cfg})
    return tinfo, cfg


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
    :class:`~semmap.config.BuildConfig`; ``calibration`` overrides the calibration file;
    ``overrides`` is a dict merged over the config (as if written in its YAML).
    Nothing appears at ``out`` until the whole map folder is written.
    """
    t_start = time.perf_counter()
    tinfo, cfg = open_build_tour(tour, config, calibration, overrides)
    frames: Any = None
    class_names: tuple[str, ...] = ()
    if tinfo.topics.frames is None:
        log.warning("%s: no camera topic; building a LiDAR-only map (no classes)", tinfo.bag)
    else:
        from .segment.base import create_segmenter

        probe = create_segmenter(cfg.segmentation)  # class names (backends load models lazily)
        class_names = probe.names
        probe.close()
    mapper: Any = None
    try:
        msgtype = tinfo.types.get(tinfo.topics.frames or "", "")
        if cfg.workers:  # started first: they load their libraries while the rest is set up
            mapper = MapperWorkers(cfg.registration, cfg.grid, class_names)
        else:
            mapper = InProcessMapper(cfg.registration, cfg.grid, class_names)
        if tinfo.topics.frames is not None:
            if cfg.workers and not _frames_are_light(cfg, msgtype):
                intr = tinfo.calibration.intrinsics if tinfo.calibration is not None else None
                shape = (intr.height, intr.width) if intr is not None else None
                frames = FrameWorker(tinfo.bag, tinfo.topics.frames, msgtype, cfg.segmentation, shape)
            else:
                frames = InProcessFrames(tinfo.bag, tinfo.topics.frames, msgtype, cfg.segmentation)
        pipe = _Pipeline(tinfo, cfg, class_names, frames, mapper)
        for part in (frames, mapper):  # workers load their libraries before the clock starts
            if part is not None:
                part.wait_ready()
        topics = [t for t in (tinfo.topics.scan, tinfo.topics.odometry) if t]
        stats = ReadStats()
        with open_bag(tinfo.bag) as reader:  # opened once: counting and streaming share its index
            n_scan_msgs = message_count(tinfo.bag, tinfo.topics.scan, reader)
            t_loop = time.perf_counter()
            cpu_loop = time.process_time()
            for topic, t_bag, msg in iter_messages(tinfo.bag, topics, stats, reader):
                if topic == tinfo.topics.scan:
                    pipe.on_scan(t_bag, msg)
                    if progress is not None and stats.read.get(topic, 0) % 50 == 0:
                        progress(stats.read.get(topic, 0), n_scan_msgs)
                else:
                    pipe.on_odometry(msg)
                pipe.process_ready(t_bag)
            pipe.flush()
        t_wait = time.perf_counter()
        pipe.result = mapper.finish()
        pipe.trace.poses = pipe.result.poses
        pipe.timers.hand_over += time.perf_counter() - t_wait  # waiting for the mapping workers to catch up
        loop_s = time.perf_counter() - t_loop
        pipe.cpu_s = {"main": round(time.process_time() - cpu_loop, 3), **pipe.result.cpu_s}
        if "cpu_s" in pipe.frame_counts:
            pipe.cpu_s["frames"] = pipe.frame_counts["cpu_s"]
        pipe.timers.read = max(0.0, loop_s - pipe.timers.paint - pipe.timers.hand_over)
        if progress is not None:
            progress(n_scan_msgs, n_scan_msgs)
        if pipe.counts["scans"] == 0:
            raise BagError(f"{tinfo.bag}: no usable scans on {tinfo.topics.scan}")
        ps = pipe.painter.stats
        if cfg.paint.below_range_min == "invalid" and ps.below_range_min > 0.02 * max(ps.beams, 1):
            log.warning("%.0f %% of the readings on %s are below range_min and clear no free space; if the "
                        "driver reports 'nothing seen' this way (Hokuyo URG does), set "
                        "paint.below_range_min: no_return", 100 * ps.below_range_min / ps.beams, tinfo.topics.scan)
        from .mapfolder.writer import write_map_folder

        with atomic_dir(out, force) as tmp:
            summary = write_map_folder(tmp, tinfo, cfg, pipe, pipe.result.layers, stats, loop_s, t_start)
    finally:
        for part in (frames, mapper):
            if part is not None:
                part.close()
    return BuildResult(Path(out), summary, time.perf_counter() - t_start)
