"""Scoring maps of simulated tours against their ground truth, and a naive mapper to compare with.

A simulated tour (:mod:`semmap.sim.tour`) carries its exact ground truth in ``ground_truth/``.
This module turns that into numbers for any map of the tour:

* :func:`score_map` scores a map folder that ``semmap build`` wrote: the trajectory is aligned
  to the true one (SE(2), :func:`semmap.register.metrics.ate_errors`), and the same alignment
  carries the map into the ground-truth frame;
* :func:`naive_map` builds the baseline every semantic map must beat: the scans as recorded
  (noise, dropouts), each placed with the *true* pose, fused into a log-odds grid, with no
  camera and no semantics (nothing is dropped as a person, nothing is flagged movable);
* :func:`score_masks` scores any occupied / semi-static mask pair with its objects; both of the
  above go through it.

The scores (keys of the returned dict; NaN where a score is undefined or its ground truth is
missing from the tour folder):

* ``f1``, ``precision``, ``recall``: occupied cells against the truth's static ∪ semi-static
  cells at 1-cell tolerance; recall over the truth cells a true beam ended on;
* ``ghost_rate``: share of the cells people's bodies swept that stay occupied;
* ``standing_left``: share of the cells a person stood on for 5 s or more that stay occupied;
  both leave out cells within 1 cell of static or semi-static structure (where a wall's own
  returns land, as the F1's tolerance allows);
* ``semi_precision``: share of flagged cells within 1 cell of truth semi-static furniture;
* ``semi_recall``: share of observable truth semi-static cells, of furniture the camera
  labelled at least once, within 1 cell of a flagged cell; ``semi_recall_all``: the same over
  every observable truth semi-static cell;
* ``walls_flagged``: flagged cells on static structure, next to no furniture;
* ``objects_*``: the map's object list against the furniture the camera labelled at least once
  (``objects_truth_lidar``: the furniture the LiDAR saw, labelled or not);
* ``ate_rmse_m`` (:func:`score_map` only): the trajectory's error after alignment.

Tolerances follow :mod:`semmap.grid.metrics`: "within 1 cell" is the 3 x 3 neighbourhood at
the resolution of the grid looked up.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..records import GridSpec

__all__ = [
    "OBJECT_MATCH_DISTANCE",
    "GroundTruth",
    "NaiveMap",
    "TruthObject",
    "load_truth",
    "match_objects",
    "naive_map",
    "score_map",
    "score_masks",
    "walls_flagged",
]

log = logging.getLogger(__name__)

#: a map object matches a truth object when its centroid lies this close to the object's footprint, m
OBJECT_MATCH_DISTANCE = 0.3

_NAN = float("nan")


# ---------------------------------------------------------------------------------------
# Ground truth


@dataclass(frozen=True)
class TruthObject:
    """A semi-static world object as the LiDAR could see it (world frame, metres).

    ``footprint`` (K, 2) is the convex hull of the object's parts cut at the LiDAR's height: a
    table's is the rectangle its legs span, a couch's its body. ``lidar_hits`` and
    ``painted_hits`` come from ``ground_truth/objects.json`` (None when the tour has none).
    """

    id: int
    name: str
    cls: str
    footprint: NDArray[np.float64]
    lidar_hits: int | None = None
    painted_hits: int | None = None

    def distance(self, point: ArrayLike) -> float:
        """Distance (m) from a point to the footprint; 0 inside it."""
        import cv2

        p = np.asarray(point, dtype=np.float64).reshape(2)
        d = cv2.pointPolygonTest(self.footprint.astype(np.float32).reshape(-1, 1, 2),
                                 (float(p[0]), float(p[1])), True)
        return max(0.0, -float(d))

    @property
    def centre(self) -> NDArray[np.float64]:
        return 0.5 * (self.footprint.min(axis=0) + self.footprint.max(axis=0))


@dataclass(frozen=True)
class GroundTruth:
    """Everything scoring needs from a tour's ``ground_truth/``, loaded once.

    Masks are (H, W) bool in ``spec`` (the truth grid, world frame). Layers a tour folder may
    lack are None: ``standing`` (``people_standing.yaml``) and ``semi_labelled`` (needs
    ``objects.json``).

    * ``swept``, ``standing``: the people layers without the cells within 1 cell of structure.
    * ``observable``: truth occupancy cells within 1 cell of a true beam end (people excluded).
    * ``semi_labelled``: truth semi-static cells of furniture the camera labelled at least once
      (``painted_hits > 0``).
    * ``objects``: the semi-static objects the LiDAR saw (``lidar_hits > 0``; without
      ``objects.json``: every semi-static object with parts at the LiDAR's height).
    """

    tour: Path | None
    spec: GridSpec
    occupancy: NDArray[np.bool_]
    static: NDArray[np.bool_]
    semi_static: NDArray[np.bool_]
    swept: NDArray[np.bool_]
    standing: NDArray[np.bool_] | None
    observable: NDArray[np.bool_]
    semi_labelled: NDArray[np.bool_] | None
    objects: tuple[TruthObject, ...]
    objects_source: str  # "objects.json" or "world.yaml"
    stamps_ns: NDArray[np.int64]  # the true trajectory
    poses: NDArray[np.float64]

    @property
    def labelled_objects(self) -> tuple[TruthObject, ...]:
        """The objects the camera labelled at least once (``painted_hits > 0``; all of
        :attr:`objects` when the tour has no ``objects.json``): what a semantic map can list and name."""
        return tuple(o for o in self.objects if o.painted_hits is None or o.painted_hits > 0)


def _layer(path: Path, spec: GridSpec) -> NDArray[np.bool_] | None:
    """A truth layer resampled into ``spec`` (None when the file is absent)."""
    from ..grid.metrics import transfer
    from ..io.mapserver import read_map

    if not path.is_file():
        return None
    m = read_map(path)
    return m.occupied if m.spec == spec else transfer(m.occupied, m.spec, spec)


def _lidar_height(tour: Path) -> float:
    from ..config import SimConfig, load_model
    from ..io.yamlio import read_yaml

    cfg = load_model(SimConfig, read_yaml(tour / "config.yaml"), str(tour / "config.yaml"))
    return float(cfg.lidar.mount.xyz[2])


def load_truth(tour: str | Path) -> GroundTruth:
    """Read a simulated tour's ground truth (see :class:`GroundTruth`)."""
    import cv2

    from ..grid.metrics import observable_cells
    from ..io.mapserver import read_map
    from ..io.tum import read_tum
    from ..records import Mobility
    from .groundtruth import rasterise, true_beam_end_points
    from .world import load_world

    tour = Path(tour)
    gt = tour / "ground_truth"
    occ = read_map(gt / "occupancy.yaml")
    spec = occ.spec
    static = _layer(gt / "static.yaml", spec)
    semi = _layer(gt / "semi_static.yaml", spec)
    swept = _layer(gt / "people_swept.yaml", spec)
    if static is None or semi is None or swept is None:
        raise FileNotFoundError(f"{gt}: static.yaml, semi_static.yaml and people_swept.yaml are needed")
    standing = _layer(gt / "people_standing.yaml", spec)
    # a return from a wall's face lands in the cell just outside the wall's rasterised polygon
    # about half the time (the F1's 1-cell tolerance): where people walked along a wall those
    # cells are wall, not ghosts, so the people layers leave out cells within 1 cell of structure
    near_structure = cv2.dilate(occ.occupied.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    swept = swept & ~near_structure
    if standing is not None:
        standing = standing & ~near_structure
    observable = observable_cells(occ.occupied, spec, true_beam_end_points(tour))

    world = load_world(gt / "world.yaml")
    height = _lidar_height(tour)
    parts = {o.id: [p.polygon for p in o.parts if p.spans(height)]
             for o in world.objects if o.mobility == Mobility.SEMI_STATIC}
    info: dict[int, Mapping[str, Any]] = {}
    if (gt / "objects.json").is_file():
        data = json.loads((gt / "objects.json").read_text(encoding="utf-8"))
        info = {int(o["id"]): o for o in data.get("objects", [])}
    objects = []
    for o in world.objects:
        polys = parts.get(o.id)
        if not polys:  # not semi-static, or nothing at the LiDAR's height
            continue
        rec = info.get(o.id)
        if info and (rec is None or int(rec.get("lidar_hits", 0)) <= 0):
            continue  # the LiDAR never saw it
        hull = cv2.convexHull(np.concatenate(polys).astype(np.float32)).reshape(-1, 2).astype(np.float64)
        objects.append(TruthObject(o.id, o.name, o.cls, hull,
                                   None if rec is None else int(rec.get("lidar_hits", 0)),
                                   None if rec is None else int(rec.get("painted_hits", 0))))
    semi_labelled = None
    if info:
        painted = [p for oid, polys in parts.items()
                   if int(info.get(oid, {}).get("painted_hits", 0)) > 0 for p in polys]
        semi_labelled = semi & rasterise(spec, painted)
    t, p = read_tum(gt / "trajectory.tum")
    return GroundTruth(tour, spec, occ.occupied, static, semi, swept, standing, observable, semi_labelled,
                       tuple(objects), "objects.json" if info else "world.yaml", t, p)


# ---------------------------------------------------------------------------------------
# Scores


def walls_flagged(semi_static: NDArray[np.bool_], spec: GridSpec, truth_static: NDArray[np.bool_],
                  truth_semi_static: NDArray[np.bool_], truth_spec: GridSpec,
                  T_gt_map: ArrayLike | None = None) -> int:
    """Cells flagged semi-static that lie on static structure and next to no furniture.

    A flagged map cell counts when its centre, carried into the truth grid with ``T_gt_map``,
    lands within 1 cell of a truth static cell (walls, pillars) and not within 1 cell of any
    truth semi-static cell. The tolerance on the static side is the one the F1 uses: a return
    from a wall's face lands in the cell just outside the wall's rasterised polygon about half
    the time. The one on the furniture side keeps a chair leg touching a wall from counting.
    """
    import cv2

    from ..grid.metrics import hits_near

    k = np.ones((3, 3), np.uint8)
    near_static = cv2.dilate(np.asarray(truth_static, np.uint8), k).astype(bool)
    near_semi = cv2.dilate(np.asarray(truth_semi_static, np.uint8), k).astype(bool)
    t = np.zeros(3) if T_gt_map is None else np.asarray(T_gt_map, dtype=np.float64)
    n, _ = hits_near(np.asarray(semi_static, bool), spec, near_static & ~near_semi, truth_spec, 0, t)
    return n


def match_objects(map_objects: Sequence[Mapping[str, Any]], truth_objects: Sequence[TruthObject],
                  T_gt_map: ArrayLike | None = None,
                  max_distance: float = OBJECT_MATCH_DISTANCE) -> dict[str, float | int]:
    """The map's object list against the truth's objects.

    ``map_objects`` are records as ``semi_static_objects.json`` holds them (``class``,
    ``centroid`` in the map frame). A map object *reaches* a truth object when its centroid,
    carried into the truth frame with ``T_gt_map``, lies within ``max_distance`` of the truth
    object's footprint (:class:`TruthObject`).

    * ``objects_truth``: truth objects; ``objects_found``: map objects.
    * ``objects_count_error``: (found - truth) / truth (NaN without truth objects).
    * ``objects_matched``: one-to-one pairs, taken greedily nearest first (footprint distance,
      then distance between centres: a chair tucked under a table is inside both).
    * ``objects_class_right``: share of matched map objects whose class is the truth's (NaN
      when none matched).
    * ``objects_split``: truth objects that are the nearest reached object of two or more map
      objects (a table seen as its four legs).
    * ``objects_spurious``: map objects reaching no truth object.
    """
    from ..geometry import se2_apply

    t = np.zeros(3) if T_gt_map is None else np.asarray(T_gt_map, dtype=np.float64)
    n_map, n_truth = len(map_objects), len(truth_objects)
    pairs = []  # (footprint distance, centre distance, map index, truth index)
    nearest: list[int | None] = []
    for i, m in enumerate(map_objects):
        c = se2_apply(t, np.asarray(m["centroid"], dtype=np.float64).reshape(2))
        best = None
        for j, o in enumerate(truth_objects):
            d = o.distance(c)
            if d <= max_distance:
                key = (d, float(np.hypot(*(c - o.centre))), i, j)
                pairs.append(key)
                best = key if best is None or key < best else best
        nearest.append(None if best is None else best[3])
    pairs.sort()
    used_map: set[int] = set()
    used_truth: set[int] = set()
    matched: list[tuple[int, int]] = []
    for _, _, i, j in pairs:
        if i not in used_map and j not in used_truth:
            used_map.add(i)
            used_truth.add(j)
            matched.append((i, j))
    per_truth = np.bincount([j for j in nearest if j is not None], minlength=n_truth)
    right = sum(map_objects[i].get("class") == truth_objects[j].cls for i, j in matched)
    return {
        "objects_truth": n_truth,
        "objects_found": n_map,
        "objects_count_error": (n_map - n_truth) / n_truth if n_truth else _NAN,
        "objects_matched": len(matched),
        "objects_class_right": right / len(matched) if matched else _NAN,
        "objects_split": int((per_truth >= 2).sum()),
        "objects_spurious": sum(j is None for j in nearest),
    }


def score_masks(tour: str | Path | None, spec: GridSpec, occupied: NDArray[np.bool_], semi_static: NDArray[np.bool_],
                objects: Sequence[Mapping[str, Any]] = (), T_gt_map: ArrayLike | None = None,
                truth: GroundTruth | None = None) -> dict[str, float | int]:
    """Score a map given as masks in ``spec`` (map frame) against the tour's ground truth.

    ``T_gt_map``: the map frame's SE(2) pose in the truth (world) frame; identity (None) for a
    map built with true poses. ``objects``: the map's objects as ``semi_static_objects.json``
    lists them. ``truth``: the tour's :func:`load_truth`, to load it once for several maps
    (``tour`` may then be None).

    * ``f1``, ``precision``, ``recall``: :func:`semmap.grid.metrics.occupancy_f1` against
      static ∪ semi-static at 1-cell tolerance, recall over ``truth.observable``.
    * ``ghost_rate``: share of ``people_swept`` cells the map marks occupied (no tolerance).
    * ``standing_left``: the same over ``people_standing`` (NaN when absent or empty).
    * ``semi_precision``: share of flagged cells within 1 cell of a truth semi-static cell.
    * ``semi_recall``: share of observable truth semi-static cells of camera-labelled furniture
      within 1 cell of a flagged cell (NaN without ``objects.json``); ``semi_recall_all``: over
      every observable truth semi-static cell.
    * ``walls_flagged``: :func:`walls_flagged`.
    * ``objects_*``: :func:`match_objects` against ``truth.labelled_objects`` (furniture the camera
      labelled at least once: an object no camera saw cannot be named); ``objects_truth_lidar``:
      how many the LiDAR saw.
    """
    from ..grid.metrics import ghost_rate, occupancy_f1, semi_static_scores

    if truth is None:
        if tour is None:
            raise ValueError("score_masks needs the tour folder or its loaded ground truth")
        truth = load_truth(tour)
    t = np.zeros(3) if T_gt_map is None else np.asarray(T_gt_map, dtype=np.float64)
    occ = np.asarray(occupied, dtype=bool)
    semi = np.asarray(semi_static, dtype=bool)
    f1 = occupancy_f1(occ, spec, truth.occupancy, truth.spec, truth.observable, 1, t)
    ghost = ghost_rate(occ, spec, truth.swept, truth.spec, t)
    standing = _NAN if truth.standing is None else ghost_rate(occ, spec, truth.standing, truth.spec, t)
    semi_all = semi_static_scores(semi, spec, truth.semi_static, truth.spec, truth.observable & truth.semi_static,
                                  1, t)
    semi_recall = _NAN
    if truth.semi_labelled is not None:
        semi_recall = semi_static_scores(semi, spec, truth.semi_static, truth.spec,
                                         truth.observable & truth.semi_labelled, 1, t).recall
    return {
        "f1": f1.f1, "precision": f1.precision, "recall": f1.recall,
        "ghost_rate": ghost, "standing_left": standing,
        "semi_precision": semi_all.precision, "semi_recall": semi_recall, "semi_recall_all": semi_all.recall,
        "walls_flagged": walls_flagged(semi, spec, truth.static, truth.semi_static, truth.spec, t),
        **match_objects(objects, truth.labelled_objects, t),
        "objects_truth_lidar": len(truth.objects),
    }


def score_map(tour: str | Path, map_dir: str | Path, truth: GroundTruth | None = None) -> dict[str, float | int]:
    """Score a map folder ``semmap build`` wrote from a simulated tour (keys of :func:`score_masks`).

    Adds ``ate_rmse_m``: the RMSE (m) of the positions of ``trajectory.tum`` against the true
    trajectory after the SE(2) alignment that also gives ``T_gt_map`` for the map scores.
    """
    from ..mapfolder.reader import load_map_folder
    from ..register.metrics import ate_errors

    m = load_map_folder(map_dir)
    truth = truth if truth is not None else load_truth(tour)
    err, t_gt_map = ate_errors(m.stamps_ns, m.poses, truth.stamps_ns, truth.poses)
    objects = [o.as_dict() for o in m.objects]
    return {"ate_rmse_m": float(np.sqrt(np.mean(err ** 2))),
            **score_masks(tour, m.spec, m.occupied, m.semi_static, objects, t_gt_map, truth)}


# ---------------------------------------------------------------------------------------
# The naive mapper


@dataclass(frozen=True)
class NaiveMap:
    """A true-pose occupancy map without semantics (grid order, row 0 = lowest y, world frame).

    ``semi_static`` is all False and ``objects`` empty: the naive mapper knows no classes.
    """

    spec: GridSpec
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    semi_static: NDArray[np.bool_]
    objects: tuple[Mapping[str, Any], ...] = ()
    n_scans: int = 0
    elapsed_s: float = 0.0


def naive_map(tour: str | Path, resolution: float | None = None) -> NaiveMap:
    """Map a simulated tour the naive way: recorded scans, true poses, log-odds, no semantics.

    Every scan of the bag (as recorded: range noise, dropouts) is read with semmap's bag reader;
    each beam is placed with the true pose (``ground_truth/trajectory.tum``, interpolated at the
    beam's own firing time) and the LiDAR mount of the tour's ``config.yaml``, then expressed in
    the base frame at the scan's middle beam, as semmap's painter deskews. The unpainted scans
    (mobility unknown) are fused with :class:`~semmap.grid.fusion.SemanticGrid` under semmap's
    default grid settings, except that evidence is taken over the LiDAR's whole ``range_max``
    (hits and free space alike). Occupied cells follow the occupancy rule
    :func:`~semmap.grid.clean.clean` starts from, with its defaults: log-odds above
    ``occupied_logodds``, or at least ``min_hits`` returns making ``hit_ratio`` of the scans that
    observed the cell (thin legs). None of cleaning's later rules apply (they read camera labels,
    or shapes such as a person's legs): no cell is dropped or flagged.
    """
    from ..config import CleaningConfig, GridConfig, SimConfig, load_model
    from ..errors import SemmapError
    from ..geometry import se3_from_xyz_rpy
    from ..grid.fusion import SemanticGrid
    from ..io.bag import iter_records
    from ..io.tour import TourManifest
    from ..io.tum import read_tum
    from ..io.yamlio import read_yaml
    from ..records import PaintedScan

    t_start = time.perf_counter()
    tour = Path(tour)
    cfg = load_model(SimConfig, read_yaml(tour / "config.yaml"), str(tour / "config.yaml"))
    manifest = load_model(TourManifest, read_yaml(tour / "tour.yaml"), str(tour / "tour.yaml"))
    topic = manifest.topics.get("scan") or cfg.lidar.topic
    t_base_lidar = se3_from_xyz_rpy(cfg.lidar.mount.xyz, cfg.lidar.mount.rpy)
    origin = t_base_lidar[:2, 3].copy()
    # evidence over the LiDAR's whole range
    grid = SemanticGrid(GridConfig.model_validate({"max_range": cfg.lidar.range_max,
                                                   **({"resolution": resolution} if resolution else {})}))

    ref_t, ref_p = read_tum(tour / "ground_truth" / "trajectory.tum")
    ref_s = (ref_t - ref_t[0]).astype(np.float64) * 1e-9
    ref_yaw = np.unwrap(ref_p[:, 2])
    layout: tuple[tuple[float, float, int], NDArray[np.float64]] | None = None
    n_scans = skipped = 0
    for _, _, scan in iter_records(tour, [topic]):
        n = scan.ranges.size
        if n == 0:
            skipped += 1
            continue
        key = (scan.angle_min, scan.angle_increment, n)
        if layout is None or layout[0] != key:
            a = scan.angles
            dirs = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)]) @ t_base_lidar[:3, :3].T
            layout = (key, dirs[:, :2].copy())
        dirs = layout[1]
        r = scan.ranges.astype(np.float64)
        lo = max(scan.range_min, 1e-3)
        hit = (r >= lo) & (r <= scan.range_max)
        # REP-117 as semmap's painter reads it: +inf is no return (free to the range limit),
        # NaN, -inf and readings under range_min are invalid (they clear nothing)
        free_len = np.where(hit, r, np.where(r > scan.range_max, min(scan.range_max, cfg.lidar.range_max), 0.0))
        local = origin + dirs * free_len[:, None]  # base frame at each beam's own time
        step_ns = int(round(scan.time_increment * 1e9)) if scan.time_increment > 0 else 0
        k = np.arange(n)
        ts = (scan.stamp_ns - ref_t[0] + step_ns * k).astype(np.float64) * 1e-9
        t_ref = (scan.stamp_ns - ref_t[0] + step_ns * (n // 2)) * 1e-9
        if ts.min() < ref_s[0] or ts.max() > ref_s[-1]:
            skipped += 1
            continue
        x, y, yaw = np.interp(ts, ref_s, ref_p[:, 0]), np.interp(ts, ref_s, ref_p[:, 1]), np.interp(ts, ref_s, ref_yaw)
        px, py, pyaw = (float(np.interp(t_ref, ref_s, v)) for v in (ref_p[:, 0], ref_p[:, 1], ref_yaw))
        # beam -> world with the pose at its own time -> base frame at the reference (middle) beam
        c, s = np.cos(yaw), np.sin(yaw)
        wx = x + c * local[:, 0] - s * local[:, 1] - px
        wy = y + s * local[:, 0] + c * local[:, 1] - py
        cr, sr = math.cos(pyaw), math.sin(pyaw)
        pts = np.column_stack([cr * wx + sr * wy, -sr * wx + cr * wy])
        painted = PaintedScan(stamp_ns=scan.stamp_ns + step_ns * (n // 2), origin=origin, points=pts, hit=hit,
                              mobility=np.zeros(n, np.uint8), class_id=np.full(n, -1, np.int16),
                              frame_id=scan.frame_id)
        grid.integrate((px, py, pyaw), painted)
        n_scans += 1
    if n_scans == 0:
        raise SemmapError(f"{tour}: no scan on {topic} lies within the true trajectory")
    if skipped:
        log.info("%s: %d scans skipped (no beams, or outside the true trajectory)", tour, skipped)
    # the occupancy rule clean() starts from, with its defaults, and none of the rules after it:
    # those read camera labels or shapes (legs, people), and the naive mapper knows neither
    layers = grid.layers()
    rule = CleaningConfig()
    occupied = layers.log_odds > rule.occupied_logodds
    if rule.hit_ratio > 0:  # thin legs: the whole tour's share of returns
        h = layers.hits.astype(np.float32)
        occupied |= (h >= rule.min_hits) & (h >= rule.hit_ratio * (h + layers.free))
    free = layers.observed & (layers.log_odds < rule.free_logodds) & ~occupied
    return NaiveMap(layers.spec, occupied, free, np.zeros(layers.spec.shape, bool), (), n_scans,
                    time.perf_counter() - t_start)
