"""The scan stream: every LiDAR scan of a tour, paired with the camera's segmentation and the odometry
around it, in scan order, one at a time.

This is the streaming core that ``semmap build`` and ``semmap paint`` share::

    from semmap.paint.stream import ScanStream

    for item in ScanStream(tour, cfg.sync, images):
        result = painter.paint(item.scan, item.odometry, item.segmentation)

With a frame selection (``segmentation.select``), a scan paired with a skipped frame comes out of the
painter with people's labels only; :class:`~semmap.paint.painter.LabelTransfer` gives it the structure
and furniture labels of the segmented frames, fed every painted scan in order with the pose it is
mapped at (``semmap build`` does this after registration; a painter built with
``label_memory(..., places=True)`` does it through the odometry instead).

It buffers just enough to pair each scan:

* A scan waits until the odometry reaches past its sweep and the latest image it may be paired
  with (deskewing and motion compensation interpolate there), or until it has waited
  ``sync.max_wait_s`` of bag time or ``sync.max_wait_scans`` scans: odometry that stops or never
  comes does not hold the tour back.
* Its segmentation is the one of the image nearest the scan's middle beam, within
  ``sync.max_image_offset``; segmentations are pulled from the :class:`ImageSource` only as far as
  that needs, and handed back once the pairing window has passed them by
  ``sync.keep_images_s``.
* Odometry older than ``sync.keep_odometry_s`` before the scan is forgotten once it is yielded.

Odometry comes from the tour's Odometry topic, or from ``/tf`` (``tour.topics.odometry_tf``: the
``odom → base`` transform of each ``/tf`` message, composed with the fixed chain to the base frame;
the other transforms are ignored), read in the same pass as the scans.

Scans with no beams, or an angle increment of 0 or NaN, are skipped and counted
(``counts.bad_scans``); so are scans whose stamp or middle beam is not after the last one's
(``counts.scans_out_of_order``).
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..config import BuildConfig, SyncConfig, merge_overrides
from ..errors import BagError
from ..io.bag import OpenBag, ReadStats, read_bag
from ..io.tour import Tour, load_build_config, open_tour
from ..records import Scan, Segmentation
from ..segment.base import backend_consumes
from ..segment.images import ImageSource, OdometrySource
from ..segment.select import SkippedFrame
from .motion import OdomTrack
from .painter import Painter

__all__ = ["PairedScan", "ScanStream", "StreamCounts", "odometry_offset_ns", "open_build_tour", "selection_odometry",
           "tour_class_names"]

ProgressFn = Callable[[int, int], None]

_OdomRecord = tuple[int, str, str, NDArray[np.float64]]

#: scans with no image close enough: the nearest image's offsets kept for the warning at the end (at most)
_MAX_OFFSETS_KEPT = 4096


@dataclass(frozen=True)
class PairedScan:
    """One scan and what it is painted with.

    ``segmentation``: the paired image's segmentation (None: no image within
    ``sync.max_image_offset``, or the tour has no camera; a :class:`SkippedFrame`: the paired image was
    not segmented, ``segmentation.select``). ``odometry``: the odometry track around
    the scan (None: the tour has no odometry); it is the stream's live track, valid until the next
    item is asked for.
    """

    scan: Scan
    segmentation: Segmentation | SkippedFrame | None
    odometry: OdomTrack | None


@dataclass
class StreamCounts:
    """What the stream read and skipped."""

    scans: int = 0  # yielded
    odometry: int = 0  # odometry messages read (from /tf: odometry transforms)
    bad_scans: int = 0
    scans_out_of_order: int = 0
    #: scans with no image close enough: how far the nearest one was, ns (at most 4096 kept)
    unpaired_offsets_ns: list[int] = field(default_factory=list)


class ScanStream:
    """The scans of ``tour`` paired with segmentations from ``images`` and with the odometry.

    Iterate once. ``bag``: the tour's bag already opened (:func:`~semmap.io.bag.read_bag`, as
    :func:`open_build_tour` used it), else it is opened here; either way it is closed when the
    iteration ends (or the iterator is closed). ``images`` is not closed here: its owner closes it.
    ``progress(done, total)`` is called every 50 scan messages and at the end.
    """

    def __init__(self, tour: Tour, sync: SyncConfig, images: ImageSource | None = None,
                 progress: ProgressFn | None = None, bag: OpenBag | None = None) -> None:
        self.tour = tour
        self._bag = bag
        self.sync = sync
        self.images = images
        self.progress = progress
        self.counts = StreamCounts()
        self.read_stats = ReadStats()
        #: the odometry track (None: the tour has no odometry topic)
        self.odometry = OdomTrack(sync.max_odom_gap) if tour.topics.odometry else None
        self._odom_tf = tour.topics.odometry_tf  # odometry from /tf: the transform that carries it
        #: added to odometry stamps to put them on the scans' clock (sync.odometry_offset; "auto" is
        #: resolved by the build before it streams, and taken as 0 by anything that does not)
        self._odom_offset_ns = odometry_offset_ns(sync)
        #: seconds spent waiting for segmentations (a slow model shows here)
        self.wait_images_s = 0.0
        self._segs: deque[Segmentation | SkippedFrame] = deque()
        self._images_done = images is None
        self._pending: deque[tuple[int, Scan]] = deque()  # (bag time, scan)
        self._max_offset_ns = int(sync.max_image_offset * 1e9)
        self._keep_images_ns = int(sync.keep_images_s * 1e9)
        self._keep_odom_ns = int(max(sync.keep_odometry_s, sync.max_image_offset) * 1e9)
        self._max_wait_ns = int(sync.max_wait_s * 1e9)
        self._last_scan_ns: tuple[int, int] | None = None  # stamp and reference time of the last scan

    def __iter__(self) -> Iterator[PairedScan]:
        tour = self.tour
        scan_topic = tour.topics.scan
        topics = [t for t in (scan_topic, tour.topics.odometry) if t]
        with contextlib.ExitStack() as stack:  # opened once: the tour, counting and streaming share its index
            bag = self._bag if self._bag is not None else stack.enter_context(read_bag(tour.bag, lazy=True))
            stack.callback(bag.close)
            total = bag.count(scan_topic)
            read = self.read_stats.read
            for topic, t_bag, record in bag.records(topics, self.read_stats):
                if topic == scan_topic:
                    self._on_scan(t_bag, record)
                    if self.progress is not None and read.get(topic, 0) % 50 == 0:
                        self.progress(read.get(topic, 0), total)
                else:
                    self._on_odometry(record)
                while self._pending and self._ready(t_bag, *self._pending[0]):
                    yield from self._pair(self._pending.popleft()[1])
            while self._pending:
                yield from self._pair(self._pending.popleft()[1])
        if self.progress is not None:
            self.progress(total, total)

    # -- inputs -----------------------------------------------------------------------------
    def _on_odometry(self, record: _OdomRecord | list[_OdomRecord]) -> None:
        """An Odometry message (stamp, frame, child frame, pose), or a /tf message's transforms
        (stamp, parent, child, T_parent_child)."""
        assert self.odometry is not None
        if self._odom_tf is not None:
            assert isinstance(record, list)
            for stamp, pose in self._odom_tf.poses(record):
                self.odometry.add(stamp + self._odom_offset_ns, pose)
                self.counts.odometry += 1
            return
        assert isinstance(record, tuple)
        stamp, _, _, pose = record
        self.odometry.add(stamp + self._odom_offset_ns, pose)
        self.counts.odometry += 1

    def _on_scan(self, t_bag: int, scan: Scan) -> None:
        if scan.ranges.size == 0 or not np.isfinite(scan.angle_increment) or scan.angle_increment == 0:
            self.counts.bad_scans += 1
            return
        self._pending.append((t_bag, scan))

    # -- pairing ------------------------------------------------------------------------------
    @staticmethod
    def _end_ns(scan: Scan) -> int:
        return scan.stamp_ns + int(scan.time_increment * 1e9 * scan.ranges.size)

    def _ready(self, t_bag_now: int, scan_bag: int, scan: Scan) -> bool:
        # odometry must reach past the sweep and the latest image it may be paired with (motion compensation)
        need = self._end_ns(scan) + self._max_offset_ns
        odom = self.odometry
        odom_ok = odom is None or (odom.last_ns is not None and odom.last_ns >= need)
        waited = t_bag_now - scan_bag > self._max_wait_ns or len(self._pending) > self.sync.max_wait_scans
        return odom_ok or waited

    def _pair(self, scan: Scan) -> Iterator[PairedScan]:
        # repeated or backwards stamps, or a sweep whose middle comes before the last one's: skipped, counted
        ref = Painter.reference_ns(scan)
        if self._last_scan_ns is not None and (scan.stamp_ns <= self._last_scan_ns[0] or ref <= self._last_scan_ns[1]):
            self.counts.scans_out_of_order += 1
            return
        self._last_scan_ns = (scan.stamp_ns, ref)
        t0 = time.perf_counter()
        seg = self._segmentation(scan)
        self.wait_images_s += time.perf_counter() - t0
        self.counts.scans += 1
        yield PairedScan(scan, seg, self.odometry)
        if self.odometry is not None:
            self.odometry.trim(scan.stamp_ns - self._keep_odom_ns)  # forget what no future scan needs

    def _segmentation(self, scan: Scan) -> Segmentation | SkippedFrame | None:
        """The segmentation nearest the scan's middle, pulling images only as far as needed."""
        mid = scan.stamp_ns + (self._end_ns(scan) - scan.stamp_ns) // 2
        segs = self._segs
        while not self._images_done and (not segs or segs[-1].stamp_ns < mid + self._max_offset_ns):
            assert self.images is not None
            seg = self.images.next()
            if seg is None:
                self._images_done = True
            else:
                segs.append(seg)
        while len(segs) > 1 and segs[0].stamp_ns < mid - self._max_offset_ns - self._keep_images_ns:
            assert self.images is not None
            self.images.release(segs.popleft())
        if not segs:
            return None
        best = min(segs, key=lambda s: abs(s.stamp_ns - mid))
        if abs(best.stamp_ns - mid) <= self._max_offset_ns:
            return best
        if len(self.counts.unpaired_offsets_ns) < _MAX_OFFSETS_KEPT:
            self.counts.unpaired_offsets_ns.append(abs(best.stamp_ns - mid))
        return None


def open_build_tour(tour: str | Path, config: str | Path | BuildConfig | None = None,
                    calibration: str | Path | None = None, overrides: dict[str, Any] | None = None,
                    source: OpenBag | None = None) -> tuple[Tour, BuildConfig]:
    """The effective config and the opened tour, as ``semmap build`` sees them (also ``semmap paint``).
    ``source``: the tour's bag, opened once for the whole build (:func:`~semmap.io.bag.read_bag`); pass
    it on to :class:`ScanStream`.

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
    seg = cfg.segmentation
    if (tinfo.manifest.get("label_classes") and "class_list" in type(seg).model_fields
            and "class_list" not in seg.model_fields_set):
        seg_cfg = seg.model_copy(update={"class_list": tinfo.manifest["label_classes"]})
        cfg = cfg.model_copy(update={"segmentation": seg_cfg})
    return tinfo, cfg


def selection_odometry(tour: Tour, cfg: BuildConfig) -> OdometrySource | None:
    """What the frame selection (``segmentation.select``) reads the robot's motion from: the tour's
    odometry, on the scans' clock (None: the tour has none)."""
    if not tour.topics.odometry:
        return None
    return OdometrySource(tour.topics.odometry, tour.topics.odometry_tf, odometry_offset_ns(cfg.sync))


def odometry_offset_ns(sync: SyncConfig) -> int:
    """``sync.odometry_offset`` in ns, added to odometry stamps ("auto" is resolved by the build before it
    streams, and taken as 0 by anything that does not)."""
    offset = sync.odometry_offset
    return int(round(offset * 1e9)) if isinstance(offset, float) else 0


def tour_class_names(tour: Tour, cfg: BuildConfig) -> tuple[str, ...]:
    """The class names the tour's scans are painted with: the segmenter's (none without a camera)."""
    if tour.topics.image is None:
        return ()
    from ..segment.base import create_segmenter

    probe = create_segmenter(cfg.segmentation)  # backends load their models lazily
    try:
        return tuple(probe.names)
    finally:
        probe.close()


def sample_scans_and_odometry(tour: Tour, bag: OpenBag, max_scans: int = 600, max_s: float = 90.0,
                              ) -> tuple[NDArray[np.int64], list[NDArray[np.float64]], NDArray[np.int64],
                                         NDArray[np.float64]]:
    """The tour's first scans (up to ``max_scans`` or ``max_s`` of bag time) as the times of their middle
    beams and base-frame points (N, 2) of their returns (not deskewed), and the odometry read alongside
    (stamps, (M, 3) poses, on its own clock). Messages that cannot be decoded are left out; the build
    reads them again, and says so."""
    topics = [t for t in (tour.topics.scan, tour.topics.odometry) if t]
    odom_tf = tour.topics.odometry_tf
    R = tour.T_base_lidar[:2, :2]
    o = tour.T_base_lidar[:2, 3]
    stamps: list[int] = []
    points: list[NDArray[np.float64]] = []
    ot: list[int] = []
    op: list[NDArray[np.float64]] = []
    t_first: int | None = None
    t_last_scan: int | None = None
    for topic, t_bag, record in bag.records(topics, skip=lambda _t, _e: None):
        if t_first is None:
            t_first = t_bag
        if topic == tour.topics.scan:
            if t_last_scan is not None or len(stamps) >= max_scans or t_bag - t_first > max_s * 1e9:
                if t_last_scan is None:
                    t_last_scan = t_bag
                if t_bag - t_last_scan > 1e9:  # odometry a second past the last scan taken, for shifts
                    break
                continue
            scan: Scan = record
            if scan.ranges.size == 0 or not np.isfinite(scan.angle_increment) or scan.angle_increment == 0:
                continue
            r = scan.ranges.astype(np.float64)
            hit = (r >= max(scan.range_min, 1e-3)) & (r <= scan.range_max)
            a = scan.angles[hit]
            xy = np.column_stack([r[hit] * np.cos(a), r[hit] * np.sin(a)]) @ R.T + o
            stamps.append(Painter.reference_ns(scan))  # the time of the middle beam, as painted scans have it
            points.append(xy)
        elif odom_tf is not None:
            for stamp, pose in odom_tf.poses(record):
                ot.append(stamp)
                op.append(pose)
        else:
            stamp, _, _, pose = record
            ot.append(stamp)
            op.append(pose)
    return (np.asarray(stamps, np.int64), points, np.asarray(ot, np.int64),
            np.asarray(op, np.float64).reshape(-1, 3))
