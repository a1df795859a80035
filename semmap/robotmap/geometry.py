"""Straightening, cropping and resampling a layer, with its origin kept right.

Every operation carries a plane from a source grid to a target grid through a rigid motion
``T`` (target frame <- source frame; the identity unless straightening). Each target cell takes the
state of the source cell under its centre (nearest neighbour), and every occupied source cell
also marks the target cell its centre lands in: a wall one cell thick stays closed when the grid is
turned or made coarser, and an obstacle never vanishes.

* **Straighten** (:func:`dominant_direction`): turn the map so that most walls run along the image's
  axes. The angle is the one that makes the occupied cells' projections on x and y sharpest. The
  exported map's frame is the build's map frame turned about its origin by that angle: the map's
  ``origin`` stays a plain (x, y, 0) (nav2's AMCL and costmap static layer read only its position), and the
  turn is recorded in ``export.json``.
* **Crop**: to the observed cells plus a margin, in whole cells, so cells keep their place.
* **Resample**: to another resolution, the lower-left corner kept.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from ..geometry import se2_apply, se2_inverse
from ..records import GridSpec
from .layers import Plane

__all__ = ["cell_centres_xy", "crop_box", "dominant_direction", "rotated_spec", "warp_mask", "warp_plane"]


def cell_centres_xy(spec: GridSpec, rows: NDArray[np.intp], cols: NDArray[np.intp]) -> NDArray[np.float64]:
    return np.stack([spec.origin_x + (cols + 0.5) * spec.resolution,
                     spec.origin_y + (rows + 0.5) * spec.resolution], axis=1).astype(np.float64)


def dominant_direction(occupied: NDArray[np.bool_], spec: GridSpec) -> float:
    """The turn (radians, within ±45°) that best lines the occupied cells up with the axes: the one
    whose x and y projections, in bins of one cell, have the largest sum of squared counts; 0 when
    that is within 0.25° of the axes already."""
    rows, cols = np.nonzero(occupied)
    if rows.size < 10:
        return 0.0
    xy = cell_centres_xy(spec, rows, cols)
    xy = xy - xy.mean(axis=0)
    res = spec.resolution

    def sharpness(a: float) -> float:
        c, s = math.cos(a), math.sin(a)
        x = c * xy[:, 0] - s * xy[:, 1]
        y = s * xy[:, 0] + c * xy[:, 1]
        total = 0.0
        for v in (x, y):
            _, counts = np.unique(np.floor(v / res).astype(np.int64), return_counts=True)
            total += float(np.sum(counts.astype(np.float64) ** 2))
        return total

    best = max(np.deg2rad(np.arange(-45.0, 45.0, 1.0)), key=sharpness)
    for step in (0.25, 0.05):
        grid = best + np.deg2rad(np.arange(-4, 5) * step)
        best = max(grid, key=sharpness)
    a = float(best)
    a = a - math.pi / 2 if a >= math.pi / 4 else a + math.pi / 2 if a < -math.pi / 4 else a
    # within the search's own precision of the axes the map is straight already: no resampling for nothing
    return 0.0 if abs(a) <= math.radians(0.25) + 1e-9 else a


def rotated_spec(spec: GridSpec, keep: NDArray[np.bool_], T: NDArray[np.float64]) -> GridSpec:
    """A grid of the same resolution holding the cells ``keep`` of ``spec`` carried by ``T``."""
    rows, cols = np.nonzero(keep)
    if rows.size == 0:
        rows, cols = np.array([0, spec.height - 1]), np.array([0, spec.width - 1])
    h = spec.resolution / 2.0
    xy = cell_centres_xy(spec, rows, cols)
    corners = np.concatenate([xy + [dx, dy] for dx in (-h, h) for dy in (-h, h)])
    p = se2_apply(T, corners)
    lo, hi = p.min(axis=0) - spec.resolution, p.max(axis=0) + spec.resolution
    return GridSpec.covering(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]), spec.resolution)


def crop_box(keep: NDArray[np.bool_], spec: GridSpec, margin_m: float) -> GridSpec:
    """The part of ``spec`` holding the cells ``keep`` plus ``margin_m``, in whole cells."""
    rows, cols = np.nonzero(keep)
    if rows.size == 0:
        return spec
    m = int(math.ceil(margin_m / spec.resolution - 1e-9))
    r0, r1 = max(int(rows.min()) - m, 0), min(int(rows.max()) + 1 + m, spec.height)
    c0, c1 = max(int(cols.min()) - m, 0), min(int(cols.max()) + 1 + m, spec.width)
    return spec.crop(r0, r1, c0, c1)


def _source_index(src: GridSpec, dst: GridSpec, T: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """For each target cell centre, its position in source cells (column, row), for ``cv2.remap``."""
    xs = dst.origin_x + (np.arange(dst.width, dtype=np.float64) + 0.5) * dst.resolution
    ys = dst.origin_y + (np.arange(dst.height, dtype=np.float64) + 0.5) * dst.resolution
    t = se2_inverse(T)
    c, s = math.cos(float(t[2])), math.sin(float(t[2]))
    xb = c * xs[None, :] - s * ys[:, None] + t[0]
    yb = s * xs[None, :] + c * ys[:, None] + t[1]
    return (((xb - src.origin_x) / src.resolution - 0.5).astype(np.float32),
            ((yb - src.origin_y) / src.resolution - 0.5).astype(np.float32))


def _landing(src: GridSpec, dst: GridSpec, T: NDArray[np.float64], mask: NDArray[np.bool_]
             ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """The target cells (rows, cols) the centres of the source cells ``mask`` land in, and which of
    the mask's cells (index into ``np.nonzero(mask)``) landed inside the target."""
    rows, cols = np.nonzero(mask)
    xy = se2_apply(T, cell_centres_xy(src, rows, cols))
    c = np.floor((xy[:, 0] - dst.origin_x) / dst.resolution + 1e-9).astype(np.intp)
    r = np.floor((xy[:, 1] - dst.origin_y) / dst.resolution + 1e-9).astype(np.intp)
    inside = np.flatnonzero((r >= 0) & (r < dst.height) & (c >= 0) & (c < dst.width))
    return r[inside], c[inside], inside


def warp_mask(mask: NDArray[np.bool_], src: GridSpec, dst: GridSpec, T: NDArray[np.float64]) -> NDArray[np.bool_]:
    """A bool mask on ``dst``: nearest source cell, and every source cell's own landing cell."""
    mx, my = _source_index(src, dst, T)
    out = cv2.remap(mask.astype(np.uint8), mx, my, interpolation=cv2.INTER_NEAREST,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    r, c, _ = _landing(src, dst, T, mask)
    out[r, c] = True
    return out


def warp_plane(plane: Plane, src: GridSpec, dst: GridSpec, T: NDArray[np.float64]) -> Plane:
    """``plane`` carried onto ``dst``. Occupied wins over free, free over unknown, within a target
    cell; the probability follows the nearest source cell, and an occupied landing keeps the
    highest probability that landed there."""
    mx, my = _source_index(src, dst, T)
    code = np.where(plane.occupied, 2, np.where(plane.free, 1, 0)).astype(np.uint8)
    near_code = cv2.remap(code, mx, my, interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=0)
    prob = cv2.remap(np.nan_to_num(plane.prob, nan=-1.0).astype(np.float32), mx, my,
                     interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
    occ = near_code == 2
    free = near_code == 1
    r, c, inside = _landing(src, dst, T, plane.occupied)
    if r.size:
        occ[r, c] = True
        src_p = plane.prob[plane.occupied][inside]
        landed = np.full(dst.shape, -1.0, np.float32)
        np.maximum.at(landed, (r, c), np.nan_to_num(src_p, nan=-1.0).astype(np.float32))
        prob = np.where(landed >= 0, np.maximum(prob, landed), prob)
    out = np.asarray(np.where(prob < 0, np.nan, prob), np.float32)
    return Plane(occ, free & ~occ, out)
