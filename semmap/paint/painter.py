"""Point painting: LiDAR beams → base-frame points → camera pixels → class and mobility.

For each scan the painter

1. turns ranges into points in the LiDAR frame and maps them into the base frame
   with ``T_base_lidar`` (from ``/tf_static`` or the config);
2. deskews them: each beam is fired at its own time while the robot moves, so each
   is moved to the scan's reference time (the middle beam) through interpolated
   wheel odometry;
3. brings them to the image's capture time the same way (the robot moves between
   the scan stamp and the image stamp), maps them into the camera with
   ``T_cam_lidar @ T_lidar_base`` and projects them with the calibrated camera model;
4. reads the label under each point and maps class → mobility through the class table;
5. runs the occlusion filter (:mod:`semmap.paint.occlusion`): points on a mask that nearer
   points of the same mask hide from the camera lose the mask's label and become ``unknown``.

Points that land outside the image, behind the camera, or on no image at all are
``unknown`` (mobility 0); points inside the image on no mask are ``static``.

A scan paired with a frame the selection did not segment (``segmentation.select``,
:class:`~semmap.segment.select.SkippedFrame`) is not painted from a mask: each return takes the label
the latest segmented frame that saw the same map cell gave it, within ``segmentation.transfer_window``
(:class:`LabelMemory`, through the odometry), and stays ``unknown`` where no such frame saw anything. A
person who walked on lands on cells no frame labelled and stays unlabelled rather than take a stale mask
at the wrong place.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from ..classes import ClassTable
from ..config import PaintConfig, SegmentationConfig, SyncConfig
from ..errors import BagError
from ..geometry import (
    project_points,
    se2_apply,
    se2_between,
    se2_inverse,
    se2_to_se3,
    se3_inverse,
    unproject_pixels,
)
from ..records import Calibration, Mobility, PaintedScan, Scan, Segmentation
from ..segment.select import SkippedFrame, every_frame
from .motion import OdomTrack
from .occlusion import hidden_points, mask_regions

__all__ = ["BlockedBeams", "CameraView", "LabelMemory", "LabelTransfer", "PaintResult", "PaintStats", "Painter",
           "cell_keys", "decided_by_one_frame", "label_codes", "label_memory", "majority_labels"]


@dataclass(frozen=True)
class BlockedBeams:
    """The beams of one beam layout masked as blocked (``paint.blocked_share``), as judged so far.

    ``index`` (K,) the blocked beams' indices in the scan; ``sectors`` their contiguous runs as
    (first beam's angle, last beam's angle, beams), angles in rad in the LiDAR frame as the scan gives them.
    """

    layout: tuple[float, float, int]  # (angle_min, angle_increment, beams) of the scans
    scans: int  # scans of this layout seen when judged
    index: NDArray[np.intp]
    sectors: tuple[tuple[float, float, int], ...]

    @property
    def count(self) -> int:
        return int(self.index.size)

    @property
    def span(self) -> float:
        """The angle the blocked beams cover, rad (beams × increment)."""
        return self.count * abs(self.layout[1])


@dataclass
class PaintStats:
    scans: int = 0
    painted: int = 0  # scans that had an image and at least one point in it
    paired: int = 0  # scans that had an image
    points_paired: int = 0  # returns of the scans that had an image
    points_ahead: int = 0  # of those, the returns in front of the camera
    points_in_view: int = 0
    points_total: int = 0
    deskewed: int = 0
    motion_compensated: int = 0
    beams: int = 0
    below_range_min: int = 0  # finite readings under range_min (0 included)
    below_range_min_unblocked: int = 0  # of those, on beams not masked as blocked (paint.below_range_min applies)
    nan_readings: int = 0
    nan_unblocked: int = 0  # of those, on beams not masked as blocked (paint.nan_readings applies)
    # returns beside those (the next or previous beam), and of these the ones beyond half of range_max: far
    # ones hint that the driver reports "nothing within range" as NaN, near ones that NaN is a dropout
    returns_beside_nan: int = 0
    returns_beside_nan_far: int = 0
    # per beam layout seen in at least paint.blocked_min_scans scans: its beams masked as blocked (maybe none)
    blocked: dict[tuple[float, float, int], BlockedBeams] = field(default_factory=dict)
    transferred: int = 0  # scans paired with a skipped frame (labels from the segmented ones: LabelMemory)
    points_transferred: int = 0  # returns that took a person's label so (the rest: LabelTransfer, in the mapping)
    occlusion_relabelled: int = 0  # points on a mask the occlusion filter made unknown
    occlusion_max_per_scan: int = 0
    occlusion_scans: int = 0  # scans with at least one such point

    @property
    def blocked_beams(self) -> int:
        """Beams masked as blocked, over all beam layouts."""
        return sum(b.count for b in self.blocked.values())


@dataclass(frozen=True)
class CameraView:
    """How the last painted scan's points fell into the camera (for pictures and debugging).

    ``beams`` (K,) indexes the scan's beams that landed in the image; ``uv`` (K, 2) their
    pixels (column, row); ``label`` (K,) the label value under them (0: no mask); ``hidden``
    (K,) the points the occlusion filter found hidden from the camera.
    """

    stamp_ns: int  # the image's capture time
    beams: NDArray[np.intp]
    uv: NDArray[np.float64]
    label: NDArray[np.intp]
    hidden: NDArray[np.bool_]


@dataclass(frozen=True)
class PaintResult:
    """One painted scan, and what the painter found on the way.

    ``odom_pose`` is the odometry pose (x, y, yaw in the odometry frame) at the scan's reference time
    (None when the odometry does not cover it); ``view`` how the scan's points fell into the camera
    (None when it was not painted).
    """

    painted: PaintedScan
    odom_pose: NDArray[np.float64] | None
    view: CameraView | None


@dataclass(frozen=True)
class _Layout:
    """Per beam layout: beam directions in the base frame and the deskew weights."""

    key: tuple[float, float, int]  # (angle_min, angle_increment, beams)
    origin3: NDArray[np.float64]  # (3,) the LiDAR's origin in the base frame
    dirs_base: NDArray[np.float64]  # (N, 3) unit beam directions in the base frame
    w_first: NDArray[np.float64]  # (N, 1) weight of the sweep's first-beam motion (1 → 0 up to the middle)
    w_last: NDArray[np.float64]  # (N, 1) weight of its last-beam motion (0 from the middle → 1)

    @classmethod
    def of(cls, key: tuple[float, float, int], T_base_lidar: NDArray[np.float64]) -> _Layout:
        angle_min, inc, n = key
        a = angle_min + inc * np.arange(n)
        dirs = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)]) @ T_base_lidar[:3, :3].T
        k = np.arange(n, dtype=np.float64)
        mid = n // 2
        w_first = np.clip((mid - k) / max(mid, 1), 0.0, 1.0)[:, None]
        w_last = np.clip((k - mid) / max(n - 1 - mid, 1), 0.0, 1.0)[:, None]
        return cls(key, T_base_lidar[:3, 3].copy(), dirs, w_first, w_last)


# beam layouts whose per-beam state is kept at once (a LiDAR keeps its layout; this bounds a bag that does not)
_MAX_LAYOUTS = 8


class _BeamState:
    """How often each beam of one layout has seen out: the blocked-beam mask, judged online.

    A beam *sees out* in a scan when it reads a real return (range_min to range_max) or a REP-117 no
    return (+inf, or beyond range_max). After ``scans`` scans of the layout, a beam that has seen out
    in at most ``paint.blocked_share`` of them is masked: its readings below range_min and its NaN
    readings clear nothing, whatever ``paint.below_range_min`` and ``paint.nan_readings`` say. This
    catches a sector blocked by the robot's body, which reads below range_min (Hokuyo URG: 0.019 m)
    or NaN in every scan, while the same codes on a beam that sees out ("nothing within range") keep
    following the settings. From the first scan on it is conservative: a beam that has not returned
    yet is masked until it does, and one spurious return in a hundred scans does not unmask a blocked
    beam. Unlike a run length over the last K scans it does not mask a beam that sees nothing for a
    long while on a tour (down a corridor: runs of 300 NaN scans in the Hokuyo bags), and it needs
    two counters per beam, whatever the length of the tour.
    """

    __slots__ = ("reported", "scans", "seen")

    def __init__(self, beams: int) -> None:
        self.scans = 0
        self.seen = np.zeros(beams, np.int64)  # scans in which each beam saw out
        self.reported: NDArray[np.bool_] | None = None  # the mask last written to the stats


def _blocked_beams(key: tuple[float, float, int], scans: int, masked: NDArray[np.bool_]) -> BlockedBeams:
    """The masked beams of a layout, and their contiguous sectors."""
    angle_min, inc, n = key
    idx = np.flatnonzero(masked)
    runs: list[tuple[int, int]] = []
    if idx.size:
        breaks = np.flatnonzero(np.diff(idx) != 1)
        runs = list(zip(np.r_[idx[0], idx[breaks + 1]].tolist(), np.r_[idx[breaks], idx[-1]].tolist()))
        # a scanner that turns full circle: a sector across the seam (the last beam beside the first) is one
        if len(runs) > 1 and runs[0][0] == 0 and runs[-1][1] == n - 1 and n * abs(inc) > 2 * np.pi - 1.5 * abs(inc):
            runs[-1] = (runs[-1][0], runs.pop(0)[1])
    sectors = tuple((angle_min + inc * a, angle_min + inc * b, (b - a) % n + 1) for a, b in runs)
    return BlockedBeams(key, scans, idx, sectors)


def _normalised_bounds(calib: Calibration) -> tuple[float, float, float, float]:
    """The range of undistorted normalised coordinates (x/z, y/z) that land in the image.

    Used to reject points far outside the field of view, which OpenCV's distortion
    polynomials can fold back into the image.
    """
    intr = calib.intrinsics
    w, h = intr.width, intr.height
    u = np.linspace(0, w - 1, 33)
    v = np.linspace(0, h - 1, 25)
    border = np.concatenate([np.column_stack([u, np.zeros_like(u)]), np.column_stack([u, np.full_like(u, h - 1)]),
                             np.column_stack([np.zeros_like(v), v]), np.column_stack([np.full_like(v, w - 1), v])])
    # not cv2.undistortPoints: its few fixed-point iterations stop short in the corners of wide
    # fisheye lenses, and the bounds then cut off points that land in the image
    und = unproject_pixels(intr.K, intr.D, border, 1.0, intr.model)[:, :2]
    (x0, y0), (x1, y1) = und.min(axis=0), und.max(axis=0)
    mx, my = 0.05 * (x1 - x0), 0.05 * (y1 - y0)
    return float(x0 - mx), float(x1 + mx), float(y0 - my), float(y1 + my)


_OFF = 1 << 20  # cell indices are offset by this to pack two into one key (±52 km at 5 cm)


def cell_keys(xy: NDArray[np.float64], cell: float) -> NDArray[np.int64]:
    """The ``cell``-sized square each (N, 2) point lies in, packed into one int64 per point (42 bits)."""
    ij = np.floor(xy / cell).astype(np.int64) + _OFF
    return (ij[:, 0] << 21) | ij[:, 1]


def label_codes(mobility: NDArray[np.uint8], class_id: NDArray[np.int16]) -> NDArray[np.int64]:
    """Mobility and class packed into one code per return (< 2**20); :func:`majority_labels` votes on them."""
    return (mobility.astype(np.int64) << 16) | (class_id.astype(np.int64) + 1)


def decided_by_one_frame(code: int) -> bool:
    """Whether one segmented frame's label (a :func:`label_codes` code) settles a cell: furniture's does. At
    LiDAR height a chair or a table is its legs, which the masks hit in some frames and miss in others, so a
    second frame's word on a leg is as likely a miss as a confirmation. Structure needs more (people: see
    :class:`LabelMemory`)."""
    return code >> 16 == Mobility.SEMI_STATIC


def majority_labels(keys: NDArray[np.int64], codes: NDArray[np.int64]) -> tuple[list[int], list[int]]:
    """Per key (< 2**43), the label code most of its returns have: the keys and their codes."""
    pairs, counts = np.unique((keys << 20) | codes, return_counts=True)
    cell = pairs >> 20
    order = np.lexsort((-counts, cell))
    cell, pairs = cell[order], pairs[order]
    first = np.r_[True, cell[1:] != cell[:-1]]
    return cell[first].tolist(), (pairs[first] & ((1 << 20) - 1)).tolist()


class LabelMemory:
    """What the segmented frames said of each map cell, in one fixed frame (the map's, or the odometry's).

    The labelled returns of every scan painted from a segmented frame are added (:meth:`add`); each frame
    casts one vote per cell it saw (the label most of its returns there had), and a cell keeps the label
    that has won the vote (a running majority: one vote up for the label in the lead, one down for any
    other). A scan paired with a frame that was not segmented looks its returns up (:meth:`lookup`): each
    takes its cell's label once that label leads, by ``MIN_LEAD`` votes for structure and by one for
    furniture, and none otherwise (a cell labelled one way and another, or structure seen by one frame).
    Furniture on one frame's word: at LiDAR height a chair or a table is its legs, which the masks hit in
    some frames and miss in others, so a leg the one segmented frame of its stretch labelled would
    otherwise keep that single label (below ``cleaning.min_labelled_hits``) while every frame between
    paints it structure. Structure and furniture stay where they are during a tour, so their labels hold
    for the whole tour. People move: a cell whose vote a person leads takes the ``dynamic`` label on one
    frame's word, and only ``window_s`` seconds after the last frame that gave it (someone standing still
    goes from the map with fewer frames; someone who walked on leaves no label).

    ``people`` / ``places``: which labels :meth:`lookup` hands out (people's, structure's and furniture's).
    A label is only as good as the poses that carry it from its frame to the scan: the painter passes
    people's over their few seconds in the odometry frame (before registration, which leaves them out of
    the match), and :class:`LabelTransfer` structure's and furniture's, which hold for the whole tour, in
    the map frame (wheel odometry drifts by a map cell in a few seconds).
    """

    #: the lead a structure label needs before it transfers (furniture: one vote; people: see above)
    MIN_LEAD = 2

    def __init__(self, cell: float, window_s: float = 3.0, people: bool = True, places: bool = True) -> None:
        self.cell = float(cell)
        self.window_ns = int(window_s * 1e9)
        self.people, self.places = people, places
        self.frame_ns: int | None = None  # the latest frame added
        self._cells: dict[int, list[int]] = {}  # key -> [label code in the lead, its lead, last frame's stamp]
        self._pending: list[tuple[NDArray[np.int64], NDArray[np.int64]]] = []  # the latest frame's keys, codes
        self._pruned_ns: int | None = None

    def add(self, frame_ns: int, xy: NDArray[np.float64], mobility: NDArray[np.uint8],
            class_id: NDArray[np.int16]) -> None:
        """The labelled returns (in the memory's frame) of a scan painted from the frame stamped ``frame_ns``."""
        if frame_ns != self.frame_ns:
            self._merge()
            self.frame_ns = frame_ns
        self._pending.append((cell_keys(xy, self.cell), label_codes(mobility, class_id)))

    def _merge(self) -> None:
        """The latest frame's votes into the cells: per cell, the label most of its returns there had."""
        if not self._pending or self.frame_ns is None:
            self._pending = []
            return
        keys, codes = majority_labels(np.concatenate([k for k, _ in self._pending]),
                                      np.concatenate([c for _, c in self._pending]))
        self._pending = []
        t = self.frame_ns
        cells = self._cells
        for k, c in zip(keys, codes):
            e = cells.get(k)
            if e is None:
                cells[k] = [c, 1, t]
            elif e[0] == c:
                e[1] += 1
                e[2] = t
            elif e[1] > 1:
                e[1] -= 1
                e[2] = t
            else:
                e[0], e[1], e[2] = c, 1, t
        if self._pruned_ns is None or t - self._pruned_ns > self.window_ns:  # forget what no scan may use
            self._cells = {k: v for k, v in cells.items()
                           if t - v[2] <= self.window_ns or (self.places and v[0] >> 16 != Mobility.DYNAMIC)}
            self._pruned_ns = t

    def lookup(self, stamp_ns: int, xy: NDArray[np.float64],
               ) -> tuple[NDArray[np.bool_], NDArray[np.uint8], NDArray[np.int16]]:
        """For each point (in the memory's frame) of a scan at ``stamp_ns``: whether its cell has a label, its
        mobility and class."""
        self._merge()
        n = xy.shape[0]
        found = np.zeros(n, bool)
        code = np.zeros(n, np.int64)
        cells, w, lead = self._cells, self.window_ns, self.MIN_LEAD
        people, places = self.people, self.places
        for i, k in enumerate(cell_keys(xy, self.cell).tolist()):
            v = cells.get(k)
            if v is None:
                continue
            if v[0] >> 16 == Mobility.DYNAMIC:  # a person: one frame's word, for a short while
                if people and abs(stamp_ns - v[2]) <= w:
                    found[i], code[i] = True, v[0]
            elif places and (v[1] >= lead or decided_by_one_frame(v[0])):
                found[i], code[i] = True, v[0]
        return found, np.where(found, code >> 16, 0).astype(np.uint8), np.where(found, (code & 0xFFFF) - 1,
                                                                               -1).astype(np.int16)


def label_memory(seg: SegmentationConfig, resolution: float, places: bool = False) -> LabelMemory | None:
    """The painter's label memory (in the odometry frame) for segmentation settings ``seg`` and map cells of
    ``resolution`` (None: every frame is segmented): people's labels, and with ``places`` structure's and
    furniture's too (a build passes those on in the map frame: :class:`LabelTransfer`)."""
    if every_frame(seg):
        return None
    return LabelMemory(resolution, seg.transfer_window, places=places)


class LabelTransfer:
    """Structure and furniture labels for the scans paired with a frame that was not segmented, passed on
    from the frames that were through the registered poses (in the map frame: through the wheel odometry a
    label would land a cell off within seconds, and metres off when the robot comes back a minute later).

    Feed it every scan in order with its pose (:meth:`apply`): a scan painted from a segmented frame casts its
    votes (:class:`LabelMemory`); a scan paired with a skipped frame comes back with its unlabelled returns
    in that frame's view labelled where a cell's label has won. :meth:`remember` casts the votes alone (a
    process that fuses the second half of a tour replays the first half's votes)."""

    def __init__(self, cell: float) -> None:
        self.memory = LabelMemory(cell, people=False)
        self.returns_labelled = 0  # returns that took a label

    def remember(self, pose: NDArray[np.float64], painted: PaintedScan) -> None:
        """Cast the votes of a scan painted from a segmented frame (others: nothing to do)."""
        if painted.segmented and painted.frame_ns is not None:
            keep = painted.hit & (painted.mobility != Mobility.UNKNOWN)
            if keep.any():
                self.memory.add(painted.frame_ns, se2_apply(pose, painted.points[keep]), painted.mobility[keep],
                                painted.class_id[keep])

    def apply(self, pose: NDArray[np.float64], painted: PaintedScan) -> PaintedScan:
        """The scan, at ``pose`` in the map frame, with the labels it takes (see the class)."""
        if painted.segmented:
            self.remember(pose, painted)
            return painted
        if painted.frame_ns is None or painted.in_view is None or self.memory.frame_ns is None:
            return painted
        idx = np.flatnonzero(painted.hit & painted.in_view & (painted.mobility == Mobility.UNKNOWN))
        if idx.size == 0:
            return painted
        found, mob, cls = self.memory.lookup(painted.stamp_ns, se2_apply(pose, painted.points[idx]))
        if not found.any():
            return painted
        mobility, class_id = painted.mobility.copy(), painted.class_id.copy()
        mobility[idx[found]] = mob[found]
        class_id[idx[found]] = cls[found]
        self.returns_labelled += int(np.count_nonzero(found))
        return replace(painted, mobility=mobility, class_id=class_id)


class Painter:
    """Paint scans with a calibrated camera's segmentations."""

    def __init__(
        self,
        T_base_lidar: NDArray[np.float64],
        calibration: Calibration | None,
        class_names: tuple[str, ...],
        class_table: ClassTable,
        paint_cfg: PaintConfig,
        sync_cfg: SyncConfig,
        no_return_range: float,
        memory: LabelMemory | None = None,
    ) -> None:
        self.T_base_lidar = np.asarray(T_base_lidar, dtype=np.float64)
        self.calib = calibration
        self.class_names = tuple(class_names)
        self.paint_cfg = paint_cfg
        self.sync_cfg = sync_cfg
        self.no_return_range = no_return_range
        # label value → mobility and class id; value 0 (no object) is static structure
        mob = [Mobility.STATIC] + [class_table.mobility_of(n) for n in self.class_names]
        self._mobility_lut = np.array([int(m) for m in mob], dtype=np.uint8)
        self._class_lut = np.arange(-1, len(self.class_names), dtype=np.int16)
        if calibration is not None:
            self.T_cam_base = calibration.T_cam_lidar @ se3_inverse(self.T_base_lidar)
            self._bounds = _normalised_bounds(calibration)
            self._pinhole_no_distortion = calibration.intrinsics.model == "pinhole" and not np.any(
                calibration.intrinsics.D)
            self._px_max = np.array([calibration.intrinsics.width - 1, calibration.intrinsics.height - 1], np.intp)
        self.stats = PaintStats()
        #: the segmented frames' labels per cell, for scans paired with a skipped frame (None: every frame is
        #: segmented, nothing to keep; :func:`label_memory`)
        self.memory = memory
        self._layout_cache: _Layout | None = None
        self._beam_states: dict[tuple[float, float, int], _BeamState] = {}
        self._occlusion = paint_cfg.occlusion if paint_cfg.occlusion.filter else None
        # per label value, the most an object of that class spans (inf: structure, or no typical size)
        self._extent: NDArray[np.float64] | None = None
        if paint_cfg.occlusion.object_extent > 0:
            self._extent = np.array([np.inf] + [paint_cfg.occlusion.object_extent * class_table.sizes[n]
                                                if n in class_table.sizes else np.inf for n in self.class_names])
        if calibration is not None:
            self._eye = se3_inverse(self.T_cam_base)[:2, 3].copy()  # the camera centre in the base frame

    def _layout(self, scan: Scan) -> _Layout:
        """What depends only on the beam layout, cached: a LiDAR keeps its layout."""
        key = (scan.angle_min, scan.angle_increment, scan.ranges.size)
        if self._layout_cache is None or self._layout_cache.key != key:
            self._layout_cache = _Layout.of(key, self.T_base_lidar)
        return self._layout_cache

    def _beams(self, scan: Scan, layout: _Layout) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]:
        """Base-frame points (N, 3) at the free-space range of each beam, the valid-return mask,
        and the ranges as float64. A beam that clears nothing gets a point at the LiDAR's origin."""
        r = scan.ranges.astype(np.float64)
        lo = max(scan.range_min, 1e-3)
        # comparisons with NaN are False (and numpy does not warn about them)
        hit = (r >= lo) & (r <= scan.range_max)  # False for NaN and ±inf alike
        # REP-117: +inf = no return (free up to the range limit); NaN, -inf, 0 = invalid (clears nothing);
        # readings below range_min (0 included) and NaN follow paint.below_range_min and paint.nan_readings
        no_return = r > scan.range_max
        below = (r < lo) & (r > -np.inf)
        nan = np.isnan(r)
        # on beams masked as blocked (or not known to see out yet) neither clears anything
        masked = self._masked_beams(layout.key, hit | no_return)
        open_below = below & ~masked
        open_nan = nan & ~masked
        if self.paint_cfg.below_range_min == "no_return":  # driver error codes meaning "nothing seen"
            no_return |= open_below
        if self.paint_cfg.nan_readings == "no_return":
            no_return |= open_nan
        st = self.stats
        st.beams += r.size
        st.below_range_min += int(np.count_nonzero(below))
        st.below_range_min_unblocked += int(np.count_nonzero(open_below))
        st.nan_readings += int(np.count_nonzero(nan))
        n_open_nan = int(np.count_nonzero(open_nan))
        st.nan_unblocked += n_open_nan
        if n_open_nan:
            beside = np.zeros(r.size, bool)
            beside[1:] |= open_nan[:-1]
            beside[:-1] |= open_nan[1:]
            beside &= hit
            st.returns_beside_nan += int(np.count_nonzero(beside))
            st.returns_beside_nan_far += int(np.count_nonzero(beside & (r > 0.5 * scan.range_max)))
        free = np.where(hit, r, np.where(no_return, min(scan.range_max, self.no_return_range), 0.0))
        return layout.origin3 + layout.dirs_base * free[:, None], hit, r

    def _masked_beams(self, key: tuple[float, float, int], seen_out: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Count this scan into its layout's beam state (``seen_out``: the beams that read a return or +inf);
        the beams masked as blocked (see :class:`_BeamState`)."""
        state = self._beam_states.get(key)
        if state is None:
            if len(self._beam_states) >= _MAX_LAYOUTS:
                del self._beam_states[next(iter(self._beam_states))]
            state = self._beam_states[key] = _BeamState(key[2])
        state.scans += 1
        state.seen += seen_out
        masked = state.seen <= self.paint_cfg.blocked_share * state.scans
        if state.scans >= self.paint_cfg.blocked_min_scans:
            if state.reported is None or not np.array_equal(masked, state.reported):
                state.reported = masked
                self.stats.blocked[key] = _blocked_beams(key, state.scans, masked)
            else:
                self.stats.blocked[key] = replace(self.stats.blocked[key], scans=state.scans)
        return masked

    @staticmethod
    def beam_step_ns(scan: Scan) -> int:
        """Nanoseconds between two beams of the sweep (0: unknown, the scan is taken as instantaneous)."""
        return int(round(scan.time_increment * 1e9)) if scan.time_increment > 0 else 0

    @classmethod
    def reference_ns(cls, scan: Scan) -> int:
        """The time a painted scan's points are expressed at: its middle beam's."""
        return scan.stamp_ns + cls.beam_step_ns(scan) * (scan.ranges.size // 2)

    def paint(self, scan: Scan, odom: OdomTrack | None, seg: Segmentation | SkippedFrame | None) -> PaintResult:
        """Paint one scan; ``seg`` is the segmentation of the image paired with it (None: no image; a
        :class:`SkippedFrame`: an image not segmented), ``odom`` the odometry covering the scan's sweep
        and the image's time (or None)."""
        n = scan.ranges.size
        layout = self._layout(scan)
        pts_base, hit, ranges = self._beams(scan, layout)  # (N, 3) at each beam's own time
        origin = self.T_base_lidar[:2, 3]
        dt_ns = self.beam_step_ns(scan)
        t_ref = self.reference_ns(scan)
        self.stats.scans += 1

        xy = pts_base[:, :2]
        poses = None
        odom_pose: NDArray[np.float64] | None = None
        if odom is not None:
            poses = odom.interpolate(np.array([scan.stamp_ns, t_ref, scan.stamp_ns + dt_ns * max(n - 1, 0)],
                                              dtype=np.int64))
            if poses is None:  # the sweep's ends may not be covered; the reference alone may be
                ref = odom.interpolate(t_ref)
                odom_pose = None if ref is None else np.asarray(ref)
            else:
                odom_pose = poses[1].copy()
        if self.sync_cfg.deskew and dt_ns and n > 2 and poses is not None:
            # the base pose at each beam's time, seen from the reference (middle) beam: the sweep
            # lasts tens of ms, so the motion is interpolated linearly from its two ends (the
            # middle beam, and the LiDAR's origin at its time, stay where they are)
            rel = layout.w_first * se2_between(poses[1], poses[0]) + layout.w_last * se2_between(poses[1], poses[2])
            c, s = np.cos(rel[:, 2]), np.sin(rel[:, 2])
            x, y = xy[:, 0], xy[:, 1]
            xy = np.empty((n, 2))
            xy[:, 0] = rel[:, 0] + c * x - s * y
            xy[:, 1] = rel[:, 1] + s * x + c * y
            self.stats.deskewed += 1
        else:
            xy = xy.copy()

        mobility = np.zeros(n, np.uint8)
        class_id = np.full(n, -1, np.int16)
        instance = np.full(n, -1, np.int32)
        view = None
        in_view = None
        if isinstance(seg, Segmentation) and self.calib is not None:
            footprint = np.abs(ranges * scan.angle_increment)
            view = self._paint_labels(xy, pts_base[:, 2], hit, footprint, t_ref, odom, seg, mobility, class_id,
                                      instance)
            if view is not None and odom_pose is not None and self.memory is not None:
                labelled = view.beams  # the returns that landed in the image, labelled or made unknown
                keep = labelled[mobility[labelled] != Mobility.UNKNOWN]
                self.memory.add(seg.stamp_ns, se2_apply(odom_pose, xy[keep]), mobility[keep], class_id[keep])
        elif isinstance(seg, SkippedFrame) and self.calib is not None:
            # structure and furniture labels go only to the returns this frame's camera saw (a mask would have
            # labelled no other: with every frame segmented a return out of view is unknown, and a cell gets as
            # many labels from skipped frames as it would have got from them segmented); a build passes them on
            # in the map frame, after registration (LabelTransfer, with in_view), and this memory only when it
            # keeps them too (label_memory's places). A person's label, kept for a few seconds on one frame's
            # word, goes here to every return on their cells: the selection may have seen them once, the map
            # must drop them, and the registration leaves them out of the match
            idx = np.flatnonzero(hit)
            in_view = np.zeros(n, bool)
            in_view[idx] = self._project(xy, pts_base[:, 2], idx, t_ref, odom, seg.stamp_ns, count=False)[2]
            self.stats.transferred += 1
            if odom_pose is not None and self.memory is not None and self.memory.frame_ns is not None:
                found, mob, cls = self.memory.lookup(t_ref, se2_apply(odom_pose, xy[idx]))
                found &= (mob == Mobility.DYNAMIC) | in_view[idx]
                mobility[idx[found]] = mob[found]
                class_id[idx[found]] = cls[found]
                self.stats.points_transferred += int(np.count_nonzero(found))
        painted = PaintedScan(
            stamp_ns=t_ref,
            origin=origin,
            points=xy,
            hit=hit,
            mobility=mobility,
            class_id=class_id,
            instance=instance,
            class_names=self.class_names,
            frame_id=scan.frame_id,
            frame_ns=seg.stamp_ns if isinstance(seg, (Segmentation, SkippedFrame)) and self.calib is not None else None,
            segmented=isinstance(seg, Segmentation) and view is not None,
            in_view=in_view,
        )
        return PaintResult(painted, odom_pose, view)

    def _project(self, xy: NDArray[np.float64], z: NDArray[np.float64], sel: NDArray[np.intp], t_ref: int,
                 odom: OdomTrack | None, image_ns: int, count: bool = True,
                 ) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.float64]]:
        """Points ``sel`` (base frame at ``t_ref``) in the image taken at ``image_ns``: their pixels (S, 2), which
        lie ahead of the camera in a column of the image, which land in the image, and the camera centre in the
        reference-time base frame (for the occlusion filter). ``count``: into the paint statistics."""
        assert self.calib is not None
        intr = self.calib.intrinsics
        # the camera sees the points where they were at the image's capture time: T_cam_base at the image
        # time, composed with the reference-time base pose seen from the image time; the occlusion filter
        # works in the reference-time base frame, with the camera centre moved into it (a rigid motion
        # keeps the distances and angles it compares)
        T_cam = self.T_cam_base
        eye = self._eye
        if self.sync_cfg.motion_compensation and odom is not None and image_ns != t_ref:
            poses = odom.interpolate(np.array([image_ns, t_ref], dtype=np.int64))
            if poses is not None:
                rel = se2_between(poses[0], poses[1])  # reference-time base pose seen from the image time
                T_cam = T_cam @ se2_to_se3(rel)
                eye = se2_apply(se2_inverse(rel), eye)
                self.stats.motion_compensated += count
        p_cam = xy[sel] @ T_cam[:3, :2].T + (z[sel, None] * T_cam[None, :3, 2] + T_cam[None, :3, 3])
        zc = p_cam[:, 2]
        x0, x1, y0, y1 = self._bounds
        with np.errstate(divide="ignore", invalid="ignore"):
            xn, yn = p_cam[:, 0] / zc, p_cam[:, 1] / zc
        ahead = (zc > self.paint_cfg.min_depth) & (xn >= x0) & (xn <= x1)  # in front, a column of the image
        front = ahead & (yn >= y0) & (yn <= y1)
        if count:
            self.stats.points_ahead += int(np.count_nonzero(zc > self.paint_cfg.min_depth))
        if self._pinhole_no_distortion:  # the common case, without OpenCV's per-call overhead
            k = intr.K
            uv = np.empty((sel.size, 2))
            uv[:, 0] = k[0, 0] * xn + k[0, 1] * yn + k[0, 2]
            uv[:, 1] = k[1, 1] * yn + k[1, 2]
            inside = (uv[:, 0] >= -0.5) & (uv[:, 0] < intr.width - 0.5) & (uv[:, 1] >= -0.5) & (
                uv[:, 1] < intr.height - 0.5)
        else:
            uv, inside = project_points(intr.K, intr.D, p_cam, intr.width, intr.height, intr.model,
                                        min_depth=self.paint_cfg.min_depth)
        return uv, ahead, inside & front, eye

    def _paint_labels(self, xy: NDArray[np.float64], z: NDArray[np.float64], hit: NDArray[np.bool_],
                      footprint: NDArray[np.float64], t_ref: int,
                      odom: OdomTrack | None, seg: Segmentation, mobility: NDArray[np.uint8],
                      class_id: NDArray[np.int16], instance: NDArray[np.int32]) -> CameraView | None:
        """Label the points the camera saw (in place); how they fell into the image (None: none did)."""
        assert self.calib is not None
        intr = self.calib.intrinsics
        if seg.label.shape != (intr.height, intr.width):
            raise BagError(f"a label image is {seg.label.shape[1]}x{seg.label.shape[0]} px, the camera calibration "
                           f"says {intr.width}x{intr.height}: wrong calibration file, or images resized after "
                           f"calibrating")
        sel = np.nonzero(hit)[0]
        self.stats.paired += 1
        self.stats.points_paired += sel.size
        if sel.size == 0:
            return None
        uv, ahead, ok, eye = self._project(xy, z, sel, t_ref, odom, seg.stamp_ns)
        # the occlusion filter also looks at points above or below the image (their label: the image's edge);
        # without distortion, every point ahead has finite pixel coordinates
        if self._occlusion is None:
            seen = ok
        elif self._pinhole_no_distortion:
            seen = ahead
        else:
            seen = ahead & np.isfinite(uv).all(axis=1)
        if not ok.any():
            return None
        px = np.rint(np.where(seen[:, None], uv, 0.0)).astype(np.intp)
        np.maximum(px, 0, out=px)
        np.minimum(px, self._px_max, out=px)
        labels = seg.label[px[seen, 1], px[seen, 0]].astype(np.intp)
        labels = np.where(labels <= len(self.class_names), labels, 0)  # values beyond the class list: no object
        hidden = np.zeros(labels.size, bool)
        if self._occlusion is not None:
            # visibility from the camera's own viewpoint, at the image time, in the LiDAR plane
            s_idx = sel[seen]
            hidden = hidden_points(xy[s_idx], eye, labels, px[seen], ok[seen],
                                   footprint[s_idx], seg.label, self._occlusion, self._extent)
        in_img = ok[seen]
        labels, hidden = labels[in_img], hidden[in_img]
        idx = sel[ok]
        mob = self._mobility_lut[labels]
        cls = self._class_lut[labels]
        n_hidden = int(np.count_nonzero(hidden))
        if n_hidden:
            mob[hidden] = Mobility.UNKNOWN
            cls[hidden] = -1
            self.stats.occlusion_relabelled += n_hidden
            self.stats.occlusion_scans += 1
            self.stats.occlusion_max_per_scan = max(self.stats.occlusion_max_per_scan, n_hidden)
        mobility[idx] = mob
        class_id[idx] = cls
        # the object each furniture point lies on, to tell objects apart in the map's object list
        semi = np.flatnonzero(mob == Mobility.SEMI_STATIC)
        if semi.size:
            pix = px[ok][semi]
            if seg.instance is not None:
                key = seg.instance[pix[:, 1], pix[:, 0]].astype(np.int32)
                key[key == 0] = -1
            else:
                key = mask_regions(seg.label, pix, labels[semi])
            instance[idx[semi]] = key
        self.stats.painted += 1
        self.stats.points_in_view += int(ok.sum())
        self.stats.points_total += int(hit.sum())
        return CameraView(seg.stamp_ns, idx, uv[ok], labels, hidden)
