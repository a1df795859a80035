"""``semmap build``: a recorded tour → a cleaned semantic map folder.

Data flows one way, one scan at a time, so memory does not grow with the tour:

    bag ─► scans + odometry ───────────────┐   (this process)
    bag ─► camera images ─► segmenter ─────┤   (image worker process; raw label images: this process)
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
import platform
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .classes import load_class_table
from .config import BuildConfig
from .errors import BagError, ConfigError
from .grid.fusion import check_grid_memory
from .io.atomic import atomic_dir
from .io.bag import OpenBag, read_bag, resolve_bag_path
from .io.topics import IMAGE_T
from .io.tour import Tour
from .mapfolder.summary import (
    BuildSummary,
    ConsistencySummary,
    CountsSummary,
    FrameSelectionSummary,
    MapSummary,
    MessagesSummary,
    OcclusionSummary,
    PaintingSummary,
    ThroughputSummary,
    TimingsSummary,
    TourFrames,
    TourSummary,
    TourTopics,
)
from .mapfolder.writer import MAP_FOLDER_VERSION, BuildOutcome, write_map_folder
from .paint.need import make_selector, need_context
from .paint.painter import Painter, label_memory
from .paint.stream import ScanStream, open_build_tour, selection_odometry, tour_class_names
from .segment.base import backend_consumes
from .segment.images import ImageSource, InProcessImages
from .segment.select import every_frame
from .version import __version__
from .workers import ImageWorker, InProcessMapper, Mapper, MapperResult, MapperWorkers

__all__ = ["BuildResult", "build"]


log = logging.getLogger(__name__)

ProgressFn = Callable[[int, int], None]


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build` produced: the map folder and its summary (``summary.json``)."""

    out: Path
    summary: BuildSummary
    elapsed_s: float


@dataclass
class _Timers:
    read: float = 0.0
    paint: float = 0.0
    hand_over: float = 0.0  # giving scans to the mapping stages, and waiting for them at the end
    wait_images: float = 0.0  # waiting for segmentations (a model slower than the mapping shows here)
    clean: float = 0.0


class _Trace:
    """Per scan: its stamp and the odometry pose at it, kept compactly (32 bytes a scan)."""

    def __init__(self) -> None:
        self._stamps = array("q")
        self._odom = array("d")  # x, y, yaw per scan; NaN where there was no odometry
        self._labels = array("B")  # where the scan's labels came from (see labels)

    def add(self, stamp_ns: int, odom_pose: NDArray[np.float64] | None, labels: int = 0) -> None:
        self._stamps.append(stamp_ns)
        self._odom.extend(_NO_ODOM if odom_pose is None else odom_pose.tolist())
        self._labels.append(labels)

    @property
    def labels(self) -> NDArray[np.uint8]:
        """(N,) per scan: 0 no labels, 1 painted from a segmented frame, 2 from earlier frames' labels."""
        return np.frombuffer(self._labels, np.uint8).copy() if self._labels else np.zeros(0, np.uint8)

    @property
    def stamps(self) -> NDArray[np.int64]:
        return np.frombuffer(self._stamps, np.int64).copy() if self._stamps else np.zeros(0, np.int64)

    @property
    def odom(self) -> NDArray[np.float64]:
        """(N, 3); rows of NaN where the scan had no odometry."""
        return np.frombuffer(self._odom, np.float64).reshape(-1, 3).copy() if self._odom else np.zeros((0, 3))


_NO_ODOM = (float("nan"),) * 3


@dataclass
class _Run:
    """What the streaming loop gathered, for the summary and the warnings."""

    stream: ScanStream
    painter: Painter
    result: MapperResult
    trace: _Trace
    timers: _Timers
    image_counts: dict[str, Any]
    loop_s: float
    cpu_s: dict[str, float]
    scans_without_image: int
    scans_without_odometry: int
    mobility_hits: NDArray[np.int64]  # painted hits per mobility value
    class_hits: NDArray[np.int64]  # painted hits per class

    @property
    def counts(self) -> dict[str, int]:
        c = self.stream.counts
        return {"scans": c.scans, "scans_without_image": self.scans_without_image,
                "scans_without_odometry": self.scans_without_odometry, "odometry": c.odometry,
                "bad_scans": c.bad_scans, "scans_out_of_order": c.scans_out_of_order}


def _images_are_light(cfg: BuildConfig, msgtype: str) -> bool:
    """Raw label images recorded in the bag: nothing to decode or infer, so they are read in the mapping
    process. A worker process would cost more than it saves: each frame copied into shared memory and
    handed over, against a view of the bag's bytes here (the office tour builds faster this way from
    ROS1 and from MCAP alike)."""
    return backend_consumes(cfg.segmentation) == "labels" and msgtype == IMAGE_T


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
    and every worker process is stopped. :func:`semmap.load_map` reads the folder back.
    """
    t_start = time.perf_counter()
    inputs = [p for p in (tour, calibration, config if not isinstance(config, BuildConfig) else None) if p]
    with contextlib.suppress(BagError):  # the bag inside a tour folder is an input too (opening it says why not)
        inputs.append(resolve_bag_path(tour))
    with _KeptWarnings() as warned, atomic_dir(out, force, marker=MAP_MARKER, inputs=inputs,
                                               what="semmap map folder") as tmp, read_bag(tour, lazy=True) as bag:
        tinfo, cfg = open_build_tour(tour, config, calibration, overrides, source=bag)
        cfg = _effective_config(tinfo, cfg)
        cfg = _resolve_odometry_offset(tinfo, bag, cfg)
        _log_detected(tinfo, cfg)
        if tinfo.topics.image is None:
            log.warning("%s: no camera topic; building a LiDAR-only map (no classes)", tinfo.bag)
        class_names = tour_class_names(tinfo, cfg)
        check_grid_memory(cfg.grid, cfg.registration.max_range, len(class_names))
        run = _run(tinfo, bag, cfg, class_names, progress)
        if run.stream.counts.scans == 0:
            raise BagError(f"{tinfo.bag}: no usable scans on {tinfo.topics.scan}")
        _warn_about_painting(tinfo, cfg, run)
        _warn_about_registration(tinfo, cfg, run)
        outcome = _outcome(tinfo, cfg, class_names, run, warned.lines(), t_start)
        summary = write_map_folder(tmp, outcome)
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


def _run(tinfo: Tour, bag: OpenBag, cfg: BuildConfig, class_names: tuple[str, ...],
         progress: ProgressFn | None) -> _Run:
    """Start the stages, stream the tour through them, and stop them, whatever happens."""
    images: ImageSource | None = None
    mapper: Mapper | None = None
    try:
        msgtype = tinfo.types.get(tinfo.topics.image or "", "")
        # scans paired with a frame the selection skipped take structure and furniture labels in the mapping,
        # through the registered poses (LabelTransfer)
        transfer = (tinfo.topics.image is not None and tinfo.calibration is not None
                    and not every_frame(cfg.segmentation))
        if cfg.workers:  # started first: they load their libraries while the rest is set up
            mapper = MapperWorkers(cfg.registration, cfg.grid, class_names, transfer=transfer)
        else:
            mapper = InProcessMapper(cfg.registration, cfg.grid, class_names, transfer=transfer)
        if tinfo.topics.image is not None:
            odometry, need = selection_odometry(tinfo, cfg), need_context(tinfo, cfg)
            if cfg.workers and not _images_are_light(cfg, msgtype):
                intr = tinfo.calibration.intrinsics if tinfo.calibration is not None else None
                shape = (intr.height, intr.width) if intr is not None else None
                images = ImageWorker(tinfo.bag, tinfo.topics.image, cfg.segmentation, shape, odometry=odometry,
                                     need=need)
            else:
                images = InProcessImages(tinfo.bag, tinfo.topics.image, cfg.segmentation,
                                         make_selector(cfg.segmentation, odometry, need))
        painter = Painter(tinfo.T_base_lidar, tinfo.calibration, class_names,
                          load_class_table(cfg.segmentation.classes_file), cfg.paint, cfg.sync,
                          cfg.grid.no_return_range,
                          memory=label_memory(cfg.segmentation, cfg.grid.resolution))
        for part in (images, mapper):  # workers load their libraries before the clock starts
            if part is not None:
                part.wait_ready()
        return _stream(tinfo, bag, cfg, painter, images, mapper, progress)
    finally:
        for stage in (images, mapper):
            if stage is not None:
                stage.close()


def _stream(tinfo: Tour, bag: OpenBag, cfg: BuildConfig, painter: Painter, images: ImageSource | None,
            mapper: Mapper, progress: ProgressFn | None) -> _Run:
    """The streaming loop: read scans and odometry, paint, hand over; then wait for the mapping stages."""
    stream = ScanStream(tinfo, cfg.sync, images, progress, bag=bag)
    trace, timers = _Trace(), _Timers()
    no_image = no_odom = 0
    n_classes = len(painter.class_names)
    mobility_hits = np.zeros(4, np.int64)
    class_hits = np.zeros(n_classes, np.int64)
    t_loop = time.perf_counter()
    cpu_loop = time.process_time()
    for item in stream:
        t0 = time.perf_counter()
        transferred = painter.stats.transferred
        try:
            res = painter.paint(item.scan, item.odometry, item.segmentation)
        except BagError as exc:  # a label image that does not fit the calibration
            raise BagError(f"{tinfo.bag}: {tinfo.topics.image}: {exc}") from None
        t1 = time.perf_counter()
        mapper.push(res.painted, res.odom_pose)
        timers.paint += t1 - t0
        timers.hand_over += time.perf_counter() - t1  # the mapper times its own work
        no_image += item.segmentation is None
        no_odom += item.odometry is not None and res.odom_pose is None
        hit = res.painted.hit
        mobility_hits += np.bincount(res.painted.mobility[hit], minlength=4)[:4]
        cls = res.painted.class_id[hit]
        cls = cls[cls >= 0]
        if cls.size:
            class_hits += np.bincount(cls, minlength=n_classes)[:n_classes]
        trace.add(res.painted.stamp_ns, res.odom_pose,
                  1 if res.view is not None else 2 if painter.stats.transferred > transferred else 0)
    t_wait = time.perf_counter()
    result = mapper.finish()
    timers.hand_over += time.perf_counter() - t_wait  # waiting for the mapping workers to catch up
    loop_s = time.perf_counter() - t_loop
    image_counts = dict(images.counts) if images is not None else {"images": 0, "bad_images": 0}
    cpu_s = {"main": round(time.process_time() - cpu_loop, 3), **result.cpu_s}
    if "cpu_s" in image_counts:
        cpu_s["images"] = image_counts["cpu_s"]
    timers.wait_images = stream.wait_images_s
    timers.read = max(0.0, loop_s - timers.paint - timers.hand_over - timers.wait_images)
    return _Run(stream, painter, result, trace, timers, image_counts, loop_s, cpu_s, no_image, no_odom,
                mobility_hits, class_hits)


def _outcome(tinfo: Tour, cfg: BuildConfig, class_names: tuple[str, ...], run: _Run, warnings: list[str],
             t_start: float) -> BuildOutcome:
    """Clean the fused grid and gather what the map folder holds."""
    from .grid import clean
    from .grid.clean import crop_to_observed

    t0 = time.perf_counter()
    layers = run.result.layers
    cleaned = clean(layers, cfg.cleaning, class_names)
    layers, cleaned = crop_to_observed(layers, cleaned, margin_m=1.0)
    run.timers.clean = time.perf_counter() - t0
    stamps, odom = run.trace.stamps, run.trace.odom
    poses = np.asarray(run.result.poses, np.float64).reshape(-1, 3)
    n = run.stream.counts.scans
    span_s = float((stamps[-1] - stamps[0]) * 1e-9) if n > 1 else 0.0
    ps = run.painter.stats
    by_class: dict[str, int] = {}
    for o in cleaned.objects:
        by_class[o.class_name] = by_class.get(o.class_name, 0) + 1
    spec = cleaned.spec
    observed = int(np.count_nonzero(layers.observed))
    consistency = None
    if run.result.endpoints is not None:
        from .grid.consistency import consistency_score, place

        xy, scan_of = run.result.endpoints
        score = consistency_score(place(xy, scan_of, poses), cleaned.occupied, spec)
        consistency = ConsistencySummary(**score.as_dict())
    t = run.timers
    loop = run.loop_s
    summary = BuildSummary(
        semmap_version=__version__,
        map_folder_version=MAP_FOLDER_VERSION,
        created_unix_s=round(time.time(), 3),
        machine=f"{platform.machine()}, Python {platform.python_version()}",
        tour=TourSummary(
            bag=str(tinfo.bag),
            scenario=tinfo.manifest.get("scenario"),
            duration_s=round(span_s, 3),
            topics=TourTopics(scan=tinfo.topics.scan, image=tinfo.topics.image,
                              image_kind=tinfo.topics.image_kind, odometry=tinfo.topics.odometry_source,
                              tf_static=tinfo.topics.tf_static),
            frames=TourFrames(base=tinfo.base_frame, lidar=tinfo.lidar_frame, map="map"),
            T_base_lidar=np.round(tinfo.T_base_lidar, 9).tolist(),
            T_base_lidar_source=tinfo.T_base_lidar_source,
            calibration=tinfo.calibration_source or None,
        ),
        messages=MessagesSummary(read=run.stream.read_stats.read, skipped=run.stream.read_stats.skipped,
                                 odometry_out_of_order=(run.stream.odometry.out_of_order
                                                        if run.stream.odometry is not None else 0)),
        counts=CountsSummary(**run.counts, images=run.image_counts.get("images", 0),
                             bad_images=run.image_counts.get("bad_images", 0),
                             skipped_images=run.image_counts.get("skipped_frames", 0)),
        painting=PaintingSummary(
            class_list=getattr(cfg.segmentation, "class_list", None) if class_names else None,
            backend=cfg.segmentation.backend if class_names else None,
            scans_painted=ps.painted,
            frame_selection=FrameSelectionSummary(
                select=cfg.segmentation.select, max_rate=cfg.segmentation.max_rate,
                max_frames=cfg.segmentation.max_frames, max_seconds=cfg.segmentation.max_seconds,
                frames_segmented=run.image_counts.get("images", 0),
                frames_skipped=run.image_counts.get("skipped_frames", 0),
                scans_from_memory=ps.transferred,
                returns_labelled_from_memory=ps.points_transferred + run.result.returns_labelled,
            ) if class_names else None,
            readings_below_range_min_fraction=round(ps.below_range_min / max(ps.beams, 1), 4),
            readings_below_range_min_unblocked_fraction=round(ps.below_range_min_unblocked / max(ps.beams, 1), 4),
            readings_nan_fraction=round(ps.nan_readings / max(ps.beams, 1), 4),
            readings_nan_unblocked_fraction=round(ps.nan_unblocked / max(ps.beams, 1), 4),
            blocked_beams=ps.blocked_beams,
            blocked_sectors=[{"first_deg": round(float(np.degrees(a)), 2), "last_deg": round(float(np.degrees(b)), 2),
                              "beams": k} for bl in ps.blocked.values() for a, b, k in bl.sectors],
            points_in_view_fraction=round(ps.points_in_view / max(ps.points_total, 1), 4),
            occlusion_filter=OcclusionSummary(
                on=cfg.paint.occlusion.filter,
                points_relabelled=ps.occlusion_relabelled,
                points_relabelled_per_painted_scan=round(ps.occlusion_relabelled / max(ps.painted, 1), 2),
                points_relabelled_max_per_scan=ps.occlusion_max_per_scan,
                scans_with_relabelled_points=ps.occlusion_scans,
            ),
            hits_by_mobility={m: int(v) for m, v in zip(("unknown", "static", "semi_static", "dynamic"),
                                                       run.mobility_hits)},
            hits_by_class={class_names[i]: int(v) for i, v in enumerate(run.class_hits) if v > 0},
        ),
        registration={"mode": cfg.registration.mode, **run.result.registration},
        warnings=warnings,
        map=MapSummary(
            resolution=spec.resolution,
            origin=[spec.origin_x, spec.origin_y, 0.0],
            size_cells=[spec.width, spec.height],
            size_m=[round(spec.width * spec.resolution, 2), round(spec.height * spec.resolution, 2)],
            occupied_cells=int(cleaned.occupied.sum()),
            free_cells=int(cleaned.free.sum()),
            semi_static_cells=int(cleaned.semi_static.sum()),
            dynamic_cells_removed=int(cleaned.dynamic_removed.sum()),
            semi_static_objects=len(cleaned.objects),
            semi_static_objects_by_class=by_class,
            observed_cells=observed,
            grid_tiles=run.result.layers.grid_tiles or None,
            grid_bytes=run.result.layers.grid_bytes or None,
            grid_bytes_per_observed_cell=(round(run.result.layers.grid_bytes / observed, 1)
                                          if run.result.layers.grid_bytes and observed else None),
        ),
        timings_s=TimingsSummary(
            read=round(t.read, 3), paint=round(t.paint, 3), hand_over=round(t.hand_over, 3),
            wait_images=round(t.wait_images, 3), clean=round(t.clean, 3), write=0.0,
            register_busy=round(run.result.register_busy_s, 3), fuse_busy=round(run.result.fuse_busy_s, 3),
            loop=round(loop, 3), total=0.0,
            segmentation_busy=round(run.image_counts.get("segment_ms", 0) / 1000.0, 3), workers=cfg.workers),
        cpu_s={**run.cpu_s, "total": round(sum(run.cpu_s.values()), 3),
               "per_scan_ms": round(1000 * sum(run.cpu_s.values()) / n, 3) if n else None},
        throughput=ThroughputSummary(
            scans_per_s=round(n / loop, 1) if loop > 0 else None,
            scans_per_s_end_to_end=None,  # the writer fills it in, at the end
            real_time_factor=round(span_s / loop, 1) if loop > 0 and span_s > 0 else None,
        ),
        peak_rss_mb=0.0,  # the writer fills it in, at the end
        peak_rss_mb_workers={**run.result.peak_rss_mb,
                             **({"images": run.image_counts["peak_rss_mb"]}
                                if "peak_rss_mb" in run.image_counts else {})},
        files=[],
        consistency=consistency,
    )
    return BuildOutcome(config=cfg, class_names=class_names, layers=layers, cleaned=cleaned, stamps_ns=stamps,
                        poses=poses, odometry=odom, summary=summary, started=t_start, labels_from=run.trace.labels)


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
        "odometry": ("tf" if tinfo.topics.odometry_tf is not None else tinfo.topics.odometry) or "none",
        "camera_info": tinfo.topics.camera_info,
        **({"labels": tinfo.topics.image} if tinfo.topics.image_kind == "labels" else {}),
        **({"image": tinfo.topics.image} if tinfo.topics.image_kind == "rgb" else {}),
    })
    frames = cfg.frames.model_copy(update={"base": tinfo.base_frame, "lidar": tinfo.lidar_frame,
                                           **({"odom": tinfo.topics.odometry_tf.odom_frame}
                                              if tinfo.topics.odometry_tf is not None else {})})
    update: dict[str, Any] = {"topics": topics, "frames": frames, "registration": reg}
    if tinfo.calibration_path is not None:
        update["calibration"] = tinfo.calibration_path.resolve()
    return cfg.model_copy(update=update)


def _resolve_odometry_offset(tinfo: Tour, bag: OpenBag, cfg: BuildConfig) -> BuildConfig:
    """``sync.odometry_offset: auto``: estimate the odometry's clock offset from the tour's first scans
    (:func:`~semmap.register.timing.estimate_odometry_offset`); the config then holds the number used."""
    if cfg.sync.odometry_offset != "auto":
        return cfg
    offset = 0.0
    if tinfo.topics.odometry:
        from .paint.stream import sample_scans_and_odometry
        from .register.timing import estimate_odometry_offset

        t0 = time.perf_counter()
        stamps, points, ot, op = sample_scans_and_odometry(tinfo, bag)
        est = estimate_odometry_offset(stamps, points, ot, op[:, 2], cfg.registration)
        if est.used:
            offset = round(float(est.offset_s), 3)
            log.warning("the odometry on %s is stamped %.0f ms %s the scans on %s: shifted by that, its turns "
                        "agree with scan matching's (RMS %.4f rad per scan instead of %.4f); the odometry is "
                        "shifted (sync.odometry_offset: %g; 0 keeps the stamps)", tinfo.topics.odometry_source,
                        abs(offset) * 1000, "before" if offset > 0 else "after", tinfo.topics.scan,
                        est.rms_at_best, est.rms_at_zero, offset)
        else:
            log.info("odometry clock offset: none applied (%s; %d scans, %.3f s)", est.reason, est.scans,
                     time.perf_counter() - t0)
    return cfg.model_copy(update={"sync": cfg.sync.model_copy(update={"odometry_offset": offset})})


def _log_detected(tinfo: Tour, cfg: BuildConfig) -> None:
    """``-v``: what was found in the data, and where it came from."""
    t = tinfo.topics
    log.info("tour %s: scans %s (frame %s), odometry %s, %s %s, camera_info %s", tinfo.bag, t.scan,
             tinfo.lidar_frame, t.odometry_source or "none", "label images" if t.image_kind == "labels" else "images",
             t.image or "none", t.camera_info or "none")
    xyz = np.round(tinfo.T_base_lidar[:3, 3], 3).tolist()
    yaw = float(np.degrees(np.arctan2(tinfo.T_base_lidar[1, 0], tinfo.T_base_lidar[0, 0])))
    log.info("T_base_lidar (%s -> %s) from %s: xyz %s m, yaw %.1f deg", tinfo.base_frame, tinfo.lidar_frame,
             tinfo.T_base_lidar_source, xyz, yaw)
    if tinfo.calibration is not None:
        log.info("calibration %s: %dx%d camera, camera image %s", tinfo.calibration_path or "from the bag",
                 tinfo.calibration.intrinsics.width, tinfo.calibration.intrinsics.height,
                 tinfo.calibration.camera_frame)
    log.info("registration %s; segmentation backend %s; scans paired with images within %.3f s",
             cfg.registration.mode, cfg.segmentation.backend, cfg.sync.max_image_offset)


def _warn_about_registration(tinfo: Tour, cfg: BuildConfig, run: _Run) -> None:
    """Say so when registration ran on less than it should have: scans without odometry, ICP results
    gated out or failed, filter restarts, each above a few per cent of the scans."""
    r = run.result.registration
    n = max(int(r.get("scans", 0)), 1)
    mode = cfg.registration.mode
    missing = int(r.get("odom_missing", 0))
    if tinfo.topics.odometry and missing > 0.02 * n:
        what = {"fused": "registered by ICP alone", "odometry": "placed by extrapolating the last motion",
                "icp": "unaffected (icp mode)"}[mode]
        log.warning("%d of %d scans (%.0f %%) had no odometry on %s at their stamp (a gap longer than "
                    "sync.max_odom_gap, %.2f s, or none at all): they were %s", missing, n, 100 * missing / n,
                    tinfo.topics.odometry_source, cfg.sync.max_odom_gap, what)
    if mode == "fused":
        rejected, resets = int(r.get("icp_rejected", 0)), int(r.get("filter_resets", 0))
        if rejected > 0.05 * n:
            hint = ("set registration.ekf.fit_margin: 0 to take ICP where the scan fits the map better, or try "
                    "registration.mode icp or odometry, and compare" if cfg.registration.ekf.fit_margin >= 1.0
                    else "try registration.mode icp or odometry and compare")
            log.warning("%d of %d ICP results (%.0f %%) were gated out by the odometry filter: odometry and scan "
                        "matching disagree often; walls may double (%s)", rejected, n, 100 * rejected / n, hint)
        if resets > 0.01 * n:
            log.warning("the odometry filter restarted %d times (%.1f %% of the scans), each a jump of the pose",
                        resets, 100 * resets / n)
    if mode != "odometry":
        failed = int(r.get("icp_failed", 0))
        if failed > 0.05 * n:
            log.warning("ICP failed on %d of %d scans (%.0f %%): too few points in range (registration.min_points, "
                        "max_range) or an empty local map", failed, n, 100 * failed / n)


def _warn_about_painting(tinfo: Tour, cfg: BuildConfig, run: _Run) -> None:
    """Report the LiDAR's blocked beams, and readings below range_min or NaN that clear no free space (or
    clear it where they should not); say so when the camera labelled (almost) nothing, and why."""
    ps = run.painter.stats
    scan_topic, beams = tinfo.topics.scan, max(ps.beams, 1)
    for blocked in ps.blocked.values():  # per beam layout; angles as the scans give them
        if blocked.count:
            sectors = ", ".join(f"{np.degrees(a):.1f}° to {np.degrees(b):.1f}° ({k})"
                                for a, b, k in blocked.sectors[:4])
            more = f" and {len(blocked.sectors) - 4} more sectors" if len(blocked.sectors) > 4 else ""
            log.warning("beams %s%s on %s read below range_min or NaN in (nearly) every one of %d scans: masked "
                        "as blocked, they clear no free space", sectors, more, scan_topic, blocked.scans)
    # the advice counts only the beams that see out otherwise: a blocked sector would clear through walls
    if cfg.paint.below_range_min == "invalid" and ps.below_range_min_unblocked > 0.02 * beams:
        log.warning("%.0f %% of the readings on %s are below range_min on beams not blocked, and clear no free "
                    "space; if the driver reports 'nothing seen' this way (Hokuyo URG does), set "
                    "paint.below_range_min: no_return", 100 * ps.below_range_min_unblocked / beams, scan_topic)
    if ps.nan_unblocked > 0.03 * beams:
        # where nothing is within range the returns beside the NaN readings are far; beside dropouts (glass,
        # black surfaces) they are at any range
        far = ps.returns_beside_nan_far / max(ps.returns_beside_nan, 1)
        share = 100 * ps.nan_unblocked / beams
        if cfg.paint.nan_readings == "invalid" and far >= 0.5:
            log.warning("%.0f %% of the readings on %s are NaN on beams not blocked, and clear no free space; "
                        "%.0f %% of the returns beside them are beyond half the range limit, as where nothing is "
                        "within range: if the driver reports that as NaN, set paint.nan_readings: no_return", share,
                        scan_topic, 100 * far)
        elif cfg.paint.nan_readings == "invalid":
            log.warning("%.0f %% of the readings on %s are NaN on beams not blocked, and clear no free space "
                        "(the returns beside them are mostly near, so they look like dropouts rather than "
                        "'nothing within range')", share, scan_topic)
        elif far < 0.5:
            log.warning("%.0f %% of the readings on %s are NaN, read as 'nothing within range' "
                        "(paint.nan_readings: no_return), but only %.0f %% of the returns beside them are beyond "
                        "half the range limit: if they are dropouts, they clear free space through walls; "
                        "consider paint.nan_readings: invalid", share, scan_topic, 100 * far)
    if tinfo.topics.image is None:
        return
    n = run.stream.counts.scans
    with_image = n - run.scans_without_image
    images = run.image_counts.get("images", 0)
    log.info("%d of %d scans were paired with an image (%d images read on %s); %.1f %% of their returns fell "
             "into the image", with_image, n, images, tinfo.topics.image,
             100 * ps.points_in_view / max(ps.points_paired, 1))
    if with_image < 0.1 * n:
        if images == 0:
            why = f"no frame on {tinfo.topics.image} could be read or segmented"
        elif run.stream.counts.unpaired_offsets_ns:
            off = float(np.median(run.stream.counts.unpaired_offsets_ns)) * 1e-9
            why = (f"the nearest image was typically {off:.3f} s from a scan, more than sync.max_image_offset "
                   f"({cfg.sync.max_image_offset} s): are the camera's stamps on another clock, or is "
                   f"the camera much slower than the LiDAR?")
        else:
            why = "the images do not overlap the scans in time"
        log.warning("only %d of %d scans were paired with an image on %s: %s", with_image, n, tinfo.topics.image,
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
