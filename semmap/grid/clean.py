"""Cleaning: from fused evidence to the map a robot loads, with people dropped and furniture flagged.

The camera sees ~56° ahead while the LiDAR sees 270°, so most returns carry no label
(mobility 0). Decisions are therefore made per *object*, not only per cell:

1. **Occupancy.** Cells with log-odds above ``occupied_logodds`` are occupied, below
   ``free_logodds`` free, the rest unknown. Cells that returned at least ``hit_ratio`` of the
   scans observing them (and ``min_hits`` times) are occupied too: a 3.5 cm chair leg fills a
   third of its cell, rays often pass it by, and the clamped log-odds forgets it.
2. **Walls.** Straight runs of occupied cells at least ``wall_min_length`` long (morphological
   openings with line kernels in 8 directions) are judged per 8-connected segment by the sum
   of their labelled hits, so a long wall outvotes labels that bled onto part of it from
   furniture or people in front (mask edges, corner-LiDAR parallax). Segments longer than
   ``structure_min_size`` are never dropped as dynamic: no person is that long.
3. **Own evidence.** Any other occupied cell with at least ``min_labelled_hits`` labelled hits
   decides by itself: dynamic when the dynamic share of its labelled hits reaches
   ``dynamic_fraction``, else semi-static when the semi-static share reaches
   ``semi_static_fraction``, else static.
4. **Objects.** Cells with too few labels take a verdict from their object: non-wall cells at
   most ``object_link_distance`` apart belong together (a person's legs are ~0.2 m apart, a
   chair's ~0.4 m), judged by the sum of their labels, and only within
   ``label_spread_distance`` of a cell whose own evidence says the same (one labelled leg
   carries a person or a chair, not a room). Cells touching a static wall or a
   static-labelled cell, or in a blob longer than ``structure_min_size``, stay static: labels
   of things standing against a wall do not leak into it.
5. **Leg prior.** A small isolated blob (at most ``leg_max_size``) that the camera never
   labelled is a furniture leg, flagged semi-static: at LiDAR height furniture is its legs,
   and rooms the robot only looks into through a door are seen by the LiDAR alone.
6. **Output.** Dynamic cells are dropped from ``occupied`` and become free (the floor a person
   stood on); semi-static cells stay occupied and are flagged; flagged cells are grouped into
   :class:`SemiStaticObject` records.

What it cannot do: a person the camera never saw (standing in a room seen only through a door)
has no dynamic evidence and stays, flagged semi-static by the leg prior if their legs are
small and apart.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from ..config import CleaningConfig
from ..records import GridSpec, Mobility
from .fusion import GridLayers

__all__ = ["CleanedMap", "SemiStaticObject", "clean", "group_cells"]

log = logging.getLogger(__name__)


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

    def as_dict(self) -> dict[str, object]:
        return {"class": self.class_name, "centroid": [round(v, 3) for v in self.centroid],
                "size": [round(v, 3) for v in self.size], "yaw": round(self.yaw, 4), "n_cells": self.n_cells}


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
    n, lab = cv2.connectedComponents(grown, connectivity=8, ltype=cv2.CV_32S)
    lab[m == 0] = 0
    return n - 1, lab


def _distance_to(mask: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Distance (cells) from every cell to the nearest set cell of ``mask`` (inf if none)."""
    if not mask.any():
        return np.full(mask.shape, np.inf, np.float32)
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def _straight_runs(mask: NDArray[np.bool_], length_cells: float) -> NDArray[np.bool_]:
    """Cells of ``mask`` on a straight run at least ``length_cells`` long, in 8 directions.

    A morphological opening with a line kernel per direction (every 22.5°) keeps exactly the
    cells covered by a full line of set cells: walls, pillar faces and couch sides, not legs.
    """
    n = max(round(length_cells), 2)
    k = n | 1
    c = k // 2
    m = np.asarray(mask, dtype=np.uint8)
    out = np.zeros(m.shape, np.uint8)
    kernels = [np.ones((1, n), np.uint8), np.ones((n, 1), np.uint8)]
    for deg in (22.5, 45.0, 67.5, 112.5, 135.0, 157.5):
        kern = np.zeros((k, k), np.uint8)
        dx, dy = c * math.cos(math.radians(deg)), c * math.sin(math.radians(deg))
        cv2.line(kern, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1, 1, cv2.LINE_8)
        kernels.append(kern)
    for kern in kernels:
        out |= cv2.morphologyEx(m, cv2.MORPH_OPEN, kern, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(bool)


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
    from ..classes import load_class_table
    from ..errors import ConfigError

    try:
        table = load_class_table()
    except ConfigError:  # naming objects must not fail cleaning
        return [None] * len(names)
    return [table.mobility.get(n) for n in names]


def clean(layers: GridLayers, cfg: CleaningConfig | None = None,
          class_names: Sequence[str] | None = None) -> CleanedMap:
    """Turn fused evidence into the cleaned map: people dropped, furniture flagged (see module doc).

    ``class_names`` names the class ids of ``layers`` (default: ``layers.class_names``).
    """
    cfg = cfg if cfg is not None else CleaningConfig()
    names = tuple(class_names) if class_names is not None else layers.class_names
    if layers.class_ids and max(layers.class_ids) >= len(names):
        raise ValueError(f"class_names has {len(names)} names; the grid uses class id {max(layers.class_ids)}")
    spec = layers.spec
    res = spec.resolution
    lo = layers.log_odds
    occ = lo > cfg.occupied_logodds
    if cfg.hit_ratio > 0:
        # thin things (chair legs) fill a fraction of their cell: rays often pass them by and
        # the clamped log-odds forgets them; the whole-tour share of returns remembers
        h = layers.hits.astype(np.float32)
        occ |= (h >= cfg.min_hits) & (h >= cfg.hit_ratio * (h + layers.free))
    free = layers.observed & (lo < cfg.free_logodds)

    m = layers.mobility.astype(np.float32)
    s_static, s_semi, s_dyn = m[Mobility.STATIC], m[Mobility.SEMI_STATIC], m[Mobility.DYNAMIC]
    lab = s_static + s_semi + s_dyn
    enough = lab >= cfg.min_labelled_hits
    with np.errstate(invalid="ignore", divide="ignore"):
        dyn_share = np.where(lab > 0, s_dyn / lab, 0.0)
        semi_share = np.where(lab > 0, s_semi / lab, 0.0)

    # walls: straight runs of occupied cells at least wall_min_length long, each 8-connected
    # segment judged as a whole, so a long wall outvotes labels that bled onto part of it from
    # furniture or people in front, and a couch's outline labelled semi-static stays so
    wall = _straight_runs(occ, cfg.wall_min_length / res)
    n_seg, seg, seg_stats, _ = cv2.connectedComponentsWithStats(wall.astype(np.uint8), connectivity=8,
                                                                ltype=cv2.CV_32S)
    seg_dyn, seg_semi = _verdicts(seg, wall, n_seg - 1, s_dyn, s_semi, lab, cfg)
    # no person is longer than structure_min_size: longer runs are never dropped, whatever
    # bled onto them (a wall seen once through a doorway with someone standing in it)
    seg_extent = np.maximum(seg_stats[:, cv2.CC_STAT_WIDTH], seg_stats[:, cv2.CC_STAT_HEIGHT]) * res
    seg_dyn &= seg_extent <= cfg.structure_min_size
    dyn = wall & seg_dyn[seg]
    semi = wall & seg_semi[seg]

    # everything else decides by its own evidence when it has enough labels
    rest = occ & ~wall
    own_dyn = rest & enough & (dyn_share >= cfg.dynamic_fraction)
    own_semi = rest & enough & ~own_dyn & (semi_share >= cfg.semi_static_fraction)
    own_static = rest & enough & ~own_dyn & ~own_semi
    undecided = rest & ~enough
    dyn |= own_dyn
    semi |= own_semi

    # blobs: occupied cells touching each other (8-connected). Unlabelled cells of a blob that
    # holds a static wall or a static-labelled cell, or is longer than structure_min_size, stay static:
    # labels of things standing against a wall do not leak into it. A small blob without any
    # label is a furniture leg (the leg prior: at LiDAR height furniture is its legs).
    n_blob, blob, stats, _ = cv2.connectedComponentsWithStats(occ.astype(np.uint8), connectivity=8,
                                                              ltype=cv2.CV_32S)
    extent = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) * res
    anchored = np.bincount(blob[own_static | (wall & ~dyn & ~semi)], minlength=n_blob) > 0
    labelled = np.bincount(blob[occ & (lab > 0)], minlength=n_blob) > 0
    structure = anchored | (extent > cfg.structure_min_size)
    leg = ~labelled & ~anchored & (extent <= cfg.leg_max_size)
    structure[0] = leg[0] = False
    inheriting = undecided & ~structure[blob]

    # objects: dynamic or semi-static cells and the undecided cells free to inherit, within
    # object_link_distance of each other, judged by the sum of their labels; undecided cells
    # take the verdict near cells that carry it
    nodes = dyn | semi | inheriting
    n_obj, obj = group_cells(nodes, cfg.object_link_distance / res)
    if n_obj:
        obj_dyn, obj_semi = _verdicts(obj, nodes, n_obj, s_dyn, s_semi, lab, cfg)
        spread = cfg.label_spread_distance / res
        near_dyn = _distance_to(dyn) <= spread
        near_semi = _distance_to(semi) <= spread
        dyn |= inheriting & obj_dyn[obj] & near_dyn
        semi |= inheriting & obj_semi[obj] & near_semi & ~dyn
    if cfg.leg_max_size > 0:
        semi |= inheriting & leg[blob] & ~dyn

    dropped = occ & dyn
    occupied = occ & ~dropped
    semi_static = occupied & semi
    free = (free | dropped) & ~occupied
    unknown = ~(occupied | free)
    objects = _objects(semi_static, layers, names, cfg.object_link_distance / res)
    log.info("cleaned map: %d occupied cells, %d dropped as dynamic, %d semi-static in %d objects",
             int(occupied.sum()), int(dropped.sum()), int(semi_static.sum()), len(objects))
    return CleanedMap(spec, occupied, free, unknown, semi_static, dropped, objects)


def _objects(semi: NDArray[np.bool_], layers: GridLayers, names: Sequence[str],
             link_cells: float) -> list[SemiStaticObject]:
    n, lab = group_cells(semi, link_cells)
    if not n:
        return []
    spec = layers.spec
    res = spec.resolution
    rows, cols = np.nonzero(lab)
    ids = lab[rows, cols]
    xs = spec.origin_x + (cols + 0.5) * res
    ys = spec.origin_y + (rows + 0.5) * res
    # class votes per object, preferring classes the class table calls semi-static
    layer_names = [names[c] for c in layers.class_ids]
    mob = _class_mobility(layer_names)
    votes = np.zeros((n + 1, len(layer_names)))
    for k in range(len(layer_names)):
        votes[:, k] = np.bincount(ids, layers.class_counts[k][rows, cols].astype(np.float64), n + 1)
    prefer = np.array([mb in (None, Mobility.SEMI_STATIC) for mb in mob], bool)
    order = np.argsort(ids, kind="stable")
    bounds = np.searchsorted(ids[order], np.arange(1, n + 2))
    out = []
    for i in range(1, n + 1):
        sel = order[bounds[i - 1]:bounds[i]]
        pts = np.column_stack([xs[sel], ys[sel]]).astype(np.float32)
        v = votes[i]
        if len(layer_names) and (v[prefer].sum() > 0 or v.sum() > 0):
            vv = np.where(prefer, v, -1.0) if v[prefer].sum() > 0 else v
            cname = layer_names[int(np.argmax(vv))]
        else:
            cname = "unknown"
        _, (w, h), ang = cv2.minAreaRect(pts)
        aw, ah = np.ptp(pts[:, 0]), np.ptp(pts[:, 1])
        if w * h >= 0.9 * aw * ah:  # barely better than the map axes: keep those
            w, h, ang = float(aw), float(ah), 0.0
        w, h = w + res, h + res  # cell centres to cell extents
        yaw = math.radians(ang)
        if h > w:
            w, h, yaw = h, w, yaw + math.pi / 2
        yaw = (yaw + math.pi / 2) % math.pi - math.pi / 2
        out.append(SemiStaticObject(cname, (float(xs[sel].mean()), float(ys[sel].mean())), (float(w), float(h)),
                                    float(yaw), int(sel.size)))
    return out
