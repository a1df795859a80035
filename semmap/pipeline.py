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

import contextlib
import logging
import time
from array import array
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .classes import load_class_table
from .config import BuildConfig, merge_overrides
from .errors import BagError, ConfigError
from .grid.fusion import check_grid_memory
from .io.atomic import atomic_dir
from .io.bag import OpenBag, ReadStats, read_bag, resolve_bag_path
from .io.messages import odometry_from_msg, scan_from_msg
from .io.topics import IMAGE_T
from .io.tour import Tour, load_build_config, open_tour
from .paint.motion import OdomTrack
from .paint.painter import Painter
from .records import PaintedScan, Scan, Segmentation
from .segment.base import backend_consumes
from .workers import FrameSource, FrameWorker, InProcessFrames, InProcessMapper, Mapper, MapperResult, MapperWorkers

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


class _Trace:
    """Per scan: its stamp and the odometry pose at it, kept compactly (32 bytes a scan), and the map-frame
    poses registration returns at the end."""

    def __init__(self) -> None:
        self._stamps = array("q")
        self._odom = array("d")  # x, y, yaw per scan; NaN where there was no odometry
        self.poses: NDArray[np.float64] = np.zeros((0, 3))

    def add(self, stamp_ns: int, odom_pose: NDArray[np.float64] | None) -> None:
        self._stamps.append(stamp_ns)
        self._odom.extend(_NO_ODOM if odom_pose is None else odom_pose.tolist())

    @property
    def stamps(self) -> NDArray[np.int64]:
        return np.frombuffer(self._stamps, np.int64) if self._stamps else np.zeros(0, np.int64)

    @property
    def odom(self) -> NDArray[np.float64]:
        """(N, 3); rows of NaN where the scan had no odometry."""
        return np.frombuffer(self._odom, np.float64).reshape(-1, 3) if self._odom else np.zeros((0, 3))


_NO_ODOM = (float("nan"),) * 3


class _Pipeline:
    """The streaming core: buffers just enough to pair scans with images and odometry."""

    def __init__(self, tour: Tour, cfg: BuildConfig, class_names: tuple[str, ...], frames: FrameSource | None,
                 mapper: Mapper | None):
        self.tour = tour
        self.cfg = cfg
        self.class_names = class_names
        self.frame_source = frames
        self.mapper = mapper
        self.result: MapperResult | None = None
        table = load_class_table(cfg.segmentation.classes_file)
        self.painter = Painter(tour.T_base_lidar, tour.calibration, class_names, table, cfg.paint, cfg.sync,
                               cfg.grid.no_return_range)
        self.odom = OdomTrack(cfg.sync.max_odom_gap) if tour.topics.odometry else None
        self.segs: deque[Segmentation] = deque()
        self.frames_done = frames is None
        self.pending: deque[tuple[int, Scan]] = deque()  # (bag time, scan)
        self.max_offset_ns = int(cfg.sync.max_image_offset * 1e9)
        self.trace = _Trace()
        self.timers = _Timers()
        self.counts = {"scans": 0, "scans_without_image": 0, "scans_without_odometry": 0, "odometry": 0,
                       "bad_scans": 0, "scans_out_of_order": 0}
        self._last_scan_ns: tuple[int, int] | None = None  # stamp and reference time of the last scan
        self.cpu_s: dict[str, float] = {}  # CPU time of the streaming loop, per process
        self.warnings: list[str] = []  # what the build warned about
        self.unpaired_offsets_ns: list[int] = []  # scans with no image close enough: the nearest one's offset
        self.mobility_hits = np.zeros(4, np.int64)
        self.class_hits = np.zeros(len(class_names), np.int64)

    # -- inputs -----------------------------------------------------------------------------
    def on_odometry(self, msg: Any) -> None:
        assert self.odom is not None
        stamp, _, _, pose = odometry_from_msg(msg, self.tour.topics.odometry or "")
        self.odom.add(stamp, pose)
        self.counts["odometry"] += 1

    def on_scan(self, t_bag: int, msg: Any) -> None:
        scan = scan_from_msg(msg, self.tour.topics.scan)
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
        if abs(best.stamp_ns - mid) <= self.max_offset_ns:
            return best
        if len(self.unpaired_offsets_ns) < 4096:  # why scans found no image: for the warning at the end
            self.unpaired_offsets_ns.append(abs(best.stamp_ns - mid))
        return None

    def _process(self, scan: Scan) -> None:
        # repeated or backwards stamps, or a sweep whose middle comes before the last one's: skipped, counted
        ref = Painter.reference_ns(scan)
        if self._last_scan_ns is not None and (scan.stamp_ns <= self._last_scan_ns[0] or ref <= self._last_scan_ns[1]):
            self.counts["scans_out_of_order"] += 1
            return
        self._last_scan_ns = (scan.stamp_ns, ref)
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
        self.trace.add(painted.stamp_ns, odom_pose)

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
                    overrides: dict[str, Any] | None = None, source: OpenBag | None = None) -> tuple[Tour, BuildConfig]:
    """The effective config and the opened tour, as ``semmap build`` sees them (also ``semmap paint``).
    ``source``: the tour's bag, opened once for the whole build (:func:`~semmap.io.bag.read_bag`).

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
    tinfo = open_tour(tour_path, cfg, cfg_dir, calibration, consumes=backend_consumes(cfg.segmentation),
                      source=source)
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

    ``out`` is checked before any work: it must not exist unless ``force``, and ``force``
    replaces only a semmap map folder, never the tour being read. Nothing appears at ``out``
    until the whole map folder is written; on any error or interrupt nothing is left there,
    and every worker process is stopped.
    """
    t_start = time.perf_counter()
    inputs = [p for p in (tour, calibration, config if not isinstance(config, BuildConfig) else None) if p]
    with contextlib.suppress(BagError):  # the bag inside a tour folder is an input too (opening it says why not)
        inputs.append(resolve_bag_path(tour))
    with _KeptWarnings() as warned, atomic_dir(out, force, marker=MAP_MARKER, inputs=inputs,
                                               what="semmap map folder") as tmp, read_bag(tour, lazy=True) as bag:
        tinfo, cfg = open_build_tour(tour, config, calibration, overrides, source=bag)
        cfg = _effective_config(tinfo, cfg)
        _log_detected(tinfo, cfg)
        frames: FrameSource | None = None
        class_names: tuple[str, ...] = ()
        if tinfo.topics.frames is None:
            log.warning("%s: no camera topic; building a LiDAR-only map (no classes)", tinfo.bag)
        else:
            from .segment.base import create_segmenter

            probe = create_segmenter(cfg.segmentation)  # class names (backends load models lazily)
            class_names = probe.names
            probe.close()
        check_grid_memory(cfg.grid, cfg.registration.max_range, len(class_names))
        mapper: Mapper | None = None
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
            stats, loop_s = _stream(tinfo, bag, pipe, mapper, progress)
        finally:
            for part in (frames, mapper):
                if part is not None:
                    part.close()
        if pipe.counts["scans"] == 0:
            raise BagError(f"{tinfo.bag}: no usable scans on {tinfo.topics.scan}")
        _warn_about_painting(tinfo, cfg, pipe)
        pipe.warnings = warned.lines()
        from .mapfolder.writer import write_map_folder

        summary = write_map_folder(tmp, tinfo, cfg, pipe, pipe.result.layers, stats, loop_s, t_start)
    return BuildResult(Path(out), summary, time.perf_counter() - t_start)


#: the file that marks a folder as a semmap map folder (``--force`` replaces nothing else)
MAP_MARKER = "summary.json"


class _KeptWarnings(logging.Handler):
    """The warnings semmap logs during a build (workers' included), for ``summary.json`` and the report;
    a warning repeated is kept once, with its count."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self._seen: dict[str, int] = {}

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        self._seen[text] = self._seen.get(text, 0) + 1

    def lines(self) -> list[str]:
        return [t if n == 1 else f"{t} (x{n})" for t, n in self._seen.items()]

    def __enter__(self) -> _KeptWarnings:
        logging.getLogger("semmap").addHandler(self)
        return self

    def __exit__(self, *exc: object) -> None:
        logging.getLogger("semmap").removeHandler(self)


def _stream(tinfo: Tour, bag: OpenBag, pipe: _Pipeline, mapper: Mapper,
            progress: ProgressFn | None) -> tuple[ReadStats, float]:
    """The streaming loop: read scans and odometry, paint, hand over; then wait for the mapping stages."""
    topics = [t for t in (tinfo.topics.scan, tinfo.topics.odometry) if t]
    stats = ReadStats()
    with contextlib.closing(bag):  # opened once: the tour, counting and streaming share its index
        n_scan_msgs = bag.count(tinfo.topics.scan)
        t_loop = time.perf_counter()
        cpu_loop = time.process_time()
        for topic, t_bag, msg in bag.messages(topics, stats):
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
    return stats, loop_s


def _effective_config(tinfo: Tour, cfg: BuildConfig) -> BuildConfig:
    """The config as the build runs it, with what was detected filled in (``config.yaml`` of the map
    folder rebuilds the same map); contradictions with the tour are errors."""
    reg = cfg.registration
    if tinfo.topics.odometry is None:
        if reg.mode == "odometry":
            raise ConfigError(f"{tinfo.bag}: registration.mode is 'odometry' but the tour has no odometry "
                              f"(topics.odometry: {cfg.topics.odometry or 'none found'}); use mode 'icp' or "
                              f"name the odometry topic")
        if reg.mode == "fused":
            log.info("no odometry: registering with KISS-ICP alone (registration.mode icp)")
            reg = reg.model_copy(update={"mode": "icp"})
    topics = cfg.topics.model_copy(update={
        "scan": tinfo.topics.scan,
        "odometry": tinfo.topics.odometry or "none",
        "camera_info": tinfo.topics.camera_info,
        **({"labels": tinfo.topics.frames} if tinfo.topics.frames_kind == "labels" else {}),
        **({"image": tinfo.topics.frames} if tinfo.topics.frames_kind == "rgb" else {}),
    })
    frames = cfg.frames.model_copy(update={"base": tinfo.base_frame, "lidar": tinfo.lidar_frame})
    update: dict[str, Any] = {"topics": topics, "frames": frames, "registration": reg}
    if tinfo.calibration_path is not None:
        update["calibration"] = tinfo.calibration_path.resolve()
    return cfg.model_copy(update=update)


def _log_detected(tinfo: Tour, cfg: BuildConfig) -> None:
    """``-v``: what was found in the data, and where it came from."""
    t = tinfo.topics
    log.info("tour %s: scans %s (frame %s), odometry %s, %s %s, camera_info %s", tinfo.bag, t.scan,
             tinfo.lidar_frame, t.odometry or "none", "label images" if t.frames_kind == "labels" else "images",
             t.frames or "none", t.camera_info or "none")
    xyz = np.round(tinfo.T_base_lidar[:3, 3], 3).tolist()
    yaw = float(np.degrees(np.arctan2(tinfo.T_base_lidar[1, 0], tinfo.T_base_lidar[0, 0])))
    log.info("T_base_lidar (%s -> %s) from %s: xyz %s m, yaw %.1f deg", tinfo.base_frame, tinfo.lidar_frame,
             tinfo.T_base_lidar_source, xyz, yaw)
    if tinfo.calibration is not None:
        log.info("calibration %s: %dx%d camera, camera frame %s", tinfo.calibration_path or "from the bag",
                 tinfo.calibration.intrinsics.width, tinfo.calibration.intrinsics.height,
                 tinfo.calibration.camera_frame)
    log.info("registration %s; segmentation backend %s; scans paired with images within %.3f s",
             cfg.registration.mode, cfg.segmentation.backend, cfg.sync.max_image_offset)


def _warn_about_painting(tinfo: Tour, cfg: BuildConfig, pipe: _Pipeline) -> None:
    """Say so when the camera labelled (almost) nothing, and why."""
    ps = pipe.painter.stats
    if cfg.paint.below_range_min == "invalid" and ps.below_range_min > 0.02 * max(ps.beams, 1):
        log.warning("%.0f %% of the readings on %s are below range_min and clear no free space; if the "
                    "driver reports 'nothing seen' this way (Hokuyo URG does), set "
                    "paint.below_range_min: no_return", 100 * ps.below_range_min / ps.beams, tinfo.topics.scan)
    if tinfo.topics.frames is None:
        return
    n = pipe.counts["scans"]
    with_image = n - pipe.counts["scans_without_image"]
    frames = pipe.frame_counts.get("frames", 0)
    log.info("%d of %d scans were paired with an image (%d frames read on %s); %.1f %% of their returns fell "
             "into the image", with_image, n, frames, tinfo.topics.frames,
             100 * ps.points_in_view / max(ps.points_paired, 1))
    if with_image < 0.1 * n:
        if frames == 0:
            why = f"no frame on {tinfo.topics.frames} could be read or segmented"
        elif pipe.unpaired_offsets_ns:
            off = float(np.median(pipe.unpaired_offsets_ns)) * 1e-9
            why = (f"the nearest image was typically {off:.3f} s from a scan, more than sync.max_image_offset "
                   f"({cfg.sync.max_image_offset} s): are the camera's stamps on another clock, or is "
                   f"the camera much slower than the LiDAR?")
        else:
            why = "the images do not overlap the scans in time"
        log.warning("only %d of %d scans were paired with an image on %s: %s", with_image, n, tinfo.topics.frames,
                    why)
        return
    if ps.points_paired and ps.points_in_view < 0.01 * ps.points_paired:
        ahead = ps.points_ahead / ps.points_paired
        if ahead < 0.05:
            why = (f"{100 * (1 - ahead):.0f} % of the LiDAR's points are behind the camera under T_cam_lidar of "
                   f"{tinfo.calibration_source or 'the calibration'}: is it inverted (T_lidar_cam written as "
                   f"T_cam_lidar), or does it map into the camera's body frame (x forward) instead of its "
                   f"optical frame (z forward)?")
        else:
            why = (f"the points are in front of the camera but outside the image; check the intrinsics and "
                   f"T_cam_lidar of {tinfo.calibration_source or 'the calibration'}")
        log.warning("only %.2f %% of the LiDAR's points fell into the camera images: %s",
                    100 * ps.points_in_view / ps.points_paired, why)
