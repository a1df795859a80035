"""Cleaning: from fused evidence to the map a robot loads, with people dropped and furniture flagged.

The camera sees ~56° ahead while the LiDAR sees 270°, so most returns carry no label
(mobility 0). Decisions are therefore made per *object*, not only per cell:

1. **Occupancy.** Cells with log-odds above ``occupied_logodds`` are occupied, below
   ``free_logodds`` free, the rest unknown. Cells that returned at least ``hit_ratio`` of the
   scans observing them (and ``min_hits`` times) are occupied too: a 3.5 cm chair leg fills a
   third of its cell, rays often pass it by, and the clamped log-odds forgets it.
2. **Walls and furniture faces.** Straight runs of occupied cells at least ``wall_min_length``
   long (morphological openings with line kernels in 8 directions) are judged per direction,
   each direction's 8-connected segments by the sum of their labelled hits: a long wall
   outvotes labels that bled onto part of it, while a bed's side that meets the wall at a right
   angle is judged apart from it. Walls at other angles are found as Hough lines at least
   ``structure_min_size`` long; one whose labels say static protects its cells the same way.
   Segments longer than ``structure_min_size`` are never dropped as dynamic.
3. **Own evidence.** Any other occupied cell with at least ``min_labelled_hits`` labelled hits
   decides by itself: dynamic when the dynamic share of its labelled hits reaches
   ``dynamic_fraction``, else semi-static when the semi-static share reaches
   ``semi_static_fraction``, else static.
4. **People, whole.** A person is one object: occupied cells within ``person_radius`` of a
   dynamic cell leave with it (the leg arcs seen only where the camera did not look), and so
   does a blob of touching cells up to ``person_max_size`` that holds dynamic evidence, unless
   they are wall or their own labels say otherwise (a counter the person stood at stays); a
   person-sized blob whose labels, summed, say dynamic leaves whole, cells labelled as furniture
   included (someone the camera also saw through a bed's mask).
   People no camera saw are found by their legs: two isolated blobs a leg wide
   (``person_leg_width``), ``person_leg_spacing`` apart, or one such blob two legs long (or, feet
   together, one leg wide) with a waist between the legs, not lying on one circle (a pot); walls
   and large furniture may be near, other small blobs (a chair's other legs) may not; blobs seen by a
   small share of the returns the map's obstacles gathered are smears, not judged. Unlabelled
   cells off the walls that scans saw free ``transient_ratio`` times as often as they hit them
   are someone who paused there, kept by the log-odds only because their hits came last.
5. **Furniture.** Unlabelled straight runs that meet a semi-static cell and are no longer than
   ``face_max_length`` are the same piece of furniture (a bed's side the camera never saw).
   Undecided cells away from walls are grouped (``object_link_distance``) and judged by the sum
   of their labels (furniture seen in one frame). Remaining unlabelled cells take the flag of
   the nearest semi-static cell when it is nearer than any wall or static-labelled cell and
   within ``label_spread_distance``, or 0.9 x its class's typical size
   (``config/classes.yaml``, ``sizes:``: the far legs of a table).
6. **No evidence, no flag.** Without camera labels nothing is called movable: a blob is not a
   furniture leg because it is small (far walls' sparse returns are small too). The leg prior
   (``leg_max_size`` > 0) restores that rule for those who want it.
7. **Output.** Dynamic cells are dropped from ``occupied`` and become free (the floor a person
   stood on); semi-static cells stay occupied and are flagged; flagged cells are grouped into
   :class:`SemiStaticObject` records per class: parts the camera saw as one object (the grid's
   sightings) join, else parts within the class's typical size, and no object grows longer than
   its class can be (a table's four legs are one table, a row of chairs several chairs); each
   records how many painted scans saw it.

What it cannot do: a person who never moved, whom no camera saw, and whose legs touch a wall
or furniture, or who stands with feet together, looks like any other small obstacle and
stays; furniture no camera saw stays static, unflagged.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..classes import ClassTable
from ..config import CleaningConfig
from ..records import REGION_BASE, GridSpec, Mobility
from .fusion import GridLayers

__all__ = ["CleanedMap", "SemiStaticObject", "clean", "crop_to_observed", "evidence_occupancy", "group_cells",
           "group_objects", "nearest_value"]

log = logging.getLogger(__name__)

_KERNEL3 = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class SemiStaticObject:
    """A movable object in the map: its class, where it is and how big (map frame, metres).

    ``size`` is the (length, width) of the oriented box around its cells, ``yaw`` the box's
    heading (rad, of the length axis). At LiDAR height a chair is its legs, so the box spans
    the legs.
    """

    class_name: str
    centroid: tuple[float, float]
    size: tuple[float, float]
    yaw: float
    n_cells: int
    #: painted scans whose furniture points landed on it (maps built before sightings were kept:
    #: the most camera-labelled hits any one of its cells gathered); 0 for an object flagged from
    #: geometry alone
    views: int = 0
    #: the corners of the oriented box around its cells (x, y, m, counter-clockwise; ``size`` and
    #: ``yaw`` are its sides and heading): the floor it takes
    footprint: tuple[tuple[float, float], ...] = ()

    def as_dict(self) -> dict[str, object]:
        return {"class": self.class_name, "centroid": [round(v, 3) for v in self.centroid],
                "size": [round(v, 3) for v in self.size], "yaw": round(self.yaw, 4), "n_cells": self.n_cells,
                "views": self.views, "footprint": [list(p) for p in self.footprint]}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SemiStaticObject:
        """The inverse of :meth:`as_dict` (an entry of ``semi_static_objects.json``)."""
        return cls(class_name=str(d["class"]), centroid=(float(d["centroid"][0]), float(d["centroid"][1])),
                   size=(float(d["size"][0]), float(d["size"][1])), yaw=float(d["yaw"]), n_cells=int(d["n_cells"]),
                   views=int(d.get("views", 0)),
                   footprint=tuple((float(x), float(y)) for x, y in d.get("footprint", ())))


@dataclass(frozen=True)
class CleanedMap:
    """The cleaned map (grid order, row 0 = lowest y); every mask is (H, W) bool, read-only.

    * ``occupied``: what a robot loads: static and semi-static obstacles; dynamic dropped.
    * ``free``, ``unknown``: the rest (``occupied``, ``free`` and ``unknown`` partition the grid).
    * ``semi_static``: occupied cells flagged movable (a subset of ``occupied``).
    * ``dynamic_removed``: cells the evidence held occupied that were dropped as dynamic.
    * ``objects``: the semi-static cells grouped into objects.
    """

    spec: GridSpec
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    unknown: NDArray[np.bool_]
    semi_static: NDArray[np.bool_]
    dynamic_removed: NDArray[np.bool_]
    objects: tuple[SemiStaticObject, ...] = ()

    def __post_init__(self) -> None:
        for name in ("occupied", "free", "unknown", "semi_static", "dynamic_removed"):
            a = np.asarray(getattr(self, name), dtype=bool)
            if a.shape != self.spec.shape:
                raise ValueError(f"{name} has shape {a.shape}, the grid {self.spec.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "objects", tuple(self.objects))

    @property
    def static(self) -> NDArray[np.bool_]:
        """Occupied and not flagged movable: walls, pillars, fixed structure."""
        return self.occupied & ~self.semi_static


def _disk(radius_cells: float) -> NDArray[np.uint8]:
    r = max(math.floor(radius_cells), 0)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return (xx * xx + yy * yy <= radius_cells * radius_cells + 1e-9).astype(np.uint8)


def group_cells(mask: NDArray[np.bool_], link_cells: float) -> tuple[int, NDArray[np.int32]]:
    """Label cells into groups: cells whose centres are at most ``link_cells`` apart join.

    Returns (number of groups, labels (H, W)): 0 outside ``mask``, 1..n inside. Implemented as
    connected components of the mask dilated by half the link distance, so it costs a few
    raster passes whatever the number of cells.
    """
    m = np.asarray(mask, dtype=np.uint8)
    if not m.any():
        return 0, np.zeros(m.shape, np.int32)
    grown = cv2.dilate(m, _disk(0.5 * link_cells)) if link_cells >= 2.0 else m
    n, lab32 = cv2.connectedComponents(grown, connectivity=8, ltype=cv2.CV_32S)
    lab = np.asarray(lab32, np.int32)
    lab[m == 0] = 0
    return n - 1, lab


def _distance_to(mask: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Distance (cells) from every cell to the nearest set cell of ``mask`` (inf if none)."""
    if not mask.any():
        return np.full(mask.shape, np.inf, np.float32)
    return np.asarray(cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE), np.float32)


def _verdicts(labels: NDArray[np.int32], member: NDArray[np.bool_], n: int, s_dyn: NDArray[np.float32],
              s_semi: NDArray[np.float32], lab: NDArray[np.float32],
              cfg: CleaningConfig) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per group 1..n (index 0 = none): dynamic / semi-static by the sum of its labelled hits."""
    idx = labels[member]
    t_dyn = np.bincount(idx, s_dyn[member], n + 1)
    t_semi = np.bincount(idx, s_semi[member], n + 1)
    t_lab = np.bincount(idx, lab[member], n + 1)
    ok = t_lab >= cfg.min_labelled_hits
    is_dyn = ok & (t_dyn >= cfg.dynamic_fraction * t_lab)
    is_semi = ok & ~is_dyn & (t_semi >= cfg.semi_static_fraction * t_lab)
    is_dyn[0] = is_semi[0] = False
    return is_dyn, is_semi


def _class_mobility(names: Sequence[str]) -> list[Mobility | None]:
    table = _class_table_or_none()
    return [None if table is None else table.mobility.get(n) for n in names]


def _direction_kernels(length_cells: float) -> list[NDArray[np.uint8]]:
    """Line kernels ``length_cells`` long in 8 directions (every 22.5°)."""
    n = max(round(length_cells), 2)
    k = n | 1
    c = k // 2
    kernels = [np.ones((1, n), np.uint8), np.ones((n, 1), np.uint8)]
    for deg in (22.5, 45.0, 67.5, 112.5, 135.0, 157.5):
        kern = np.zeros((k, k), np.uint8)
        dx, dy = c * math.cos(math.radians(deg)), c * math.sin(math.radians(deg))
        cv2.line(kern, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1, 1, cv2.LINE_8)
        kernels.append(kern)
    return kernels


@dataclass(frozen=True)
class _Runs:
    """Straight runs of occupied cells, each direction's 8-connected segments judged apart."""

    on: NDArray[np.bool_]  # on a run in some direction
    static: NDArray[np.bool_]  # on a segment whose labels say static (a wall)
    semi: NDArray[np.bool_]  # on a segment whose labels say semi-static (a bed's side), and on no static one
    dynamic: NDArray[np.bool_]  # on a short segment whose labels say dynamic, and on no other
    unlabelled: NDArray[np.bool_]  # on segments without enough labels only
    #: per direction: (the run's cells as flat indices, each one's segment (1..n), unlabelled per segment
    #: (index 0 unused), extent per segment in m): the runs are a few per cent of the grid, so not whole
    #: rasters (on a 150 m floor at 5 cm eight int32 rasters were 280 MB)
    segments: tuple[tuple[NDArray[np.intp], NDArray[np.int32], NDArray[np.bool_], NDArray[np.float64]], ...]


def _mark(out: NDArray[np.bool_], per_segment: NDArray[np.bool_], cells: NDArray[np.intp],
          seg: NDArray[np.int32]) -> None:
    """Set ``out`` (H, W) on the run cells (``_Runs.segments``) whose segment has ``per_segment`` true."""
    out.reshape(-1)[cells[per_segment[seg]]] = True


def _runs(occ: NDArray[np.bool_], cfg: CleaningConfig, res: float, s_dyn: NDArray[np.float32],
          s_semi: NDArray[np.float32], lab: NDArray[np.float32], longest: NDArray[np.float32] | None = None) -> _Runs:
    """Straight runs of occupied cells (walls, pillar faces, a bed's or couch's sides), judged per direction.

    Each direction's runs are split into their own 8-connected segments, so a bed's side that
    meets a wall at a right angle is judged apart from the wall, while a wall's own segment
    outvotes labels that bled onto part of it. A cell on a static segment in any direction is
    static (the corner where a bed meets the wall stays wall). ``longest`` (per cell, m; 0 where no
    movable class named it): a segment whose labels say semi-static but which is longer than the
    longest object its cells' classes make is a wall the labels bled onto (seen under a bed from
    across the room), and is static.
    """
    m = occ.astype(np.uint8)
    on = np.zeros(occ.shape, bool)
    r_static = np.zeros(occ.shape, bool)
    r_semi = np.zeros(occ.shape, bool)
    r_dyn = np.zeros(occ.shape, bool)
    r_lab = np.zeros(occ.shape, bool)
    segments = []
    for kern in _direction_kernels(cfg.wall_min_length / res):
        run = cv2.morphologyEx(m, cv2.MORPH_OPEN, kern, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
        if not run.any():
            continue
        n, seg32, stats, _ = cv2.connectedComponentsWithStats(run.astype(np.uint8), connectivity=8,
                                                              ltype=cv2.CV_32S)
        seg = np.asarray(seg32, np.int32)
        is_dyn, is_semi = _verdicts(seg, run, n - 1, s_dyn, s_semi, lab, cfg)
        labelled = np.bincount(seg[run], lab[run], n) >= cfg.min_labelled_hits
        labelled[0] = False
        # no person is longer than structure_min_size: longer runs are never dropped
        extent = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) * res
        is_dyn &= extent <= cfg.structure_min_size
        if longest is not None:
            most = np.zeros(n, np.float32)
            np.maximum.at(most, seg[run], longest[run])
            is_semi &= (most == 0) | (extent <= most)
        on |= run
        r_dyn |= run & is_dyn[seg]
        r_semi |= run & is_semi[seg]
        r_static |= run & (labelled & ~(is_dyn | is_semi))[seg]
        r_lab |= run & labelled[seg]
        at = np.flatnonzero(run)
        segments.append((at, seg.reshape(-1)[at], ~labelled, extent.astype(np.float64)))
        del seg, seg32, run
    # walls at any angle: the kernels above step by 22.5°, and a thin wall at 30° zig-zags off them.
    # Long straight lines (Hough) judged one by one protect such walls from labels that bled onto
    # them (a bed's mask over the wall the LiDAR sees beneath it)
    lines = cv2.HoughLinesP(m, 1, math.pi / 180, threshold=max(int(0.5 * cfg.structure_min_size / res), 4),
                            minLineLength=max(cfg.structure_min_size / res, 2.0),
                            maxLineGap=2)
    if lines is not None:
        for x0, y0, x1, y1 in lines.reshape(-1, 4):
            band = np.zeros(occ.shape, np.uint8)
            cv2.line(band, (int(x0), int(y0)), (int(x1), int(y1)), 1, 1, cv2.LINE_8)
            cells = band.astype(bool) & occ
            t_lab = float(lab[cells].sum())
            # only walls: a line the labels call movable is left to the rules for furniture; one
            # without labels is a wall when it is longer than any furniture (a wall's far face,
            # seen by the LiDAR alone from the next room)
            longer = math.hypot(float(x1) - float(x0), float(y1) - float(y0)) * res > max(cfg.face_max_length,
                                                                                          cfg.structure_min_size)
            if (t_lab < cfg.min_labelled_hits and longer) or (
                    t_lab >= cfg.min_labelled_hits and s_semi[cells].sum() < cfg.semi_static_fraction * t_lab
                    and s_dyn[cells].sum() < cfg.dynamic_fraction * t_lab):
                on |= cells
                r_lab |= cells
                r_static |= cells
    r_semi &= ~r_static
    r_dyn &= ~(r_static | r_semi)
    return _Runs(on, r_static, r_semi, r_dyn, on & ~r_lab, tuple(segments))


def _class_table_or_none() -> ClassTable | None:
    """The shipped class table, or None when it cannot be read: naming objects must not fail cleaning."""
    from ..classes import load_class_table
    from ..errors import ConfigError

    try:
        return load_class_table()
    except ConfigError:
        return None


def _class_sizes(layers: GridLayers, names: Sequence[str]) -> NDArray[np.float64]:
    """Typical size (m) of the class of each class layer, and a last entry (1 m) for 'no class'."""
    table = _class_table_or_none()
    sizes = [table.size_of(names[c]) if table is not None else 1.0 for c in layers.class_ids]
    return np.array(sizes + [1.0], np.float64)


def _best_semi_class(layers: GridLayers, names: Sequence[str]) -> NDArray[np.int16]:
    """Per cell, the class layer with the most hits among classes not known to be static or
    dynamic (-1 where none; the first such layer on a tie): the class a movable cell is named by.
    Layer by layer, so a large floor holds two rasters, not a copy of every class layer."""
    best = np.full(layers.spec.shape, -1, np.int16)
    if not layers.class_ids:
        return best
    mob = _class_mobility([names[c] for c in layers.class_ids])
    most = np.zeros(layers.spec.shape, np.uint16)
    for k, mb in enumerate(mob):
        if mb not in (None, Mobility.SEMI_STATIC):
            continue
        counts = layers.class_counts[k]
        more = counts > most
        best[more] = k
        np.maximum(most, counts, out=most)
    return best


#: a blob near a person's legs that holds at most this share of the smaller leg's cells, and spans no more
#: than a leg must (``_LEG_MIN_EXTENT``), is a furniture leg beside them, not a sign they are furniture: a
#: table's leg that beams smeared over five cells and 15 cm beside legs of eleven (random:327:b)
_LEG_NEIGHBOUR_SHARE = 0.5
#: ... when both legs are blobs too large to be a furniture leg (2-8 cm across): this many m² and this wide
_LEG_MIN_AREA = 0.0125
_LEG_MIN_EXTENT = 0.15
#: two leg-sized blobs that have a twin pair, as far apart and turned the same way to within this (m), whose
#: offset from them is square to them to within ``_RECT_COS`` (cosine) and ``_RECT_SPAN`` (m) long at most,
#: are two ends of a table's (or bed's) legs, not a person: a dining table of 0.4 × 0.85 m whose four legs
#: no camera labelled left a development map whole as two people (random:607:b, random:624). On 57
#: development maps the twins of furniture were within 0.035 m and 0.06; a table turned 34° on the grid,
#: 0.056 m (its legs' centres fall differently on the cells). Two people one behind the other stand that
#: alike only when their stances agree to a few centimetres: they would stay
_RECT_TOL = 0.07
_RECT_COS = 0.12
_RECT_SPAN = 2.5
#: a blob that lies on one circle (``_one_ring``) and is wider than this many times the widest person's leg
#: (``person_leg_width``) is a pillar, a bin or a pot, no furniture leg: people stand by them as by walls,
#: so it does not make two legs beside it furniture (random:615 kept someone standing 0.3 m from a pillar
#: 0.45 m across, 15 % of their cells). Any blob that wide, ring or not, dropped clutter of the real Hokuyo
#: tours as people (consistency 98.6 -> 98.2 % on before1): rings only
_POST_WIDTH = 1.0


def _leg_pairs(occ: NDArray[np.bool_], vetoed: NDArray[np.bool_], structure: NDArray[np.bool_], res: float,
               cfg: CleaningConfig, semi: NDArray[np.float32], hits: NDArray[np.uint16],
               static_veto: NDArray[np.bool_], static: NDArray[Any] | None = None,
               dynamic: NDArray[Any] | None = None, labelled: NDArray[Any] | None = None,
               dropped: NDArray[np.bool_] | None = None) -> NDArray[np.bool_]:
    """Cells of people no camera labelled, found by their legs: two isolated blobs a person's leg wide
    (``person_leg_width``), their centres ``person_leg_spacing`` apart, with nothing else near.

    At LiDAR height a standing person is two legs 10-16 cm wide about 20 cm apart; furniture legs
    are 2-8 cm wide and 40 cm or more apart, and each has neighbours (a chair's other legs). A blob
    touching anything else is part of a larger blob, and one carrying camera labels that say it is
    something else is never a leg: labels of structure (``static_veto``, when ``static`` hits are
    ``person_leg_veto_share`` of the blob's ``hits`` too; all of them without ``static``), or labels of furniture
    (``vetoed`` cells, their ``semi`` hits at least ``person_leg_veto_share`` of the blob's ``hits``).
    Neither vetoes a blob whose ``dynamic`` labels are ``person_leg_seen_share`` of its ``labelled`` returns
    (and ``_SEEN_MIN_LABELS`` or more; two leg blobs apart: summed): a person behind a bed, whose legs at
    LiDAR height the camera sees under the bed's edge, painted as the bed's in most frames and as a
    person's in the rest.
    Walls (``structure``) and anything longer than ``structure_min_size`` may be near: people stand by
    walls, beds and counters. Only blobs the LiDAR saw well are judged: their cells gathered at least
    ``person_leg_min_density`` of the returns per cell of the map's obstacles (the median); a blob seen
    by a few returns, from afar or in a few scans, is a smear whose outline says nothing.
    ``dropped``: blobs already dropped as people (by their labels); a leg blob with no furniture label pairs
    with one of them (the camera labelled one leg of someone, in a frame or two, and not the other), and
    they are no neighbours that make a leg part of something else.
    """
    if dropped is not None:
        dropped = dropped & ~occ
        occ = occ | dropped
    n, lab, stats, cent = cv2.connectedComponentsWithStats(occ.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:  # (one blob may be a person: two legs close together)
        return np.zeros(occ.shape, bool)
    w = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) * res
    lo, hi = cfg.person_leg_width
    s_lo, s_hi = cfg.person_leg_spacing
    veto = np.bincount(lab[vetoed], minlength=n) > 0
    pair_veto = veto  # what vetoes two leg blobs apart
    seen_dyn: NDArray[Any] | None = None  # per blob, its person labels and all its labels
    seen_lab: NDArray[Any] = np.zeros(n)
    if cfg.person_leg_veto_share > 0:
        # furniture and structure labels veto a blob when they are a share of its returns: a person the
        # camera missed in a few frames (5 "no mask" labels among 547 returns on two blobs, 18 among 1458
        # on one) is no post
        on = lab > 0
        share = cfg.person_leg_veto_share * np.bincount(lab[on], hits[on].astype(np.float64), n)
        furniture = veto & (np.bincount(lab[on], semi[on], n) >= share)
        built = np.bincount(lab[static_veto], minlength=n) > 0
        if static is not None:
            built &= np.bincount(lab[on], static[on].astype(np.float64), n) >= share
        pair_veto = furniture | built
        veto = pair_veto.copy()  # (the person labels below lift the veto on one blob, not on a pair)
        if dynamic is not None and labelled is not None and cfg.person_leg_seen_share > 0:
            seen_dyn = np.bincount(lab[on], dynamic[on].astype(np.float64), n)
            seen_lab = np.bincount(lab[on], labelled[on].astype(np.float64), n)
            veto &= ~_seen_as_person(seen_dyn, seen_lab, cfg)
    veto[0] = pair_veto[0] = True
    gone = np.zeros(n, bool)  # blobs dropped as people already
    furnished = np.zeros(n, bool)  # blobs with a furniture label
    if dropped is not None and dropped.any():
        gone = np.bincount(lab[dropped], minlength=n) * 2 > stats[:, cv2.CC_STAT_AREA]
        gone[0] = False
        furnished = np.bincount(lab[semi > 0], minlength=n) > 0
    xy = cent * res
    reach = s_hi + 0.5 * hi  # nothing else this close to a person's centre: a chair's legs are not people

    # per blob, the share of its cells on straight runs (``wall_min_length``, 40 cm, or longer)
    area = stats[:, cv2.CC_STAT_AREA]
    on_run = structure
    straight = np.bincount(lab[on_run], minlength=n) / np.maximum(area, 1)
    # walls and large furniture may be near (people stand by them); small blobs may not
    structure = structure | (w > cfg.structure_min_size)[lab]
    rad = int(math.ceil(reach / res))
    yy, xx = np.mgrid[-rad:rad + 1, -rad:rad + 1]
    disc = (xx * xx + yy * yy) * res * res <= reach * reach

    posts: dict[int, bool] = {}

    def post(b: int) -> bool:
        """Whether blob ``b`` is a pillar, a bin or a pot (``_POST_WIDTH``): people stand by them."""
        if b not in posts:
            posts[b] = False
            if w[b] > _POST_WIDTH * hi:
                rows, cols = _blob_cells(lab, stats, b)
                posts[b] = _one_ring(np.column_stack([cols, rows]).astype(np.float64) * res, res)
        return posts[b]

    def alone(p: NDArray[np.float64], blobs: Sequence[int], thin_near: bool = False) -> bool:
        """No occupied cell but those of ``blobs`` within ``reach`` of ``p`` (m, grid frame); with
        ``thin_near``, bar blobs far smaller than the smallest of them: a chair's thin leg, a cell or
        two, beside two blobs of five cells or more does not make them a chair (its legs are alike).
        One blob is two legs: each is half of it."""
        r, c = int(round(p[1] / res)), int(round(p[0] / res))
        r0, c0 = r - rad, c - rad
        win = lab[max(r0, 0):r + rad + 1, max(c0, 0):c + rad + 1]
        d = disc[max(r0, 0) - r0:max(r0, 0) - r0 + win.shape[0], max(c0, 0) - c0:max(c0, 0) - c0 + win.shape[1]]
        near = win[d & (win > 0) & ~structure[max(r0, 0):r + rad + 1, max(c0, 0):c + rad + 1]]
        others = np.unique(near[~np.isin(near, blobs)])
        others = others[[not gone[o] and not post(int(o)) for o in others]]
        if not others.size:
            return True
        own = list(blobs)
        leg_area = float(area[own].min()) / (2.0 if len(own) == 1 else 1.0)
        if (not thin_near or leg_area * res * res < _LEG_MIN_AREA - 1e-9
                or w[own].min() < _LEG_MIN_EXTENT - 1e-9):
            return False
        small = (area[others] <= _LEG_NEIGHBOUR_SHARE * leg_area) & (w[others] <= _LEG_MIN_EXTENT + 1e-9)
        return bool(small.all())

    person = np.zeros(n, bool)
    # two legs, two blobs
    # (a blob the furniture labels veto may still pair when the two, summed, were seen as a person's)
    may_pair = ~pair_veto if seen_dyn is None else np.ones(n, bool)
    # a blob's shape says something only where the LiDAR saw it well: a blob whose cells gathered a small share
    # of the returns a map's obstacle cells typically gather was glimpsed (from afar, in a few scans), its
    # outline a smear of a few returns (a far wall's, a table leg's seen across a room), no pair of legs
    typical = float(np.median(hits[occ])) if occ.any() else 0.0
    dense = np.bincount(lab.reshape(-1), hits.reshape(-1).astype(np.float64), n) >= (
        cfg.person_leg_min_density * typical * area)
    ids = np.flatnonzero((w >= lo) & (w <= hi) & may_pair & dense)
    if ids.size >= 2:
        d = np.hypot(xy[ids, None, 0] - xy[None, ids, 0], xy[ids, None, 1] - xy[None, ids, 1])
        legs_like = np.flatnonzero(w <= hi)
        legs_like = legs_like[legs_like > 0]
        for i, j in zip(*np.nonzero(np.triu((d >= s_lo) & (d <= s_hi), 1))):
            two = [ids[i], ids[j]]
            if gone[two].all() or (gone[two].any() and furnished[two].any()):
                continue  # (a leg the camera saw as furniture is no one's other leg)
            said = seen_dyn is not None and _seen_as_person(seen_dyn[two].sum(), seen_lab[two].sum(), cfg)
            if seen_dyn is not None and (pair_veto[ids[i]] or pair_veto[ids[j]]) and not said:
                continue
            if not said and _has_twin(xy, two, legs_like, seen_dyn, seen_lab, cfg):
                continue
            if alone(0.5 * (xy[ids[i]] + xy[ids[j]]), (ids[i], ids[j]), thin_near=True):
                person[ids[i]] = person[ids[j]] = True
    # two legs close together merge into one blob: a leg wide across, two legs long, with a waist
    # between them when seen from all around. A blob no longer than one leg is wide is two legs only
    # when it has that waist (a post or a bin that size is round). Touching legs are no longer than two
    # legs are wide (legs further apart are two blobs): a wall's end 65 cm long and two cells thick, with
    # stray returns beside it, is no person (a real Hokuyo tour, until stop 53)
    for b in np.flatnonzero((w >= lo) & (w <= 2 * hi) & ~veto & ~person & ~gone & dense):
        rows, cols = _blob_cells(lab, stats, int(b))
        pts = np.asarray(np.column_stack([cols, rows]) * res, np.float64)
        (_, _), (bw, bh), _ = cv2.minAreaRect(pts.astype(np.float32))
        # cell centres lie on whole cells: a width measured from them in float32 is a whole number of
        # cells to within rounding, and a blob exactly ``lo`` across must not fall on either side by chance
        thick = min(bw, bh) + 0.01 * res
        # (a chair's thin leg beside it does not make a blob a leg thick across a chair: a person stood
        # by the chair; a face a cell or two thick has no such allowance)
        if not alone(xy[b], (int(b),), thin_near=thick >= lo):
            continue
        if straight[b] >= 0.5 and _face(pts, on_run[rows, cols], res):
            continue
        if w[b] <= hi:
            # seen from around (a leg wide across both ways; an arc, a post seen from one side, is not)
            person[b] = thick >= lo and _two_lobes(pts, res, lo)
            continue
        if _one_ring(pts, res):  # a pot, a bin, a round post: one circle, where two legs are two
            continue
        # a flat face (a pillar's side seen from one side) is a cell or two thick: legs are round. Two
        # legs side by side are one leg thick across, however they stand: a square post seen from three
        # sides (two faces joined by the back one, a C as wide as long) has two lobes too, but is wider
        if lo <= thick <= hi - res + 0.02 * res or (thick <= hi + 0.02 * res and _two_lobes(pts, res, lo)):
            person[b] = True
    return person[lab]


def _blob_cells(lab: Any, stats: Any, b: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The rows and columns of blob ``b`` of a connected-components labelling (``stats`` its bounding boxes), in
    the order ``np.nonzero(lab == b)`` gives them, found within the blob's box instead of the whole grid."""
    x0, y0 = int(stats[b, cv2.CC_STAT_LEFT]), int(stats[b, cv2.CC_STAT_TOP])
    rows, cols = np.nonzero(lab[y0:y0 + stats[b, cv2.CC_STAT_HEIGHT], x0:x0 + stats[b, cv2.CC_STAT_WIDTH]] == b)
    return rows + y0, cols + x0  # (lab, stats: cv2's labelling; its stubs type them differently by release)


def _has_twin(xy: NDArray[np.floating[Any]], pair: Sequence[int], legs_like: NDArray[np.intp],
              seen_dyn: NDArray[Any] | None, seen_lab: NDArray[Any], cfg: CleaningConfig) -> bool:
    """Whether two blobs (centres ``xy``, m) have a twin pair among ``legs_like`` (blobs no wider than a leg):
    the same step between them to within ``_RECT_TOL``, its offset from them square to that step (within
    ``_RECT_COS``), ``_RECT_SPAN`` m at most and longer than the step: four legs at the corners of a table.
    A twin whose labels say person is no table's."""
    a, b = int(pair[0]), int(pair[1])
    step = xy[b] - xy[a]
    length = float(np.hypot(step[0], step[1]))
    mid = 0.5 * (xy[a] + xy[b])
    near = legs_like[(np.hypot(xy[legs_like, 0] - mid[0], xy[legs_like, 1] - mid[1]) <= _RECT_SPAN + length)
                     & (legs_like != a) & (legs_like != b)]
    if near.size < 2:
        return False
    p = xy[near]
    for u in range(near.size):
        # the twin's step, each way: the blob that corresponds to b minus the one that corresponds to a
        other = p - p[u]
        close = np.hypot(other[:, 0] - step[0], other[:, 1] - step[1]) <= _RECT_TOL
        close[u] = False
        for v in np.flatnonzero(close):
            offset = 0.5 * (p[u] + p[v]) - mid
            span = float(np.hypot(offset[0], offset[1]))
            if not (length < span <= _RECT_SPAN):
                continue
            if abs(float(offset @ step)) > _RECT_COS * span * length:
                continue
            twin = [int(near[u]), int(near[v])]
            if seen_dyn is not None and _seen_as_person(seen_dyn[twin].sum(), seen_lab[twin].sum(), cfg):
                continue
            return True
    return False


def _face(pts: NDArray[np.float64], on_run: NDArray[np.bool_], res: float) -> bool:
    """Whether a blob (cell centres, m) mostly on a straight run (``on_run``) is a face: its other cells
    all lie on one side of the run (a cabinet's side seen down a corridor, with a few cells of its front
    that rays grazing along it left). Two legs seen all round, in line with each other, put a run through
    both; their rings have cells on both sides of it."""
    run = pts[on_run]
    off = pts[~on_run]
    if run.shape[0] < 2 or off.shape[0] == 0:
        return True
    c = run.mean(axis=0)
    _, _, vt = np.linalg.svd(run - c, full_matrices=False)
    side = (off - c) @ vt[1]
    return not (bool((side > 0.5 * res).any()) and bool((side < -0.5 * res).any()))


#: a cell off the walls with a camera label or so, too few to count (``min_labelled_hits``), is someone who
#: paused there when scans saw it free this many times ``transient_ratio`` as often as they hit it: a stray
#: label (a person painted as wall through parallax) kept a cell hit 9 times and seen free 416 in a
#: development map, which made a table's footprint half a room long to the diff (random:622). On 80
#: development maps: ghosts fewer on 6 and occupied F1 higher on the same 6, lower on none (four decimals);
#: semi-static precision higher on 2, lower by 0.0002 at most on 3, recall the same on all. At 1 × the ratio
#: semi-static recall fell on 13 (the rims of furniture seen with a label or two)
_TRANSIENT_LABELLED = 10.0
#: person labels a leg blob (or two) needs at the least before they can outweigh furniture labels: more
#: than a frame or two's (a chair's two legs on a development map took 2 among 15 chair labels, from a
#: person passing in front of them)
_SEEN_MIN_LABELS = 10


def _seen_as_person(dyn: Any, labelled: Any, cfg: CleaningConfig) -> Any:
    """Whether a blob's (or blobs') person labels outweigh furniture labels for the legs rule: at least
    ``_SEEN_MIN_LABELS`` and ``person_leg_seen_share`` of its labelled returns."""
    return (dyn >= max(cfg.min_labelled_hits, _SEEN_MIN_LABELS)) & (dyn >= cfg.person_leg_seen_share * labelled)


def _one_ring(pts: NDArray[np.float64], res: float) -> bool:
    """Whether points (cell centres, m) lie on one circle to within a cell's rounding: two arcs of a
    pot, a bin or a round post seen from two sides, not two legs (each a ring of its own)."""
    if pts.shape[0] < 6:
        return False
    c = pts - pts.mean(axis=0)
    # algebraic circle fit: x^2 + y^2 = 2 a x + 2 b y + k
    A = np.column_stack([2 * c, np.ones(len(c))])
    (a, b, k), *_ = np.linalg.lstsq(A, (c * c).sum(axis=1), rcond=None)
    r = math.sqrt(max(k + a * a + b * b, 0.0))
    resid = np.hypot(c[:, 0] - a, c[:, 1] - b) - r
    return bool(np.sqrt(np.mean(resid * resid)) <= 0.65 * res)


def _two_lobes(pts: NDArray[np.float64], res: float, min_width: float) -> bool:
    """A blob (cell centres, m) shaped like two legs side by side: along its long axis it is at least
    ``min_width`` wide at both ends and at most half that in between (a ring or a bar is not)."""
    if pts.shape[0] < 6:
        return False
    c = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    along = c @ vt[0]
    t = np.floor((along - along.min()) / res + 0.5).astype(int)  # cell centres fall on whole steps
    u = c @ vt[1]
    bins = t.max() + 1
    if bins < 5:
        return False
    width = np.zeros(bins, int)  # cells across, per cell along
    for k in range(bins):
        sel = u[t == k]
        width[k] = round(float(np.ptp(sel)) / res) + 1 if sel.size else 0
    third = bins // 3
    ends = min(width[:third + 1].max(), width[bins - third - 1:].max())
    waist = width[third:bins - third].min()
    return bool(ends * res >= 0.8 * min_width and 2 * waist <= ends)


def nearest_value(mask: NDArray[np.bool_],
                  values: NDArray[np.generic]) -> tuple[NDArray[np.float32], NDArray[np.generic]]:
    """Distance (cells) from every cell to the nearest ``mask`` cell, and that cell's entry of ``values``.

    Where ``mask`` is empty the distances are inf and the values -1.
    """
    if not mask.any():
        return np.full(mask.shape, np.inf, np.float32), np.full(mask.shape, -1, values.dtype)
    dist, idx = cv2.distanceTransformWithLabels((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    # DIST_LABEL_PIXEL numbers the zero pixels (the mask's cells) 1, 2, ... in raster order
    order = values.reshape(-1)[np.flatnonzero(mask.reshape(-1))]
    return np.asarray(dist, np.float32), order[np.maximum(idx, 1) - 1]


#: cells kept around the observed area when cleaning works on a crop of the grid's window
_CROP_PAD = 16


def clean(layers: GridLayers, cfg: CleaningConfig | None = None,
          class_names: Sequence[str] | None = None) -> CleanedMap:
    """Turn fused evidence into the cleaned map: people dropped, furniture flagged (see module doc).

    ``class_names`` names the class ids of ``layers`` (default: ``layers.class_names``). The work
    is done on the observed part of the grid (the fusion window keeps a margin of never-observed
    cells around it); the masks returned cover the whole grid.
    """
    cfg = cfg if cfg is not None else CleaningConfig()
    names = tuple(class_names) if class_names is not None else layers.class_names
    if layers.class_ids and max(layers.class_ids) >= len(names):
        raise ValueError(f"class_names has {len(names)} names; the grid uses class id {max(layers.class_ids)}")
    obs = layers.observed
    h, w = obs.shape
    rows, cols = np.flatnonzero(obs.any(axis=1)), np.flatnonzero(obs.any(axis=0))
    if rows.size == 0:
        r0, r1, c0, c1 = 0, h, 0, w
    else:
        # always the observed area and _CROP_PAD cells around it, padded with unobserved cells where the
        # grid's window is tighter: what cleaning decides must not depend on where the window's edges
        # fall (OpenCV's probabilistic Hough transform samples by position)
        r0, r1 = int(rows[0]) - _CROP_PAD, int(rows[-1]) + _CROP_PAD + 1
        c0, c1 = int(cols[0]) - _CROP_PAD, int(cols[-1]) + _CROP_PAD + 1
    if (r0, r1, c0, c1) == (0, h, 0, w):
        return _clean(layers, cfg, names)
    sub = _crop(layers, r0, r1, c0, c1)
    cm = _clean(sub, cfg, names)
    inside = (slice(max(r0, 0), min(r1, h)), slice(max(c0, 0), min(c1, w)))
    of_sub = (slice(max(r0, 0) - r0, min(r1, h) - r0), slice(max(c0, 0) - c0, min(c1, w) - c0))

    def full(mask: NDArray[np.bool_], fill: bool) -> NDArray[np.bool_]:
        out = np.full((h, w), fill, bool)
        out[inside] = mask[of_sub]
        return out

    return CleanedMap(layers.spec, full(cm.occupied, False), full(cm.free, False), full(cm.unknown, True),
                      full(cm.semi_static, False), full(cm.dynamic_removed, False), cm.objects)


def _crop(layers: GridLayers, r0: int, r1: int, c0: int, c1: int) -> GridLayers:
    """Rows ``r0:r1`` and columns ``c0:c1`` of the layers (views); a range reaching past the window is
    padded with unobserved cells (copies)."""
    sp = layers.spec
    h, w = sp.shape
    spec = GridSpec(sp.resolution, sp.origin_x + c0 * sp.resolution, sp.origin_y + r0 * sp.resolution,
                    c1 - c0, r1 - r0)
    if r0 >= 0 and c0 >= 0 and r1 <= h and c1 <= w:
        win = (slice(r0, r1), slice(c0, c1))

        def take(a: NDArray[Any]) -> NDArray[Any]:
            return a[(..., *win)]
    else:
        src = (slice(max(r0, 0), min(r1, h)), slice(max(c0, 0), min(c1, w)))
        dst = (slice(max(r0, 0) - r0, min(r1, h) - r0), slice(max(c0, 0) - c0, min(c1, w) - c0))

        def take(a: NDArray[Any]) -> NDArray[Any]:
            out = np.zeros((*a.shape[:-2], r1 - r0, c1 - c0), a.dtype)
            out[(..., *dst)] = a[(..., *src)]
            return out
    return GridLayers(spec, take(layers.log_odds), take(layers.hits), take(layers.free), take(layers.mobility),
                      take(layers.class_counts), layers.class_ids, layers.class_names, layers.n_scans,
                      crop_sightings(layers.sightings, r0, r1, c0, c1))


def crop_sightings(sightings: NDArray[np.int32], r0: int, r1: int, c0: int, c1: int) -> NDArray[np.int32]:
    """The sightings (``GridLayers.sightings``) inside rows ``r0:r1`` and columns ``c0:c1``, in the
    cropped grid's cells."""
    r, c = sightings[:, 2], sightings[:, 3]
    out = sightings[(r >= r0) & (r < r1) & (c >= c0) & (c < c1)].copy()
    out[:, 2] -= r0
    out[:, 3] -= c0
    out.setflags(write=False)
    return out


def evidence_occupancy(layers: GridLayers, cfg: CleaningConfig | None = None
                       ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Step 1 of cleaning, the occupancy before any semantic decision: (occupied, free), (H, W) bool.

    Occupied: log-odds above ``occupied_logodds``, or a return from at least ``hit_ratio`` of the
    scans observing the cell (``min_hits`` at least); free: observed with log-odds below
    ``free_logodds``. The two can overlap (a chair leg whose cell rays mostly pass); occupied wins.
    """
    cfg = cfg if cfg is not None else CleaningConfig()
    lo = layers.log_odds
    occ = lo > cfg.occupied_logodds
    if cfg.hit_ratio > 0:
        # thin things (chair legs) fill a fraction of their cell: rays often pass them by and
        # the clamped log-odds forgets them; the whole-tour share of returns remembers
        h = layers.hits.astype(np.float32)
        occ |= (h >= cfg.min_hits) & (h >= cfg.hit_ratio * (h + layers.free))
    free = layers.observed & (lo < cfg.free_logodds)
    return occ, free


def _clean(layers: GridLayers, cfg: CleaningConfig, names: tuple[str, ...]) -> CleanedMap:
    # the decisions' rasters (a dozen per cell) are gone before the objects are grouped
    occupied, free, unknown, semi_static, dropped = _decide(layers, cfg, names)
    objects, _ = group_objects(semi_static, layers, names, cfg.object_link_distance / layers.spec.resolution)
    log.info("cleaned map: %d occupied cells, %d dropped as dynamic, %d semi-static in %d objects",
             int(occupied.sum()), int(dropped.sum()), int(semi_static.sum()), len(objects))
    return CleanedMap(layers.spec, occupied, free, unknown, semi_static, dropped, tuple(objects))


def _decide(layers: GridLayers, cfg: CleaningConfig, names: tuple[str, ...]
            ) -> tuple[NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
    """Cleaning's decisions, cell by cell: (occupied, free, unknown, semi-static, dropped as dynamic)."""
    res = layers.spec.resolution
    occ, free = evidence_occupancy(layers, cfg)

    # (counts, not their float copies, where only compared: a 150 m floor at 5 cm has 9 million cells)
    s_static = layers.mobility[Mobility.STATIC]
    s_semi, s_dyn = (layers.mobility[k].astype(np.float32) for k in (Mobility.SEMI_STATIC, Mobility.DYNAMIC))
    lab = s_static + s_semi + s_dyn
    enough = lab >= cfg.min_labelled_hits
    with np.errstate(invalid="ignore", divide="ignore"):
        dyn_share = np.where(lab > 0, s_dyn / lab, 0.0)
        dyn_major, dyn_low = dyn_share >= cfg.dynamic_fraction, dyn_share < 0.1
        del dyn_share
        semi_major = np.where(lab > 0, s_semi / lab, 0.0) >= cfg.semi_static_fraction

    # walls and furniture faces: straight runs, each direction's segments judged as a whole
    # per cell, its most-hit movable class (-1: none) and each class's typical size (last entry: none)
    best, sizes = _best_semi_class(layers, names), _class_sizes(layers, names)
    longest = None
    if cfg.face_size_factor > 0 and layers.class_ids:
        longest = np.where(best >= 0, cfg.face_size_factor * sizes[best], 0.0).astype(np.float32)
    runs = _runs(occ, cfg, res, s_dyn, s_semi, lab, longest)
    del longest  # (a raster a cell: on a large floor each one counts)

    # everything else decides by its own evidence when it has enough labels
    rest = occ & ~runs.on
    own_dyn = rest & enough & dyn_major
    own_semi = rest & enough & ~own_dyn & semi_major
    own_static = rest & enough & ~own_dyn & ~own_semi
    undecided = rest & ~enough
    dyn = runs.dynamic | own_dyn
    semi = runs.semi | own_semi

    # people: a person is one object. Occupied cells within person_radius of a cell labelled
    # dynamic leave with it (the leg arcs no camera labelled), and so does a whole blob of touching
    # cells up to person_max_size that holds dynamic evidence; walls (static runs), furniture
    # faces (semi-static runs) and cells whose own labels clearly say something else stay
    if dyn.any() and cfg.person_radius > 0:
        # a furniture face's run may reach into the legs of someone standing against it: cells
        # whose own labels say dynamic are not protected by it (a wall's run protects everything)
        labelled_dyn = (s_dyn > 0) & dyn_major
        clearly_other = (runs.static | (runs.semi & ~labelled_dyn) | own_semi
                         | (own_static & (s_static >= 2 * cfg.min_labelled_hits) & dyn_low))
        free_to_go = occ & ~clearly_other
        person = free_to_go & (_distance_to(dyn) <= cfg.person_radius / res)
        n_blob, blob, stats, _ = cv2.connectedComponentsWithStats(free_to_go.astype(np.uint8), connectivity=8,
                                                                  ltype=cv2.CV_32S)
        extent = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) * res
        carries = np.bincount(blob[dyn & free_to_go], minlength=n_blob) > 0
        whole = carries & (extent <= cfg.person_max_size)
        whole[0] = False
        person |= whole[blob]
        # a person the camera also saw through a table's or a bed's mask: a blob up to person_max_size
        # whose labels, summed, say dynamic leaves whole, cells labelled as furniture included
        mixed = free_to_go | (own_semi & ~runs.on)
        n_blob, blob, stats, _ = cv2.connectedComponentsWithStats(mixed.astype(np.uint8), connectivity=8,
                                                                  ltype=cv2.CV_32S)
        extent = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) * res
        t_dyn = np.bincount(blob[mixed], s_dyn[mixed], n_blob)
        t_lab = np.bincount(blob[mixed], lab[mixed], n_blob)
        whole = (extent <= cfg.person_max_size) & (t_lab >= cfg.min_labelled_hits) & (
            t_dyn >= cfg.dynamic_fraction * t_lab)
        whole[0] = False
        person |= whole[blob]
        del blob, mixed, free_to_go
        dyn |= person
        semi &= ~dyn
        undecided &= ~dyn

    # people no camera labelled (standing all tour beside or behind the robot): their legs
    if cfg.person_leg_spacing[1] > 0:
        # (a blob touching a wall is part of the wall's blob, far too long to be a person)
        vetoed = (lab >= cfg.min_labelled_hits) & ~dyn_major
        # a blob's furniture labels count when they are a share of its returns: a person the camera never
        # saw as one, standing behind a chair from the camera's side, takes a few returns painted through
        # the chair's mask (parallax) among hundreds; structure labels as a share too
        legs = occ & ~dyn & _leg_pairs(occ & ~dyn, vetoed, runs.static | runs.unlabelled, res, cfg,
                                       s_semi, layers.hits, vetoed & (s_static >= cfg.min_labelled_hits), s_static,
                                       s_dyn, lab, occ & dyn)
        if legs.any():
            dyn |= legs
            semi &= ~dyn
            undecided &= ~dyn

    # cells seen free far more often than hit, with no camera label: someone who paused there
    # (their hits keep the log-odds up only because they were the last word), not furniture
    grazed = np.zeros(occ.shape, bool)
    if cfg.transient_ratio > 0:
        # a label too few to count (below min_labelled_hits) asks for _TRANSIENT_LABELLED times the ratio
        # (one float32 copy of the hits, as before: a 150 m floor at 5 cm has 9 million cells)
        least = cfg.transient_ratio * layers.hits.astype(np.float32)
        least[s_static + s_semi > 0] *= _TRANSIENT_LABELLED  # (a person's label or two says the same as the rays)
        transient = occ & ~runs.on & (lab < cfg.min_labelled_hits) & (layers.free >= least)
        if transient.any():
            # the rim of an obstacle that stays (a thin leg's outer cells, which rays grazing past it
            # cleared) is floor too, but no one paused there: free, not dropped as dynamic
            stays = occ & ~dyn & ~transient
            grazed = transient & cv2.dilate(stays.astype(np.uint8), _KERNEL3).astype(bool)
            dyn |= transient & ~grazed
            semi &= ~(dyn | grazed)
            undecided &= ~(dyn | grazed)

    # furniture faces the camera did not label: an unlabelled straight run that meets a
    # semi-static cell and is no longer than the longest piece of furniture is part of it
    # (a bed's or couch's side seen only from where the camera did not look)
    if semi.any() and cfg.face_max_length > 0:
        touch = cv2.dilate(semi.astype(np.uint8), _KERNEL3).astype(bool)
        faces = np.zeros(occ.shape, bool)
        flat_touch = touch.reshape(-1)
        for cells, seg, unlabelled, extent in runs.segments:
            meets = np.bincount(seg[flat_touch[cells]], minlength=unlabelled.size) > 0
            grow = unlabelled & meets & (extent <= cfg.face_max_length)
            grow[0] = False
            _mark(faces, grow, cells, seg)
        semi |= faces & runs.unlabelled & ~dyn

    # furniture the camera saw in one or two frames: its cells hold a label or so each, too few to
    # decide alone; undecided cells within object_link_distance of each other, away from walls,
    # are judged by the sum of their labels, and those labelled semi-static become furniture
    if undecided.any():
        by_wall = cv2.dilate((runs.static | own_static).astype(np.uint8), _KERNEL3).astype(bool)
        pool = undecided & ~by_wall
        n_grp, grp = group_cells(pool, cfg.object_link_distance / res)
        if n_grp:
            _, grp_semi = _verdicts(grp, pool, n_grp, np.zeros_like(s_dyn), s_semi, lab, cfg)
            semi |= pool & grp_semi[grp] & (s_semi > 0)
        del grp, pool, by_wall

    # unlabelled cells off the runs (legs the camera did not see, the far legs of a table) take a
    # semi-static verdict from the nearest semi-static cell when it is nearer than any wall or
    # static-labelled cell, and no farther than label_spread_distance, or for large furniture
    # 0.9 x its class's typical size (config/classes.yaml, sizes:)
    if semi.any() and undecided.any():
        d_semi, near_cls = nearest_value(semi, best)
        # cells touching a wall belong to it unless a semi-static cell is nearer; a blob standing
        # apart (a bed's leg 5 cm from the wall its headboard touches) competes only with cells
        # labelled static off the walls
        # (a straight run longer than any furniture is wall, labelled or not)
        long_runs = np.zeros(occ.shape, bool)
        for cells, seg, unlabelled, extent in runs.segments:
            far = unlabelled & (extent > max(cfg.face_max_length, cfg.structure_min_size))
            far[0] = False
            _mark(long_runs, far, cells, seg)
        wall = runs.static | own_static | long_runs
        by_wall = cv2.dilate(wall.astype(np.uint8), _KERNEL3).astype(bool)
        d_static = _distance_to(own_static)
        d_static[by_wall] = _distance_to(wall)[by_wall]
        cand = np.flatnonzero(undecided & (d_semi < d_static))
        del d_static
        # how far a class's verdict reaches, at the candidate cells only (-1 names the last entry)
        reach = np.maximum(cfg.label_spread_distance, 0.9 * sizes[near_cls.reshape(-1)[cand]]) / res
        semi.reshape(-1)[cand[d_semi.reshape(-1)[cand] <= reach]] = True
    if cfg.leg_max_size > 0:
        # the leg prior (off by default): a small isolated blob no camera labelled is a furniture leg
        n_blob, blob, stats, _ = cv2.connectedComponentsWithStats(occ.astype(np.uint8), connectivity=8,
                                                                  ltype=cv2.CV_32S)
        extent = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) * res
        labelled = np.bincount(blob[occ & (lab > 0)], minlength=n_blob) > 0
        leg = ~labelled & (extent <= cfg.leg_max_size)
        leg[0] = False
        semi |= undecided & leg[blob] & ~dyn

    dropped = occ & dyn
    occupied = occ & ~dropped & ~grazed
    if cfg.faint_leg_ratio > 0:
        legs = _faint_legs(layers, occupied, dropped | (s_dyn > 0), s_semi, s_dyn, cfg)
        occupied |= legs
        semi |= legs
    semi_static = occupied & semi
    free = (free | dropped | grazed) & ~occupied
    unknown = ~(occupied | free)
    return occupied, free, unknown, semi_static, dropped


#: returns a cell needs before :func:`_faint_legs` considers it (the diff's faint obstacles: FAINT_MIN_HITS)
_FAINT_LEG_MIN_HITS = 3


def _faint_legs(layers: GridLayers, occupied: NDArray[np.bool_], people: NDArray[np.bool_],
                s_semi: NDArray[np.float32], s_dyn: NDArray[np.float32], cfg: CleaningConfig) -> NDArray[np.bool_]:
    """Thin furniture legs the log-odds lost whole: cells not occupied, touching no occupied cell, that
    returned for at least ``faint_leg_ratio`` of the scans that observed them (``_FAINT_LEG_MIN_HITS``
    returns or more), that the camera labelled furniture (a semi-static label) and never a person, in pieces of at most
    ``faint_leg_max_cells`` cells, and farther than ``faint_leg_people_distance`` from ``people`` (cells
    labelled dynamic or dropped as people). A 4 cm leg fills part of its 5 cm cell: rays grazing past it
    cross the cell more often than beams end in it (a table leg: 30-40 returns among 170-200 rays), and it
    leaves the map, and the diff cannot see the table go. People leave such cells too (their legs, where
    they stood): on the diff's 80 development maps every one of those lay within 0.3 m of people evidence
    or carried no furniture label (furniture's: 650 of 730 beyond it)."""
    res = layers.spec.resolution
    cand = ~occupied & (layers.hits >= _FAINT_LEG_MIN_HITS) & (s_semi > 0) & (s_dyn == 0)
    idx = np.flatnonzero(cand)
    if idx.size == 0:
        return cand
    # the share test at the candidates only (a 150 m floor at 5 cm has 9 million cells)
    h = layers.hits.reshape(-1)[idx].astype(np.float64)
    weak = h < cfg.faint_leg_ratio * (h + layers.free.reshape(-1)[idx])
    cand.reshape(-1)[idx[weak]] = False
    if people.any():
        cand &= _distance_to(people) > cfg.faint_leg_people_distance / res
    _, lab, stats, _ = cv2.connectedComponentsWithStats(cand.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    keep = stats[:, cv2.CC_STAT_AREA] <= cfg.faint_leg_max_cells
    # a leg the map lost whole, not the rim of one it kept (the cells grazing rays cleared round a leg that
    # stays): a rim would move the leg, and the object, off where it stands
    touching = cv2.dilate(occupied.astype(np.uint8), _KERNEL3).astype(bool)
    keep[np.unique(lab[touching & cand])] = False
    keep[0] = False
    return keep[lab]


def semi_cell_classes(semi: NDArray[np.bool_], layers: GridLayers, names: Sequence[str]) -> NDArray[np.int16]:
    """Per semi-static cell, the class layer (index into ``layers.class_ids``) it is named by: its own
    most-hit movable class, or else the nearest named cell's of the same piece (8-connected), or, in a
    piece with no named cell, the nearest named cell's; -1 elsewhere, and everywhere when no cell is
    named. The objects are grouped per this class.

    The piece first: a couch's front the camera never labelled, seen under a table in front of it, is
    the couch's, not the nearer table leg's."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    best = _best_semi_class(layers, names)
    named = semi & (best >= 0)
    if not named.any():
        return np.full(semi.shape, -1, np.int16)
    _, near = nearest_value(named, best)
    out = np.where(semi, near, np.int16(-1))
    pieces, _ = ndimage.label(semi, structure=np.ones((3, 3), bool))
    nr, nc = np.nonzero(named)
    ur, uc = np.nonzero(semi & ~named)
    if ur.size:
        has_named = np.zeros(int(pieces.max()) + 1, bool)
        has_named[pieces[nr, nc]] = True
        sel = has_named[pieces[ur, uc]]
        ur, uc = ur[sel], uc[sel]
    if ur.size:
        # one tree for every piece: a piece's cells lie far apart from any other piece's along a third axis
        far = float(sum(semi.shape))
        tree = cKDTree(np.column_stack([nr, nc, pieces[nr, nc] * far]).astype(np.float64))
        _, j = tree.query(np.column_stack([ur, uc, pieces[ur, uc] * far]).astype(np.float64))
        out[ur, uc] = best[nr[j], nc[j]]
    return out


def group_objects(semi: NDArray[np.bool_], layers: GridLayers, names: Sequence[str],
                  link_cells: float) -> tuple[list[SemiStaticObject], NDArray[np.int32]]:
    """Group the semi-static cells into objects: per class, then by the camera's sightings, proximity and size.
    Returns the objects (sorted by centroid, y then x) and, per cell, the index of the object that
    holds it (-1 for none).

    Each cell is named by its own most-hit movable class, or else by the nearest named cell's.
    Cells of one class join into objects as :func:`_join_parts` says (the camera's sightings,
    else proximity and typical size, ``config/classes.yaml``, sizes:); a group much longer than
    one object of its class (a row of chairs) is cut along its length into as many objects as
    fit. An object's ``views`` are the painted scans whose furniture points landed on it.
    """
    index = np.full(semi.shape, -1, np.int32)
    if not semi.any():
        return [], index
    spec = layers.spec
    res = spec.resolution
    cls = semi_cell_classes(semi, layers, names)
    sizes = _class_sizes(layers, names)
    layer_names = [names[c] for c in layers.class_ids]
    labelled = layers.labelled
    seen_by = _scans_per_cell(layers.sightings, spec.shape)
    out: list[SemiStaticObject] = []
    cells: list[tuple[NDArray[np.intp], NDArray[np.intp]]] = []
    for k in np.unique(cls[semi]):
        mask = semi & (cls == k)
        size = float(sizes[k])
        n, lab = _join_parts(mask, layers.sightings, link_cells, size / res)
        rows, cols = np.nonzero(lab)
        ids = lab[rows, cols]
        order = np.argsort(ids, kind="stable")
        bounds = np.searchsorted(ids[order], np.arange(1, n + 2))
        cname = layer_names[k] if k >= 0 else "unknown"
        groups = [order[bounds[i - 1]:bounds[i]] for i in range(1, n + 1)]
        groups = _attach_unseen(groups, rows, cols, labelled, 0.9 * size / res)
        for sel in groups:
            xs = spec.origin_x + (cols[sel] + 0.5) * res
            ys = spec.origin_y + (rows[sel] + 0.5) * res
            for part in _split(np.column_stack([xs, ys]), size):
                r_, c_ = rows[sel][part], cols[sel][part]
                views = seen_by(r_, c_) if seen_by is not None else int(labelled[r_, c_].max())
                out.append(_box(cname, np.column_stack([xs[part], ys[part]]), res, views))
                cells.append((r_, c_))
    # by centroid, to the micrometre: a crop of the grid moves the cell centres' last bits, which
    # must not reorder two objects whose centroids tie in y
    ranked = sorted(range(len(out)), key=lambda i: (round(out[i].centroid[1], 6), round(out[i].centroid[0], 6)))
    for j, i in enumerate(ranked):
        index[cells[i]] = j
    return [out[i] for i in ranked], index


#: two parts of one class are one object when, of the scans that saw both on objects, at least this
#: share saw them on one object (one instance mask, or one connected region of their class's mask)
_TOGETHER = 0.5
#: ... and two parts are two objects, however near, when at most this share did (over 3 scans or more)
_APART = 0.2


def _join_parts(mask: NDArray[np.bool_], sightings: NDArray[np.int32], link_cells: float,
                size_cells: float) -> tuple[int, NDArray[np.int32]]:
    """Group the cells of one class into objects: (number of objects, labels as :func:`group_cells`).

    Cells ``link_cells`` apart form parts (a leg, a face). Two parts are one object when the
    camera saw them as one (``sightings``: over the scans that saw both, a share of at least
    ``_TOGETHER`` saw them on one object) and they lie within ``_SPLIT_LENGTH`` object sizes;
    failing camera evidence, when they lie within 0.9 object sizes (a table's legs span its top),
    unless the camera saw them apart (``_APART``; only a backend's instances tell objects apart, see
    ``REGION_BASE``). Pairs join best evidence first, and never into an object longer than its
    class can be (``_PROXIMITY_LENGTH`` sizes joined by proximity, ``_SPLIT_LENGTH`` seen as one).
    """
    n, lab = group_cells(mask, link_cells)
    if n < 2:
        return n, lab
    from scipy.spatial import cKDTree

    rows, cols = np.nonzero(lab)
    part = lab[rows, cols] - 1
    pts = np.column_stack([rows, cols]).astype(np.float64)
    # part pairs within 1.5 sizes, with their least cell distance
    far = _SPLIT_LENGTH * size_cells
    tree = cKDTree(pts)
    pairs = tree.query_pairs(far, output_type="ndarray")
    a, b = part[pairs[:, 0]], part[pairs[:, 1]]
    keep = a != b
    if not keep.any():
        return n, lab
    a, b = np.minimum(a[keep], b[keep]), np.maximum(a[keep], b[keep])
    d = np.hypot(*(pts[pairs[keep, 0]] - pts[pairs[keep, 1]]).T)
    key = a.astype(np.int64) * n + b
    order = np.lexsort((d, key))
    first = np.concatenate([[True], key[order][1:] != key[order][:-1]])
    key, d = key[order][first], d[order][first]
    pa, pb = key // n, key % n
    # scans that saw both parts, and scans that saw them on one object
    together, both = np.zeros(key.size), np.zeros(key.size)
    together_told, both_told = np.zeros(key.size), np.zeros(key.size)
    if sightings.shape[0]:
        h, w = lab.shape
        sr, sc = sightings[:, 2], sightings[:, 3]
        inside = (sr >= 0) & (sr < h) & (sc >= 0) & (sc < w)
        sp = np.full(sightings.shape[0], -1, np.int64)
        sp[inside] = lab[sr[inside], sc[inside]].astype(np.int64) - 1
        on = sp >= 0
        if on.any():
            scan, inst, sp = sightings[on, 0].astype(np.int64), sightings[on, 1].astype(np.int64), sp[on]
            both = _co_seen(scan, sp, n, pa, pb)
            _, view = np.unique((scan << 32) | inst, return_inverse=True)  # one object in one scan
            view = view.reshape(-1)
            together = np.minimum(_co_seen(view, sp, n, pa, pb), both)
            told = inst < REGION_BASE  # the backend's instances: they also tell objects apart
            if told.any():
                both_told = _co_seen(scan[told], sp[told], n, pa, pb)
                together_told = np.minimum(_co_seen(view[told], sp[told], n, pa, pb), both_told)
    same = (together >= 2) & (together >= _TOGETHER * both) & (d <= far)
    apart = (both_told >= 3) & (together_told <= _APART * both_told)
    near = (d <= 0.9 * size_cells) & ~apart
    # join the best-evidenced pairs first (seen as one, by share; then the nearest), while the object
    # stays no longer than one of its class can be (a row of desks the camera saw as one region is
    # several desks)
    cand = np.flatnonzero(same | near)
    share = np.where(same, together / np.maximum(both, 1), 0.0)
    cand = cand[np.lexsort((d[cand], -share[cand]))]
    parent = np.arange(n)
    members: dict[int, NDArray[np.intp]] = {}

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = int(parent[i])
        return i

    by_part = np.argsort(part, kind="stable")
    bounds = np.searchsorted(part[by_part], np.arange(n + 1))
    for i in range(n):
        members[i] = by_part[bounds[i]:bounds[i + 1]]
    for j in cand:
        ra, rb = root(int(pa[j])), root(int(pb[j]))
        if ra == rb:
            continue
        cells = np.concatenate([members[ra], members[rb]])
        if _length(pts[cells]) > (far if same[j] else _PROXIMITY_LENGTH * size_cells):
            continue
        parent[rb] = ra
        members[ra] = cells
        del members[rb]
    roots = np.array([root(i) for i in range(n)])
    _, obj = np.unique(roots, return_inverse=True)
    m = int(obj.max()) + 1
    out = np.zeros_like(lab)
    out[rows, cols] = obj[part] + 1
    return m, out


def _co_seen(group: NDArray[np.int64], part: NDArray[np.int64], n: int, pa: NDArray[np.int64],
             pb: NDArray[np.int64]) -> NDArray[np.float64]:
    """For each part pair (pa, pb): how many of the groups (scans, or objects in a scan) hold both."""
    from scipy.sparse import coo_matrix

    g = np.unique(group * n + part)
    gi, p = g // n, g % n
    inc = coo_matrix((np.ones(g.size), (gi, p)), shape=(int(gi.max()) + 1, n)).tocsc()
    co = (inc.T @ inc).tocsr()
    return np.asarray(co[pa, pb]).reshape(-1)


def _scans_per_cell(sightings: NDArray[np.int32], shape: tuple[int, int]
                    ) -> Callable[[NDArray[np.intp], NDArray[np.intp]], int] | None:
    """How many scans sighted any of some cells (None for a grid without sightings: maps built
    before they were kept, whose ``views`` are the most labelled hits of one cell instead)."""
    if sightings.shape[0] == 0:
        return None
    _h, w = shape
    flat = sightings[:, 2].astype(np.int64) * w + sightings[:, 3]
    order = np.argsort(flat, kind="stable")
    flat, scans = flat[order], sightings[order, 0]

    def count(rows: NDArray[np.intp], cols: NDArray[np.intp]) -> int:
        cells = np.unique(rows.astype(np.int64) * w + cols)
        lo, hi = np.searchsorted(flat, cells), np.searchsorted(flat, cells, side="right")
        if not (hi > lo).any():
            return 0
        return int(np.unique(np.concatenate([scans[a:b] for a, b in zip(lo, hi) if b > a])).size)

    return count


def _attach_unseen(groups: list[NDArray[np.intp]], rows: NDArray[np.intp], cols: NDArray[np.intp],
                   labelled: NDArray[np.uint32], reach_cells: float) -> list[NDArray[np.intp]]:
    """Join each group without a camera-labelled cell (cells that took their flag from a neighbour)
    to the nearest labelled group within ``reach_cells``: it is part of that object, not another."""
    seen = [bool(labelled[rows[g], cols[g]].any()) for g in groups]
    if all(seen) or not any(seen):
        return groups
    out = [g for g, v in zip(groups, seen) if v]
    centres = np.array([[rows[g].mean(), cols[g].mean()] for g in out])
    for g, v in zip(groups, seen):
        if v:
            continue
        d = np.hypot(centres[:, 0] - rows[g].mean(), centres[:, 1] - cols[g].mean())
        j = int(np.argmin(d))
        if d[j] <= reach_cells:
            out[j] = np.concatenate([out[j], g])
        else:
            out.append(g)
    return out


#: parts joined by proximity alone make an object at most this many times its class's typical size
#: long; parts the camera saw as one, at most _SPLIT_LENGTH times (a long table, a counter); longer
#: runs are cut (a row of chairs)
_PROXIMITY_LENGTH = 1.3
_SPLIT_LENGTH = 1.5
#: m, the space objects standing in a row keep between them (chairs along a table)
_ROW_GAP = 0.1


def _length(pts: NDArray[np.float64]) -> float:
    """How far ``pts`` (K, 2) span along their principal axis."""
    if pts.shape[0] < 2:
        return 0.0
    c = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    return float(np.ptp(c @ vt[0]))


def _split(pts: NDArray[np.float64], size: float) -> list[NDArray[np.intp]]:
    """Indices of ``pts`` cut into pieces about ``size`` long along their principal axis, as many as
    objects of that size fit with ``_ROW_GAP`` between them (one piece when they span less than
    ``_SPLIT_LENGTH`` sizes)."""
    if pts.shape[0] < 2:
        return [np.arange(pts.shape[0])]
    c = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    t = c @ vt[0]
    length = float(np.ptp(t))
    if length <= _SPLIT_LENGTH * size:
        return [np.arange(pts.shape[0])]
    # k objects of ``size`` in a row, _ROW_GAP apart, span k * size + (k - 1) * _ROW_GAP
    k = max(round((length + _ROW_GAP) / (size + _ROW_GAP)), 2)
    edges = t.min() + length * np.arange(1, k) / k
    piece = np.searchsorted(edges, t)
    return [np.flatnonzero(piece == j) for j in range(k) if (piece == j).any()]


def _box(cname: str, pts: NDArray[np.float64], res: float, views: int) -> SemiStaticObject:
    p32 = pts.astype(np.float32)
    (cx, cy), (w, h), ang = cv2.minAreaRect(p32)
    aw, ah = np.ptp(pts[:, 0]), np.ptp(pts[:, 1])
    if w * h >= 0.9 * aw * ah:  # barely better than the map axes: keep those
        (cx, cy), w, h, ang = (pts.min(axis=0) + 0.5 * np.array([aw, ah])), float(aw), float(ah), 0.0
    w, h = w + res, h + res  # cell centres to cell extents
    yaw = math.radians(ang)
    if h > w:
        w, h, yaw = h, w, yaw + math.pi / 2
    yaw = (yaw + math.pi / 2) % math.pi - math.pi / 2
    # the footprint: that box's corners, counter-clockwise (an object seen from two sides, such as a
    # couch in a corner, is its whole box, not the L its seen faces make)
    c, s = math.cos(yaw), math.sin(yaw)
    half = 0.5 * np.array([[w, h], [-w, h], [-w, -h], [w, -h]])
    corners = np.array([float(cx), float(cy)]) + half @ np.array([[c, s], [-s, c]])
    return SemiStaticObject(cname, (float(pts[:, 0].mean()), float(pts[:, 1].mean())), (float(w), float(h)),
                            float(yaw), int(pts.shape[0]), views,
                            tuple((round(float(x), 3) + 0.0, round(float(y), 3) + 0.0) for x, y in corners))  # no -0.0


def crop_to_observed(layers: GridLayers, cleaned: CleanedMap, margin_m: float) -> tuple[GridLayers, CleanedMap]:
    """Cut the grid down to the observed cells plus a margin (the fusion window grows in big steps)."""
    rows, cols = np.nonzero(~cleaned.unknown)
    if rows.size == 0:
        return layers, cleaned
    m = int(np.ceil(margin_m / layers.spec.resolution))
    h, w = layers.spec.shape
    r0, r1 = max(int(rows.min()) - m, 0), min(int(rows.max()) + 1 + m, h)
    c0, c1 = max(int(cols.min()) - m, 0), min(int(cols.max()) + 1 + m, w)
    spec = layers.spec.crop(r0, r1, c0, c1)
    win = (slice(r0, r1), slice(c0, c1))
    layers = replace(layers, spec=spec, log_odds=layers.log_odds[win], hits=layers.hits[win], free=layers.free[win],
                     mobility=layers.mobility[(slice(None), *win)],
                     class_counts=layers.class_counts[(slice(None), *win)],
                     sightings=crop_sightings(layers.sightings, r0, r1, c0, c1))
    cleaned = replace(cleaned, spec=spec, occupied=cleaned.occupied[win], free=cleaned.free[win],
                      unknown=cleaned.unknown[win], semi_static=cleaned.semi_static[win],
                      dynamic_removed=cleaned.dynamic_removed[win])
    return layers, cleaned
