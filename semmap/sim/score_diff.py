"""Scoring ``semmap diff`` against a simulated session pair's truth.

Session B's tour (a change scenario: ``ward_b``, ``office_b``, ``random:SEED:b``...) carries the truth
of what changed against its base world: ``ground_truth/changes.png`` (0 none, 1 added, 2 removed, in
B's truth grid, the world frame) and ``changes.json`` (objects moved, removed, added). Each map
folder's frame is placed in the world by aligning its trajectory with the true one (as the ATE does),
which gives the true ``T_a_b`` too.

The scores:

* **alignment error**: the RMS distance, over B's obstacle cells, between where the estimated and the
  true ``T_a_b`` put them, and the yaw difference;
* **F1 of added and removed cells** at a 2-cell tolerance: precision over the mask's cells; recall over
  the truth cells a session could have seen change (an added cell: some true beam of B ended within a
  cell of it and A observed the place; a removed cell: some true beam of A ended there and B observed
  the place);
* **moved objects**: each truth move of a semi-static object the sessions could see (B observed
  where it was, A observed where it went, and each tour's LiDAR hit it), matched to a reported move
  of its class ending within 0.5 m of its new place, and the reported displacement's error
  (``displacement_error_m``; ``displacement_error_any_m`` measures a move that starts within 0.25 m of
  where another object of the class stood, moved or removed, from that place: identical chairs that
  traded places cannot be told apart on a map, and a diff that says "a chair moved from X to Y" is
  right when one left X and one came to Y). A move of
  furniture neither camera labelled is reported with no class; it matches a truth move of any class
  (``unlabelled`` says so, and the benchmark counts such matches apart);
* **false changes**: reported changes (not explored areas) farther than 0.5 m from every truth change.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..compare.result import DiffResult
from ..geometry import se2_apply, se2_compose, se2_inverse, wrap_angle
from ..grid.metrics import observable_cells, occupancy_f1, transfer
from ..records import GridSpec

__all__ = ["score_diff", "t_world_map", "truth_changes"]


def t_world_map(tour: str | Path, map_dir: str | Path) -> NDArray[np.float64]:
    """The map folder's frame in the simulated world (x, y, yaw), from its trajectory."""
    from ..io.tum import read_tum
    from ..mapfolder.reader import load_map_folder
    from ..register.metrics import ate_errors

    m = load_map_folder(map_dir)
    stamps, poses = read_tum(Path(tour) / "ground_truth" / "trajectory.tum")
    _, t = ate_errors(m.stamps_ns, m.poses, stamps, poses)
    return t


def truth_changes(tour_b: str | Path) -> tuple[GridSpec, NDArray[np.uint8], list[dict[str, Any]]]:
    """B's truth: the change mask's grid, the mask (0 none, 1 added, 2 removed) and the change list."""
    import cv2

    from ..io.yamlio import read_yaml

    gt = Path(tour_b) / "ground_truth"
    meta = read_yaml(gt / "changes.yaml", "change mask")
    img = cv2.imread(str(gt / str(meta["image"])), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(gt / str(meta["image"]))
    mask = np.flipud(img).astype(np.uint8)
    spec = GridSpec(float(meta["resolution"]), float(meta["origin"][0]), float(meta["origin"][1]),
                    mask.shape[1], mask.shape[0])
    data = json.loads((gt / "changes.json").read_text(encoding="utf-8"))
    changes = data["changes"] if isinstance(data, dict) else data
    return spec, mask, list(changes)


def _observed_in(result_side_occ: NDArray[np.bool_], result_side_free: NDArray[np.bool_], spec: GridSpec,
                 target: GridSpec, t_world_map: NDArray[np.float64]) -> NDArray[np.bool_]:
    return transfer(result_side_occ | result_side_free, spec, target, t_world_map)


def score_diff(tour_a: str | Path, map_a: str | Path, tour_b: str | Path, map_b: str | Path,
               result: DiffResult, tolerance_cells: int = 2) -> dict[str, Any]:
    """Score ``result`` (the diff of ``map_b`` against ``map_a``) against the truth of ``tour_b``."""
    from .groundtruth import true_beam_end_points

    ta, tb = t_world_map(tour_a, map_a), t_world_map(tour_b, map_b)
    true_t_a_b = se2_compose(se2_inverse(ta), tb)
    est = np.asarray(result.alignment.T_a_b, np.float64)
    b = result.b
    rows, cols = np.nonzero(b.occupied & ~b.semi_static)
    pts = np.stack([b.spec.origin_x + (cols + 0.5) * b.spec.resolution,
                    b.spec.origin_y + (rows + 0.5) * b.spec.resolution], axis=1)
    gap = np.linalg.norm(se2_apply(est, pts) - se2_apply(true_t_a_b, pts), axis=1) if pts.size else np.zeros(1)
    align_err_m = float(np.sqrt(np.mean(gap ** 2)))
    align_err_deg = abs(math.degrees(float(wrap_angle(est[2] - true_t_a_b[2]))))

    spec_t, mask_t, changes_t = truth_changes(tour_b)
    a = result.a
    seen_a = _observed_in(a.occupied, a.free, a.spec, spec_t, ta)
    seen_b = _observed_in(b.occupied, b.free, b.spec, spec_t, tb)
    ends_a, ends_b = true_beam_end_points(tour_a), true_beam_end_points(tour_b)
    added_t, removed_t = mask_t == 1, mask_t == 2
    visible_added = observable_cells(added_t, spec_t, ends_b) & seen_a
    visible_removed = observable_cells(removed_t, spec_t, ends_a) & seen_b
    pr_add = occupancy_f1(result.mask == 1, a.spec, added_t, spec_t, visible_added, tolerance_cells, ta)
    pr_rem = occupancy_f1(result.mask == 2, a.spec, removed_t, spec_t, visible_removed, tolerance_cells, ta)
    tp_pred = pr_add.n_true_positive_pred + pr_rem.n_true_positive_pred
    n_pred = pr_add.n_predicted + pr_rem.n_predicted
    tp_truth = pr_add.n_true_positive_truth + pr_rem.n_true_positive_truth
    n_truth = pr_add.n_truth + pr_rem.n_truth
    precision = tp_pred / n_pred if n_pred else float("nan")
    recall = tp_truth / n_truth if n_truth else float("nan")
    f1 = 2 * precision * recall / (precision + recall) if n_pred and n_truth and precision + recall > 0 else (
        1.0 if not n_pred and not n_truth else 0.0)

    # moved objects: truth moves of semi-static objects, in the world
    reported = [c for c in result.changes if c.type == "object_moved"]
    # a reported move is found where its object went ("matched to their new place")
    rep_to = [se2_apply(ta, np.array([c.to_xy if c.to_xy else c.centroid]))[0] for c in reported]
    moves = []
    hits_a, hits_b = _lidar_hits(tour_a), _lidar_hits(tour_b)
    # per class, where its objects stood before: the places the moved ones left and the removed ones'
    sources: dict[Any, list[NDArray[np.float64]]] = {}
    for t in changes_t:
        if t.get("type") in ("moved", "removed"):
            sources.setdefault(t.get("class"), []).append(
                np.asarray((t["from"] if t["type"] == "moved" else t["centroid"])[:2], float))
    for t in changes_t:
        if t.get("type") != "moved" or t.get("mobility", "semi_static") != "semi_static":
            continue
        if hits_a.get(int(t["id"]), 1) <= 0 or hits_b.get(int(t["id"]), 1) <= 0:
            continue  # a LiDAR session never hit it (a monitor above the scan plane): no map can see it move
        src, dst = np.asarray(t["from"][:2], float), np.asarray(t["to"][:2], float)
        # a move can be seen when B observed where the object was and A observed where it went
        seen = _share_near(seen_b, spec_t, src) >= 0.5 and _share_near(seen_a, spec_t, dst) >= 0.5
        best, best_d = None, math.inf
        for k, c in enumerate(reported):
            if c.class_name is not None and c.class_name != t.get("class"):
                continue  # an object of another class (None: furniture no camera labelled, of any class)
            d = float(np.linalg.norm(rep_to[k] - dst))
            if d < best_d:
                best, best_d = k, d
        match = best is not None and best_d <= 0.5
        err = err_any = None
        if match and best is not None:
            rep = float(reported[best].displacement_m or 0.0)
            err = err_any = abs(rep - float(t["displacement_m"]))
            # identical objects that traded places (three chairs of one table, each moved to where
            # another stood) cannot be told apart on a map: a move from where another object of the
            # class stood (it moved or went) is measured against that object's place
            c = reported[best]
            if c.from_xy is not None:
                rep_from = se2_apply(ta, np.array([c.from_xy]))[0]
                near = [p for p in sources.get(t.get("class"), [])
                        if float(np.linalg.norm(rep_from - p)) <= _SAME_PLACE_M]
                if near:
                    src_alt = min(near, key=lambda p: float(np.linalg.norm(rep_from - p)))
                    err_any = abs(rep - float(np.linalg.norm(dst - src_alt)))
        moves.append({"name": t.get("name"), "class": t.get("class"), "displacement_m": t["displacement_m"],
                      "matched": match, "displacement_error_m": err, "displacement_error_any_m": err_any,
                      "seen": seen,
                      "unlabelled": bool(match and best is not None and reported[best].class_name is None)})

    # false changes: reported changes far from every truth change
    truth_pts = [np.stack([spec_t.origin_x + (c + 0.5) * spec_t.resolution,
                           spec_t.origin_y + (r + 0.5) * spec_t.resolution], axis=1)
                 for r, c in [np.nonzero(mask_t > 0)]]
    for t in changes_t:
        for key in ("from", "to", "centroid"):
            if key in t:
                truth_pts.append(np.asarray(t[key][:2], float)[None])
    truth_xy = np.concatenate(truth_pts) if truth_pts else np.zeros((0, 2))
    false = []
    from scipy.spatial import cKDTree

    tree = cKDTree(truth_xy) if truth_xy.size else None
    for c in result.changes:
        if c.type in ("newly_explored", "no_longer_covered"):
            continue
        w = se2_apply(ta, np.array([c.centroid]))[0]
        d = float(tree.query(w)[0]) if tree is not None else math.inf
        if d > 0.5:
            false.append({"type": c.type, "class": c.class_name, "centroid_world": [round(float(v), 2) for v in w],
                          "distance_m": round(d, 2)})
    return {
        "alignment_error_m": align_err_m, "alignment_error_deg": align_err_deg,
        "true_T_a_b": [float(v) for v in true_t_a_b],
        "f1": f1, "precision": precision, "recall": recall,
        "added": {"precision": pr_add.precision, "recall": pr_add.recall, "n_pred": pr_add.n_predicted,
                  "n_truth": pr_add.n_truth},
        "removed": {"precision": pr_rem.precision, "recall": pr_rem.recall, "n_pred": pr_rem.n_predicted,
                    "n_truth": pr_rem.n_truth},
        "moves": moves, "false_changes": false, "seconds": result.seconds,
        "counts": result.counts(),
    }


#: a reported move starting this close to where an object of its class stood starts at that object's place
_SAME_PLACE_M = 0.25


def _lidar_hits(tour: str | Path) -> dict[int, int]:
    """True LiDAR hits per object id in a tour (``ground_truth/objects.json``); empty when absent."""
    p = Path(tour) / "ground_truth" / "objects.json"
    if not p.is_file():
        return {}
    data = json.loads(p.read_text(encoding="utf-8"))
    return {int(o["id"]): int(o.get("lidar_hits", 0)) for o in data.get("objects", [])}


def _share_near(mask: NDArray[np.bool_], spec: GridSpec, xy: NDArray[np.float64], radius: float = 0.3) -> float:
    """Share of the cells within ``radius`` of ``xy`` that ``mask`` holds."""
    r, c = spec.world_to_cell(xy[None])[0]
    k = int(math.ceil(radius / spec.resolution))
    win = mask[max(0, r - k):r + k + 1, max(0, c - k):c + k + 1]
    return float(win.mean()) if win.size else 0.0


def _inside(spec: GridSpec, xy: NDArray[np.float64]) -> bool:
    r, c = spec.world_to_cell(xy[None])[0]
    return bool(0 <= r < spec.height and 0 <= c < spec.width)
