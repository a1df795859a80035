"""``segmentation.select: need``: segment a frame when what it looks at lacks camera evidence.

The selector runs where the model runs (the image worker), ahead of the mapping, so the mapping never
waits for its decisions. It reads the LiDAR scans and the odometry in the same pass as the images and
keeps its own record of what the camera has said about each place, in cells of ``need_cell`` (0.25 m)
in the odometry frame:

* Before the model sees a frame, the latest scan is projected into the camera (the painter, with a
  blank mask): the returns the frame would label. Each lacks evidence in proportion to how far its cell
  is from ``need_frames`` segmented frames in a row that gave it one label (a cell never labelled lacks
  it all; a cell a frame labelled furniture has it, as the painter's label memory transfers furniture on
  one frame's word); a cell first hit less than a second ago needs none yet (someone walking through, whom the
  cleaning drops for the free space seen behind them). What the LiDAR alone cannot tell apart is small
  things: a run of returns shorter than 1 m is a leg, a person, a pot or a chair, a longer one a wall
  or a long face. The frame is segmented when the cells in view lack ``need_cells`` cells' worth of
  evidence, a cell on a small thing counting 1 and one on a wall 0.1 (ten new wall cells, a new room,
  count as one new chair).
* After the model has run, the same scan is painted with the frame's mask, and each cell it labels
  counts one frame more, or starts again from one when the label changed (a person walked in front of
  a wall, a chair was moved): a place whose mobility is still undecided keeps being looked at.

So a corridor driven down with its walls already labelled costs no model time; a new room, furniture
seen for the first time, and people (who stand on cells the camera has not labelled yet, or change a
cell's label) do. ``select_interval`` (0 by default) and ``max_rate`` apply on top.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..classes import load_class_table
from ..config import BuildConfig, PaintConfig, SegmentationConfig, SyncConfig
from ..geometry import se2_apply
from ..io.tour import Tour
from ..records import Calibration, Mobility, Scan, Segmentation
from ..segment.select import FrameSelector, OdometrySource
from .painter import Painter, cell_keys, decided_by_one_frame, label_codes, majority_labels

__all__ = ["NeedContext", "NeedSelector", "make_selector", "need_context"]


@dataclass(frozen=True)
class NeedContext:
    """What the need selector must know of the tour besides the segmentation settings (picklable: it
    travels to the image worker)."""

    scan_topic: str
    T_base_lidar: NDArray[np.float64]
    calibration: Calibration
    paint: PaintConfig
    sync: SyncConfig
    no_return_range: float
    classes_file: Path | None


def need_context(tour: Tour, cfg: BuildConfig) -> NeedContext | None:
    """The context for ``select: need`` (None: another selection, or no calibrated camera)."""
    if cfg.segmentation.select != "need" or tour.calibration is None:
        return None
    return NeedContext(tour.topics.scan, np.asarray(tour.T_base_lidar, np.float64), tour.calibration, cfg.paint,
                       cfg.sync, cfg.grid.no_return_range, cfg.segmentation.classes_file)


def make_selector(cfg: SegmentationConfig, odometry: OdometrySource | None,
                  context: NeedContext | None) -> FrameSelector:
    """The selector ``cfg.select`` asks for. ``need`` without odometry or a calibrated camera has no
    place to keep its evidence: it selects as ``motion`` would."""
    if cfg.select == "need" and context is not None and odometry is not None:
        return NeedSelector(cfg, odometry, context)
    if cfg.select == "need":
        cfg = cfg.model_copy(update={"select": "motion"})
    return FrameSelector(cfg, odometry)


#: neighbouring returns farther apart than GAP (m), or than GAP_BEAMS beam spacings at their range, belong
#: to different things; a thing shorter than SMALL_EXTENT (m) end to end and nearer than SMALL_RANGE (m) is
#: small (a leg, a person, a pot, a chair seen from the side); a longer one is a wall or a long face, and a
#: farther one is left to the closer views the robot will have of it
GAP = 0.15
GAP_BEAMS = 3.0
SMALL_EXTENT = 1.0
SMALL_RANGE = 5.0
#: a cell on a wall or a long face lacking evidence counts this much of one on a small thing
WALL_WEIGHT = 0.1
#: a cell the LiDAR has hit for less than this (ns) needs no label yet: someone walking through
PERSIST_NS = 1_000_000_000


def _on_small_things(points: NDArray[np.float64], origin: NDArray[np.float64], step: float) -> NDArray[np.bool_]:
    """For (N, 2) returns in beam order, seen from ``origin`` with beams ``step`` rad apart: whether each lies
    on a small thing (see ``SMALL_EXTENT``)."""
    n = points.shape[0]
    if n == 0:
        return np.zeros(0, bool)
    r = np.linalg.norm(points - origin, axis=1)
    limit = np.maximum(GAP, GAP_BEAMS * abs(step) * np.maximum(r[1:], r[:-1]))
    gap = np.linalg.norm(np.diff(points, axis=0), axis=1) > limit
    run = np.r_[0, np.cumsum(gap)]
    starts = np.r_[0, np.flatnonzero(gap) + 1]
    ends = np.r_[np.flatnonzero(gap), n - 1]
    extent = np.linalg.norm(points[ends] - points[starts], axis=1)
    return (extent < SMALL_EXTENT)[run] & (r < SMALL_RANGE)


class NeedSelector(FrameSelector):
    """``select: need`` (see the module's docstring)."""

    def __init__(self, cfg: SegmentationConfig, odometry: OdometrySource, context: NeedContext) -> None:
        super().__init__(cfg, odometry)
        self.context = context
        self.frames_needed = cfg.need_frames
        self.threshold = cfg.need_cells
        self.cell = cfg.need_cell
        self._table = load_class_table(context.classes_file)
        intr = context.calibration.intrinsics
        self._blank = Segmentation(0, np.zeros((intr.height, intr.width), np.uint16), ())
        self._probe = self._painter_for(())
        self._painter: Painter | None = None  # built at the first segmentation, with the model's class names
        self._scan: Scan | None = None
        self._scan_pose: NDArray[np.float64] | None = None
        self._view: tuple[NDArray[np.int64], NDArray[np.bool_]] | None = None  # the last probe: cells, small
        #: per cell (packed key) and kind of thing (small or not, the lowest bit): [segmented frames in a row
        #: with one label, that label's code]
        self._evidence: dict[int, list[int]] = {}
        #: per cell: when a LiDAR return first landed in it (a cell hit for less than PERSIST_NS so far may be
        #: someone walking through: it needs no label yet)
        self._first_hit: dict[int, int] = {}

    def _painter_for(self, names: tuple[str, ...]) -> Painter:
        c = self.context
        return Painter(c.T_base_lidar, c.calibration, names, self._table, c.paint, c.sync, c.no_return_range)

    @property
    def topics(self) -> list[str]:
        return [*super().topics, self.context.scan_topic]

    def on_record(self, topic: str, record: Any) -> None:
        if topic == self.context.scan_topic:
            if record.ranges.size and np.isfinite(record.angle_increment) and record.angle_increment != 0:
                self._scan, self._scan_pose, self._view = record, self._pose, None
                if self._pose is not None:
                    self._count_hits(record)
            return
        super().on_record(topic, record)

    def _count_hits(self, scan: Scan) -> None:
        """When each cell a return of ``scan`` lands in was first hit."""
        r = scan.ranges.astype(np.float64)
        ok = (r >= max(scan.range_min, 1e-3)) & (r <= scan.range_max)
        a = scan.angles[ok]
        T = self.context.T_base_lidar
        xy = np.column_stack([r[ok] * np.cos(a), r[ok] * np.sin(a)]) @ T[:2, :2].T + T[:2, 3]
        first = self._first_hit
        t = scan.stamp_ns
        for q in np.unique(self._keys(xy)).tolist():
            first.setdefault(q, t)

    def _keys(self, xy_base: NDArray[np.float64]) -> NDArray[np.int64]:
        assert self._scan_pose is not None
        return cell_keys(se2_apply(self._scan_pose, xy_base), self.cell)

    def _in_view(self) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """The latest scan's returns the camera sees: their evidence keys (cell, and whether on a small thing:
        a chair's leg by a wall shares a cell with the wall, not its evidence), and which lie on small things."""
        if self._view is None:
            assert self._scan is not None
            p = self._probe.paint(self._scan, None, self._blank).painted
            on = p.hit & (p.mobility != Mobility.UNKNOWN)
            small = _on_small_things(p.points[p.hit], p.origin, self._scan.angle_increment)[on[p.hit]]
            self._view = ((self._keys(p.points[on]) << 1) | small, small)
        return self._view

    def need(self) -> float | None:
        """How many cells' worth of camera evidence the cells of the latest scan's returns in view lack: a
        cell on a small thing (legs, people, pots) lacking it all counts 1, one on a wall or a long face
        ``WALL_WEIGHT``. None: no scan or pose yet."""
        if self._scan is None or self._scan_pose is None:
            return None
        keys, small = self._in_view()
        if keys.size == 0:
            return 0.0
        k = self.frames_needed
        ev, first = self._evidence, self._first_hit
        assert self._scan is not None
        young = self._scan.stamp_ns - PERSIST_NS

        def frames(q: int) -> int:
            """Of the k frames in a row a cell needs, how many it has: all when first hit a moment ago (no
            label needed yet) or labelled furniture (on one frame's word, as the label memory passes it on)."""
            if first.get(q >> 1, young + 1) > young:
                return k
            e = ev.get(q)
            if e is None:
                return 0
            return k if decided_by_one_frame(e[1]) else min(e[0], k)

        have = np.fromiter((frames(q) for q in keys.tolist()), np.float64, keys.size)
        lack = 1.0 - have / k
        # per cell, not per return: a thing near the robot (many returns) counts as much as one farther away
        cells, one, index = np.unique(keys, return_index=True, return_inverse=True)
        on_small = np.zeros(cells.size, bool)
        np.logical_or.at(on_small, index, small)
        return float((lack[one] * np.where(on_small, 1.0, WALL_WEIGHT)).sum())

    def wanted(self, stamp_ns: int) -> bool:
        if self._last_ns is None:
            return True
        if self.interval_ns > 0 and stamp_ns - self._last_ns >= self.interval_ns:
            return True
        need = self.need()
        if need is None:  # no scan or odometry yet: as 'motion' would
            return self._moved(stamp_ns)
        return need >= self.threshold

    def segmented(self, seg: Segmentation) -> None:
        if self._scan is None or self._scan_pose is None:
            return
        if self._painter is None or self._painter.class_names != tuple(seg.names):
            self._painter = self._painter_for(tuple(seg.names))
        p = self._painter.paint(self._scan, None, seg).painted
        on = p.hit & (p.mobility != Mobility.UNKNOWN)
        if not on.any():
            return
        small = _on_small_things(p.points[p.hit], p.origin, self._scan.angle_increment)[on[p.hit]]
        keys = (self._keys(p.points[on]) << 1) | small
        ev = self._evidence
        # one label per cell and frame: the most frequent of its returns'
        for q, c in zip(*majority_labels(keys, label_codes(p.mobility[on], p.class_id[on]))):
            e = ev.get(q)
            if e is None or e[1] != c:
                ev[q] = [1, c]
            else:
                e[0] += 1
