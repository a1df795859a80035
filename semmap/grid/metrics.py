"""Scoring a map against ground truth: occupancy F1, ghost rate, semi-static precision/recall.

Every function takes boolean masks with their :class:`~semmap.records.GridSpec`; the map and
the truth may live in different frames and grids. ``T_gt_map`` is the SE(2) pose
``(x, y, yaw)`` of the map frame in the ground-truth frame (identity when the map was built
with true poses). Cells are compared through their centres: a map cell's centre is carried
into the truth grid and looked up there, and the other way round, so different resolutions
and origins work (tolerances are counted in cells of the grid being looked up).

Tolerance: "within 1 cell" means in the 3 x 3 neighbourhood (8-connected), as usual for
map-to-truth comparisons at the grid's resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..geometry import se2_apply, se2_inverse
from ..records import GridSpec

__all__ = [
    "PrecisionRecall",
    "cells_to_points",
    "ghost_rate",
    "hits_near",
    "observable_cells",
    "occupancy_f1",
    "points_to_mask",
    "semi_static_scores",
    "transfer",
]

_IDENTITY = np.zeros(3)


@dataclass(frozen=True)
class PrecisionRecall:
    """Precision, recall and F1 with the cell counts behind them (NaN when undefined)."""

    precision: float
    recall: float
    n_predicted: int  # cells the map marks
    n_truth: int  # truth cells counted for recall
    n_true_positive_pred: int  # predicted cells near a truth cell
    n_true_positive_truth: int  # truth cells near a predicted cell

    @property
    def f1(self) -> float:
        p, r = self.precision, self.recall
        if not (p + r > 0):
            return float("nan") if np.isnan(p) or np.isnan(r) else 0.0
        return 2.0 * p * r / (p + r)

    def as_dict(self) -> dict[str, float | int]:
        return {"precision": self.precision, "recall": self.recall, "f1": self.f1,
                "n_predicted": self.n_predicted, "n_truth": self.n_truth}


def cells_to_points(mask: NDArray[np.bool_], spec: GridSpec) -> NDArray[np.float64]:
    """(N, 2) centres (x, y) of the true cells of a mask, in the grid's frame."""
    r, c = np.nonzero(np.asarray(mask, dtype=bool))
    return np.column_stack([spec.origin_x + (c + 0.5) * spec.resolution,
                            spec.origin_y + (r + 0.5) * spec.resolution])


def points_to_mask(points: ArrayLike, spec: GridSpec) -> NDArray[np.bool_]:
    """Mark the cells of ``spec`` holding (N, 2) points; points outside the grid are ignored."""
    out = np.zeros(spec.shape, bool)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    rc = spec.world_to_cell(pts)
    inside = (rc[:, 0] >= 0) & (rc[:, 0] < spec.height) & (rc[:, 1] >= 0) & (rc[:, 1] < spec.width)
    out[rc[inside, 0], rc[inside, 1]] = True
    return out


def _dilate(mask: NDArray[np.bool_], cells: int) -> NDArray[np.bool_]:
    if cells <= 0:
        return np.asarray(mask, dtype=bool)
    k = np.ones((2 * cells + 1, 2 * cells + 1), np.uint8)
    return cv2.dilate(np.asarray(mask, dtype=np.uint8), k).astype(bool)


def _lookup(points: NDArray[np.float64], mask: NDArray[np.bool_], spec: GridSpec) -> NDArray[np.bool_]:
    """For (N, 2) points in the frame of ``spec``: is the cell holding each one set?"""
    rc = spec.world_to_cell(points)
    inside = (rc[:, 0] >= 0) & (rc[:, 0] < spec.height) & (rc[:, 1] >= 0) & (rc[:, 1] < spec.width)
    out = np.zeros(points.shape[0], bool)
    out[inside] = mask[rc[inside, 0], rc[inside, 1]]
    return out


def transfer(mask: NDArray[np.bool_], spec: GridSpec, target: GridSpec,
             T_target_source: ArrayLike = _IDENTITY) -> NDArray[np.bool_]:
    """Resample a mask into another grid (nearest cell centre); ``T_target_source`` as SE(2)."""
    pts = cells_to_points(np.ones(target.shape, bool), target)
    src = se2_apply(se2_inverse(np.asarray(T_target_source, dtype=np.float64)), pts)
    return _lookup(src, np.asarray(mask, dtype=bool), spec).reshape(target.shape)


def hits_near(source: NDArray[np.bool_], source_spec: GridSpec, target: NDArray[np.bool_],
              target_spec: GridSpec, tolerance_cells: int = 1,
              T_target_source: ArrayLike = _IDENTITY) -> tuple[int, int]:
    """(cells of ``source`` within ``tolerance_cells`` of a ``target`` cell, cells of ``source``)."""
    pts = cells_to_points(source, source_spec)
    if pts.shape[0] == 0:
        return 0, 0
    pts = se2_apply(np.asarray(T_target_source, dtype=np.float64), pts)
    near = _lookup(pts, _dilate(target, tolerance_cells), target_spec)
    return int(near.sum()), int(pts.shape[0])


def observable_cells(truth: NDArray[np.bool_], spec: GridSpec, beam_end_points: ArrayLike,
                     tolerance_cells: int = 1) -> NDArray[np.bool_]:
    """Truth cells a LiDAR could see: set cells within ``tolerance_cells`` of a true beam end.

    ``beam_end_points`` (N, 2) are where true beams ended on the structure, in the frame of
    ``spec``. The tolerance catches beams ending on a surface whose cell lies just outside the
    rasterised truth (thin legs, polygon edges).
    """
    ends = points_to_mask(beam_end_points, spec)
    return np.asarray(truth, dtype=bool) & _dilate(ends, tolerance_cells)


def _scores(pred: NDArray[np.bool_], pred_spec: GridSpec, truth: NDArray[np.bool_], truth_spec: GridSpec,
            observable: NDArray[np.bool_] | None, tolerance_cells: int, T_gt_map: ArrayLike) -> PrecisionRecall:
    t = np.asarray(T_gt_map, dtype=np.float64)
    tp_pred, n_pred = hits_near(pred, pred_spec, truth, truth_spec, tolerance_cells, t)
    counted = np.asarray(truth, dtype=bool) if observable is None else np.asarray(observable, dtype=bool) & truth
    tp_truth, n_truth = hits_near(counted, truth_spec, pred, pred_spec, tolerance_cells, se2_inverse(t))
    precision = tp_pred / n_pred if n_pred else float("nan")
    recall = tp_truth / n_truth if n_truth else float("nan")
    return PrecisionRecall(precision, recall, n_pred, n_truth, tp_pred, tp_truth)


def occupancy_f1(occupied: NDArray[np.bool_], spec: GridSpec, truth: NDArray[np.bool_], truth_spec: GridSpec,
                 observable: NDArray[np.bool_] | None = None, tolerance_cells: int = 1,
                 T_gt_map: ArrayLike = _IDENTITY) -> PrecisionRecall:
    """Occupied cells against truth (static ∪ semi-static) at a cell tolerance.

    Precision: share of map-occupied cells within ``tolerance_cells`` of a truth cell.
    Recall: share of *observable* truth cells (``observable``, in the truth grid; all truth
    cells when None) within ``tolerance_cells`` of a map-occupied cell.
    """
    return _scores(occupied, spec, truth, truth_spec, observable, tolerance_cells, T_gt_map)


def semi_static_scores(semi_static: NDArray[np.bool_], spec: GridSpec, truth: NDArray[np.bool_],
                       truth_spec: GridSpec, observable: NDArray[np.bool_] | None = None,
                       tolerance_cells: int = 1, T_gt_map: ArrayLike = _IDENTITY) -> PrecisionRecall:
    """The semi-static flag against the truth's semi-static cells, as :func:`occupancy_f1`."""
    return _scores(semi_static, spec, truth, truth_spec, observable, tolerance_cells, T_gt_map)


def ghost_rate(occupied: NDArray[np.bool_], spec: GridSpec, swept: NDArray[np.bool_], swept_spec: GridSpec,
               T_gt_map: ArrayLike = _IDENTITY) -> float:
    """Share of the cells people swept (truth) that the map still marks occupied (no tolerance)."""
    pts = cells_to_points(swept, swept_spec)
    if pts.shape[0] == 0:
        return float("nan")
    pts = se2_apply(se2_inverse(np.asarray(T_gt_map, dtype=np.float64)), pts)
    return float(_lookup(pts, np.asarray(occupied, dtype=bool), spec).mean())
