"""Fusing painted scans into a log-odds occupancy grid with class evidence per cell.

:class:`SemanticGrid` keeps, per cell of the square tiles a scan has reached (``grid.tile_margin``
m on a side, allocated as the robot gets there, so memory follows the area observed):

* ``log_odds`` (float32): occupancy evidence, clamped to ``[l_min, l_max]``. Inside, it is kept in
  steps of 0.001 as uint16 counted up from ``l_min``: half the memory of float32, and a
  saturating subtraction clamps at ``l_min`` in the same pass.
* ``hits`` / ``free`` (uint16, saturating): how many scans ended a return in the cell / crossed it.
* ``mobility`` (uint16, 4 layers): how many scans ended a return in the cell painted with
  each :class:`~semmap.records.Mobility` value (0 unknown, 1 static, 2 semi-static,
  3 dynamic): Dirichlet-style counts, saturating at 65535.
* ``class_counts`` (uint16, one layer per class *seen in the tile*): the same per object class, so
  memory does not grow with the length of the class list (80 COCO classes).

Every count is at most one per scan and cell, however many beams of the scan land there;
close walls would otherwise outvote far ones.

Free space is rasterised, not ray-cast (OpenCV is ~25x faster than Python Bresenham): each
scan's polygon (the LiDAR origin followed by the beam end points in scan order) is filled with
:func:`cv2.fillPoly` into a scratch mask over the scan's bounding box, then

* returns are pulled back towards the sensor by ``hit_free_margin`` and the mask is eroded by
  one cell (``free_erode``), so rays grazing a wall or pillar face do not clear it;
* a beam without a return between returning neighbours (``dropout_guard``) clears no further
  than they do, so a dropout does not punch a ray through a wall;
* the cells a return of the same scan ended in are removed from the mask, so a ray never
  clears its own end cell.

The log-odds of each tile the bounding box overlaps is then updated with one OpenCV pass; hits,
mobility and class counts with one sort of the scan's (cell, code) keys. A 541-beam indoor scan costs
~0.3-0.5 ms on one core.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ..config import GridConfig
from ..errors import ConfigError, SemmapError
from ..records import GridSpec, Mobility, PaintedScan

__all__ = [
    "LOG_ODDS_STEP",
    "N_MOBILITY",
    "GridLayers",
    "GridMemoryEstimate",
    "SemanticGrid",
    "check_grid_memory",
    "estimate_grid_memory",
    "merge_continued",
]

log = logging.getLogger(__name__)

#: Number of mobility values (layers of :attr:`GridLayers.mobility`).
N_MOBILITY = len(Mobility)

_SHIFT = 4  # fractional bits of the polygon vertices handed to cv2.fillPoly
#: m: an occluding edge casts a shadow free space keeps out of when the return before it spans more
#: than this (a couch's arm, a box, a door frame); behind a person's leg or a post it is narrower
#: than the gap between two beams, and the legs of someone who stood there must be seen free again
_LEG_WIDTH = 0.25
_U16_MAX = np.iinfo(np.uint16).max
_KERNEL3 = np.ones((3, 3), np.uint8)
LOG_ODDS_STEP = 1e-3  #: the resolution log-odds are kept at (l_occ, l_free and the clamps are rounded to it)


_A = TypeVar("_A", bound=np.ndarray)


def _frozen(a: _A) -> _A:
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class GridLayers:
    """A snapshot of a :class:`SemanticGrid`: everything cleaning and the map folder need.

    All arrays are read-only copies in grid order (row 0 = lowest y, see :class:`GridSpec`):

    * ``log_odds`` (H, W) float32: occupancy log-odds, 0 = never observed.
    * ``hits`` (H, W) uint16: scans with a return ending in the cell.
    * ``free`` (H, W) uint16: scans whose free-space polygon covered the cell.
    * ``mobility`` (4, H, W) uint16: hits per :class:`Mobility` value (index = value).
    * ``class_counts`` (K, H, W) uint16: hits per class, for the K classes seen.
    * ``class_ids`` (K,): index into ``class_names`` of each layer of ``class_counts``.
    * ``class_names``: the grid's class list, which ``PaintedScan.class_id`` indexes.
    * ``n_scans``: scans integrated.
    * ``sightings`` (M, 4) int32: ``scan, instance, row, column``: the cells the returns of one
      scan that the camera saw on one object (``PaintedScan.instance``) ended in. Cells that are
      sighted together as one object belong to one object; the object list uses them.
    """

    spec: GridSpec
    log_odds: NDArray[np.float32]
    hits: NDArray[np.uint16]
    free: NDArray[np.uint16]
    mobility: NDArray[np.uint16]
    class_counts: NDArray[np.uint16]
    class_ids: tuple[int, ...]
    class_names: tuple[str, ...]
    n_scans: int = 0
    sightings: NDArray[np.int32] = field(default_factory=lambda: _frozen(np.zeros((0, 4), np.int32)))
    #: the fusing grid's memory when the snapshot was taken (its tiles' layers), bytes, and its tiles (0: not
    #: from a :class:`SemanticGrid`)
    grid_bytes: int = 0
    grid_tiles: int = 0

    def __post_init__(self) -> None:
        shape = self.spec.shape
        if self.sightings.ndim != 2 or self.sightings.shape[1] != 4:
            raise ValueError(f"sightings must have shape (M, 4), got {self.sightings.shape}")
        if self.log_odds.shape != shape or self.hits.shape != shape or self.free.shape != shape:
            raise ValueError(f"layers must have the grid's shape {shape}")
        if self.mobility.shape != (N_MOBILITY, *shape):
            raise ValueError(f"mobility must have shape {(N_MOBILITY, *shape)}, got {self.mobility.shape}")
        if self.class_counts.shape != (len(self.class_ids), *shape):
            raise ValueError("class_counts must have one layer per entry of class_ids")
        if any(not 0 <= c < len(self.class_names) for c in self.class_ids):
            raise ValueError("class_ids must index class_names")

    @property
    def observed(self) -> NDArray[np.bool_]:
        """Cells some scan hit or crossed."""
        return (self.hits > 0) | (self.free > 0)

    @property
    def labelled(self) -> NDArray[np.uint32]:
        """Hits the camera labelled (static + semi-static + dynamic), per cell."""
        return self.mobility[1:].sum(axis=0, dtype=np.uint32)

    def class_layer(self, name: str) -> NDArray[np.uint16]:
        """Hits per cell of one class by name (zeros when the class was never seen)."""
        try:
            k = self.class_names.index(name)
        except ValueError:
            raise KeyError(f"unknown class {name!r}") from None
        if k in self.class_ids:
            return self.class_counts[self.class_ids.index(k)]
        return np.zeros(self.spec.shape, np.uint16)

    @property
    def nbytes(self) -> int:
        return int(self.log_odds.nbytes + self.hits.nbytes + self.free.nbytes + self.mobility.nbytes
                   + self.class_counts.nbytes + self.sightings.nbytes)


#: m of unobserved cells kept around the tiles in the window :meth:`SemanticGrid.layers` assembles
_WINDOW_PAD_M = 2.0


class _Tile:
    """One square tile of the grid: its cells' layers (class layers only for the classes hit in it)."""

    __slots__ = ("cls", "free", "hi", "hits", "lo", "mob")

    def __init__(self, side: int, q_start: int, q_high: int | None = None) -> None:
        self.lo = np.full((side, side), q_start, np.uint16)
        # a grid that continues another's (:meth:`SemanticGrid.continuing`): ``lo`` and ``hi`` are the
        # cell's log-odds after this grid's scans had it started at l_min and at l_max
        self.hi = None if q_high is None else np.full((side, side), q_high, np.uint16)
        self.hits = np.zeros((side, side), np.uint16)
        self.free = np.zeros((side, side), np.uint16)
        self.mob = np.zeros((N_MOBILITY, side, side), np.uint16)
        self.cls: dict[int, NDArray[np.uint16]] = {}

    @property
    def nbytes(self) -> int:
        return int(self.lo.nbytes + self.hits.nbytes + self.free.nbytes + self.mob.nbytes
                   + (0 if self.hi is None else self.hi.nbytes) + sum(a.nbytes for a in self.cls.values()))


class SemanticGrid:
    """A log-odds occupancy grid with mobility and class evidence, grown as scans arrive.

    ``class_names`` is the list that ``PaintedScan.class_id`` indexes. The grid is stored in
    square tiles ``cfg.tile_margin`` m on a side, on a lattice fixed by the first scan; a tile is
    allocated when a scan first reaches it, and holds a class layer only for the classes hit in
    it. So memory follows the area observed: an L-shaped or sparse building does not pay for its
    bounding box, and growing never copies what is already there. :meth:`layers` assembles the
    tiles into one window (their bounding box) for cleaning and the map folder.
    """

    def __init__(self, cfg: GridConfig | None = None, class_names: Sequence[str] = ()) -> None:
        self.cfg = cfg if cfg is not None else GridConfig()
        if self.cfg.l_min >= 0 or self.cfg.l_max <= 0:
            raise ValueError("GridConfig needs l_min < 0 < l_max")
        self.class_names: tuple[str, ...] = tuple(class_names)
        self.res = float(self.cfg.resolution)
        self._budget = MEMORY_SHARE * _machine_memory()[0]  # bytes the layers may take (growth refuses more)
        #: cells on a tile's side
        self.tile_cells = max(16, round(float(self.cfg.tile_margin) / self.res))
        # log-odds as uint16 steps above l_min: l = l_min + q * LOG_ODDS_STEP
        # the clamps are rounded towards 0, so the values kept stay inside [l_min, l_max]
        self._q_zero = math.floor(-self.cfg.l_min / LOG_ODDS_STEP + 1e-6)  # log-odds 0: nothing known
        self._q_max = self._q_zero + math.floor(self.cfg.l_max / LOG_ODDS_STEP + 1e-6)
        if self._q_max > _U16_MAX:
            raise ValueError(f"l_max - l_min must be at most {_U16_MAX * LOG_ODDS_STEP:g}")
        # a step larger than the whole range saturates all the same (and must fit the uint16 rasters)
        self._q_free = min(max(1, round(self.cfg.l_free / LOG_ODDS_STEP)), max(self._q_max, 1))
        self._q_occ = min(max(1, round(self.cfg.l_occ / LOG_ODDS_STEP)), max(self._q_max, 1))
        self._tiles: dict[tuple[int, int], _Tile] = {}
        # the lattice's origin (m, a multiple of the resolution): set by the first scan, tile_margin
        # below and left of its box, so that its cells are those a window around it would have
        self._gx = 0.0
        self._gy = 0.0
        self._lattice_set = False
        #: a grid that continues another's (:meth:`continuing`): the scans before its first
        self.first_scan = 0
        self._continues = False
        self._tile_bytes = 0
        self._cls_ids: list[int] = []
        self._layer_of = np.full(len(self.class_names), -1, np.intp)
        self.n_scans = 0
        # (scan, instance, row, column) of each cell a return painted on an object ended in; row and
        # column counted in cells of the tiles' lattice
        self._sightings: list[NDArray[np.int32]] = []
        self._sightings_n = 0
        # per-scan scratch rasters, kept between scans (fresh pages for each scan cost page faults)
        self._scratch: list[NDArray[Any]] = [np.zeros(0, np.uint8), np.zeros(0, np.uint8), np.zeros(0, np.uint16)]

    @classmethod
    def continuing(cls, cfg: GridConfig | None, class_names: Sequence[str], lattice: tuple[float, float],
                   first_scan: int) -> SemanticGrid:
        """A grid for the later scans of a tour, from ``first_scan`` on, while another grid on the same
        ``lattice`` (its :attr:`lattice`) fuses the earlier ones: two processes fuse one tour, and
        :func:`merge_continued` gives exactly the layers one grid fusing every scan in order would.

        Log-odds are clamped at every update, so the later scans' effect on a cell depends on where the
        earlier ones left it. It is a clamped shift ``clip(l + s, lo, hi)`` (clamped shifts compose into
        one), so this grid keeps, per cell, what its scans make of l_min and of l_max; ``s`` is its
        hits times ``l_occ`` less its free crossings times ``l_free``.
        """
        grid = cls(cfg, class_names)
        grid._gx, grid._gy = float(lattice[0]), float(lattice[1])
        grid._lattice_set = True
        grid._continues = True
        grid.first_scan = grid.n_scans = int(first_scan)
        return grid

    @property
    def lattice(self) -> tuple[float, float] | None:
        """The origin (m) of the lattice the tiles lie on, set by the first scan; None before it."""
        return (self._gx, self._gy) if self._lattice_set else None

    # -- geometry -------------------------------------------------------------------------
    @property
    def n_tiles(self) -> int:
        """Tiles allocated so far."""
        return len(self._tiles)

    def _tile_span(self) -> tuple[int, int, int, int]:
        rows = [k[0] for k in self._tiles]
        cols = [k[1] for k in self._tiles]
        return min(rows), max(rows) + 1, min(cols), max(cols) + 1

    @property
    def _pad(self) -> int:
        """Unobserved cells the window of :meth:`layers` keeps around the tiles' bounding box: a wall at a
        tile's edge is not at the map's (the map folder keeps a metre around what was observed)."""
        return math.ceil(_WINDOW_PAD_M / self.res)

    @property
    def spec(self) -> GridSpec | None:
        """The window of :meth:`layers`: the tiles' bounding box and a margin; None before the first scan."""
        if not self._tiles:
            return None
        t, p = self.tile_cells, self._pad
        tr0, tr1, tc0, tc1 = self._tile_span()
        return GridSpec(self.res, self._gx + (tc0 * t - p) * self.res, self._gy + (tr0 * t - p) * self.res,
                        (tc1 - tc0) * t + 2 * p, (tr1 - tr0) * t + 2 * p)

    @property
    def nbytes(self) -> int:
        """Memory held by the grid's layers."""
        return self._tile_bytes + 16 * self._sightings_n

    def _tile(self, tr: int, tc: int, where: tuple[float, float]) -> _Tile:
        """Tile (tr, tc), allocated on first use. Refused when the tiles, or the window :meth:`layers`
        assembles over their bounding box, would not fit the memory budget: a pose that jumped far
        away asks for that, not a building."""
        tile = self._tiles.get((tr, tc))
        if tile is not None:
            return tile
        t = self.tile_cells
        res = self.res
        if self._tiles:
            tr0, tr1, tc0, tc1 = self._tile_span()
        else:
            tr0, tr1, tc0, tc1 = tr, tr + 1, tc, tc + 1
        nr0, nr1, nc0, nc1 = min(tr0, tr), max(tr1, tr + 1), min(tc0, tc), max(tc1, tc + 1)
        window = float(nr1 - nr0) * float(nc1 - nc0) * t * t * (_CELL_BYTES + 2 + 2 * len(self._cls_ids))
        need = max(self._tile_bytes + t * t * _CELL_BYTES, window)
        if need > self._budget:
            x0, y0 = self._gx + tc0 * t * res, self._gy + tr0 * t * res
            x1, y1 = self._gx + tc1 * t * res, self._gy + tr1 * t * res
            away = math.hypot(max(x0 - where[0], where[0] - x1, 0.0), max(y0 - where[1], where[1] - y1, 0.0))
            seen = f", {away:.0f} m from the area mapped so far" if self._tiles else ""
            raise SemmapError(f"a scan at ({where[0]:.0f}, {where[1]:.0f}) m{seen} would grow the grid to "
                              f"{(nc1 - nc0) * t * res:.0f} m x {(nr1 - nr0) * t * res:.0f} m ({_size(need)}, more "
                              f"than the {_size(self._budget)} it may use): the robot's pose jumped (check the "
                              f"odometry and registration), or the building is larger than a grid.resolution of "
                              f"{res:g} m allows")
        tile = self._tiles[(tr, tc)] = (_Tile(t, 0, self._q_max) if self._continues else _Tile(t, self._q_zero))
        self._tile_bytes += tile.nbytes
        log.debug("grid tile (%d, %d): %d tiles", tr, tc, len(self._tiles))
        return tile

    def _class_layers(self, ids: NDArray[np.intp]) -> NDArray[np.intp]:
        """Layer index of each class id, registering classes seen for the first time."""
        layer = self._layer_of[ids]
        missing = layer < 0
        if missing.any():
            for c in np.unique(ids[missing]):
                self._layer_of[c] = len(self._cls_ids)
                self._cls_ids.append(int(c))
            log.debug("class layers: %s", [self.class_names[c] for c in self._cls_ids])
            layer = self._layer_of[ids]
        return layer

    # -- fusion ---------------------------------------------------------------------------
    def integrate(self, pose: NDArray[np.float64] | Sequence[float], scan: PaintedScan) -> None:
        """Fuse one painted scan; ``pose`` = base_link (x, y, yaw) in the map frame.

        Cells a return ended in gain ``l_occ`` (once per scan); cells inside the scan's
        free-space polygon lose ``l_free``; both are clamped to ``[l_min, l_max]``. Returns
        add their mobility and class to the evidence counts of their cell.
        """
        cfg = self.cfg
        res = self.res
        pts = scan.points
        if pts.shape[0] == 0:  # a scan without beams: nothing seen, nothing to allocate
            self.n_scans += 1
            return
        o = scan.origin
        hit = scan.hit
        dx = pts[:, 0] - o[0]
        dy = pts[:, 1] - o[1]
        ok = np.isfinite(dx) & np.isfinite(dy)
        if not ok.all():
            hit = hit & ok
            dx = np.where(ok, dx, 0.0)
            dy = np.where(ok, dy, 0.0)
        rng = np.hypot(dx, dy)
        # evidence for and against a cell is judged over the same range: a return farther than
        # max_range counts as "nothing within max_range" (it clears to max_range and is no hit),
        # else far sightings of a person pacing add hits that free space never takes back
        far = hit & (rng > cfg.max_range)
        if far.any():
            hit = hit & ~far
        # free length per beam: returns stop a margin short of their end point; beams without a
        # return clear to their end point (the painter's free-space range), at most
        # max_range, but one with returns on both sides within dropout_guard beams (a
        # dropout) clears no further than they do, so it cannot punch a ray through a wall
        free_len = np.where(hit, rng - cfg.hit_free_margin, rng)
        np.minimum(np.maximum(free_len, 0.0, out=free_len), cfg.max_range, out=free_len)
        k = int(cfg.dropout_guard)
        gaps = np.flatnonzero(~hit & ok) if k > 0 else np.zeros(0, np.intp)
        if len(gaps) and len(gaps) < rng.size:
            n = rng.size
            near = np.where(hit, rng, np.inf)
            side = np.arange(1, k + 1)
            li = gaps[:, None] - side
            ri = gaps[:, None] + side
            left = np.where(li >= 0, near[np.maximum(li, 0)], np.inf).min(axis=1)
            right = np.where(ri < n, near[np.minimum(ri, n - 1)], np.inf).min(axis=1)
            wall = np.maximum(left, right)
            inner = np.isfinite(wall)
            g = gaps[inner]
            free_len[g] = np.minimum(np.maximum(wall[inner] - cfg.hit_free_margin, 0.0), free_len[g])
        scale = free_len / np.maximum(rng, 1e-12)

        # into the map frame: origin + R (end - origin)
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        ox_m = x + c * o[0] - s * o[1]
        oy_m = y + s * o[0] + c * o[1]
        rx = c * dx - s * dy
        ry = s * dx + c * dy
        fx = ox_m + scale * rx
        fy = oy_m + scale * ry
        hx = ox_m + rx[hit]
        hy = oy_m + ry[hit]

        x0, x1 = min(fx.min(), ox_m), max(fx.max(), ox_m)
        y0, y1 = min(fy.min(), oy_m), max(fy.max(), oy_m)
        if hx.size:
            x0, x1 = min(x0, hx.min()), max(x1, hx.max())
            y0, y1 = min(y0, hy.min()), max(y1, hy.max())
        if not self._lattice_set:
            m = float(cfg.tile_margin)
            self._gx, self._gy = float(np.floor((x0 - m) / res) * res), float(np.floor((y0 - m) / res) * res)
            self._lattice_set = True
        gx, gy = self._gx, self._gy
        # the scan's box in cells of the lattice
        c0, r0 = math.floor((x0 - gx) / res), math.floor((y0 - gy) / res)
        c1, r1 = math.floor((x1 - gx) / res) + 1, math.floor((y1 - gy) / res) + 1
        bw = c1 - c0

        # hit cells (clipped: a float can round onto the box's far edge)
        hc = np.minimum(np.maximum(np.floor((hx - gx) / res).astype(np.intp), c0), c1 - 1)
        hr = np.minimum(np.maximum(np.floor((hy - gy) / res).astype(np.intp), r0), r1 - 1)
        assert scan.instance is not None  # PaintedScan fills it in
        inst = scan.instance[hit]
        on = inst >= 0
        if on.any():  # which cells the camera saw as one object in this scan (the object list's evidence)
            key = np.unique((inst[on].astype(np.int64) << 32) | ((hr[on] - r0) * bw + (hc[on] - c0)))
            cell = key & 0xFFFFFFFF
            row = np.empty((key.size, 4), np.int32)
            row[:, 0] = self.n_scans
            row[:, 1] = key >> 32
            row[:, 2] = cell // bw + r0
            row[:, 3] = cell % bw + c0
            self._sightings.append(row)
            self._sightings_n += key.size

        # free space: the scan polygon, minus the cells returns of this scan ended in
        scratch = self._raster(0, r1 - r0, bw)
        scratch.fill(0)
        f = (1 << _SHIFT) / res
        bx, by = gx + res * (c0 + 0.5), gy + res * (r0 + 0.5)
        if cfg.free_shadows and fx.size > 1:
            # between two neighbouring beams whose free lengths differ by more than two cells at the
            # edge of something wider than a leg, free space reaches only the nearer: the wedge
            # beyond it is that edge's shadow
            fx, fy = _shadowed(fx, fy, ox_m, oy_m, free_len, 2.0 * res, _LEG_WIDTH)
        verts = np.empty((fx.size + 1, 2), np.int32)
        verts[0] = round((ox_m - bx) * f), round((oy_m - by) * f)
        np.rint((fx - bx) * f, out=verts[1:, 0], casting="unsafe")
        np.rint((fy - by) * f, out=verts[1:, 1], casting="unsafe")
        cv2.fillPoly(scratch, [verts], 1, cv2.LINE_8, _SHIFT)
        if cfg.free_erode:
            # keep free space a cell away from the polygon's edge: rays grazing a surface pass
            # through the cells it lies in without hitting them
            scratch = cv2.erode(scratch, _KERNEL3, dst=self._raster(1, r1 - r0, bw),
                                borderType=cv2.BORDER_CONSTANT, borderValue=0)
        scratch[hr - r0, hc - c0] = 0
        # l_free on the free cells, 0 elsewhere: a plain saturating subtraction (OpenCV's masked one is
        # not vectorised and costs several times more)
        step = np.multiply(scratch, self._q_free, out=self._raster(2, r1 - r0, bw), dtype=np.uint16)
        t = self.tile_cells
        # the tiles the box overlaps, numbered row by row from its first; those a return ended in
        btr0, btc0 = r0 // t, c0 // t
        nbc = (c1 - 1) // t - btc0 + 1
        box_tile = (hr // t - btr0) * nbc + (hc // t - btc0)
        has_hit = np.zeros(((r1 - 1) // t - btr0 + 1) * nbc, bool)
        has_hit[box_tile] = True
        where = (float(ox_m), float(oy_m))
        # the sensor's own tile, whatever the scan saw (a scan of beams that returned nothing still
        # places the robot in the grid)
        self._tile(math.floor((oy_m - gy) / res) // t, math.floor((ox_m - gx) / res) // t, where)
        for tr in range(btr0, (r1 - 1) // t + 1):
            a0, a1 = max(r0, tr * t), min(r1, (tr + 1) * t)
            for tc in range(btc0, (c1 - 1) // t + 1):
                b0, b1 = max(c0, tc * t), min(c1, (tc + 1) * t)
                sub = scratch[a0 - r0:a1 - r0, b0 - c0:b1 - c0]
                if not cv2.countNonZero(sub):
                    if has_hit[(tr - btr0) * nbc + tc - btc0]:
                        self._tile(tr, tc, where)  # returns only: their counts go in below
                    continue  # no free space here (a corner of the box, or outside the building)
                tile = self._tile(tr, tc, where)
                win = (slice(a0 - tr * t, a1 - tr * t), slice(b0 - tc * t, b1 - tc * t))
                lo = tile.lo[win]
                step_win = step[a0 - r0:a1 - r0, b0 - c0:b1 - c0]
                cv2.subtract(lo, step_win, dst=lo)  # saturates at 0, which is l_min
                if tile.hi is not None:
                    hi = tile.hi[win]
                    cv2.subtract(hi, step_win, dst=hi)
                fr = tile.free[win]
                if self.n_scans < _U16_MAX:  # counts cannot reach the cap yet: plain add
                    np.add(fr, sub, out=fr, casting="unsafe")
                else:
                    # (through Any: the stubs of some OpenCV releases take no scalar src2)
                    cast(Any, cv2).add(fr, 1, dst=fr, mask=sub)

        if hr.size:
            # one sorted key per (cell, evidence code): codes 0-3 mobility, 4+ class layer; cells
            # counted in the scan's box
            flat = (hr - r0) * bw + (hc - c0)
            mob = scan.mobility[hit].astype(np.intp)
            mob[mob >= N_MOBILITY] = 0
            cid = scan.class_id[hit].astype(np.intp)
            seen = (cid >= 0) & (cid < len(self.class_names))
            layer = self._class_layers(cid[seen]) if seen.any() else np.zeros(0, np.intp)
            n_codes = N_MOBILITY + len(self._cls_ids)
            keys = np.concatenate([flat * n_codes + mob, flat[seen] * n_codes + N_MOBILITY + layer])
            keys.sort()
            keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]
            cell = keys // n_codes
            code = keys - cell * n_codes
            first = np.concatenate([[True], cell[1:] != cell[:-1]])
            rr, cc = cell // bw + r0, cell % bw + c0
            tr_of, tc_of = rr // t, cc // t
            local = (rr - tr_of * t) * t + (cc - tc_of * t)
            tile_ids, tile_of = np.unique((tr_of - btr0) * nbc + (tc_of - btc0), return_inverse=True)
            for i, b in enumerate(tile_ids.tolist()):
                tile = self._tiles[(btr0 + b // nbc, btc0 + b % nbc)]
                here = tile_of == i
                lu = local[here & first]
                lo_flat = tile.lo.reshape(-1)
                lo_flat[lu] = np.minimum(lo_flat[lu].astype(np.int32) + self._q_occ, self._q_max)
                if tile.hi is not None:
                    hi_flat = tile.hi.reshape(-1)
                    hi_flat[lu] = np.minimum(hi_flat[lu].astype(np.int32) + self._q_occ, self._q_max)
                _bump(tile.hits.reshape(-1), lu)
                hc_code, hl = code[here], local[here]
                is_mob = hc_code < N_MOBILITY
                _bump(tile.mob.reshape(-1), hc_code[is_mob] * (t * t) + hl[is_mob])
                if not is_mob.all():
                    for k_layer in np.unique(hc_code[~is_mob] - N_MOBILITY).tolist():
                        arr = tile.cls.get(k_layer)
                        if arr is None:
                            arr = tile.cls[k_layer] = np.zeros((t, t), np.uint16)
                            self._tile_bytes += arr.nbytes
                        _bump(arr.reshape(-1), hl[hc_code == N_MOBILITY + k_layer])
        self.n_scans += 1

    def _raster(self, i: int, h: int, w: int) -> NDArray[Any]:
        """Scratch raster ``i`` as an (h, w) array (contents undefined), grown as boxes grow."""
        buf = self._scratch[i]
        if buf.size < h * w:
            buf = self._scratch[i] = np.empty(h * w, buf.dtype)
        return buf[:h * w].reshape(h, w)

    def layers(self) -> GridLayers:
        """A read-only snapshot of the grid: its tiles assembled into one window, their bounding box
        (copies; the grid keeps integrating). Cells of tiles never allocated are unobserved."""
        spec = self.spec
        if spec is None:
            raise ValueError("the grid is empty: integrate a scan first")
        if self._continues:
            raise ValueError("a grid that continues another's has no layers of its own: merge_continued")
        t, p = self.tile_cells, self._pad
        tr0, _, tc0, _ = self._tile_span()
        h, w = spec.height, spec.width
        n_cls = len(self._cls_ids)
        log_odds = np.zeros((h, w), np.float32)
        hits = np.zeros((h, w), np.uint16)
        free = np.zeros((h, w), np.uint16)
        mob = np.zeros((N_MOBILITY, h, w), np.uint16)
        cls = np.zeros((n_cls, h, w), np.uint16)
        for (tr, tc), tile in self._tiles.items():
            win = (slice((tr - tr0) * t + p, (tr - tr0 + 1) * t + p), slice((tc - tc0) * t + p, (tc - tc0 + 1) * t + p))
            np.multiply(tile.lo.astype(np.int32) - self._q_zero, LOG_ODDS_STEP, out=log_odds[win], casting="unsafe")
            hits[win] = tile.hits
            free[win] = tile.free
            mob[(slice(None), *win)] = tile.mob
            for k, arr in tile.cls.items():
                cls[(k, *win)] = arr
        return GridLayers(
            spec=spec,
            log_odds=_frozen(log_odds),
            hits=_frozen(hits),
            free=_frozen(free),
            mobility=_frozen(mob),
            class_counts=_frozen(cls),
            class_ids=tuple(self._cls_ids),
            class_names=self.class_names,
            n_scans=self.n_scans,
            sightings=_frozen(self._window_sightings(tr0 * t - p, tc0 * t - p)),
            grid_bytes=self.nbytes,
            grid_tiles=len(self._tiles),
        )

    def _window_sightings(self, row0: int, col0: int) -> NDArray[np.int32]:
        if not self._sightings:
            return np.zeros((0, 4), np.int32)
        if len(self._sightings) > 1:  # one array from now on
            self._sightings = [np.concatenate(self._sightings)]
        out = self._sightings[0].copy()
        out[:, 2] -= row0
        out[:, 3] -= col0
        return out


#: scans a grid that continues another's may fuse: its hit and free counts give the log-odds shift, and
#: must not saturate
MAX_CONTINUED_SCANS = _U16_MAX


def merge_continued(head: GridLayers, tail: SemanticGrid) -> GridLayers:
    """The layers of one grid that fused ``head``'s scans and then ``tail``'s, in order.

    ``head`` is a grid's :meth:`~SemanticGrid.layers` after the tour's first scans; ``tail`` a grid
    :meth:`SemanticGrid.continuing` it on the same lattice from the next scan. Bit for bit the layers
    of a single grid, but for the memory figures (``grid_bytes``: both grids').
    """
    if not tail._continues:
        raise ValueError("tail must be a grid made by SemanticGrid.continuing")
    if tail.first_scan != head.n_scans:
        raise ValueError(f"tail starts at scan {tail.first_scan}, head holds {head.n_scans}")
    if tail.n_scans - tail.first_scan > MAX_CONTINUED_SCANS:
        raise ValueError(f"a continuing grid fuses at most {MAX_CONTINUED_SCANS} scans")
    if not tail._tiles:
        return head
    res, t, p = tail.res, tail.tile_cells, tail._pad
    hs = head.spec
    # the head's window in cells of the lattice, and its tiles' span (the window less its pad)
    hc0 = round((hs.origin_x - tail._gx) / res)
    hr0 = round((hs.origin_y - tail._gy) / res)
    if (hc0 + p) % t or (hr0 + p) % t or hs.resolution != res:
        raise ValueError("head and tail are not on one lattice")
    htr0, htc0 = (hr0 + p) // t, (hc0 + p) // t
    htr1, htc1 = htr0 + (hs.height - 2 * p) // t, htc0 + (hs.width - 2 * p) // t
    ttr0, ttr1, ttc0, ttc1 = tail._tile_span()
    tr0, tr1, tc0, tc1 = min(htr0, ttr0), max(htr1, ttr1), min(htc0, ttc0), max(htc1, ttc1)
    spec = GridSpec(res, tail._gx + (tc0 * t - p) * res, tail._gy + (tr0 * t - p) * res,
                    (tc1 - tc0) * t + 2 * p, (tr1 - tr0) * t + 2 * p)
    h, w = spec.height, spec.width
    mr0, mc0 = tr0 * t - p, tc0 * t - p  # the window's first cell on the lattice
    hwin = (slice(hr0 - mr0, hr0 - mr0 + hs.height), slice(hc0 - mc0, hc0 - mc0 + hs.width))

    q_zero = tail._q_zero
    log_odds = np.zeros((h, w), np.float32)
    hits = np.zeros((h, w), np.uint16)
    free = np.zeros((h, w), np.uint16)
    mob = np.zeros((N_MOBILITY, h, w), np.uint16)
    log_odds[hwin], hits[hwin], free[hwin] = head.log_odds, head.hits, head.free
    mob[(slice(None), *hwin)] = head.mobility
    class_ids = list(head.class_ids)
    for c in tail._cls_ids:
        if c not in class_ids:
            class_ids.append(c)
    cls = np.zeros((len(class_ids), h, w), np.uint16)
    cls[(slice(0, len(head.class_ids)), *hwin)] = head.class_counts
    layer_of = [class_ids.index(c) for c in tail._cls_ids]
    for (tr, tc), tile in tail._tiles.items():
        win = (slice(tr * t - mr0, (tr + 1) * t - mr0), slice(tc * t - mc0, (tc + 1) * t - mc0))
        assert tile.hi is not None
        # the head's log-odds in steps, shifted by the tail's evidence and clamped as the tail's updates were
        q = np.rint(log_odds[win] * (1.0 / LOG_ODDS_STEP)).astype(np.int32)
        q += q_zero + tile.hits.astype(np.int32) * tail._q_occ - tile.free.astype(np.int32) * tail._q_free
        np.clip(q, tile.lo, tile.hi, out=q)
        np.multiply(q - q_zero, LOG_ODDS_STEP, out=log_odds[win], casting="unsafe")
        # counts: saturating sums, as the one grid's saturating increments
        cv2.add(hits[win], tile.hits, dst=hits[win])
        cv2.add(free[win], tile.free, dst=free[win])
        for k in range(N_MOBILITY):
            cv2.add(mob[(k, *win)], tile.mob[k], dst=mob[(k, *win)])
        for k, arr in tile.cls.items():
            cv2.add(cls[(layer_of[k], *win)], arr, dst=cls[(layer_of[k], *win)])
    sightings = [head.sightings.astype(np.int32, copy=True)] if len(head.sightings) else []
    if sightings:
        sightings[0][:, 2] += hr0 - mr0
        sightings[0][:, 3] += hc0 - mc0
    if tail._sightings:
        sightings.append(tail._window_sightings(mr0, mc0))
    observed = np.zeros((tr1 - tr0, tc1 - tc0), bool)
    seen = (head.hits > 0) | (head.free > 0)
    for i in range(htr1 - htr0):  # the head's tiles: those it observed a cell of
        for j in range(htc1 - htc0):
            observed[htr0 - tr0 + i, htc0 - tc0 + j] = seen[p + i * t:p + (i + 1) * t, p + j * t:p + (j + 1) * t].any()
    for tr, tc in tail._tiles:
        observed[tr - tr0, tc - tc0] = True

    return GridLayers(
        spec=spec, log_odds=_frozen(log_odds), hits=_frozen(hits), free=_frozen(free), mobility=_frozen(mob),
        class_counts=_frozen(cls), class_ids=tuple(class_ids), class_names=head.class_names, n_scans=tail.n_scans,
        sightings=_frozen(np.concatenate(sightings) if sightings else np.zeros((0, 4), np.int32)),
        grid_bytes=head.grid_bytes + tail.nbytes, grid_tiles=int(observed.sum()),
    )


def _shadowed(fx: NDArray[np.float64], fy: NDArray[np.float64], ox: float, oy: float, length: NDArray[np.float64],
              jump: float, min_width: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The free polygon's vertices (after the origin), stepping back at each occluding edge.

    ``fx, fy``: each beam's free end point, ``length`` from the sensor at ``(ox, oy)``.
    Between beams i and i+1 whose lengths differ by more than ``jump`` the straight edge between their
    end points is kept where it runs along one surface seen at a grazing angle (either end point lies,
    within ``jump`` / 2, on the line through the other and its outer neighbour), and where the nearer
    return is something no wider than ``min_width`` (a leg, a post: its shadow is narrower than the
    gap between the beams). Elsewhere it crosses the shadow of an occluding edge (the nearer return's
    run of beams spans more than ``min_width``, or it is a face receding from its other neighbour), and
    two vertices go in: each beam's point at the shorter length. The polygon then runs along the
    farther beam back to the nearer range, where no beam went beyond.
    """
    n = fx.size
    brk = np.flatnonzero(np.abs(length[:-1] - length[1:]) > jump)  # runs of beams end here
    if brk.size == 0:
        return fx, fy
    tol = 0.5 * jump

    def off_line(p: NDArray[np.intp], q: NDArray[np.intp], r: NDArray[np.intp]) -> NDArray[np.float64]:
        """Distance of point r from the line through p and q (inf where p and q are under tol apart)."""
        ux, uy = fx[q] - fx[p], fy[q] - fy[p]
        norm = np.hypot(ux, uy)
        cross = np.abs(ux * (fy[r] - fy[p]) - uy * (fx[r] - fx[p]))
        return np.where(norm > tol, cross / np.maximum(norm, 1e-12), np.inf)

    before = np.full(brk.size, np.inf)
    ok = brk >= 1
    before[ok] = off_line(brk[ok] - 1, brk[ok], brk[ok] + 1)
    after = np.full(brk.size, np.inf)
    ok = brk + 2 < n
    after[ok] = off_line(brk[ok] + 2, brk[ok] + 1, brk[ok])
    j = brk[(before > tol) & (after > tol)]
    if j.size == 0:
        return fx, fy
    # the nearer return's run of beams: the edge of something wider than a person's leg
    run = np.zeros(n, np.intp)
    run[brk + 1] = 1
    run = np.cumsum(run)
    first = np.concatenate([[0], brk + 1])
    last = np.concatenate([brk, [n - 1]])
    width = np.hypot(fx[last] - fx[first], fy[last] - fy[first])
    near = np.where(length[j] <= length[j + 1], j, j + 1)
    # or a face seen at a grazing angle, receding from the beam on the near return's other side
    other = np.clip(np.where(near == j, j - 1, j + 2), 0, n - 1)
    apart = np.hypot(fx[other] - fx[near], fy[other] - fy[near])
    receding = (length[other] < length[near] - jump) & (apart > min_width)
    j = j[(width[run[near]] > min_width) | receding]
    if j.size == 0:
        return fx, fy
    stepped = np.zeros(n - 1, bool)
    stepped[j] = True
    vx, vy = fx - ox, fy - oy
    m = np.minimum(length[j], length[j + 1])
    ka = m / np.maximum(length[j], 1e-12)
    kb = m / np.maximum(length[j + 1], 1e-12)
    pos = np.arange(n)
    pos[1:] += 2 * np.cumsum(stepped)
    out_x = np.empty(n + 2 * j.size)
    out_y = np.empty(n + 2 * j.size)
    out_x[pos], out_y[pos] = fx, fy
    out_x[pos[j] + 1], out_y[pos[j] + 1] = ox + ka * vx[j], oy + ka * vy[j]
    out_x[pos[j] + 2], out_y[pos[j] + 2] = ox + kb * vx[j + 1], oy + kb * vy[j + 1]
    return out_x, out_y


def _bump(flat: NDArray[np.uint16], idx: NDArray[np.intp]) -> None:
    """Add one at unique flat indices of a uint16 array, saturating at 65535."""
    v = flat[idx]
    flat[idx] = v + (v < _U16_MAX)


# -- memory --------------------------------------------------------------------------------

#: bytes per cell of the layers every window has: log-odds, hits, free (uint16) and 4 mobility counts
_CELL_BYTES = 2 + 2 + 2 + 2 * N_MOBILITY
#: bytes per cell of a scan's bounding box in the scratch rasters (polygon, eroded polygon, l_free step)
_SCRATCH_BYTES = 1 + 1 + 2
#: share of the machine's memory the grid may take: the map folder and the other stages need the rest
MEMORY_SHARE = 0.5


@dataclass(frozen=True)
class GridMemoryEstimate:
    """What a :class:`SemanticGrid` allocates, worst case, for a LiDAR of a given range.

    * ``window_m``: the side of the square of tiles the first scan may reach (its farthest returns
      on both sides, rounded out to whole tiles of ``tile_margin``).
    * ``first_window_bytes``: those tiles' layers (log-odds, hits, free, mobility, and a layer for
      every class in every tile: the worst case).
    * ``scratch_bytes``: the rasters one scan is drawn into (its bounding box).
    * ``class_copy_bytes``: 0 (kept for callers of older versions: class layers are added per tile,
      copying nothing).
    * ``growth_bytes``: the layers once a scan has moved into the next row and column of tiles (tiles
      are added, nothing is copied), plus the scratch.
    """

    window_m: float
    first_window_bytes: float
    scratch_bytes: float
    class_copy_bytes: float
    growth_bytes: float

    @property
    def peak_bytes(self) -> float:
        """The most held at once: the first tiles and the scratch, or one growth step."""
        return max(self.first_window_bytes + self.class_copy_bytes + self.scratch_bytes, self.growth_bytes)


def estimate_grid_memory(cfg: GridConfig, max_range: float, n_classes: int) -> GridMemoryEstimate:
    """The memory a grid needs for its first scan and one growth step (see :class:`GridMemoryEstimate`).

    ``max_range`` is the farthest return the LiDAR reports (its ``range_max``), m; a non-finite one
    counts as ``cfg.max_range``; the grid uses no return beyond ``cfg.max_range``. Every one of
    ``n_classes`` is assumed seen in every tile (one layer each).
    Floats, so absurd settings give huge numbers (or inf) instead of overflowing.
    """
    res = float(cfg.resolution)
    reach = _reach(cfg, max_range)
    per_cell = _CELL_BYTES + 2.0 * max(int(n_classes), 0)
    tile = float(max(16, round(cfg.tile_margin / res))) if math.isfinite(cfg.tile_margin / res) else math.inf
    box = 2.0 * reach / res + 2.0  # a scan's bounding box, cells (floored origin, +1)
    if not (math.isfinite(box) and math.isfinite(tile)):
        return GridMemoryEstimate(math.inf, math.inf, math.inf, 0.0, math.inf)
    n_side = float(math.ceil(box / tile) + 1)  # tiles a box can touch along a side
    tile_bytes = tile * tile * per_cell
    first = n_side * n_side * tile_bytes  # products of floats: inf, never OverflowError, for absurd settings
    scratch = box * box * _SCRATCH_BYTES
    grown = (n_side + 1.0) * (n_side + 1.0) * tile_bytes + scratch
    return GridMemoryEstimate(n_side * tile * res, first, scratch, 0.0, grown)


def _reach(cfg: GridConfig, max_range: float) -> float:
    """How far from the sensor the grid takes evidence: the LiDAR's range, at most ``cfg.max_range``."""
    lidar = float(max_range) if math.isfinite(max_range) and max_range > 0 else math.inf
    return min(lidar, float(cfg.max_range))


def _machine_memory() -> tuple[float, str]:
    """Physical memory, or the container's limit where that is lower, and how to name it."""
    total = float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    what = "this machine's"
    for f in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(f, encoding="ascii") as fh:
                v = fh.read().strip()
        except OSError:
            continue
        if v.isdigit() and 0 < int(v) < total:
            total, what = float(v), "this container's"
        break
    return total, what


def _size(n: float) -> str:
    for unit, scale in (("TiB", 2.0 ** 40), ("GiB", 2.0 ** 30), ("MiB", 2.0 ** 20)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n / 1024:.3g} KiB"


def check_grid_memory(cfg: GridConfig, max_range: float, n_classes: int, available_bytes: int | None = None) -> int:
    """Refuse, before any work, a grid whose first window (and one growth step) would not fit in memory.

    Returns the estimated peak in bytes (:func:`estimate_grid_memory`); raises
    :class:`~semmap.errors.ConfigError` naming the settings and the estimate when it exceeds
    ``available_bytes`` (default: half of the machine's physical memory, or of the container's
    limit where that is lower).
    """
    est = estimate_grid_memory(cfg, max_range, n_classes)
    need = est.peak_bytes
    if available_bytes is None:
        total, whose = _machine_memory()
        limit = MEMORY_SHARE * total
        budget = f"the {_size(limit)} it may use (half of {whose} {_size(total)})"
    else:
        limit = float(available_bytes)
        budget = f"the {_size(limit)} available"
    if need <= limit:
        return int(need)
    side = est.window_m
    reach = _reach(cfg, max_range)
    needs = f"needs {_size(need)}, more than {budget}" if math.isfinite(need) else "needs more memory than exists"
    if cfg.tile_margin > max(reach, 50.0):
        fix = "use a smaller grid.tile_margin (10 m is typical)"
    else:
        fix = "use a coarser grid.resolution (0.05 m is typical)"
    classes = f", {n_classes} classes" if n_classes else ""
    raise ConfigError(
        f"grid.resolution {cfg.resolution:g} m (grid.tile_margin {cfg.tile_margin:g} m, range {reach:g} m"
        f"{classes}): the grid's first {side:.4g} m x {side:.4g} m window {needs}; {fix}")
