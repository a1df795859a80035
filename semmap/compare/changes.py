"""What changed between two aligned sessions, and of what kind.

Both maps are laid on one grid: session A's grid, grown to hold B's cells as well, so A's cells keep
their place and B's are looked up by nearest cell through the alignment. Then, cell by cell:

* a cell is **added** when B holds an obstacle where A saw free floor, and A held no obstacle
  within ``tolerance_m`` (the alignment and a wall's thickness wobble by a cell or two);
  **removed** the other way round. A cell only one session observed is *unobserved*, never
  changed;
* cells near where either session saw people (dynamic evidence, and cells cleaning dropped as
  dynamic) are never changes: a person left in one map is not an obstacle added;
* added and removed cells on movable objects become object changes: the objects of the two
  sessions are matched by class and footprint (``moved``, with displacement and rotation measured
  by fitting the object's cells, ``appeared``, ``disappeared``); an object only one session could
  see is left out, not reported as gone;
* the rest are **static** changes, grouped into connected pieces;
* floor observed by only one session, in pieces of at least ``min_explored_m2``, is **newly
  explored** (only B) or **no longer covered** (only A).

A plain map_server map carries no semantic layers: its diff has static changes and explored areas
only (``DiffResult.semantic`` is False and the report says so).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..geometry import dilate_mask, disk_kernel, se2_apply, se2_inverse, wrap_angle
from ..grid import SemiStaticObject
from ..records import GridSpec
from ..register.metrics import align_se2
from .session import LEG_M, Session

__all__ = [
    "CHANGE_TYPES",
    "Change",
    "ChangeSettings",
    "LaidOut",
    "classify_changes",
    "lay_out",
]

#: every change type, in the order reports list them
CHANGE_TYPES = ("static_added", "static_removed", "object_moved", "object_appeared", "object_disappeared",
                "newly_explored", "no_longer_covered")

#: the shortest side of a rectangle of legs (m): four blobs closer than this are one blob's noise
_LEG_RECT_SHORTEST = 0.25

# bits of the code image both sessions are resampled through
_OCC, _FREE, _SEMI, _DYN, _FAINT, _GLIMPSE, _FIRM, _LAB, _BARE = 1, 2, 4, 8, 16, 32, 64, 128, 256


@dataclass(frozen=True)
class ChangeSettings:
    """How strict the comparison is (metres unless named otherwise)."""

    #: an obstacle this close to one of the other session's is the same obstacle
    tolerance_m: float = 0.10
    #: cells this close to where people were seen are never changes, in pieces a person could be:
    #: no longer than ``person_m``, or with ``person_share`` of their cells on people evidence
    people_margin_m: float = 0.30
    person_m: float = 0.8
    person_share: float = 0.3
    #: a static change smaller than this (m²) is noise
    min_static_m2: float = 0.01
    #: cells of one static change may be this far apart (the legs of a table are one change)
    group_m: float = 0.5
    #: an object that moved less than this, and turned less than ``still_deg``, did not move
    still_m: float = 0.10
    still_deg: float = 10.0
    #: a face at least this long of an object that did not move, standing where the other session saw
    #: floor, is a change: the object was replaced by another of its class (a wider couch) or extended
    face_m: float = 0.3
    #: an object is matched to one of its class at most this far away
    max_move_m: float = 4.0
    #: an object counts as seen by the other session when this share of its footprint was observed there
    seen_share: float = 0.6
    #: an obstacle no larger than this (m²) may be a leg of furniture the camera did not label
    leg_m2: float = 0.03
    #: pieces of changed cells no camera labelled, at most this long, that a rigid motion lays onto each
    #: other for at least ``unlabelled_fit`` of their cells, are an object that moved (class unknown)
    max_object_m: float = 2.5
    unlabelled_fit: float = 0.7
    #: ... and as many legs of each on the other's at least (one or two legs fit any blob). So many
    #: obstacles, each too small for a change, within ``leg_span_m`` of each other are furniture
    min_fit_legs: int = 3
    leg_span_m: float = 1.3
    #: ... or four such obstacles at the corners of a rectangle whose sides are ``leg_rect_m`` long at
    #: most (a dining table or a bed, whose legs stand further apart than ``leg_span_m``)
    leg_rect_m: float = 3.0
    #: an object whose cells span at most this (m) is a pole at LiDAR height (a screen's stand, a lamp)
    pole_m: float = 0.2
    #: explored or no-longer-covered floor smaller than this (m²) is not reported
    min_explored_m2: float = 1.0
    #: a straight piece at least this long whose line the other session's walls continue beyond both
    #: ends is a door closed in a doorway (or one opened), never a face the other session saw edge-on
    door_min_m: float = 0.5
    #: the inside of an obstacle that changed (which its own session cannot see), enclosed by its
    #: changed faces and the other session's wall behind it, is a change up to this size (m²)
    max_fill_m2: float = 2.5


@dataclass(frozen=True)
class Change:
    """One change, in A's map frame."""

    type: str
    centroid: tuple[float, float]
    area_m2: float
    cells: int
    class_name: str | None = None
    #: for ``object_moved``: where it was and is (A's map frame), how far and how much it turned (None
    #: where a turn cannot be measured: a round object, or one about as wide as long, such as a chair)
    from_xy: tuple[float, float] | None = None
    to_xy: tuple[float, float] | None = None
    displacement_m: float | None = None
    rotation_deg: float | None = None

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"type": self.type, "class": self.class_name,
                             "centroid": [round(v, 3) for v in self.centroid],
                             "area_m2": round(self.area_m2, 4), "cells": self.cells}
        if self.type == "object_moved":
            assert self.from_xy is not None and self.to_xy is not None
            d |= {"from": [round(v, 3) for v in self.from_xy], "to": [round(v, 3) for v in self.to_xy],
                  "displacement_m": round(float(self.displacement_m or 0.0), 3),
                  "rotation_deg": None if self.rotation_deg is None else round(float(self.rotation_deg), 1)}
        return d


@dataclass(frozen=True)
class LaidOut:
    """Both sessions on one grid (A's, grown to hold B's cells too); masks (H, W) bool."""

    spec: GridSpec
    #: where A's own grid sits in ``spec``: rows and columns ``[r0, r0 + h)``, ``[c0, c0 + w)``
    a_window: tuple[int, int, int, int]
    occ_a: NDArray[np.bool_]
    free_a: NDArray[np.bool_]
    semi_a: NDArray[np.bool_]
    dyn_a: NDArray[np.bool_]
    occ_b: NDArray[np.bool_]
    free_b: NDArray[np.bool_]
    semi_b: NDArray[np.bool_]
    dyn_b: NDArray[np.bool_]
    #: faint obstacles (see :class:`Session`): free cells that were hit again and again
    faint_a: NDArray[np.bool_] | None = None
    faint_b: NDArray[np.bool_] | None = None
    #: per cell, the index of the object of its session that holds it (-1: none; None: not known)
    index_a: NDArray[np.int32] | None = None
    index_b: NDArray[np.int32] | None = None
    #: glimpsed cells (see :class:`Session`): free cells beams ended in again and again
    glimpse_a: NDArray[np.bool_] | None = None
    glimpse_b: NDArray[np.bool_] | None = None
    #: weak obstacles (see :class:`Session`): occupied cells fewer than three returns ended in
    weak_a: NDArray[np.bool_] | None = None
    weak_b: NDArray[np.bool_] | None = None
    #: cells the camera painted (see :class:`Session`)
    lab_a: NDArray[np.bool_] | None = None
    lab_b: NDArray[np.bool_] | None = None
    #: bare floor (see :class:`Session`)
    bare_a: NDArray[np.bool_] | None = None
    bare_b: NDArray[np.bool_] | None = None


def _code(s: Session) -> NDArray[np.uint16]:
    c = np.zeros(s.spec.shape, np.uint16)
    c[s.occupied] |= _OCC
    c[s.free & ~s.occupied] |= _FREE
    c[s.semi_static] |= _SEMI
    c[s.dynamic] |= _DYN
    if s.faint is not None:
        c[s.faint] |= _FAINT
    if s.glimpsed is not None:
        c[s.glimpsed] |= _GLIMPSE
    if s.weak is not None:  # carried as its opposite: a cell two of B's fall in is firm if either is
        c[s.occupied & ~s.weak] |= _FIRM
    if s.labelled is not None:
        c[s.labelled] |= _LAB
    if s.bare is not None:
        c[s.bare & ~s.occupied] |= _BARE
    return c


def lay_out(a: Session, b: Session, T_a_b: NDArray[np.float64]) -> LaidOut:
    """Put both sessions on A's grid, grown by whole cells to cover B's cells carried into A's frame."""
    sa, sb = a.spec, b.spec
    res = sa.resolution
    corners = np.array([[sb.origin_x, sb.origin_y], [sb.origin_x + sb.width * sb.resolution, sb.origin_y],
                        [sb.origin_x, sb.origin_y + sb.height * sb.resolution],
                        [sb.origin_x + sb.width * sb.resolution, sb.origin_y + sb.height * sb.resolution]])
    cb = se2_apply(T_a_b, corners)
    x0 = min(sa.origin_x, float(cb[:, 0].min()))
    y0 = min(sa.origin_y, float(cb[:, 1].min()))
    x1 = max(sa.origin_x + sa.width * res, float(cb[:, 0].max()))
    y1 = max(sa.origin_y + sa.height * res, float(cb[:, 1].max()))
    c0 = int(math.ceil((sa.origin_x - x0) / res - 1e-6))  # whole cells, so A's cells keep their place
    r0 = int(math.ceil((sa.origin_y - y0) / res - 1e-6))
    width = c0 + int(math.ceil((x1 - sa.origin_x) / res - 1e-6))
    height = r0 + int(math.ceil((y1 - sa.origin_y) / res - 1e-6))
    spec = GridSpec(res, sa.origin_x - c0 * res, sa.origin_y - r0 * res, width, height)

    code_a = np.zeros(spec.shape, np.uint16)
    code_a[r0:r0 + sa.height, c0:c0 + sa.width] = _code(a)
    # every cell centre of the grown grid, carried into B's frame, and the B cell it falls in
    xs = spec.origin_x + (np.arange(spec.width, dtype=np.float64) + 0.5) * res
    ys = spec.origin_y + (np.arange(spec.height, dtype=np.float64) + 0.5) * res
    t_b_a = se2_inverse(T_a_b)
    cs, sn = math.cos(float(t_b_a[2])), math.sin(float(t_b_a[2]))
    # B's (fractional) column and row of each: a sum of a term per column and a term per row
    map_x = np.add.outer((-sn * ys) / sb.resolution,
                         (cs * xs + t_b_a[0] - sb.origin_x) / sb.resolution - 0.5).astype(np.float32)
    map_y = np.add.outer((cs * ys) / sb.resolution,
                         (sn * xs + t_b_a[1] - sb.origin_y) / sb.resolution - 0.5).astype(np.float32)
    raw_b = _code(b)
    code_b = np.asarray(cv2.remap(raw_b, map_x, map_y, interpolation=cv2.INTER_NEAREST,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=0), np.uint16)
    # sampling a turned grid at A's cell centres skips some of B's cells: a thin leg that is one cell
    # would vanish. B's obstacle cells are also carried forward into the cell their centre falls in
    solid = _OCC | _SEMI | _DYN | _FAINT | _FIRM
    rows_b, cols_b = np.nonzero(raw_b & solid)
    if rows_b.size:
        xy = se2_apply(T_a_b, np.stack([sb.origin_x + (cols_b + 0.5) * sb.resolution,
                                        sb.origin_y + (rows_b + 0.5) * sb.resolution], axis=1))
        c = np.floor((xy[:, 0] - spec.origin_x) / res).astype(np.intp)
        r = np.floor((xy[:, 1] - spec.origin_y) / res).astype(np.intp)
        ok = (r >= 0) & (r < spec.height) & (c >= 0) & (c < spec.width)
        bits_b = (raw_b[rows_b, cols_b] & (solid | _LAB))[ok]
        np.bitwise_or.at(code_b, (r[ok], c[ok]), bits_b)
        code_b[r[ok], c[ok]] &= ~np.uint16(_FREE | _BARE)

    def bits(code: NDArray[np.uint16], bit: int) -> NDArray[np.bool_]:
        return (code & bit) > 0

    index_a = index_b = None
    if a.object_index is not None:
        index_a = np.full(spec.shape, -1, np.int32)
        index_a[r0:r0 + sa.height, c0:c0 + sa.width] = a.object_index
    if b.object_index is not None:  # exact for indices below 2**24
        index_b = np.asarray(cv2.remap(b.object_index.astype(np.float32), map_x, map_y,
                                       interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                       borderValue=-1), np.int32)
    return LaidOut(spec, (r0, c0, sa.height, sa.width),
                   bits(code_a, _OCC), bits(code_a, _FREE), bits(code_a, _SEMI), bits(code_a, _DYN),
                   bits(code_b, _OCC), bits(code_b, _FREE), bits(code_b, _SEMI), bits(code_b, _DYN),
                   bits(code_a, _FAINT), bits(code_b, _FAINT), index_a, index_b,
                   bits(code_a, _GLIMPSE) if a.glimpsed is not None else None,
                   bits(code_b, _GLIMPSE) if b.glimpsed is not None else None,
                   bits(code_a, _OCC) & ~bits(code_a, _FIRM) if a.weak is not None else None,
                   bits(code_b, _OCC) & ~bits(code_b, _FIRM) if b.weak is not None else None,
                   bits(code_a, _LAB) if a.labelled is not None else None,
                   bits(code_b, _LAB) if b.labelled is not None else None,
                   bits(code_a, _BARE) if a.bare is not None else None,
                   bits(code_b, _BARE) if b.bare is not None else None)


_disk = disk_kernel
_dilate = dilate_mask


@dataclass
class _Obj:
    """An object of one session in A's frame, with the cells it holds on the common grid."""

    src: SemiStaticObject
    centroid: NDArray[np.float64]
    yaw: float
    footprint: NDArray[np.float64]  # (4, 2) corners, A's frame; (0, 2) when the object has none
    cells: NDArray[np.intp] = field(default_factory=lambda: np.zeros((0, 2), np.intp))  # (n, 2) row, col


def _objects(objs: tuple[SemiStaticObject, ...], T: NDArray[np.float64] | None, spec: GridSpec,
             semi: NDArray[np.bool_], index: NDArray[np.int32] | None = None) -> list[_Obj]:
    """The objects carried into A's frame (``T``: their map's pose in A's; None: they are A's).

    Each movable cell goes to the object the build grouped it into (``index``, the object's place in
    ``objs`` per cell, -1 for none); without it, or for a cell it leaves to none, to the object whose
    box (grown by a cell) holds it, else to the nearest object's centroid within a metre."""
    out = []
    for o in objs:
        c = np.asarray(o.centroid, np.float64)
        fp = np.asarray(o.footprint, np.float64).reshape(-1, 2)
        yaw = o.yaw
        if T is not None:
            c = se2_apply(T, c[None])[0]
            fp = se2_apply(T, fp) if fp.size else fp
            yaw = float(wrap_angle(yaw + float(T[2])))
        out.append(_Obj(o, c, yaw, fp))
    rows, cols = np.nonzero(semi)
    if out and rows.size:
        img = np.zeros(spec.shape, np.int32)
        for k, ob in enumerate(out):
            if ob.footprint.shape[0] >= 3:
                c = ob.footprint.mean(axis=0)
                grown = c + (ob.footprint - c) * (1.0 + spec.resolution / max(1e-3, float(
                    np.min(np.linalg.norm(ob.footprint - c, axis=1)))))
                pts = np.round(((grown - [spec.origin_x, spec.origin_y]) / spec.resolution - 0.5) * 16)
                cv2.fillPoly(img, [pts.astype(np.int32)], k + 1, lineType=cv2.LINE_8, shift=4)
        owner = img[rows, cols].astype(np.intp) - 1
        if index is not None:
            built = index[rows, cols].astype(np.intp)
            owner = np.where((built >= 0) & (built < len(out)), built, owner)
        rest = owner < 0
        if rest.any():
            xy = _cells_xy(np.stack([rows[rest], cols[rest]], axis=1), spec)
            d, k = cKDTree(np.stack([ob.centroid for ob in out])).query(xy)
            near = d <= 1.0  # a stray cell of no object stays no one's
            owner[np.flatnonzero(rest)[near]] = k[near]
        for k, ob in enumerate(out):
            sel = owner == k
            ob.cells = np.stack([rows[sel], cols[sel]], axis=1)
    return out


def _icp(src: NDArray[np.float64], dst: NDArray[np.float64], pose: NDArray[np.float64],
         iters: int = 30) -> tuple[NDArray[np.float64], float]:
    """Point-to-point ICP of ``src`` onto ``dst`` from ``pose``; the pose and its RMS residual."""
    tree = cKDTree(dst)
    rms = math.inf
    for _ in range(iters):
        d, j = tree.query(se2_apply(pose, src))
        keep = d <= max(float(np.median(d)) * 3.0, 0.05)
        if keep.sum() < 2:
            break
        new = align_se2(src[keep], dst[j[keep]])
        done = np.allclose(new, pose, atol=1e-5)
        pose = new
        if done:
            break
    d, _ = tree.query(se2_apply(pose, src))
    rms = float(np.sqrt(np.mean(np.minimum(d, 0.3) ** 2)))
    return pose, rms


def _seen_better(changed: list[_Obj], unchanged_other: list[_Obj],
                 too_long: Callable[[_Obj], bool] | None = None, leg_cells: int = 0,
                 min_legs: int = 0, other_bare: NDArray[np.bool_] | None = None
                 ) -> tuple[list[_Obj], list[tuple[NDArray[np.intp], str]]]:
    """``changed`` less the objects that are an object of their class in ``unchanged_other`` (the
    other session's objects that did not change) seen more fully: most of that object's cells, and a
    third of this one's, lie within a cell and a half of each other (two legs of a chair in A, four in
    B). Not when they share a cell or two: a build may list a moved table with a leg of the unchanged
    table beside it, or two beds as one. Nor when it is ``too_long`` for its class: more than one
    object of its class, grouped by its build (a new couch put beside one that stayed).

    Also the cells of such an object beyond the other one when they are ``min_legs`` or more legs of
    their own (groups of at most ``leg_cells`` cells): not legs the other session lost, but a second
    object its build grouped with the first (a table of four legs that went from the end of one that
    stayed; a chair tucked at a table's end that moved away). They are the caller's to pair with the
    other end of a move, or to report gone (or new) on their own.

    Not seen more fully when two of its legs wholly beyond the other object, fewer than a second object's,
    stand wholly on the other session's bare floor (``other_bare``, as for :func:`_legs_still`): they are no legs
    the other session missed."""
    out: list[_Obj] = []
    rests: list[tuple[NDArray[np.intp], str]] = []
    for o in changed:
        xy = o.cells.astype(np.float64)
        same = False
        if too_long is not None and too_long(o):
            out.append(o)
            continue
        for u in unchanged_other:
            if u.src.class_name != o.src.class_name or not u.cells.shape[0] or not xy.shape[0]:
                continue
            uxy = u.cells.astype(np.float64)
            d_o = cKDTree(uxy).query(xy)[0]
            d_u = cKDTree(xy).query(uxy)[0]
            if float(np.mean(d_o <= 1.5)) >= 1.0 / 3.0 and float(np.mean(d_u <= 1.5)) >= 0.5:
                beyond = o.cells[d_o > 1.5]
                if other_bare is not None and leg_cells:
                    # (its legs wholly beyond the other object: two on bare floor, and too few for a second)
                    groups, legs = _leg_groups(o.cells, leg_cells)
                    far = _legs_beyond(d_o, groups, legs)
                    if (not min_legs or far.sum() < min_legs) and \
                            _bare_legs(o.cells, groups, legs[far], other_bare) >= 2:
                        continue
                same = True
                if min_legs and _legs_of_its_own(beyond.astype(np.float64), leg_cells) >= min_legs:
                    rests.append((beyond, o.src.class_name))
                break
        if not same:
            out.append(o)
    return out, rests


def _onto_itself(changed: list[_Obj], unchanged_other: list[_Obj], too_long: Callable[[_Obj], bool],
                 other_bare: NDArray[np.bool_] | None, leg_cells: int) -> list[tuple[int, _Obj]]:
    """Of ``changed`` (gone or new, matched to nothing), the objects on legs that moved onto part of their own
    place: two legs or more on an unchanged object of their class in the other session (half that one's cells
    within a cell and a half of theirs), and two or more legs wholly beyond it standing on the other
    session's bare floor (``other_bare``), where it saw no leg. A chair turned on the spot: two legs on two
    of its old places. Each with that object (index in ``changed``, the other object), one pair per object;
    not an object too long for its class (more than one, grouped by its build). None without bare floor."""
    out: list[tuple[int, _Obj]] = []
    if other_bare is None:
        return out
    used: set[int] = set()
    for k, o in enumerate(changed):
        if not o.cells.shape[0] or too_long(o):
            continue
        groups, legs = _leg_groups(o.cells, leg_cells)
        if legs.size < 4:
            continue
        xy = o.cells.astype(np.float64)
        tree = cKDTree(xy)
        for u in unchanged_other:
            if id(u) in used or u.src.class_name != o.src.class_name or not u.cells.shape[0] or too_long(u):
                continue
            if float(np.mean(tree.query(u.cells.astype(np.float64))[0] <= 1.5)) < 0.5:
                continue
            d_o = cKDTree(u.cells.astype(np.float64)).query(xy)[0]
            far = _legs_beyond(d_o, groups, legs)
            if legs.size - far.sum() >= 2 and _bare_legs(o.cells, groups, legs[far], other_bare) >= 2:
                out.append((k, u))
                used.add(id(u))
                break
    return out


def _legs_of_its_own(cells: NDArray[np.float64], leg_cells: int) -> int:
    """How many legs ``cells`` (row, col) hold: 8-connected groups of at most ``leg_cells`` cells."""
    if not cells.shape[0]:
        return 0
    sizes = np.bincount(_clusters(cells, 1.5))
    return int(np.count_nonzero(sizes <= leg_cells))


def _clusters(xy: NDArray[np.float64], link: float) -> NDArray[np.intp]:
    """Per point, its cluster: points joined through neighbours closer than ``link``."""
    pairs = cKDTree(xy).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(pairs.shape[0]), (pairs[:, 0], pairs[:, 1])), shape=(xy.shape[0],) * 2)
    return np.asarray(connected_components(graph, directed=False)[1], np.intp)


def _rectangles(xy: NDArray[np.float64], longest: float, shortest: float, tol: float
                ) -> list[tuple[int, int, int, int]]:
    """Sets of four points at the corners of a rectangle with sides from ``shortest`` to ``longest``:
    two pairs of points (its diagonals) of one length and one midpoint, within ``tol``, crossing at
    an angle that leaves each side at least ``shortest`` long. Each point is in one set at most; of
    rival sets, the tightest."""
    n = xy.shape[0]
    if n < 4:
        return []
    pairs = cKDTree(xy).query_pairs(math.hypot(longest, longest) + tol, output_type="ndarray")
    if pairs.shape[0] < 2:
        return []
    d = xy[pairs[:, 1]] - xy[pairs[:, 0]]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length >= math.hypot(shortest, shortest) - tol
    pairs, d, length = pairs[ok], d[ok], length[ok]
    if pairs.shape[0] < 2:
        return []
    mid = 0.5 * (xy[pairs[:, 0]] + xy[pairs[:, 1]])
    feats = np.column_stack([mid, length / 2.0])
    cands = []
    for i, j in cKDTree(feats).query_pairs(tol, output_type="ndarray"):
        corners = {*pairs[i].tolist(), *pairs[j].tolist()}
        if len(corners) < 4:
            continue
        # the rectangle's sides, from the diagonals' length and the angle between them
        a = float(np.arctan2(d[i, 1], d[i, 0]) - np.arctan2(d[j, 1], d[j, 0]))
        diag = 0.5 * (length[i] + length[j])
        s1, s2 = abs(diag * math.sin(a / 2.0)), abs(diag * math.cos(a / 2.0))
        if min(s1, s2) < shortest or max(s1, s2) > longest:
            continue
        a0, a1, a2, a3 = sorted(corners)
        cands.append((float(np.linalg.norm(feats[i] - feats[j])), (a0, a1, a2, a3)))
    out: list[tuple[int, int, int, int]] = []
    used: set[int] = set()
    for _, quad in sorted(cands):
        if used.isdisjoint(quad):
            out.append(quad)
            used.update(quad)
    return out


def _legs(xy: NDArray[np.float64], link: float) -> NDArray[np.float64]:
    """Centres of the groups of points (cells) closer than ``link`` to each other: an object's legs."""
    roots = _clusters(xy, link)
    return np.stack([xy[roots == r].mean(axis=0) for r in np.unique(roots)])


def _leg_pair_turns(legs_a: NDArray[np.float64], legs_b: NDArray[np.float64], tol: float,
                    have: tuple[float, ...], most: int = 4) -> tuple[float, ...]:
    """Turns that lay a pair of A's legs on a pair of B's as far apart (within ``tol``), both ways
    round, not within 3 degrees of one in ``have``: the object's turn whenever each session saw two of
    its legs, however its box was drawn. The ``most`` that most pairs agree on."""
    if legs_a.shape[0] < 2 or legs_b.shape[0] < 2:
        return ()
    found: list[float] = []
    for i in range(legs_a.shape[0]):
        for j in range(i + 1, legs_a.shape[0]):
            va = legs_a[j] - legs_a[i]
            da = float(np.hypot(*va))
            for k in range(legs_b.shape[0]):
                for m in range(k + 1, legs_b.shape[0]):
                    vb = legs_b[m] - legs_b[k]
                    if da < 2 * tol or abs(float(np.hypot(*vb)) - da) > tol:
                        continue
                    t = float(wrap_angle(math.atan2(vb[1], vb[0]) - math.atan2(va[1], va[0])))
                    found += [t, float(wrap_angle(t + math.pi))]
    if not found:
        return ()
    near = 3.0 * math.pi / 180.0
    arr = np.array(found)
    support = [int(np.sum(np.abs(wrap_angle(arr - t)) <= near)) for t in found]
    out: list[float] = []
    for k in np.argsort(support)[::-1]:
        t = found[int(k)]
        if all(abs(float(wrap_angle(t - h))) > near for h in tuple(have) + tuple(out)):
            out.append(t)
        if len(out) >= most:
            break
    return tuple(out)


def _fit_motion(src: NDArray[np.float64], dst: NDArray[np.float64], turns: tuple[float, ...], res: float,
                contradicts: Any = None, furniture_a: Any = None, furniture_b: Any = None,
                contradicts_back: Any = None) -> NDArray[np.float64]:
    """The rigid motion (x, y, yaw) taking an object's cells ``src`` (session A) onto its cells ``dst``
    (session B). The sessions may have seen different legs of it (two of a bed's four in one, three
    in the other), so the centroids need not correspond: every pairing of a leg of A with a leg of B,
    at each candidate turn in ``turns`` (radians), is a hypothesis, as is the centroid shift. A
    hypothesis is scored by the shares of either session's cells it explains, less the share of A's
    cells it puts where B contradicts them (``contradicts(xy) -> bool mask``: floor B saw free, or
    beyond what B saw at all, behind its walls); the best few are refined by ICP and scored again, and
    the best refined one wins (of equal ones, the smallest motion), unless none beats staying put. A
    cell is explained when it lands on the other session's cells of the object, or on any furniture
    of the other session (``furniture_a`` / ``furniture_b(xy) -> bool mask``): a build may list a
    table's far legs as another object, or none, and the motion that puts them there is the right one."""
    link = 1.6 * res
    legs_a, legs_b = _legs(src, link), _legs(dst, link)
    tree_a, tree_b = cKDTree(src), cKDTree(dst)
    tol = 1.6 * res
    cs, cd = src.mean(axis=0), dst.mean(axis=0)

    def score(pose: NDArray[np.float64]) -> float:
        moved = se2_apply(pose, src)
        back = se2_apply(se2_inverse(pose), dst)
        hit_b = tree_a.query(back)[0] <= tol
        hit_a = tree_b.query(moved)[0] <= tol
        if furniture_a is not None:
            hit_b |= furniture_a(back)
        if furniture_b is not None:
            hit_a |= furniture_b(moved)
        explained_b, explained_a = np.count_nonzero(hit_b), np.count_nonzero(hit_a)
        bad = np.count_nonzero(contradicts(moved) & ~hit_a) if contradicts is not None else 0
        bad_b = np.count_nonzero(contradicts_back(back) & ~hit_b) if contradicts_back is not None else 0
        shift = float(np.linalg.norm(se2_apply(pose, cs[None])[0] - cs))
        return ((explained_b - bad_b) / dst.shape[0] + (explained_a - bad) / src.shape[0]) - 1e-3 * shift

    # the best hypotheses of each turn are refined: a turn whose raw placements all sit a little off
    # (an L of a couch's front and side in A, its front alone in B: no leg pairing lines them up)
    # may still refine to the best motion of all, and must not lose its place to other turns'
    axes_b = np.linalg.svd(dst - cd, full_matrices=False)[2] if dst.shape[0] >= 2 else None  # once, for every turn
    hyps = []
    for turn in tuple(turns) + _leg_pair_turns(legs_a, legs_b, 2.0 * res, turns):
        c, s_ = math.cos(turn), math.sin(turn)
        rot = np.array([[c, -s_], [s_, c]])
        at_turn = []
        for t in [cd - rot @ cs] + [lb - rot @ la for la in legs_a for lb in legs_b] + _end_shifts(src @ rot.T, dst,
                                                                                                 axes_b):
            pose = np.array([t[0], t[1], turn])
            at_turn.append((score(pose), pose))
        at_turn.sort(key=lambda h: -h[0])
        hyps += [(sc, pose, rank) for rank, (sc, pose) in enumerate(at_turn)]
    hyps.sort(key=lambda h: -h[0])
    # (that it stayed is the motion the refined ones must beat: ICP of two unlike sets of cells may carry
    # every hypothesis off)
    best, best_score = np.zeros(3), score(np.zeros(3))
    for i, (_, pose, rank) in enumerate(hyps):
        if i >= 6 and rank >= _REFINED_PER_TURN:
            continue
        refined, _ = _icp(src, dst, pose)
        sc = score(refined)
        if sc > best_score + 1e-9:
            best, best_score = refined, sc
    return best


def _end_shifts(src: NDArray[np.float64], dst: NDArray[np.float64],
                axes: NDArray[np.float64] | None) -> list[NDArray[np.float64]]:
    """Shifts that line up the ends of ``src`` with those of ``dst`` along ``dst``'s long axis
    (``axes``: its principal axes, rows; None for fewer than two cells), its centroids across it: a
    face seen whole in both sessions, a couch's front, whose centroids do not correspond when one
    session also saw a side of it. ICP slides such faces along their length."""
    if axes is None or src.shape[0] < 2:
        return []
    u, v = axes[0], axes[1]
    ps, pd = src @ u, dst @ u
    across = float(dst.mean(axis=0) @ v - src.mean(axis=0) @ v)
    return [float(pd.min() - ps.min()) * u + across * v, float(pd.max() - ps.max()) * u + across * v]


#: raw motion hypotheses refined by ICP: the best six of all, and the best two of each candidate turn
_REFINED_PER_TURN = 2


def _reference_point(src: NDArray[np.float64], dst: NDArray[np.float64], motion: NDArray[np.float64]
                     ) -> NDArray[np.float64]:
    """Where the object is in A, from what both sessions saw of it: the centre of the smallest box
    around A's cells and B's cells carried back by the inverse motion (more legs than either alone)."""
    both = np.concatenate([src, se2_apply(se2_inverse(motion), dst)]).astype(np.float32)
    if both.shape[0] < 3:
        return both.mean(axis=0).astype(np.float64)
    (cx, cy), _, _ = cv2.minAreaRect(both)
    return np.array([cx, cy], np.float64)


def _arc_centre(cells: NDArray[np.intp], spec: GridSpec, max_radius: float) -> tuple[NDArray[np.float64], float] | None:
    """The centre and radius of the circle an object's cells lie on, when they are one arc (gaps of
    a cell bridged: a pot, a bin, a round pedestal seen from one side) that fits a circle to 0.75 cell RMS and spans a
    quarter turn or more; None otherwise (legs, faces, blobs). The middle of what one session saw of a
    round object lies toward where it looked from: the centre does not."""
    if cells.shape[0] < 6:
        return None
    r0, c0 = cells.min(axis=0)
    img = np.zeros(tuple(cells.max(axis=0) - (r0, c0) + 3), bool)
    img[cells[:, 0] - r0 + 1, cells[:, 1] - c0 + 1] = True
    # one piece, gaps of a cell bridged (a thin rim crossing a turned grid skips cells); legs stand
    # farther apart
    if ndimage.label(ndimage.binary_dilation(img, np.ones((3, 3), bool)), structure=np.ones((3, 3), bool))[1] != 1:
        return None
    xy = _cells_xy(cells, spec)
    m = xy.mean(axis=0)
    u = xy - m  # Kasa's fit: |p - c|^2 = r^2 as linear least squares in (c, r^2 - |c|^2)
    a = np.column_stack([2.0 * u, np.ones(len(u))])
    sol, *_ = np.linalg.lstsq(a, np.sum(u * u, axis=1), rcond=None)
    centre = sol[:2]
    radius_sq = float(sol[2] + centre @ centre)
    if radius_sq <= 0.0:
        return None
    # Kasa's fit shrinks the circle of a short noisy arc: a few geometric Gauss-Newton steps from it
    radius = math.sqrt(radius_sq)
    for _ in range(10):
        diff = u - centre
        d = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
        jac = np.column_stack([-diff / d[:, None], -np.ones(len(d))])
        step, *_ = np.linalg.lstsq(jac, -(d - radius), rcond=None)
        centre, radius = centre + step[:2], radius + float(step[2])
        if float(np.abs(step).max()) < 1e-5:
            break
    d = np.linalg.norm(u - centre, axis=1)
    if not 2.0 * spec.resolution <= radius <= max_radius:
        return None
    if float(np.sqrt(np.mean((d - radius) ** 2))) > 0.75 * spec.resolution:
        return None
    ang = np.sort(np.arctan2(u[:, 1] - centre[1], u[:, 0] - centre[0]))
    gaps = np.diff(np.r_[ang, ang[0] + 2.0 * math.pi])
    if 2.0 * math.pi - float(gaps.max()) < math.pi / 2:  # the arc spans under a quarter turn
        return None
    return centre + m, radius


def _lookup(img: NDArray[np.bool_], spec: GridSpec, xy: NDArray[np.float64], outside: bool = False
            ) -> NDArray[np.bool_]:
    """``img`` (on ``spec``'s grid) at the points ``xy`` (m), ``outside`` beyond the grid."""
    res = spec.resolution
    c = np.floor((xy[:, 0] - spec.origin_x) / res).astype(np.intp)
    r = np.floor((xy[:, 1] - spec.origin_y) / res).astype(np.intp)
    ok = (r >= 0) & (r < spec.height) & (c >= 0) & (c < spec.width)
    out = np.full(xy.shape[0], outside)
    out[ok] = img[r[ok], c[ok]]
    return out


def _cells_xy(cells: NDArray[np.intp], spec: GridSpec) -> NDArray[np.float64]:
    return np.stack([spec.origin_x + (cells[:, 1] + 0.5) * spec.resolution,
                     spec.origin_y + (cells[:, 0] + 0.5) * spec.resolution], axis=1).astype(np.float64)


@dataclass
class _MovePart:
    """A moved object's pair of objects, fitted: its class (None: unlabelled), where it was and went
    (A's frame), the motion, what both sessions saw of it in A's place (points, m), the cells it holds in
    B, whether its turn is measurable, and whether it is round (its centres are its circle's)."""

    class_name: str | None
    from_c: NDArray[np.float64]
    to_c: NDArray[np.float64]
    motion: NDArray[np.float64]
    both: NDArray[np.float64]
    cells: int
    turnable: bool
    round_obj: bool


def _join_pairs(items: list[Any], join: Callable[[Any, Any], Any]) -> list[Any]:
    """``items`` with pairs joined while any two join: ``join(a, b)`` gives the one item both are,
    or None. The first pair (in order) that joins is replaced by its join, and the search starts again."""
    out = list(items)
    joined = True
    while joined:
        joined = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                both = join(out[i], out[j])
                if both is not None:
                    out[i] = both
                    del out[j]
                    joined = True
                    break
            if joined:
                break
    return out


def _half_turns(part: _MovePart) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A part's motion, and the one that takes its place to the same place turned by a further half
    turn: a pair of legs, a box, fits itself either way, and the fit of each part alone may pick
    either."""
    yaw = float(wrap_angle(part.motion[2] + math.pi))
    c, s_ = math.cos(yaw), math.sin(yaw)
    t = part.to_c - np.array([[c, -s_], [s_, c]]) @ part.from_c
    return part.motion, np.array([t[0], t[1], yaw])


def _same_motion(mp: NDArray[np.float64], mq: NDArray[np.float64], p: _MovePart, q: _MovePart, res: float) -> bool:
    """Two parts moved by one motion: turns within 3°, and each one's place carried by the other's
    motion lands within two cells of where it went."""
    return abs(float(wrap_angle(mp[2] - mq[2]))) <= math.radians(3.0) and \
        float(np.linalg.norm(se2_apply(mp, q.from_c[None])[0] - q.to_c)) <= 2 * res and \
        float(np.linalg.norm(se2_apply(mq, p.from_c[None])[0] - p.to_c)) <= 2 * res


def _one_motion(parts: list[_MovePart], size_of: Callable[[str], float], res: float) -> list[_MovePart]:
    """Moves of parts of one object joined: two moves of one class by the same motion (each one's
    place carried by the other's motion lands within two cells of where it went, turns within 3°)
    whose parts together are no longer than 1.5 times the class's objects are one object, which its
    builds split (a 2.7 m table is two objects of a class 2 m long). Its place is the middle of the
    box around both parts. Two chairs side by side moved alike stay two: together they are twice a
    chair's length."""
    def join(p: _MovePart, q: _MovePart) -> _MovePart | None:
        if p.class_name is None or p.class_name != q.class_name or p.round_obj or q.round_obj:
            return None
        motion = next((mp for mp in _half_turns(p) for mq in _half_turns(q) if _same_motion(mp, mq, p, q, res)), None)
        if motion is None:
            return None
        both = np.concatenate([p.both, q.both])
        rect = cv2.minAreaRect(both.astype(np.float32))
        if max(rect[1]) > 1.5 * float(size_of(p.class_name)) + res:
            return None
        from_c = np.asarray(rect[0], np.float64)
        return _MovePart(p.class_name, from_c, se2_apply(motion, from_c[None])[0], motion, both, p.cells + q.cells,
                         p.turnable or q.turnable, False)

    return _join_pairs(parts, join)


def _box_turn(yaw_a: float, yaw_b: float) -> float:
    """The turn between two boxes' headings, taken the short way: a box looks the same turned by 180°."""
    d = float(wrap_angle(yaw_b - yaw_a))
    if d > math.pi / 2:
        d -= math.pi
    elif d < -math.pi / 2:
        d += math.pi
    return d


def _candidate_turns(yaw_a: float, yaw_b: float) -> tuple[float, ...]:
    """The turns a fit of two boxes tries: none and the turn between their headings (:func:`_box_turn`),
    each also by quarter and half turns (a box looks alike turned half way round, a square one a
    quarter)."""
    box = _box_turn(yaw_a, yaw_b)
    return tuple(base + q for base in (0.0, box) for q in (0.0, math.pi / 2, -math.pi / 2, math.pi))


def _match_objects(objs_a: list[_Obj], objs_b: list[_Obj], st: ChangeSettings
                   ) -> tuple[list[tuple[int, int]], list[int], list[int]]:
    """Pairs (index in A, index in B) of the same object, then A's and B's unmatched objects."""
    pairs: list[tuple[int, int]] = []
    used_a: set[int] = set()
    used_b: set[int] = set()
    for cls in sorted({o.src.class_name for o in objs_a} | {o.src.class_name for o in objs_b}):
        ia = [i for i, o in enumerate(objs_a) if o.src.class_name == cls]
        ib = [j for j, o in enumerate(objs_b) if o.src.class_name == cls]
        if not ia or not ib:
            continue
        ca = np.stack([objs_a[i].centroid for i in ia])
        cb = np.stack([objs_b[j].centroid for j in ib])
        dist = np.linalg.norm(ca[:, None, :] - cb[None, :, :], axis=2)
        # by class and distance only: what a session saw of one object (two legs of a bed, or four) can
        # differ by more than any size test would allow
        cost = np.where(dist <= st.max_move_m, dist, 1e6)
        ra, rb = linear_sum_assignment(cost)
        for x, y in zip(ra, rb, strict=True):
            if cost[x, y] < 1e6:
                pairs.append((ia[x], ib[y]))
                used_a.add(ia[x])
                used_b.add(ib[y])
    return (pairs, [i for i in range(len(objs_a)) if i not in used_a],
            [j for j in range(len(objs_b)) if j not in used_b])


def _misnamed(objs_a: list[_Obj], only_a: list[int], objs_b: list[_Obj], only_b: list[int], spec: GridSpec,
              st: ChangeSettings, size_of: Callable[[str], float]) -> list[tuple[int, int, str]]:
    """Moves of an object one session's camera named wrongly (a pot under a bed's mask, a chair labelled
    table): of A's gone objects ``only_a`` and B's new ones ``only_b`` that no object of their class took,
    pairs of different classes that :func:`_unlabelled_moves`'s shape test says are one object (lengths
    within 30 %, at most ``max_move_m`` apart, ``unlabelled_fit`` of each one's cells and ``min_fit_legs``
    legs laid on the other's, or arcs of one circle), the pairs that move least in all; each with the
    class whose typical size (``size_of``) is nearer the object's, the more often seen on a tie."""
    res = spec.resolution

    def box(o: _Obj) -> tuple[NDArray[np.float64], float, float, float] | None:
        return _piece_box(o.cells, spec) if o.cells.shape[0] >= 3 else None

    ba = {i: box(objs_a[i]) for i in only_a}
    bb = {j: box(objs_b[j]) for j in only_b}
    cands: list[tuple[int, int, float]] = []
    for i, pa in ba.items():
        for j, pb in bb.items():
            if pa is None or pb is None or objs_a[i].src.class_name == objs_b[j].src.class_name:
                continue
            if max(pa[1], pb[1]) > st.max_object_m or abs(pa[1] - pb[1]) > 0.3 * max(pa[1], pb[1]) + 2 * res:
                continue
            d = float(np.linalg.norm(pa[0].mean(axis=0) - pb[0].mean(axis=0)))
            if d > st.max_move_m:
                continue
            q, legs, _ = _shape_fit(pa[0], pb[0], _candidate_turns(pa[3], pb[3]), res)
            if q < st.unlabelled_fit:
                continue
            if legs < st.min_fit_legs and not _same_arc(_piece_arc(objs_a[i].cells, pa[1], spec),
                                                        _piece_arc(objs_b[j].cells, pb[1], spec)):
                continue
            cands.append((i, j, d))
    if not cands:
        return []
    ia, jb = sorted({i for i, _, _ in cands}), sorted({j for _, j, _ in cands})
    cost = np.full((len(ia), len(jb)), 1e6)
    for i, j, d in cands:
        cost[ia.index(i), jb.index(j)] = d
    out = []
    for x, y in zip(*linear_sum_assignment(cost), strict=True):
        if cost[x, y] >= 1e6:
            continue
        oa, ob = objs_a[ia[x]], objs_b[jb[y]]
        length = max(*oa.src.size, *ob.src.size, res)

        def misfit(o: _Obj, length: float = length) -> tuple[float, int]:
            typical = float(size_of(o.src.class_name))
            return abs(math.log(length / typical)) if typical > 0 else math.inf, -o.src.views

        out.append((ia[x], jb[y], min(oa, ob, key=misfit).src.class_name))
    return out


def _slid(objs_a: list[_Obj], objs_b: list[_Obj], removed: NDArray[np.bool_], added: NDArray[np.bool_],
          still_a: NDArray[np.bool_], still_b: NDArray[np.bool_], seen_by_b: NDArray[np.bool_],
          seen_by_a: NDArray[np.bool_]) -> list[tuple[_Obj, _Obj]]:
    """Pairs of objects that slid by less than their own size. Of ``objs_a`` (A's objects not matched
    yet), those with two or more cells removed (B saw floor there), a quarter or more of their cells
    that B observed (``seen_by_b``) with no obstacle of B within the tolerance (``still_a``); each
    with the nearest object of its class in ``objs_b`` (B's unmatched ones) within the larger one's
    length that has as much added (A saw floor there). One session's evidence alone is not enough: a
    leg the other session did not see is no move. Cells the other session did not observe say
    nothing: a couch pushed along its wall hides most of where it stood behind its new self."""

    def moved_share(o: _Obj, changed: NDArray[np.bool_], still: NDArray[np.bool_], seen: NDArray[np.bool_]
                    ) -> float:
        r, c = o.cells[:, 0], o.cells[:, 1]
        n = int(np.count_nonzero(changed[r, c]))
        return n / max(1, int(np.count_nonzero(seen[r, c] & ~still[r, c]))) if n >= 2 else 0.0

    out = []
    used: set[int] = set()
    for oa in objs_a:
        if moved_share(oa, removed, still_a, seen_by_b) < 0.25:
            continue
        best, best_d = None, math.inf
        for ob in objs_b:
            if id(ob) in used or ob.src.class_name != oa.src.class_name:
                continue
            d = float(np.linalg.norm(ob.centroid - oa.centroid))
            if d <= max(*oa.src.size, *ob.src.size) and d < best_d \
                    and moved_share(ob, added, still_b, seen_by_a) >= 0.25:
                best, best_d = ob, d
        if best is not None:
            used.add(id(best))
            out.append((oa, best))
    return out


def _slid_unlabelled(objs: list[_Obj], others: list[_Obj], own_changed: NDArray[np.bool_],
                     other_changed: NDArray[np.bool_], other_plain: NDArray[np.bool_], spec: GridSpec,
                     st: ChangeSettings, in_a: bool) -> list[tuple[_Obj, _Obj]]:
    """Objects that slid by less than their length where the other session's camera labelled nothing.
    Each of ``objs`` (one session's objects neither gone nor new nor paired) with no object of its class
    in the other session within their lengths, a face of it (``face_m``) on floor the other session saw
    (``own_changed``), and, grown from the other session's plain obstacles on its cells
    (``other_plain``) through that session's changed cells (``other_changed``: obstacles where this
    session saw floor), a new face as long: the other end is those obstacles, as an object of its class.
    A couch pushed along its wall keeps most of its outline on the other session's and shows one new
    end; a new chair standing apart from it is not reached. Pairs are (A's, B's)."""
    res = spec.resolution
    out: list[tuple[_Obj, _Obj]] = []
    used = np.zeros(spec.shape, bool)
    for o in objs:
        if not o.src.class_name or o.cells.shape[0] < 3:
            continue
        length = max(*o.src.size)
        if any(ob.src.class_name == o.src.class_name
               and float(np.linalg.norm(ob.centroid - o.centroid)) <= length + max(*ob.src.size) for ob in others):
            continue
        if not _long_pieces(o, own_changed, spec, st.face_m).any():
            continue
        steps = int(math.ceil(length / res))
        # all of it happens within the growth's reach of the object: work on that window of the grid
        m = steps + 4
        r0, c0 = max(int(o.cells[:, 0].min()) - m, 0), max(int(o.cells[:, 1].min()) - m, 0)
        win = (slice(r0, int(o.cells[:, 0].max()) + m + 1), slice(c0, int(o.cells[:, 1].max()) + m + 1))
        plain = other_plain[win] & ~used[win]
        own = o.cells - (r0, c0)
        on = _cells_near(plain, own, 1.0)
        if on.shape[0] < 3:
            continue
        seed = np.zeros(plain.shape, bool)
        seed[on[:, 0], on[:, 1]] = True
        # (through its plain obstacles by the object too: the band within the tolerance of the object's
        # end, where the other session's obstacles are no change)
        by = _cells_near(plain, own, st.tolerance_m / res + 2.0)
        bridge = np.zeros(plain.shape, bool)
        bridge[by[:, 0], by[:, 1]] = True
        # (over gaps of a cell: a face resampled into the other grid is dotted)
        changed = other_changed[win] & ~used[win]
        solid = changed | bridge | seed
        grown = _grow_along(seed, _dilate(solid, 1.0), steps) & solid
        rr, cc = np.nonzero(grown & changed)
        if rr.size < 2 or res * (max(np.ptp(rr), np.ptp(cc)) + 1) < st.face_m:
            continue
        cells = (np.argwhere(grown) + (r0, c0)).astype(np.intp)
        if res * float(np.ptp(cells, axis=0).max()) > 1.3 * length + 2 * res:
            continue  # larger than the object: something else
        used[win] |= grown
        twin = _piece_object(cells, o.src.class_name, spec)
        out.append((o, twin) if in_a else (twin, o))
    return out


def _pieces(changed: NDArray[np.bool_], spec: GridSpec, group_cells: float) -> list[NDArray[np.intp]]:
    """The cells (n, 2) row, col of each piece of ``changed`` as :func:`_component_changes` joins them
    (cells up to ``group_cells`` apart: the legs of a table are one piece)."""
    _, _, lab, ids = _component_changes(changed, spec, "", group_cells, 1)
    out = []
    slices = ndimage.find_objects(lab)
    for k in ids:
        sl = slices[k - 1]
        if sl is not None:
            r, c = np.nonzero(lab[sl] == k)
            out.append(np.stack([r + sl[0].start, c + sl[1].start], axis=1).astype(np.intp))
    return out


def _long_pieces(o: _Obj, changed: NDArray[np.bool_], spec: GridSpec, min_length: float) -> NDArray[np.bool_]:
    """The pieces of ``changed`` on object ``o``'s cells (8-connected) that reach ``min_length`` (m) along
    a grid axis: faces, not a leg's cell or two."""
    own = np.zeros(spec.shape, bool)
    own[o.cells[:, 0], o.cells[:, 1]] = True
    lab, _ = ndimage.label(changed & own, np.ones((3, 3), bool))
    out = np.zeros(spec.shape, bool)
    for k, sl in enumerate(ndimage.find_objects(lab), 1):
        if sl is not None and spec.resolution * max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) >= min_length:
            out[sl] |= lab[sl] == k
    return out


def _piece_box(cells: NDArray[np.intp], spec: GridSpec) -> tuple[NDArray[np.float64], float, float, float]:
    """A piece's cell centres, and the length, width and heading of the smallest box around them."""
    xy = _cells_xy(cells, spec)
    _, (w, h), ang = cv2.minAreaRect(xy.astype(np.float32))
    yaw = math.radians(ang) if w >= h else math.radians(ang) + math.pi / 2
    return xy, float(max(w, h)), float(min(w, h)), float(wrap_angle(yaw))


def _piece_object(cells: NDArray[np.intp], class_name: str, spec: GridSpec) -> _Obj:
    """A piece of changed cells as an object (no footprint: its cells are what was seen of it)."""
    xy, length, width, yaw = _piece_box(cells, spec)
    c = xy.mean(axis=0)
    res = spec.resolution
    return _Obj(SemiStaticObject(class_name, (float(c[0]), float(c[1])), (length + res, width + res), yaw,
                                 int(cells.shape[0])), c, yaw, np.zeros((0, 2)), cells)


def _shape_fit(src: NDArray[np.float64], dst: NDArray[np.float64], turns: tuple[float, ...], res: float,
               hidden_a: Any = None, hidden_b: Any = None, min_legs: int = 0) -> tuple[float, int, bool]:
    """How well one set of cells fits another by a rigid motion (for cells no camera labelled: only
    their shape says they are one object): the smaller share of either set's cells the best motion
    lays within 1.6 cells of the other's, and the fewer legs of either set it lays on a leg of the
    other (within two cells); and whether the legs count those hidden (below).

    ``hidden_a`` / ``hidden_b`` (``(xy) -> bool mask``: session A's / B's obstacles), used when the
    plain fit has fewer than ``min_legs`` legs: a cell of one set the motion lays on the other
    session's obstacles, not on the other set, is explained too: a leg that stood against a wall there,
    which that session's map holds as part of the wall. When two or more legs of each set lie on legs
    of the other, and every leg of the set given no obstacles does, the legs are then those of the set
    with more, each on a leg of the other or on its obstacles (two legs of a chair by a wall in A, which
    are four legs in B, the other two on A's wall). The fit with hidden legs is returned when it has
    ``min_legs`` legs."""
    tol = 1.6 * res
    legs_a, legs_b = _legs(src, tol), _legs(dst, tol)

    def fit(ha: Any, hb: Any) -> tuple[float, int, int, bool]:
        motion = _fit_motion(src, dst, turns, res, None, ha, hb)
        moved, back = se2_apply(motion, src), se2_apply(se2_inverse(motion), dst)
        hit_src = cKDTree(dst).query(moved)[0] <= tol
        hit_dst = cKDTree(src).query(back)[0] <= tol
        if hb is not None:
            hit_src = hit_src | hb(moved)
        if ha is not None:
            hit_dst = hit_dst | ha(back)
        q = min(float(np.mean(hit_src)), float(np.mean(hit_dst)))
        legs_a_moved, legs_b_back = se2_apply(motion, legs_a), se2_apply(se2_inverse(motion), legs_b)
        on_b = cKDTree(legs_b).query(legs_a_moved)[0] <= 2 * res
        on_a = cKDTree(legs_a).query(legs_b_back)[0] <= 2 * res
        direct = int(min(on_b.sum(), on_a.sum()))
        if ha is None and hb is None:
            return q, direct, direct, True
        hid_src = hb(legs_a_moved) & ~on_b if hb is not None else np.zeros(on_b.shape, bool)
        hid_dst = ha(legs_b_back) & ~on_a if ha is not None else np.zeros(on_a.shape, bool)
        # the set whose legs no obstacle hides has every leg on a leg of the other
        whole = bool(on_b.all()) if ha is not None else True
        whole &= bool(on_a.all()) if hb is not None else True
        return q, direct, int(max(on_b.sum() + hid_src.sum(), on_a.sum() + hid_dst.sum())), whole

    q, legs, _, _ = fit(None, None)
    if legs >= min_legs or (hidden_a is None and hidden_b is None):
        return q, legs, False
    q_h, direct, legs_h, whole = fit(hidden_a, hidden_b)
    if direct >= 2 and whole and legs_h >= min_legs:
        return q_h, legs_h, True
    return q, legs, False


def _unlabelled_partners(objs: list[_Obj], pieces: list[NDArray[np.intp]], spec: GridSpec, st: ChangeSettings,
                         objects_in_a: bool, other_obstacles: NDArray[np.bool_] | None = None,
                         own_walls: NDArray[np.bool_] | None = None, piece_walls: NDArray[np.bool_] | None = None,
                         own_changed: NDArray[np.bool_] | None = None
                         ) -> tuple[list[tuple[_Obj, _Obj]], set[int], set[int]]:
    """Moves whose other end the camera did not label: each object of ``objs`` (gone from A, or new
    in B, with no object of its class to match) paired with a piece of the other session's changed
    cells that are no object (``pieces``: B's added, or A's removed) of about its size, within
    ``max_move_m``, when a rigid motion lays at least ``unlabelled_fit`` of each one's cells on the
    other's and ``min_fit_legs`` legs or more of each on the other's (a chair's four legs on four
    legs; one or two legs fit any blob), or both are arcs of circles of one radius (a pot, seen as its
    rim). The piece becomes an object of the same class. Pairs are (A's, B's).

    An object moved by less than its own size may put legs where legs of its own stood: those are
    no change, so the piece holds only the others (two of a chair's four). ``other_obstacles`` (the
    other session's obstacles, on the common grid): for a piece within one object length, its cells
    on the object's own cells join the piece. ``own_walls`` (the objects' session's obstacles grown by
    the fit's tolerance, on the common grid): legs of the piece that the motion lays on them are
    explained (:func:`_shape_fit`): a chair that stood with two legs against a wall, which that session
    saw as two legs and a wall. ``piece_walls`` (the pieces' session's obstacles, grown alike): when
    that fit has too few legs, the object's legs the motion lays on them are explained instead, every
    leg of the piece still on a leg of the object: a table that stood along a wall, of which the
    piece's session saw two legs and a wall. A piece is also taken with the other pieces within the
    object's length of it (up to four): a table's legs stand further apart than pieces are joined.
    ``own_changed`` (the objects' session's changed cells): when the whole object does not fit, its
    changed cells alone, ``min_fit_legs`` legs or more, may fit the piece alone: the legs of a chair
    that stayed, which the build grouped with the bed that moved, are the bed's unchanged cells. Such
    an object is paired as its changed cells alone (an object of its own).
    Also returns the ids of the pieces' objects paired through hidden legs, and those of the objects
    of ``objs`` paired (whole or by a part)."""
    res = spec.resolution
    hidden_a = hidden_b = None
    if own_walls is not None:
        lookup = functools.partial(_lookup, own_walls, spec)
        hidden_a, hidden_b = (lookup, None) if objects_in_a else (None, lookup)
    piece_hidden: tuple[Any, Any] | None = None
    if piece_walls is not None:
        lookup = functools.partial(_lookup, piece_walls, spec)
        piece_hidden = (None, lookup) if objects_in_a else (lookup, None)
    out: list[tuple[_Obj, _Obj]] = []
    used: set[int] = set()
    through_hidden: set[int] = set()
    paired: set[int] = set()
    for o in objs:
        if o.cells.shape[0] < 2:
            continue
        oxy = _cells_xy(o.cells, spec)
        length = max(*o.src.size, float(np.ptp(oxy, axis=0).max()))
        own = _cells_near(other_obstacles, o.cells, 1.5) if other_obstacles is not None else None
        o_tree = cKDTree(oxy) if own is not None and own.shape[0] else None
        best, best_cells, best_hidden, best_part = None, None, False, False
        best_rank = (False, 0.0)  # (a fit with no legs excused, its share)
        o_arc: tuple[float | None] | None = None  # the object's arc radius, fitted when first needed
        max_len = 1.3 * length + 2 * res  # (a piece longer than the object is something else)
        # (the object's changed cells, when some of it did not change: what moved, if the rest stayed)
        mxy = None
        if own_changed is not None:
            part = own_changed[o.cells[:, 0], o.cells[:, 1]]
            if 2 <= part.sum() < part.size:
                mxy, m_cells = oxy[part], o.cells[part]
                if _legs(mxy, 1.6 * res).shape[0] < st.min_fit_legs:
                    mxy = None
        for ks, piece in _piece_groups(pieces, used, oxy, length, st.max_move_m, spec):
            if piece.shape[0] < 2:
                continue
            cells, by_part = piece, False
            if o_tree is not None and own is not None and \
                    float(o_tree.query(_cells_xy(piece, spec))[0].min()) <= length:
                cells = np.unique(np.concatenate([piece, own]), axis=0)
            pxy, p_len, _, p_yaw = _piece_box(cells, spec)
            if p_len > max_len and cells is not piece:
                # (the other session's obstacles on the object's cells are a wall it stood by, not legs
                # of its own: the piece alone)
                cells = piece
                pxy, p_len, _, p_yaw = _piece_box(cells, spec)
            q, legs, by_hidden = 0.0, 0, False
            # (not farther than a move, nor larger than the object)
            if float(np.linalg.norm(pxy.mean(axis=0) - oxy.mean(axis=0))) <= st.max_move_m \
                    and p_len <= max_len:
                src, dst = (oxy, pxy) if objects_in_a else (pxy, oxy)
                turns = _candidate_turns(o.yaw, p_yaw) if objects_in_a else _candidate_turns(p_yaw, o.yaw)
                q, legs, by_hidden = _shape_fit(src, dst, turns, res, hidden_a, hidden_b, st.min_fit_legs)
                if legs < st.min_fit_legs and piece_hidden is not None:
                    # or the piece's own session holds some of the object's legs in its wall: a table that
                    # stood along a wall, whose two far legs are all that session saw of it
                    q2, legs2, hid2 = _shape_fit(src, dst, turns, res, piece_hidden[0], piece_hidden[1],
                                                 st.min_fit_legs)
                    if legs2 >= st.min_fit_legs:
                        q, legs, by_hidden = q2, legs2, hid2
            if q < st.unlabelled_fit and mxy is not None:
                # or what changed of the object fits the piece alone, leg for leg (the rest of it stayed)
                pxy, p_len, _, p_yaw = _piece_box(piece, spec)
                if float(np.linalg.norm(pxy.mean(axis=0) - mxy.mean(axis=0))) <= st.max_move_m \
                        and p_len <= max_len:
                    turns = _candidate_turns(o.yaw, p_yaw) if objects_in_a else _candidate_turns(p_yaw, o.yaw)
                    q3, legs3, _ = _shape_fit(mxy, pxy, turns, res) if objects_in_a else \
                        _shape_fit(pxy, mxy, turns, res)
                    if q3 >= st.unlabelled_fit and legs3 >= st.min_fit_legs:
                        q, legs, by_hidden, cells, by_part = q3, legs3, False, piece, True
            # (a fit of legs seen beats one that counts legs the other session's obstacles would hide: a
            # bed's four legs that fit are its place, not one of them that fits with three excused)
            if q < st.unlabelled_fit or (not by_hidden, q) <= best_rank:
                continue
            if legs < st.min_fit_legs:  # no legs to fit: a pot, when both are arcs of one circle
                if o_arc is None:
                    o_arc = (_piece_arc(o.cells, length, spec),)
                if not _same_arc(o_arc[0], _piece_arc(cells, p_len, spec)):
                    continue
            best, best_rank, best_cells, best_hidden, best_part = ks, (not by_hidden, q), cells, by_hidden, by_part
        if best is None and _pole(oxy, st):
            # a pole (a screen's stand, a lamp: one leg at LiDAR height) has no shape to fit: its other end
            # is the one pole-sized piece near it (the nearest, by half again as near as any other)
            o_mid = oxy.mean(axis=0)
            near = sorted((float(np.linalg.norm(_cells_xy(p, spec).mean(axis=0) - o_mid)), k)
                          for k, p in enumerate(pieces) if k not in used and p.shape[0] >= 2
                          and _pole(_cells_xy(p, spec), st))
            near = [d for d in near if d[0] <= st.max_move_m]
            if near and (len(near) == 1 or near[1][0] >= 1.5 * near[0][0]):
                best, best_cells = (near[0][1],), pieces[near[0][1]]
        if best is None or best_cells is None:
            continue
        used.update(best)
        twin = _piece_object(best_cells, o.src.class_name, spec)
        paired.add(id(o))
        if best_part:  # what moved of it: its changed cells, the rest stayed (boxed as they are)
            o = _piece_object(m_cells, o.src.class_name, spec)
        out.append((o, twin) if objects_in_a else (twin, o))
        if best_hidden:
            through_hidden.add(id(twin))
    return out, through_hidden, paired


def _pole(xy: NDArray[np.float64], st: ChangeSettings) -> bool:
    """Whether cells (centres, m) are one pole at LiDAR height: no longer than ``pole_m`` across."""
    return bool(xy.shape[0] >= 1 and float(np.ptp(xy, axis=0).max()) <= st.pole_m)


def _piece_groups(pieces: list[NDArray[np.intp]], used: set[int], oxy: NDArray[np.float64], length: float,
                  max_move: float, spec: GridSpec) -> list[tuple[tuple[int, ...], NDArray[np.intp]]]:
    """The pieces an object may have moved to or from (within ``max_move`` of it, not ``used``): each
    alone, and each with the others within ``length`` (the object's) of it, up to four in all (a table's
    legs, which stand further apart than the pieces' grouping joins)."""
    res = spec.resolution
    centre = oxy.mean(axis=0)
    xys = {k: _cells_xy(p, spec) for k, p in enumerate(pieces) if k not in used}
    near = [k for k, xy in xys.items() if float(np.linalg.norm(xy.mean(axis=0) - centre)) <= max_move + length]
    out: list[tuple[tuple[int, ...], NDArray[np.intp]]] = [((k,), pieces[k]) for k in near]
    trees = {k: cKDTree(xys[k]) for k in near}
    seen: set[tuple[int, ...]] = set()
    for k in near:
        group = tuple(sorted([k] + [j for j in near if j != k and
                                    float(trees[j].query(xys[k])[0].min()) <= length + res]))
        if 1 < len(group) <= 4 and group not in seen:
            seen.add(group)
            out.append((group, np.concatenate([pieces[j] for j in group])))
    return out


def _piece_arc(cells: NDArray[np.intp], length: float, spec: GridSpec) -> float | None:
    """The radius of the circle a piece is an arc of (:func:`_arc_centre`: 90° of a rim or more, so a
    radius at most three quarters of the piece's length), or None when it is no arc."""
    arc = _arc_centre(cells, spec, 0.75 * max(length, spec.resolution))
    return None if arc is None else arc[1]


def _same_arc(radius_a: float | None, radius_b: float | None) -> bool:
    """Two pieces are arcs of circles whose radii differ by at most a quarter."""
    return radius_a is not None and radius_b is not None and \
        abs(radius_a - radius_b) <= 0.25 * max(radius_a, radius_b)


def _cells_near(mask: NDArray[np.bool_], cells: NDArray[np.intp], radius: float) -> NDArray[np.intp]:
    """The cells (n, 2) of ``mask`` within ``radius`` cells of any of ``cells``."""
    r = int(math.floor(radius))
    h, w = mask.shape
    r0, c0 = max(int(cells[:, 0].min()) - r, 0), max(int(cells[:, 1].min()) - r, 0)
    r1, c1 = min(int(cells[:, 0].max()) + r + 1, h), min(int(cells[:, 1].max()) + r + 1, w)
    window = np.zeros((r1 - r0, c1 - c0), bool)
    window[cells[:, 0] - r0, cells[:, 1] - c0] = True
    near = _dilate(window, radius) & mask[r0:r1, c0:c1]
    rr, cc = np.nonzero(near)
    return np.stack([rr + r0, cc + c0], axis=1).astype(np.intp)


def _unlabelled_moves(pieces_a: list[NDArray[np.intp]], pieces_b: list[NDArray[np.intp]],
                      dyn_a: NDArray[np.bool_] | None, dyn_b: NDArray[np.bool_] | None, spec: GridSpec,
                      st: ChangeSettings) -> list[tuple[_Obj, _Obj]]:
    """Moves of furniture neither session's camera labelled: a piece of A's removed cells and one of
    B's added cells (no objects, each at most ``max_object_m`` long, of lengths within 30 % of each
    other and at most ``max_move_m`` apart) onto which a rigid motion lays at least
    ``unlabelled_fit`` of each one's cells and ``min_fit_legs`` of each one's legs (four legs on four
    legs: two people's legs fit each other too), or which are arcs of circles of one radius (a pot,
    a round bin: one blob, no legs, but its rim); of those, the pairs that move least in all. Their
    class is None: an object, of unknown class. A piece whose own cells are a third or more people's
    (``dyn_a``, ``dyn_b``: a person cleaning left in; None: pieces already judged no people) is none."""
    res = spec.resolution

    def usable(cells: NDArray[np.intp], dyn: NDArray[np.bool_] | None) -> bool:
        return cells.shape[0] >= 3 and (dyn is None or float(dyn[cells[:, 0], cells[:, 1]].mean()) < 1.0 / 3.0)

    ba = [_piece_box(c, spec) if usable(c, dyn_a) else None for c in pieces_a]
    bb = [_piece_box(c, spec) if usable(c, dyn_b) else None for c in pieces_b]
    arc_a: dict[int, float | None] = {}  # each piece's arc radius, fitted when first needed
    arc_b: dict[int, float | None] = {}
    cands = []
    for i, pa in enumerate(ba):
        if pa is None or pa[1] > st.max_object_m:
            continue
        for j, pb in enumerate(bb):
            if pb is None or pb[1] > st.max_object_m:
                continue
            if abs(pa[1] - pb[1]) > 0.3 * max(pa[1], pb[1]) + 2 * res:
                continue
            if float(np.linalg.norm(pa[0].mean(axis=0) - pb[0].mean(axis=0))) > st.max_move_m:
                continue
            turns = _candidate_turns(pa[3], pb[3])
            q, legs, _ = _shape_fit(pa[0], pb[0], turns, res)
            if q < st.unlabelled_fit:
                continue
            if legs < st.min_fit_legs:  # a blob with no legs to fit: a pot, when both are arcs of one circle
                if i not in arc_a:
                    arc_a[i] = _piece_arc(pieces_a[i], pa[1], spec)
                if j not in arc_b:
                    arc_b[j] = _piece_arc(pieces_b[j], pb[1], spec)
                if not _same_arc(arc_a[i], arc_b[j]):
                    continue
            cands.append((i, j, float(np.linalg.norm(pa[0].mean(axis=0) - pb[0].mean(axis=0)))))
    if not cands:
        return []
    # of the pairs that fit, the ones that move the least in all (two alike chairs swapped places is
    # less likely than each moved a little)
    cost = np.full((len(pieces_a), len(pieces_b)), 1e6)
    for i, j, d in cands:
        cost[i, j] = d
    out = []
    for i, j in zip(*linear_sum_assignment(cost), strict=True):
        if cost[i, j] < 1e6:
            out.append((_piece_object(pieces_a[i], "", spec), _piece_object(pieces_b[j], "", spec)))
    return out


def _static_moves(changes: list[Change], removed: list[tuple[Change, NDArray[np.intp]]],
                  added: list[tuple[Change, NDArray[np.intp]]], spec: GridSpec, st: ChangeSettings) -> list[Change]:
    """``changes`` with a static change removed and a static change added that are one piece of furniture no
    camera labelled, moved, reported as that move (class None): furniture on legs whose legs the diff found
    only as static changes, a session's cleaning having dropped two of its four as a person's (the leg
    sets of the static changes take such legs back; the moves of unlabelled furniture, judged before them,
    see two legs, too few to fit). ``removed`` / ``added``: the static changes and their cells; the pairs
    are those :func:`_unlabelled_moves` fits (three legs on three, or arcs of one circle), every cell of
    them already a change, so the mask stays as it is."""
    if not removed or not added:
        return changes
    # (static changes are obstacles, no people: the leg sets and the stances judged them)
    pairs = _unlabelled_moves([p for _, p in removed], [p for _, p in added], None, None, spec, st)
    if not pairs:
        return changes
    res = spec.resolution
    gone: set[int] = set()
    for oa, ob in pairs:
        ca = next(c for c, p in removed if p is oa.cells)
        cb = next(c for c, p in added if p is ob.cells)
        src, dst = _cells_xy(oa.cells, spec), _cells_xy(ob.cells, spec)
        motion = _fit_motion(src, dst, _candidate_turns(oa.yaw, ob.yaw), res)
        from_c = _reference_point(src, dst, motion)
        to_c = se2_apply(motion, from_c[None])[0]
        disp = float(np.linalg.norm(to_c - from_c))
        if disp < st.still_m:
            continue
        turn = math.degrees(_box_turn(0.0, float(motion[2]))) if _elongated(oa) and _elongated(ob) else None
        gone |= {id(ca), id(cb)}
        changes.append(Change("object_moved", (float(to_c[0]), float(to_c[1])), cb.area_m2, cb.cells, None,
                              (float(from_c[0]), float(from_c[1])), (float(to_c[0]), float(to_c[1])), disp, turn))
    return [c for c in changes if id(c) not in gone]


def _cell_mask(o: _Obj, spec: GridSpec) -> NDArray[np.bool_]:
    """The floor the object takes: the convex hull of its cells (a bed's four legs and what is
    between them), and its footprint when it has one."""
    m = np.zeros(spec.shape, np.uint8)
    if o.cells.shape[0]:
        hull = cv2.convexHull(o.cells[:, ::-1].astype(np.int32))  # (col, row) points
        cv2.fillConvexPoly(m, hull, 1)
        m[o.cells[:, 0], o.cells[:, 1]] = 1
    if o.footprint.shape[0] >= 3:
        pts = np.round(((o.footprint - [spec.origin_x, spec.origin_y]) / spec.resolution - 0.5) * 16)
        cv2.fillPoly(m, [pts.astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    return m > 0


def _joined(cells: NDArray[np.intp], loose: NDArray[np.bool_], spec: GridSpec, reach: float, limit: float,
            margin: int) -> NDArray[np.intp]:
    """``cells`` (n, 2) with the pieces of ``loose`` (8-connected, within ``margin`` cells of them) that
    come within ``reach`` cells of them, each while the smallest box around the whole stays at most
    ``limit`` m long."""
    if cells.shape[0] == 0 or not loose.any():
        return cells
    r0, c0 = max(0, int(cells[:, 0].min()) - margin), max(0, int(cells[:, 1].min()) - margin)
    r1 = min(spec.height, int(cells[:, 0].max()) + margin + 1)
    c1 = min(spec.width, int(cells[:, 1].max()) + margin + 1)
    win = loose[r0:r1, c0:c1]
    if not win.any():
        return cells
    lab, _ = ndimage.label(win, structure=np.ones((3, 3), bool))
    own = np.zeros(win.shape, bool)
    own[cells[:, 0] - r0, cells[:, 1] - c0] = True
    near = np.unique(lab[_dilate(own, reach) & (lab > 0)])
    out = cells
    for k in near.tolist():
        rr, cc = np.nonzero(lab == k)
        cand = np.unique(np.concatenate([out, np.stack([rr + r0, cc + c0], axis=1)]), axis=0)
        if _piece_box(cand, spec)[1] <= limit:
            out = cand
    return out


def _with_touching(o: _Obj, loose: NDArray[np.bool_], spec: GridSpec, size_of: Any) -> NDArray[np.intp]:
    """The object's cells and the pieces of ``loose`` (changed cells no camera labelled) that touch them
    (within three cells) while the whole stays within 1.3 times the object's length (its class's typical
    one, or what its session saw)."""
    res = spec.resolution
    length = max(*o.src.size, size_of(o.src.class_name) if o.src.class_name else 0.0)
    return _joined(o.cells, loose, spec, 3.0, 1.3 * length + 2 * res, int(math.ceil(1.3 * length / res)) + 3)


def _elongated(o: _Obj) -> bool:
    """A turn is measurable: the object is clearly longer than wide, and more than a few cells."""
    length, width = sorted(o.src.size, reverse=True)
    return o.cells.shape[0] >= 4 and length >= 1.3 * max(width, 1e-3)


#: an object the other session saw less than ``seen_share`` of is still gone (or new) when it saw at
#: least this many of its cells, and 40 % of them, and every one of those was floor
_UNANIMOUS_CELLS = 5


def _changed_objects(objs: list[_Obj], changed: NDArray[np.bool_], still: NDArray[np.bool_],
                     other_observed: NDArray[np.bool_], people: NDArray[np.bool_], st: ChangeSettings,
                     left_out: dict[str, int], key: str, by_wall: NDArray[np.bool_] | None = None,
                     others: list[_Obj] | None = None,
                     kept_legs: tuple[NDArray[np.bool_], NDArray[np.bool_], int, float, NDArray[np.bool_] | None]
                     | None = None,
                     too_long: Callable[[_Obj], bool] | None = None) -> list[_Obj]:
    """The objects most of whose cells changed (``removed`` for A's, ``added`` for B's). A cell with
    an obstacle of the other session within the tolerance (``still``) is there still; one beside
    people (``people``) with none is no evidence either way; nor, for an object with no object of its
    class near it in the other session (``others``: it went, or came, rather than slid), is a cell by
    a wall both sessions see (``by_wall``: this session's obstacles that are in no object, grown by
    the tolerance): a table's back legs against a wall, and the wall behind them its labels bled onto,
    are within the tolerance of the other session's wall whether the table is there or not, so its
    front legs decide (when they are three cells or more and a fifth of it). An object the other
    session did not see enough of is left out (counted under ``key``), never called gone. Nor is one of
    whose legs the other session kept two, and half (``kept_legs``: the other session's legs and small
    obstacles grown by the tolerance, and the most cells a leg has; :func:`_legs_still`)."""
    out = []
    for o in objs:
        if o.cells.shape[0] == 0:
            continue
        r, c = o.cells[:, 0], o.cells[:, 1]
        clear = ~people[r, c] | still[r, c]
        seen = other_observed[r, c] & clear
        # the other session saw enough of it; or saw less, but saw floor on every cell it saw (a pot's
        # rim seen half from its new place: floor where it stood, the rest behind it)
        unanimous = seen.sum() >= _UNANIMOUS_CELLS and float(seen.sum()) >= 0.4 * r.size \
            and bool(changed[r, c][seen].all())
        if clear.sum() < max(2, 0.3 * r.size) or (float(other_observed[r, c][clear].mean()) < st.seen_share
                                                  and not unanimous):
            left_out[key] += 1
            continue
        judged = clear
        if by_wall is not None and not any(
                ob.src.class_name == o.src.class_name
                and float(np.linalg.norm(ob.centroid - o.centroid)) <= max(*o.src.size, *ob.src.size)
                for ob in others or ()):
            judged = clear & ~(by_wall[r, c] & still[r, c])
            if judged.sum() < max(3, 0.2 * r.size):
                judged = clear
        # (of the cells the other session observed: what it never saw says nothing either way; but for
        # an object too long for its class, more than one, which is judged by its parts that changed)
        judged_seen = judged if too_long is not None and too_long(o) else judged & other_observed[r, c]
        if judged_seen.any() and float(changed[r, c][judged_seen].mean()) >= 0.5 and not (
                kept_legs is not None and _legs_still(o, *kept_legs)):
            out.append(o)
    return out


def _legs_still(o: _Obj, kept: NDArray[np.bool_], other_changed: NDArray[np.bool_], leg_cells: int,
                res: float, other_bare: NDArray[np.bool_] | None = None) -> bool:
    """Whether an object of three legs or more (and little else) has two of them, and half, with a leg (or a small
    obstacle) of the other session on them, and the other session changed nothing within the object's
    size of it: it stands there still, and the other map lost its other legs (thin legs that rays
    grazing past cleared, or that beams ended on too seldom). A chair pushed back by its legs' spacing
    puts two legs where two stood, and two new ones beside them. Not when two of the legs the other
    session did not keep stand wholly on its bare floor (``other_bare``, :attr:`Session.bare`): rays
    passed there again and again and none ended, so no leg stood there. A chair turned on the spot puts
    two legs on two of its old places and two on floor that was bare (`random:643`)."""
    cells = o.cells
    groups, legs = _leg_groups(cells, leg_cells)
    if legs.size < 3:
        return False  # (furniture of legs alone: a couch's faces in pieces are no legs)
    held = np.intersect1d(np.unique(groups[kept[cells[:, 0], cells[:, 1]]]), legs)
    if held.size < 2 or held.size < 0.5 * legs.size:
        return False
    if other_bare is not None and _bare_legs(cells, groups, np.setdiff1d(legs, held), other_bare) >= 2:
        return False
    return _cells_near(other_changed, cells, max(*o.src.size, 2 * res) / res).shape[0] < 2


def _legs_beyond(d: NDArray[np.float64], groups: NDArray[np.intp], legs: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Per leg group in ``legs``, whether all its cells lie farther than a cell and a half from another object
    (``d``: each cell's distance to it, in cells; ``groups``: each cell's group)."""
    return np.array([bool((d[groups == g] > 1.5).all()) for g in legs.tolist()], bool)


def _bare_legs(cells: NDArray[np.intp], groups: NDArray[np.intp], legs: NDArray[np.intp],
               bare: NDArray[np.bool_]) -> int:
    """How many of the groups ``legs`` of ``cells`` (per cell its group) lie wholly on ``bare``."""
    on = bare[cells[:, 0], cells[:, 1]]
    return sum(bool(on[groups == g].all()) for g in legs.tolist())


def _leg_groups(cells: NDArray[np.intp], leg_cells: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Per cell (row, col) its 8-connected group, and the groups that are legs (at most ``leg_cells``
    cells each); no legs unless they hold 80 % of the cells (furniture of legs alone, not a face)."""
    if not cells.shape[0]:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    groups = _clusters(cells.astype(np.float64), 1.5)
    sizes = np.bincount(groups)
    legs = np.flatnonzero(sizes <= leg_cells)
    if sizes[legs].sum() < 0.8 * cells.shape[0]:
        legs = legs[:0]
    return groups, legs


def _on_legs(o: _Obj, leg_cells: int) -> bool:
    """Whether the object's cells are legs (two groups or more of a leg's size at most, holding 80 % of
    them): a chair or a table at LiDAR height, not a couch's face."""
    return _leg_groups(o.cells, leg_cells)[1].size >= 2


def _merge_fragments(objs: list[_Obj], size_of: Any, spec: GridSpec) -> list[_Obj]:
    """Join pieces of one object: a build may list a bed as two objects where the other found one.
    Pieces of one class merge while the smallest box around the whole is no longer than that class's
    typical length."""
    def join(a: _Obj, b: _Obj) -> _Obj | None:
        if a.src.class_name != b.src.class_name:
            return None
        cells = np.concatenate([a.cells, b.cells])
        xy = _cells_xy(cells, spec)
        # the long side of the smallest box around both (a square chair's diagonal is longer than its
        # typical length, its side is not)
        _, (w, h), _ = cv2.minAreaRect(xy.astype(np.float32))
        if float(max(w, h)) > 1.1 * size_of(a.src.class_name) + spec.resolution:
            return None
        lo_xy, hi_xy = xy.min(axis=0), xy.max(axis=0)
        return _Obj(a.src, 0.5 * (lo_xy + hi_xy), a.yaw, np.zeros((0, 2)), cells)

    return _join_pairs(objs, join)


def _merge_legs(objs: list[_Obj], leg_cells: int, size_of: Any, spec: GridSpec) -> list[_Obj]:
    """``objs`` with the objects of at most ``leg_cells`` cells (one leg each) joined by class into
    the objects they fit in (:func:`_merge_fragments`); larger objects as they are."""
    legs = [o for o in objs if 0 < o.cells.shape[0] <= leg_cells]
    if len(legs) < 2:
        return objs
    leg_ids = {id(o) for o in legs}
    return [o for o in objs if id(o) not in leg_ids] + _merge_fragments(legs, size_of, spec)


def _component_changes(mask: NDArray[np.bool_], spec: GridSpec, kind: str, group_cells: float,
                       min_cells: int) -> tuple[list[Change], NDArray[np.bool_], NDArray[np.int32], list[int]]:
    """Connected pieces of ``mask`` (cells up to ``group_cells`` apart join), as changes of ``kind``;
    also the cells of the pieces kept, the pieces' label image and each change's label."""
    if not mask.any():
        return [], np.zeros_like(mask), np.zeros(mask.shape, np.int32), []
    joined = _dilate(mask, group_cells / 2.0)
    lab_joined, n = ndimage.label(joined, structure=np.ones((3, 3), bool))
    # the grid is large and the changes few: work on the changed cells only
    rows, cols = np.nonzero(mask)
    ids = lab_joined[rows, cols]
    counts = np.bincount(ids, minlength=n + 1)
    keep_ids = np.flatnonzero(counts >= min_cells)
    keep_ids = keep_ids[keep_ids > 0]
    lab = np.zeros(mask.shape, np.int32)
    lab[rows, cols] = ids
    keep = counts[ids] >= min_cells
    kept = np.zeros_like(mask)
    kept[rows[keep], cols[keep]] = True
    out = []
    if keep_ids.size:
        area = spec.resolution ** 2
        sum_r = np.bincount(ids, weights=rows, minlength=n + 1)
        sum_c = np.bincount(ids, weights=cols, minlength=n + 1)
        for k in keep_ids:
            m = int(counts[k])
            cx = spec.origin_x + (sum_c[k] / m + 0.5) * spec.resolution
            cy = spec.origin_y + (sum_r[k] / m + 0.5) * spec.resolution
            out.append(Change(kind, (float(cx), float(cy)), float(m * area), m))
    return out, kept, lab, [int(k) for k in keep_ids]


def _leg_sets(cells: NDArray[np.bool_], spec: GridSpec, kind: str, span_cells: float, min_legs: int,
              strong: NDArray[np.bool_] | None = None, rect_cells: float = 0.0,
              corners_only: NDArray[np.bool_] | None = None, crowd: NDArray[np.bool_] | None = None,
              crowd_cells: float = 2.0) -> tuple[list[Change], NDArray[np.bool_], NDArray[np.int32], list[int]]:
    """Of ``cells`` (pieces each too small to be a change), the sets of ``min_legs`` blobs or more
    whose centres are joined within ``span_cells``, as :func:`_component_changes` gives pieces; and,
    with ``rect_cells``, first, sets of four at the corners of a rectangle whose sides are at most that
    long (:func:`_rectangles`: a table's or a bed's legs, further apart than a chair's).
    With ``strong`` (where no people were), a set also needs two of its blobs to touch it: two legs by
    people may be a person's two. Blobs of ``corners_only`` alone may complete a rectangle (as blobs
    not strong), never a set joined by span: legs the session's cleaning dropped as a person's; not
    where ``crowd`` (the session's people evidence) has more than one blob beyond those it uses within
    ``crowd_cells`` of the rectangle's corners' circle."""
    none: tuple[list[Change], NDArray[np.bool_], NDArray[np.int32], list[int]] = (
        [], np.zeros_like(cells), np.zeros(cells.shape, np.int32), [])
    if corners_only is not None and rect_cells > 0:
        corners_only = corners_only & ~cells
        cells = cells | corners_only
    else:
        corners_only = None
    blobs, n = ndimage.label(cells, structure=np.ones((3, 3), bool))
    if n < (min(min_legs, 4) if rect_cells > 0 else min_legs):  # (a rectangle has four)
        return none
    rr, cc = np.nonzero(blobs)
    ids = blobs[rr, cc]
    count = np.bincount(ids, minlength=n + 1)[1:].astype(np.float64)
    centres = np.stack([np.bincount(ids, weights=rr, minlength=n + 1)[1:] / count,
                        np.bincount(ids, weights=cc, minlength=n + 1)[1:] / count], axis=1)
    is_strong = np.ones(n, bool) if strong is None else \
        np.bincount(ids, weights=strong[rr, cc], minlength=n + 1)[1:] > 0
    corner_only = np.zeros(n, bool)
    if corners_only is not None:  # (a blob wholly of them; one touching a leg of ``cells`` is that leg)
        corner_only = np.bincount(ids, weights=~corners_only[rr, cc], minlength=n + 1)[1:] == 0
        is_strong &= ~corner_only
    group = np.zeros(n + 1, np.int32)  # blob label -> set id (0: none)
    k = 0
    if rect_cells > 0:  # (first: four corners of a rectangle are the stronger shape)
        for quad in _rectangles(centres, rect_cells, _LEG_RECT_SHORTEST / spec.resolution, 2.0):
            idx = np.asarray(quad, np.intp)
            if int(is_strong[idx].sum()) < 2:
                continue
            used = int(corner_only[idx].sum())
            if used and crowd is not None:
                # (blobs of people evidence in a crowd of them are people: where people walked to and fro,
                # four corners of some rectangle always turn up; a chair's two legs taken for a person's
                # have at most one more such blob by them)
                mid = centres[idx].mean(axis=0)
                reach = float(np.linalg.norm(centres[idx] - mid, axis=1).max()) + crowd_cells
                if _blobs_within(crowd, mid, reach) > used + 1:
                    continue
            k += 1
            group[1:][idx] = k
    left = np.flatnonzero((group[1:] == 0) & ~corner_only)
    if left.size >= min_legs:
        roots = _clusters(centres[left], span_cells)
        for r, c in zip(*np.unique(roots, return_counts=True), strict=True):
            if c >= min_legs and int(is_strong[left[roots == r]].sum()) >= 2:
                k += 1
                group[1:][left[roots == r]] = k
    if k == 0:
        return none
    sets = group[ids]
    lab = np.zeros(cells.shape, np.int32)
    lab[rr, cc] = sets
    m = k + 1
    size = np.bincount(sets, minlength=m)
    sum_r = np.bincount(sets, weights=rr, minlength=m)
    sum_c = np.bincount(sets, weights=cc, minlength=m)
    area = spec.resolution ** 2
    out = [Change(kind, (float(spec.origin_x + (sum_c[k] / size[k] + 0.5) * spec.resolution),
                         float(spec.origin_y + (sum_r[k] / size[k] + 0.5) * spec.resolution)),
                  float(size[k] * area), int(size[k])) for k in range(1, m)]
    return out, lab > 0, lab, list(range(1, m))


def _blobs_within(mask: NDArray[np.bool_], centre: NDArray[np.float64], reach: float) -> int:
    """How many blobs (8-connected) of ``mask`` have their centre within ``reach`` cells of ``centre``
    (row, col)."""
    r = int(math.ceil(reach)) + 1
    h, w = mask.shape
    r0, c0 = max(int(centre[0]) - r, 0), max(int(centre[1]) - r, 0)
    r1, c1 = min(int(centre[0]) + r + 1, h), min(int(centre[1]) + r + 1, w)
    lab, n = ndimage.label(mask[r0:r1, c0:c1], structure=np.ones((3, 3), bool))
    if n == 0:
        return 0
    mids = np.asarray(ndimage.center_of_mass(np.ones_like(lab), lab, range(1, n + 1)), np.float64).reshape(-1, 2)
    mids += (r0, c0)
    return int(np.count_nonzero(np.linalg.norm(mids - centre, axis=1) <= reach))


def _void_people(changed: NDArray[np.bool_], zone: NDArray[np.bool_], on_people: NDArray[np.bool_],
                 st: ChangeSettings, res: float) -> NDArray[np.bool_]:
    """``changed`` less the cells in ``zone`` (near where people were seen) of the pieces that may be
    people: pieces (cells up to ``group_m`` apart) that fit in ``person_m``, or that lie on people
    evidence (``on_people``) for at least ``person_share`` of their cells (a walker's trail). A piece
    larger than a person and mostly away from people is an obstacle, kept whole."""
    hit = changed & zone
    if not hit.any():
        return changed
    lab, _ = ndimage.label(_dilate(changed, st.group_m / res / 2.0), structure=np.ones((3, 3), bool))
    lab = np.where(changed, lab, 0)
    out = changed.copy()
    slices = ndimage.find_objects(lab)
    for k in np.unique(lab[hit]):
        sl = slices[k - 1]
        if sl is None:
            continue
        piece = lab[sl] == k
        rows, cols = np.nonzero(piece)
        extent = math.hypot(float(rows.max() - rows.min()), float(cols.max() - cols.min())) * res
        if extent > st.person_m and float(on_people[sl][piece].mean()) < st.person_share:
            continue  # an obstacle people stood by
        out[sl][piece & zone[sl]] = False
    return out


def _with_legs(o: _Obj, legs: NDArray[np.bool_], spec: GridSpec, size_of: Any) -> _Obj:
    """The object with the pieces of ``legs`` (its session's changed leg-sized obstacles that no camera
    labelled, or that its build gave another object) within its class's typical length of it, while
    the whole stays within 1.1 times that length: a chair whose camera labelled two of its legs, the
    other two seen by the LiDAR alone or grouped with the bed beside it."""
    if not o.src.class_name:
        return o
    res = spec.resolution
    length = float(size_of(o.src.class_name))
    cells = _joined(o.cells, legs, spec, length / res, 1.1 * length + res, int(math.ceil(length / res)) + 1)
    return o if cells.shape[0] == o.cells.shape[0] else _Obj(o.src, o.centroid, o.yaw, o.footprint, cells)


def _small_blobs(occ: NDArray[np.bool_], max_cells: int, join: bool = False) -> NDArray[np.bool_]:
    """Obstacles of at most ``max_cells`` cells (8-connected): legs of furniture, posts, not walls. With
    ``join``, cells a cell apart are one obstacle (a wall resampled into the other map's grid is dotted)."""
    if not occ.any():
        return np.zeros_like(occ)
    lab, n = ndimage.label(_dilate(occ, 1.0) if join else occ, structure=np.ones((3, 3), bool))
    if n == 0:
        return np.zeros_like(occ)
    small = np.bincount(lab[occ], minlength=n + 1) <= max_cells
    small[0] = False
    return np.asarray(small[lab], bool) & occ


def _thin(piece: NDArray[np.bool_]) -> bool:
    """At most two cells thick everywhere (no 3 x 3 block of it): a face, not a body."""
    return not ndimage.binary_erosion(piece, np.ones((3, 3), bool)).any()


def _in_doorway(labels: NDArray[np.int32], slices: list[tuple[slice, slice] | None], k: int,
                walls: NDArray[np.bool_], min_cells: float) -> bool:
    """Whether piece ``k`` is straight, at least ``min_cells`` long, and ``walls`` continue its line
    beyond both its ends (three of the five cells past each end have a wall within a cell): a door
    across a doorway in the other session's wall."""
    sl = slices[k - 1]
    if sl is None:
        return False
    rc = np.argwhere(labels[sl] == k).astype(np.float64) + (sl[0].start, sl[1].start)
    centre = rc.mean(axis=0)
    _, sv, vt = np.linalg.svd(rc - centre, full_matrices=False)
    axis = vt[0]
    along = (rc - centre) @ axis
    if float(np.ptp(along)) + 1.0 < min_cells or (sv.size > 1 and sv[1] / max(sv[0], 1e-9) > 0.2):
        return False
    grown = _dilate(walls[max(0, sl[0].start - 8):sl[0].stop + 8, max(0, sl[1].start - 8):sl[1].stop + 8], 1.5)
    off = np.array([max(0, sl[0].start - 8), max(0, sl[1].start - 8)], np.float64)
    for end in (float(along.min()), float(along.max())):
        sign = 1.0 if end > 0 else -1.0
        pts = centre + np.outer(end + sign * np.arange(1.0, 6.0), axis) - off
        ij = np.round(pts).astype(np.intp)
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < grown.shape[0]) & (ij[:, 1] >= 0) & (ij[:, 1] < grown.shape[1])
        if int(grown[ij[ok, 0], ij[ok, 1]].sum()) < 3:
            return False
    return True


def _strips_along(labels: NDArray[np.int32], slices: list[tuple[slice, slice] | None], ids: list[int],
                  near: NDArray[np.bool_], band_cells: float, max_parts: int | None = None) -> set[int]:
    """The pieces (label ids) at most two cells thick lying, for at least 80 % of their cells, within
    ``band_cells`` of ``near``. Two uses:

    * the far face of a wall the other session saw from one side only (``near``: its obstacles,
      within twice the tolerance). Rays grazing along a wall's face mark it free; the wall is there.
      A door closed in a doorway is not such a strip: most of it is far from the jambs;
    * a face the other session saw only edge-on (``near``: what it never observed, within two cells:
      the inside of a pillar it saw two faces of). Its beams grazed along the face, marking the cells
      on it free at a 5 cm grid; a new wall across floor the other session saw has floor on both sides.
      What it never observed lies along such a face, in one or two pieces (``max_parts``): bands of
      unknown crossing a piece, three or more, are floor the other session saw in stripes between
      rays fanning out far away, and the piece (a new cabinet standing there) is a change.
    """
    if not ids:
        return set()
    out = set()
    m = int(math.ceil(band_cells)) + 1  # the band around a piece, from ``near`` this far around it
    h, w = labels.shape
    for k in ids:
        sl = slices[k - 1]
        if sl is None:
            continue
        piece = labels[sl] == k
        if not _thin(piece):
            continue
        r0, c0 = max(0, sl[0].start - m), max(0, sl[1].start - m)
        win = near[r0:min(h, sl[0].stop + m), c0:min(w, sl[1].stop + m)]
        around = _dilate(win, band_cells)
        band = around[sl[0].start - r0:sl[0].stop - r0, sl[1].start - c0:sl[1].stop - c0]
        if float(band[piece].mean()) < 0.8:
            continue
        if max_parts is not None:
            own = np.zeros(around.shape, bool)
            own[sl[0].start - r0:sl[0].stop - r0, sl[1].start - c0:sl[1].stop - c0] = piece
            beside = win & _dilate(own, band_cells)
            # (a cell's gap bridged: a band rasterised from another map's turned grid breaks up)
            if ndimage.label(_dilate(beside, 1.5), structure=np.ones((3, 3), bool))[1] > max_parts:
                continue
        out.add(k)
    return out


def classify_changes(a: Session, b: Session, lo: LaidOut, T_a_b: NDArray[np.float64],
                     st: ChangeSettings | None = None) -> tuple[list[Change], NDArray[np.uint8], dict[str, int]]:
    """The changes from A to B on the common grid ``lo``: the list, the change mask on the common
    grid (0 none, 1 added, 2 removed) and counts of what was left out (objects only one session saw)."""
    st = st or ChangeSettings()
    spec = lo.spec
    res = spec.resolution
    tol = st.tolerance_m / res
    people = _dilate(lo.dyn_a | lo.dyn_b, st.people_margin_m / res)
    # a leg of furniture the session flagged movable is not a person, even where people stood beside it
    semi_a, semi_b = lo.semi_a & lo.occ_a, lo.semi_b & lo.occ_b
    # furniture is matched at a finer tolerance than walls: a chair's legs 10 cm from a wall are
    # not the wall (the alignment is good to a cell)
    fine = min(tol, 1.0)
    leg_cells = max(1, int(round(st.leg_m2 / (res * res))))  # the most cells a leg of furniture has
    # a faint obstacle (a thin leg the map lost to rays grazing past it) is an obstacle here: the
    # session saw something stand there
    obst_a = lo.occ_a if lo.faint_a is None else lo.occ_a | lo.faint_a
    obst_b = lo.occ_b if lo.faint_b is None else lo.occ_b | lo.faint_b
    wide_a, wide_b = _dilate(obst_a, tol), _dilate(obst_b, tol)
    near_a = np.where(semi_b, _dilate(obst_a, fine), wide_a)
    near_b = np.where(semi_a, _dilate(obst_b, fine), wide_b)
    # where either session saw people, an obstacle may be a person the other's cleaning left in (a
    # person standing out of the camera's view has no label of its own): no change. Only for pieces
    # a person could be: a cabinet face a metre long with one person-labelled cell beside it is new
    # A piece as long as a person or longer is a trail of a person the session's own cleaning left in
    # when it lies on that session's people evidence: the other session's walkers, who crossed the place
    # where this session now sees a couch's back, say nothing about what this session saw
    added_raw, removed_raw = lo.occ_b & lo.free_a & ~near_a, lo.occ_a & lo.free_b & ~near_b
    # legs of furniture against a wall, where a session's own map joins them to the wall and the other
    # session's wall is within the tolerance of them (that session saw floor on them): leg-sized pieces
    # of its obstacles on the other session's floor that stand out two cells or more from the other's
    # obstacles (a wall resampled into the other grid is a cell off here and there)
    bumps: dict[bool, NDArray[np.bool_]] = {}

    def bumps_of(in_a: bool) -> NDArray[np.bool_]:
        if in_a not in bumps:
            own_occ, other_free = (lo.occ_a, lo.free_b) if in_a else (lo.occ_b, lo.free_a)
            own_semi, own_dyn, other_obst = (semi_a, lo.dyn_a, obst_b) if in_a else (semi_b, lo.dyn_b, obst_a)
            cand = own_occ & other_free & ~own_semi & ~own_dyn & (wide_b if in_a else wide_a)
            out = np.zeros_like(cand)
            rr, cc = np.nonzero(cand)
            if rr.size:  # (on the candidates' cells only: the grid is large, they are few)
                n, lab, stats, _ = cv2.connectedComponentsWithStats(cand.astype(np.uint8), connectivity=8)
                ids = lab[rr, cc]
                h, w = cand.shape  # (no obstacle of the other session in the 3 x 3 around: 2 cells out)
                far = np.ones(rr.size, bool)
                for dr in (-1, 0, 1):
                    for dc in (-1, 0, 1):
                        far &= ~other_obst[np.clip(rr + dr, 0, h - 1), np.clip(cc + dc, 0, w - 1)]
                keep = (stats[:, cv2.CC_STAT_AREA] <= leg_cells) & (np.bincount(ids[far], minlength=n) > 0)
                keep[0] = False
                sel = keep[ids]
                out[rr[sel], cc[sel]] = True
            bumps[in_a] = out
        return bumps[in_a]

    added = _void_people(added_raw, people & ~semi_b, _dilate(lo.dyn_b, tol), st, res)
    removed = _void_people(removed_raw, people & ~semi_a, _dilate(lo.dyn_a, tol), st, res)
    changes: list[Change] = []
    mask = np.zeros(spec.shape, np.uint8)
    left_out = {"objects_unobserved_in_b": 0, "objects_unobserved_in_a": 0, "cells_near_people": 0,
                "wall_faces": 0, "hidden_faces": 0, "weak_obstacles": 0, "people_stances": 0}
    left_out["cells_near_people"] = int(((lo.occ_b & lo.free_a) | (lo.occ_a & lo.free_b))[people].sum())

    # movable objects: an object whose cells the other session saw free is gone (or new); gone and
    # new ones of one class are matched into moves
    on_objects = np.zeros(spec.shape, bool)
    if a.semantic and b.semantic:
        from ..classes import load_class_table

        sizes = load_class_table()
        near = max(1.0, tol)
        # a build may list each leg of a chair as an object of its own, too small to judge alone: the
        # legs of one class that fit in one object of it are that object
        objs_a = _merge_legs(_objects(a.objects, None, spec, lo.semi_a & lo.occ_a, lo.index_a), leg_cells,
                             sizes.size_of, spec)
        objs_b = _merge_legs(_objects(b.objects, T_a_b, spec, lo.semi_b & lo.occ_b, lo.index_b), leg_cells,
                             sizes.size_of, spec)
        obs_a, obs_b = lo.occ_a | lo.free_a, lo.occ_b | lo.free_b
        # an object's own cells are furniture by its session's labels: cells its own session saw people
        # on are no evidence, nor cells within a cell and a half (the alignment's wobble) of people the
        # other session saw there: its cleaning took this very chair's legs for a person's and dropped
        # them. Only the legs' own cells: a person who stood a step away from where a chair is now does
        # not hide the chair
        people_for_a = lo.dyn_a | _dilate(lo.dyn_b, 1.5)
        people_for_b = lo.dyn_b | _dilate(lo.dyn_a, 1.5)
        # a leg the other session's beams ended on again and again (however many passed it by) may be
        # there still: its map lost a thin leg, which is no evidence the object went
        still_a = near_b if lo.glimpse_b is None else near_b | _dilate(lo.glimpse_b, fine)
        still_b = near_a if lo.glimpse_a is None else near_a | _dilate(lo.glimpse_a, fine)
        # each session's walls, as far as its own map tells: obstacles in no object of it
        wall_a = lo.occ_a & ~lo.semi_a if lo.index_a is None else lo.occ_a & ~lo.semi_a & (lo.index_a < 0)
        wall_b = lo.occ_b & ~lo.semi_b if lo.index_b is None else lo.occ_b & ~lo.semi_b & (lo.index_b < 0)
        wall_a, wall_b = _dilate(wall_a, tol), _dilate(wall_b, tol)
        # the cells each session changed with no obstacle of the other there still
        gone_cells, new_cells = removed & ~still_a, added & ~still_b
        # (and legs the other session kept of it: its legs, or small obstacles, on the object's legs, never
        # its walls: a couch pushed against a wall has its back legs by the wall the other session saw)
        kept_a = _dilate(_small_blobs(obst_b, leg_cells, join=True) | semi_b, fine)
        kept_b = _dilate(_small_blobs(obst_a, leg_cells, join=True) | semi_a, fine)
        def too_long(o: _Obj) -> bool:
            """Longer than one object of its class can be: more than one, grouped by its build."""
            return bool(o.src.class_name) and max(o.src.size) > 1.1 * float(sizes.size_of(o.src.class_name)) + res

        gone = _changed_objects(objs_a, gone_cells, still_a, obs_b, people_for_a, st, left_out,
                                "objects_unobserved_in_b", wall_a, objs_b, (kept_a, added, leg_cells, res, lo.bare_b),
                                too_long)
        new = _changed_objects(objs_b, new_cells, still_b, obs_a, people_for_b, st, left_out,
                               "objects_unobserved_in_a", wall_b, objs_a, (kept_b, removed, leg_cells, res, lo.bare_a),
                               too_long)
        # an object whose legs stand on an unchanged object of its class in the other session is that
        # object, seen more fully by one session (two legs of a chair in A, four in B)
        new_ids = {id(o) for o in new}
        gone, rests_a = _seen_better(gone, [o for o in objs_b if id(o) not in new_ids], too_long, leg_cells,
                                     st.min_fit_legs, lo.bare_b)
        gone_ids = {id(o) for o in gone}
        new, rests_b = _seen_better(new, [o for o in objs_a if id(o) not in gone_ids], too_long, leg_cells,
                                    st.min_fit_legs, lo.bare_a)
        # an object too long for its class (more than one, grouped by its build) most of whose cells did
        # not change may hold one that did: its changed cells, when they are three legs or more of their
        # own (a new table its build grouped with the one beside it that stayed)
        # Nor is one whose labels bled onto the wall beside it, most of whose cells are that wall (on the
        # other session's obstacles in no object): a face of it half a metre long or more that changed
        # is an object of its own (a new cabinet its build joined to the wall its labels bled onto)
        for objs_side, changed_ids, changed_cells, rests, other_wall, face_cells in (
                (objs_a, gone_ids, gone_cells, rests_a, wall_b, removed),
                (objs_b, {id(o) for o in new}, new_cells, rests_b, wall_a, added)):
            for o in objs_side:
                if id(o) in changed_ids or not o.cells.shape[0]:
                    continue
                on = changed_cells[o.cells[:, 0], o.cells[:, 1]]
                part = o.cells[on]
                if too_long(o):
                    # (two cells a leg at least: three stray cells of a pot's rim are no table)
                    if part.shape[0] >= 2 * st.min_fit_legs and \
                            _legs_of_its_own(part.astype(np.float64), leg_cells) >= st.min_fit_legs:
                        rests.append((part, o.src.class_name))
                elif part.shape[0] and (~on).any() and \
                        float(other_wall[o.cells[~on, 0], o.cells[~on, 1]].mean()) >= 0.5:
                    faced = _long_pieces(o, face_cells, spec, 2 * st.face_m)
                    if faced.any():
                        rests.append((np.argwhere(faced), o.src.class_name))
        for ob in objs_a + objs_b:
            if ob.cells.size:
                on_objects[ob.cells[:, 0], ob.cells[:, 1]] = True
        gone = _merge_fragments(gone, sizes.size_of, spec)
        new = _merge_fragments(new, sizes.size_of, spec)
        pairs, only_a, only_b = _match_objects(gone, new, st)
        moved = [(gone[i], new[j]) for i, j in pairs]
        # an object that moved onto part of its own place (a chair turned on the spot: two legs on two of
        # its old places, two on the other session's bare floor) is that object moved, not a second one
        gone_ids, new_ids = {id(o) for o in gone}, {id(o) for o in new}
        for objs_side, idx, others, in_a in ((gone, only_a, [o for o in objs_b if id(o) not in new_ids], True),
                                             (new, only_b, [o for o in objs_a if id(o) not in gone_ids], False)):
            for k, u in _onto_itself([objs_side[k] for k in idx], others, too_long, lo.bare_b if in_a else lo.bare_a,
                                     leg_cells):
                o = objs_side[idx[k]]
                moved.append((o, u) if in_a else (u, o))
            in_moves = {id(p) for pair in moved for p in pair}
            idx[:] = [k for k in idx if id(objs_side[k]) not in in_moves]
        # an object slid by less than its own size (a table pushed 30 cm) keeps part of its cells on
        # the other session's: it is gone with nothing new to match, or not gone at all, but each
        # session saw floor where the other saw some of its legs
        in_moves = {id(p) for pair in moved for p in pair}
        slid = _slid([gone[i] for i in only_a] + [o for o in objs_a if id(o) not in gone_ids | in_moves],
                     [new[j] for j in only_b] + [o for o in objs_b if id(o) not in new_ids | in_moves], removed, added,
                     near_b, near_a, obs_b, obs_a)
        slid_ids = {id(o) for pair in slid for o in pair}
        moved += slid
        only_a = [i for i in only_a if id(gone[i]) not in slid_ids]
        only_b = [j for j in only_b if id(new[j]) not in slid_ids]
        # an object one session's camera named wrongly: gone as one class, new as another, of one shape
        renamed = _misnamed(gone, only_a, new, only_b, spec, st, sizes.size_of)
        for i, j, cls in renamed:
            was, now = (_Obj(replace(o.src, class_name=cls), o.centroid, o.yaw, o.footprint, o.cells)
                        for o in (gone[i], new[j]))
            moved.append((was, now))
        renamed_a, renamed_b = {i for i, _, _ in renamed}, {j for _, j, _ in renamed}
        only_a = [i for i in only_a if i not in renamed_a]
        only_b = [j for j in only_b if j not in renamed_b]
        # an object that slid by less than its length where the other session's camera labelled nothing:
        # most of it lies on the other session's plain obstacles, so it is neither gone nor new, and there
        # is no object to pair it with (a couch pushed along its wall)
        paired = {id(o) for pair in moved for o in pair}
        moved += _slid_unlabelled([o for o in objs_a if id(o) not in gone_ids and id(o) not in paired], objs_b,
                                  removed, added & ~semi_b & ~lo.dyn_b, lo.occ_b & ~semi_b & ~lo.dyn_b, spec, st, True)
        moved += _slid_unlabelled([o for o in objs_b if id(o) not in new_ids and id(o) not in paired], objs_a,
                                  added, removed & ~semi_a & ~lo.dyn_a, lo.occ_a & ~semi_a & ~lo.dyn_a, spec, st, False)
        # the other end of a move may be cells the camera never labelled (the object stood beside the
        # robot's path, out of the camera's view): a piece of the other session's changes that is no
        # object, of its size, onto which its cells fit
        group = st.group_m / res
        off_semi_a, off_semi_b = ~_dilate(semi_a, near), ~_dilate(semi_b, near)
        # (and the other session's unlabelled obstacles on the object's own cells: legs put back where
        # legs of its own stood)
        # (pieces by people count, the people's own cells left out: a leg a person stood beside is no
        # less a leg, and the fit needs three legs on three legs, which two people's legs do not make)
        # (and the cells of an object that stayed which the other session saw free: a chair tucked at a
        # table's end, which the build grouped with the table, pulled away from it)
        def remnant(objs: list[_Obj], changed_objs: set[int], changed: NDArray[np.bool_]) -> NDArray[np.bool_]:
            out = np.zeros(spec.shape, bool)
            for o in objs:
                if id(o) not in changed_objs and o.cells.size:
                    out[o.cells[:, 0], o.cells[:, 1]] = True
            return out & changed

        # (an object paired as slid lends its cells too: a chair pulled away from its table makes the
        # object, table and chair, look pushed by less than its size)
        rem_a = remnant(objs_a, gone_ids, gone_cells)
        rem_b = remnant(objs_b, new_ids, new_cells)
        sides = ((only_a, gone, ((added_raw & off_semi_b) | rem_b) & ~lo.dyn_b, True, obst_b & off_semi_b),
                 (only_b, new, ((removed_raw & off_semi_a) | rem_a) & ~lo.dyn_a, False, obst_a & off_semi_a))
        # (an object takes its own session's changed legs within its length that no camera labelled, or
        # that its build put in another object that stayed: two legs a camera labelled and two the LiDAR
        # alone saw, or two its build gave the bed beside it, are one chair, whose four legs fit the
        # other end's)
        legs_a, legs_b = _small_blobs(lo.occ_a, leg_cells), _small_blobs(lo.occ_b, leg_cells)
        own_legs = {True: ((removed_raw & ~semi_a & ~lo.dyn_a) | rem_a) & legs_a,
                    False: ((added_raw & ~semi_b & ~lo.dyn_b) | rem_b) & legs_b}
        through_hidden: set[int] = set()  # objects paired with legs the other session's walls hid
        # each session's obstacles grown by the fit's tolerance (1.6 cells: a leg stood against the
        # obstacle, not in it), made when first needed
        walls: dict[bool, NDArray[np.bool_]] = {}

        def walls_of(in_a: bool) -> NDArray[np.bool_]:
            if in_a not in walls:
                walls[in_a] = _dilate(obst_a if in_a else obst_b, 1.6)
            return walls[in_a]
        for objs_idx, objs_all, changed, in_a, other in sides:
            if not objs_idx:
                continue
            whole = {i: _with_legs(objs_all[i], own_legs[in_a], spec, sizes.size_of) for i in objs_idx}
            # (the objects' own changed cells: a part of one may have moved, the rest stayed)
            own_changed = (gone_cells | own_legs[True]) if in_a else (new_cells | own_legs[False])
            partners, hidden_twins, done = _unlabelled_partners(
                [whole[i] for i in objs_idx], _pieces(changed, spec, group), spec, st, in_a, other, walls_of(in_a),
                walls_of(not in_a), own_changed)
            moved += partners
            through_hidden |= hidden_twins
            objs_idx[:] = [i for i in objs_idx if id(whole[i]) not in done]
        # and furniture neither camera labelled (beside the path in both tours) moved when a piece of
        # A's removed cells fits one of B's added cells, legs on legs; the pieces the moves above
        # took are theirs
        taken = np.zeros(spec.shape, bool)
        for pair in moved:
            for o in pair:
                taken[o.cells[:, 0], o.cells[:, 1]] = True
        # Pieces people stood by count too (people's evidence voids a chair-sized piece, and a chair
        # the camera never saw is one): the fit needs three legs on three legs, which two people's
        # legs do not make
        free_a_pieces = [p for p in _pieces(removed_raw & off_semi_a, spec, group)
                         if not taken[p[:, 0], p[:, 1]].any()]
        free_b_pieces = [p for p in _pieces(added_raw & off_semi_b, spec, group)
                         if not taken[p[:, 0], p[:, 1]].any()]
        unlabelled = _unlabelled_moves(free_a_pieces, free_b_pieces, lo.dyn_a, lo.dyn_b, spec, st)
        moved += unlabelled
        # the second object a build grouped with one that stayed (see _seen_better), when no move took
        # its cells: gone (or new) on its own, where its cells changed
        for pair in unlabelled:
            for o in pair:
                taken[o.cells[:, 0], o.cells[:, 1]] = True
        for rests, changed_cells, objs_side, idx in ((rests_a, gone_cells, gone, only_a),
                                                     (rests_b, new_cells, new, only_b)):
            for rest, class_name in rests:
                r, c = rest[:, 0], rest[:, 1]
                if float(taken[r, c].mean()) < 0.5 and float(changed_cells[r, c].mean()) >= 0.5:
                    objs_side.append(_piece_object(rest, class_name, spec))
                    idx.append(len(objs_side) - 1)
        # an object of A carried by a candidate motion is contradicted on floor B saw free with no
        # obstacle of B within a cell and a half, and beyond half a metre of anything B saw (behind
        # its walls, out of the building); it is explained on furniture either session saw: cells
        # flagged movable, and obstacles small enough to be a leg (the camera may not have labelled it)
        b_floor = lo.free_b & ~_dilate(lo.occ_b, 1.5)
        b_contra = b_floor | ~_dilate(obs_b, 0.5 / res)
        furn_a = _dilate(semi_a | legs_a, 1.5) if moved else semi_a
        furn_b = _dilate(semi_b | legs_b, 1.5) if moved else semi_b

        def contradicts(xy: NDArray[np.float64]) -> NDArray[np.bool_]:
            return _lookup(b_contra, spec, xy, True)

        # and an object of B carried back, on floor A saw free with nothing A glimpsed there (a thin leg
        # A's map lost is no floor): two legs of a bed fit either pair of its four, and the other pair
        # carried back lands where A saw its legs, or on A's floor
        a_seen = lo.occ_a if lo.glimpse_a is None else lo.occ_a | lo.glimpse_a
        a_seen = a_seen if lo.faint_a is None else a_seen | lo.faint_a
        a_contra = (lo.free_a & ~_dilate(a_seen, 1.5)) | ~_dilate(obs_a, 0.5 / res)

        def contradicts_back(xy: NDArray[np.float64]) -> NDArray[np.bool_]:
            return _lookup(a_contra, spec, xy, True)

        def furniture_a(xy: NDArray[np.float64]) -> NDArray[np.bool_]:
            return _lookup(furn_a, spec, xy)

        def furniture_b(xy: NDArray[np.float64]) -> NDArray[np.bool_]:
            return _lookup(furn_b, spec, xy)

        def hidden_too(furniture: Callable[[NDArray[np.float64]], NDArray[np.bool_]], in_a: bool
                       ) -> Callable[[NDArray[np.float64]], NDArray[np.bool_]]:
            grown = walls_of(in_a)
            return lambda xy: furniture(xy) | _lookup(grown, spec, xy)

        def mark(o: _Obj, zone: NDArray[np.bool_], changed: NDArray[np.bool_], other_free: NDArray[np.bool_],
                 value: int) -> None:
            """Into the mask: the changed cells in the object's zone, and the object's own cells the
            other session saw free, however near a wall (a couch pushed against one is within the
            tolerance of it, but labelled couch)."""
            mask[changed & zone] = value
            r, c = o.cells[:, 0], o.cells[:, 1]
            own = other_free[r, c] & zone[r, c]
            mask[r[own], c[own]] = value

        def with_own_legs(o: _Obj, in_a: bool, zone: NDArray[np.bool_]) -> tuple[_Obj, NDArray[np.bool_]]:
            """The object with its legs no camera labelled (what changed with it), in the open and, for an
            object on legs, against a wall (a couch's face is no leg, and the wall beside it no part of
            it); and ``zone`` grown by their cells (only: the floor between its legs is no change)."""
            legs = own_legs[in_a] | bumps_of(in_a) if _on_legs(o, leg_cells) else own_legs[in_a]
            whole = _with_legs(o, legs, spec, sizes.size_of)
            if whole is o:
                return o, zone
            zone = zone.copy()
            zone[whole.cells[:, 0], whole.cells[:, 1]] = True
            return whole, zone

        # what no camera labelled of a moved object changed with it: a couch's face the build left
        # unflagged, seen in one session only beside its flagged side. It joins the fit (a flagged face
        # alone slides along the other session's couch) when it touches the object and the two stay
        # within the object's length
        loose_a, loose_b = removed & ~semi_a & ~lo.dyn_a, added & ~semi_b & ~lo.dyn_b
        move_parts: list[_MovePart] = []
        for oa, ob in moved:
            elongated = _elongated(oa) and _elongated(ob)
            cells_a = _with_touching(oa, loose_a, spec, sizes.size_of)
            cells_b = _with_touching(ob, loose_b, spec, sizes.size_of)
            src_xy, dst_xy = _cells_xy(cells_a, spec), _cells_xy(cells_b, spec)
            turns = _candidate_turns(oa.yaw, ob.yaw)
            fa: Callable[[NDArray[np.float64]], NDArray[np.bool_]] = furniture_a
            fb: Callable[[NDArray[np.float64]], NDArray[np.bool_]] = furniture_b
            if id(oa) in through_hidden or id(ob) in through_hidden:
                # paired on legs the other session's walls hid: those walls explain them here too
                fa, fb = hidden_too(furniture_a, True), hidden_too(furniture_b, False)
            motion = _fit_motion(src_xy, dst_xy, turns, res, contradicts, fa, fb, contradicts_back)
            # cells with an obstacle of the other session where they are (a neighbour that did not
            # move, grouped with the object) say nothing of where it went; keep three or more
            keep_a = ~near_b[cells_a[:, 0], cells_a[:, 1]]
            keep_b = ~near_a[cells_b[:, 0], cells_b[:, 1]]
            ref_a, ref_b = (src_xy[keep_a], dst_xy[keep_b]) if keep_a.sum() >= 3 and keep_b.sum() >= 3 else \
                (src_xy, dst_xy)
            from_c = _reference_point(ref_a, ref_b, motion)
            new_c = se2_apply(motion, from_c[None])[0]
            # a box looks the same turned half way round: the turn is the short one, within ±90°
            turn = math.degrees(_box_turn(0.0, float(motion[2]))) if elongated else 0.0
            # a round object seen from two sides: two arcs of one circle, which a rigid fit slides
            # along each other; the circles' centres are where it was and went
            max_r = 0.75 * max(*oa.src.size, *ob.src.size, 2.0 * res)
            arc_a, arc_b = _arc_centre(oa.cells, spec, max_r), _arc_centre(ob.cells, spec, max_r)
            round_obj = False
            if arc_a is not None and arc_b is not None and _same_arc(arc_a[1], arc_b[1]):
                from_c, new_c, turn, round_obj = arc_a[0], arc_b[0], 0.0, True
            disp = float(np.linalg.norm(new_c - from_c))
            if disp < st.still_m and abs(turn) < st.still_deg and not round_obj:
                # a fit that says it stayed may have laid cells that stayed on each other (a wall's face
                # its builds' labels bled onto, grouped with a table that moved): the changed cells, when
                # three legs or more of each side fit each other leg on leg, moved
                part_a = cells_a[removed[cells_a[:, 0], cells_a[:, 1]]]
                part_b = cells_b[added[cells_b[:, 0], cells_b[:, 1]]]
                if min(_legs_of_its_own(part_a.astype(np.float64), leg_cells),
                       _legs_of_its_own(part_b.astype(np.float64), leg_cells)) >= st.min_fit_legs:
                    pa_xy, pb_xy = _cells_xy(part_a, spec), _cells_xy(part_b, spec)
                    q, legs, _ = _shape_fit(pa_xy, pb_xy, turns, res)
                    if q >= st.unlabelled_fit and legs >= st.min_fit_legs:
                        motion = _fit_motion(pa_xy, pb_xy, turns, res, contradicts, fa, fb, contradicts_back)
                        ref_a, ref_b = pa_xy, pb_xy
                        from_c = _reference_point(ref_a, ref_b, motion)
                        new_c = se2_apply(motion, from_c[None])[0]
                        turn = math.degrees(_box_turn(0.0, float(motion[2]))) if elongated else 0.0
                        disp = float(np.linalg.norm(new_c - from_c))
            zone = _dilate(_cell_mask(oa, spec) | _cell_mask(ob, spec), near)
            if disp < st.still_m and abs(turn) < st.still_deg:
                # it did not move, but a face of it may stand where the other session saw floor
                for o, changed, value, kind in ((oa, removed, 2, "object_disappeared"),
                                                (ob, added, 1, "object_appeared")):
                    faced = _long_pieces(o, changed, spec, st.face_m)
                    if faced.any():
                        mask[faced] = value
                        # reported where its faces changed: the object may hold the wall behind it
                        at = _cells_xy(np.argwhere(faced), spec).mean(axis=0)
                        n = int(np.count_nonzero(faced))
                        changes.append(Change(kind, (float(at[0]), float(at[1])), n * res * res, n, o.src.class_name))
                continue
            both = np.concatenate([ref_a, se2_apply(se2_inverse(motion), ref_b)])
            move_parts.append(_MovePart(oa.src.class_name or None, from_c, new_c, motion, both,
                                        int(ob.cells.shape[0]), elongated and not round_obj, round_obj))
            mark(*with_own_legs(ob, False, zone), added, lo.free_a, 1)
            mark(*with_own_legs(oa, True, zone), removed, lo.free_b, 2)
        # parts of one object its builds split in two (a table longer than its class's objects) moved
        # by one motion: one move
        for mp in _one_motion(move_parts, sizes.size_of, res):
            n = mp.cells
            turn_deg = math.degrees(_box_turn(0.0, float(mp.motion[2]))) if mp.turnable else None
            changes.append(Change("object_moved", (float(mp.to_c[0]), float(mp.to_c[1])), n * res * res, n,
                                  mp.class_name, (float(mp.from_c[0]), float(mp.from_c[1])),
                                  (float(mp.to_c[0]), float(mp.to_c[1])),
                                  float(np.linalg.norm(mp.to_c - mp.from_c)), turn_deg))  # None: not measurable
        for kind, idx, objs in (("object_disappeared", only_a, gone), ("object_appeared", only_b, new)):
            in_a = kind == "object_disappeared"
            for i in idx:
                o = objs[i]
                full, zone = with_own_legs(o, in_a, _dilate(_cell_mask(o, spec), near))
                n = int(full.cells.shape[0])
                at = o.centroid
                # reported where its cells changed, not at its box's middle: a build may group with a new
                # table the wall its labels bled onto (random:266: 0.55 m off), or a new couch with one
                # beside it that stayed. Its legs no camera labelled changed with it (a table labelled at
                # one end is reported at its middle)
                held = full.cells
                changed = (added if kind == "object_appeared" else removed)[held[:, 0], held[:, 1]]
                if full is not o:
                    w = spec.width
                    changed |= ~np.isin(held[:, 0] * w + held[:, 1], o.cells[:, 0] * w + o.cells[:, 1])
                if changed.any():
                    # (of furniture on legs, the middle of the box around them: legs of more cells or
                    # fewer; of a face, the middle of its cells, which a box would put behind it)
                    xy = _cells_xy(held[changed], spec)
                    at = np.asarray(cv2.minAreaRect(xy.astype(np.float32))[0], np.float64) \
                        if xy.shape[0] >= 3 and _on_legs(full, leg_cells) else xy.mean(axis=0)
                    if too_long(o):  # more than one object grouped: only the changed one's cells
                        n = int(changed.sum())
                changes.append(Change(kind, (float(at[0]), float(at[1])), n * res * res, n, o.src.class_name))
                if in_a:
                    mark(full, zone, removed, lo.free_b, 2)
                else:
                    mark(full, zone, added, lo.free_a, 1)
        # cells flagged movable, in an object or not, are never static changes
        on_objects = _dilate(on_objects | (lo.semi_a & lo.occ_a) | (lo.semi_b & lo.occ_b), near)

    # static changes: what is left, in connected pieces; a piece touching an object that changed is
    # part of that object (its legs the camera did not label), not a change of its own
    min_cells = max(1, int(math.ceil(st.min_static_m2 / (res * res))))
    near_object_change = _dilate(mask > 0, st.group_m / res)
    reported: dict[int, list[tuple[Change, NDArray[np.intp]]]] = {1: [], 2: []}  # each static change's cells
    for (kind, cells, voided, value, own_occ, own_free, other_occ, other_free, other_semi, own_faint, other_near,
         own_weak, own_dyn, in_a) in (
            ("static_added", added & ~on_objects, added_raw & ~added & ~on_objects, 1, lo.occ_b, lo.free_b, lo.occ_a,
             lo.free_a, lo.semi_a, lo.faint_b, near_a, lo.weak_b, lo.dyn_b, False),
            ("static_removed", removed & ~on_objects, removed_raw & ~removed & ~on_objects, 2, lo.occ_a, lo.free_a,
             lo.occ_b, lo.free_b, lo.semi_b, lo.faint_a, near_b, lo.weak_a, lo.dyn_a, True)):
        found, kept, labels, ids = _component_changes(cells, spec, kind, st.group_m / res, min_cells)
        # pieces too small to count alone (a leg of a new table no camera labelled is a cell) count
        # when three or more stand within a table's span of each other: furniture, not noise. Legs
        # voided as people's count too, and join the set, when two of its legs stand away from people
        # (a table a person stood at, whose map dropped cells beside two of its legs). And leg-sized
        # blobs of people evidence its cleaning dropped from the map, on the other session's floor, when
        # with two legs that stand away from people they make the four corners of a rectangle: a chair
        # whose map took two of its legs for a person's. Legs against a wall (see ``bumps_of``) count
        # too, as legs by people do: a set needs two legs in the open
        dropped = _small_blobs(own_dyn & ~own_occ, leg_cells) & other_free & ~other_near & ~on_objects
        by_wall = bumps_of(in_a) & ~on_objects & ~cells
        # (and pieces kept on their own that are no larger than a leg: a table's leg seen whole is a
        # change of its own, its two thin legs beside it a cell each; the set takes such a piece in)
        rk, ck = np.nonzero(kept)
        lone = np.bincount(labels[rk, ck], minlength=int(labels.max()) + 1)[labels[rk, ck]] <= leg_cells
        lone_legs = np.zeros_like(kept)
        lone_legs[rk[lone], ck[lone]] = True
        f2, k2, l2, i2 = _leg_sets((cells & ~kept) | voided | by_wall | lone_legs, spec, kind, st.leg_span_m / res,
                                   st.min_fit_legs, ~people & ~by_wall, st.leg_rect_m / res, dropped, own_dyn,
                                   st.people_margin_m / res)
        if i2:
            taken_in = set(np.unique(labels[(l2 > 0) & lone_legs]).tolist())
            found = [c for c, k in zip(found, ids, strict=True) if k not in taken_in]
            ids = [k for k in ids if k not in taken_in]
            off = int(labels.max())
            on_sets = l2 > 0
            labels[on_sets] = l2[on_sets] + off
            found, ids, kept = found + f2, ids + [i + off for i in i2], kept | k2
        touching = set(np.unique(labels[near_object_change & (labels > 0)]).tolist())
        slices = ndimage.find_objects(labels)
        # (a wall's far face runs along the other session's wall, not along its furniture: a couch's
        # front 20 cm out from where the other session saw it is the couch pulled from the wall)
        other_walls = other_occ & ~other_semi
        faces = _strips_along(labels, slices, ids, other_walls, 2.0 * tol)
        left_out["wall_faces"] += len(faces)
        hidden = _strips_along(labels, slices, [k for k in ids if k not in faces], ~(other_occ | other_free), 2.0, 2)
        # (beyond a door closed in a doorway lies the room the other session never looked into)
        hidden = {k for k in hidden if not _in_doorway(labels, slices, k, other_walls, st.door_min_m / res)}
        left_out["hidden_faces"] += len(hidden)
        faces |= hidden
        if own_weak is not None:
            # an obstacle most of whose cells rest on one or two returns (a wall seen once, edge-on, from
            # across the room, where the other session's beams passed many times) is too little to call;
            # not a door closed in a doorway, which a robot on the far side sees with few returns
            weak = {k for k in _weak_pieces(labels, slices, [k for k in ids if k not in faces], own_weak)
                    if not _in_doorway(labels, slices, k, other_walls, st.door_min_m / res)}
            left_out["weak_obstacles"] += len(weak)
            faces |= weak
        # two leg-sized blobs a stride apart, alone on the floor, that no camera saw: a person who stood
        # there while the robot passed (cleaning keeps what it has no label for), not an obstacle
        own_lab = lo.lab_a if in_a else lo.lab_b
        stances = _stances(labels, slices, [k for k in ids if k not in faces], own_occ, own_lab, res)
        left_out["people_stances"] += len(stances)
        faces |= stances
        # a change reaches on, through its own obstacle cells the other session saw free, up to the
        # tolerance into the band by the other's obstacles: the end of a cabinet's face where it meets
        # the wall it stands against
        is_face = np.zeros(len(slices) + 1, bool)
        is_face[list(faces)] = True
        shown = kept & ~is_face[labels]
        reach = own_occ & other_free & ~on_objects & ~people & (mask == 0)
        shown = _grow_along(shown, reach, int(math.ceil(tol)))
        if own_faint is not None:
            # and along its own faint obstacles, up to ten cells: a face seen at a grazing angle is
            # occupied where beams ended on it often enough and faint between (the rays that grazed it
            # cleared it), but it is one face
            shown = _grow_along(shown, own_faint & other_free & ~other_near & ~on_objects & ~people & (mask == 0), 10)
        mask[shown] = value
        # a solid obstacle's inside, which its own session never saw, between the faces that changed and
        # the other session's wall behind it: a cabinet against a wall changes on three faces, and its
        # back, a cell from the other session's wall, is within the tolerance of that wall
        changed_here, max_fill = mask == value, st.max_fill_m2 / (res * res)
        inside = _enclosed(changed_here, other_occ, own_free, other_free, max_fill)
        # (and a cabinet against a wall seen on two faces only: its far end faced away)
        inside |= _boxed(changed_here, other_occ, own_free, other_free, max_fill, st.face_m / res) & (mask == 0)
        if inside.any():
            mask[inside] = value
            found = _with_insides(found, ids, labels, inside, spec)
        for k, change in enumerate(found):
            if ids[k] in touching or ids[k] in faces:
                continue
            changes.append(change)
            sl = slices[ids[k] - 1] if ids[k] - 1 < len(slices) else None
            if sl is not None:
                rr, cc = np.nonzero((labels[sl] == ids[k]) & (mask[sl] == value))
                reported[value].append((change, np.stack([rr + sl[0].start, cc + sl[1].start], axis=1).astype(np.intp)))
    if a.semantic and b.semantic:
        changes = _static_moves(changes, reported[2], reported[1], spec, st)

    # floor only one session observed
    min_explored = max(1, int(math.ceil(st.min_explored_m2 / (res * res))))
    obs_a, obs_b = lo.occ_a | lo.free_a, lo.occ_b | lo.free_b
    for kind, cells in (("newly_explored", obs_b & ~obs_a), ("no_longer_covered", obs_a & ~obs_b)):
        # thin slivers along the edge of the other map's view are not areas: open them away first
        opened = cv2.morphologyEx(cells.astype(np.uint8), cv2.MORPH_OPEN, _disk(3.0)) > 0
        found, _, _, _ = _component_changes(opened, spec, kind, 1.0, min_explored)
        changes += found
    order = {t: i for i, t in enumerate(CHANGE_TYPES)}
    changes.sort(key=lambda c: (order[c.type], -c.area_m2))
    return changes, mask, left_out


#: a static change piece is left out when fewer than this share of its cells are firm obstacles (hit by
#: three returns or more, ``FAINT_MIN_HITS``) in its own session. On the development pairs random:640-659 the
#: two false pieces (B's corridor wall seen edge-on beyond a door, 0.15 m off A's wall) held 0 and 36 %
#: firm cells; the 60 other pieces 71 % or more (the least: a closed door seen from across a room)
_WEAK_SHARE = 0.5


#: a person's stance at LiDAR height: two legs, each a blob of at least ``_STANCE_LEG_CELLS`` cells no
#: wider than ``LEG_M``, their centres at most ``_STANCE_M`` apart, nothing else within ``_STANCE_CLEAR_M``
#: but a stray cell or two (a chair's or a table's legs, 3-7 cm, are a cell or two each)
_STANCE_LEG_CELLS = 3
_STANCE_M = 0.45
_STANCE_CLEAR_M = 0.3


def _stances(labels: NDArray[np.int32], slices: list[Any], ids: list[int], own_occ: NDArray[np.bool_],
             own_lab: NDArray[np.bool_] | None, res: float) -> set[int]:
    """The pieces (label ids) that are a person's stance (see ``_STANCE_M``) in their own map, with no
    cell of it or near it painted by a camera: two blobs of the piece's cells (and at most two cells
    more: a stray return up to half a metre off, which the change's grouping joined), each the changed
    part of an obstacle of its own map no wider than a leg."""
    out = set()
    pad = int(math.ceil((_STANCE_CLEAR_M + LEG_M) / res)) + 1
    h, w = own_occ.shape
    eight = np.ones((3, 3), bool)
    for k in ids:
        sl = slices[k - 1]
        if sl is None:
            continue
        win = (slice(max(sl[0].start - pad, 0), min(sl[0].stop + pad, h)),
               slice(max(sl[1].start - pad, 0), min(sl[1].stop + pad, w)))
        piece = labels[win] == k
        lab, n = ndimage.label(piece, structure=eight)
        sizes = np.bincount(lab.ravel(), minlength=n + 1)
        legs = [j for j in range(1, n + 1) if sizes[j] >= _STANCE_LEG_CELLS]
        if len(legs) != 2 or int(piece.sum()) - int(sizes[legs].sum()) > 2:
            continue
        # the legs as their own map holds them (a leg's cells by the other session's obstacles are no
        # change, but they are the leg): two obstacles, each no wider than a leg
        own = own_occ[win]
        olab, _ = ndimage.label(own, structure=eight)
        held = np.unique(olab[np.isin(lab, legs)])
        held = held[held > 0]
        if held.size != 2:
            continue
        body = np.isin(olab, held)
        boxes = ndimage.find_objects(olab)
        if any(max(b[0].stop - b[0].start, b[1].stop - b[1].start) * res > LEG_M
               for b in (boxes[j - 1] for j in held)):
            continue
        # nothing else of their map within reach but a stray cell or two, and no camera saw any of it
        around = _dilate(body, _STANCE_CLEAR_M / res) & own & ~body
        if int(around.sum()) > 2:
            continue
        if own_lab is not None and (own_lab[win] & (body | around)).any():
            continue
        centres = np.array(ndimage.center_of_mass(own, olab, held.tolist()), np.float64)
        if float(np.linalg.norm(centres[0] - centres[1])) * res <= _STANCE_M:
            out.add(k)
    return out


def _weak_pieces(labels: NDArray[np.int32], slices: list[Any], ids: list[int], weak: NDArray[np.bool_]) -> set[int]:
    """The pieces (label ids) fewer than ``_WEAK_SHARE`` of whose cells are firm (not ``weak``)."""
    out = set()
    for k in ids:
        sl = slices[k - 1]
        if sl is None:
            continue
        own = labels[sl] == k
        n = int(own.sum())
        if n and int((own & weak[sl]).sum()) > (1.0 - _WEAK_SHARE) * n:
            out.add(k)
    return out


#: the share of an enclosed inside's outline (off the other session's obstacles) that must be changed
#: cells for the inside to be filled: 0.80-1.00 around the simulated cabinets and couches, 0.38-0.62
#: around scattered clutter on the real Hokuyo tours
_OUTLINE_SHARE = 0.75


def _enclosed(changed: NDArray[np.bool_], other_occ: NDArray[np.bool_], own_free: NDArray[np.bool_],
              other_free: NDArray[np.bool_], max_cells: float) -> NDArray[np.bool_]:
    """The inside of solid obstacles that changed: cells the changed cells enclose, alone or with the
    other session's obstacles (grown by a cell: the gap a cabinet leaves to the wall), that the
    obstacle's own session never saw free and the other saw free. Each inside is at most ``max_cells``,
    its own session saw at most half of it free (not a room a new wall closes), changed cells line
    a third of its rim at least (a cabinet against a wall changes on three faces of four; not the
    inside of a pillar the other session saw), and ``_OUTLINE_SHARE`` of its rim where the other
    session's obstacles do not close it (faces, not clutter)."""
    out = np.zeros(changed.shape, bool)
    if not changed.any():
        return out
    rows, cols = np.nonzero(changed)
    pad = 3
    r0, r1 = max(0, rows.min() - pad), min(changed.shape[0], rows.max() + pad + 1)
    c0, c1 = max(0, cols.min() - pad), min(changed.shape[1], cols.max() + pad + 1)
    win = (slice(r0, r1), slice(c0, c1))
    ch = changed[win]
    # (the faces grown by a cell, so that a face with gaps of a cell or two still closes)
    near_other = _dilate(other_occ[win], 1.0)
    barrier = _dilate(ch, 1.0) | near_other
    holes = ndimage.binary_fill_holes(barrier) & ~barrier
    if not holes.any():
        return out
    labels, n = ndimage.label(holes)
    # only insides of the size of an obstacle, next to changed cells (the rooms A's walls close are
    # holes too, and many)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    by_changes = np.zeros(n + 1, bool)
    by_changes[np.unique(labels[_dilate(ch, 2.5)])] = True
    slices = ndimage.find_objects(labels)
    for k, sl in enumerate(slices, start=1):
        if sl is None or sizes[k] > max_cells or not by_changes[k]:
            continue
        grown = tuple(slice(max(0, s.start - 3), s.stop + 3) for s in sl)
        # the inside, grown back by the cells the barrier took: a cell up to the changed cells, and two up
        # to the other session's obstacles (not out through a gap in a dotted face)
        free_of = ~ch[grown] & ~other_occ[win][grown]
        hole = _grow_along(labels[grown] == k, free_of, 1)
        hole = _grow_along(hole, free_of & near_other[grown], 1)
        size = int(hole.sum())
        if size > max_cells:
            continue
        rim = _dilate(hole, 1.5) & ~hole
        if ch[grown][rim].mean() < 1.0 / 3.0:
            continue
        # its outline, where the other session's obstacles do not close it, is of changed cells with a
        # gap here and there (a face resampled into the other grid is dotted): a solid obstacle's faces,
        # not returns of clutter scattered about a room, whose gaps the barrier's growth closed
        off = rim & ~near_other[grown]
        if not off.any() or ch[grown][off].mean() < _OUTLINE_SHARE:
            continue
        if own_free[win][grown][hole].mean() > 0.5:
            continue  # its own session saw floor inside: not solid
        fill = hole & other_free[win][grown]
        sub = out[win][grown]
        sub |= fill
    return out


def _l_box(rows: NDArray[np.intp], cols: NDArray[np.intp], min_side: float, max_cells: float
           ) -> tuple[tuple[float, float, float, float], float, float, tuple[float, float]] | None:
    """The box two perpendicular faces of cells (an L) outline: its bounds in the box's axes (u along
    the first, v along the second: u = col cos + row sin, v = -col sin + row cos), the cosine and sine
    of its heading, and the u and v of the two sides across from the L's faces. The heading is the one,
    in 1° steps, at which two adjacent sides are best lined with cells (a minimum-area rectangle is no
    help: an L's hull is a right triangle, which the box along its long side fits as tightly). None when
    no two adjacent sides are lined to ``_BOX_FACE``, or a side is shorter than ``min_side`` cells, or
    the box holds more than ``max_cells``."""
    rad = np.radians(np.arange(90.0))
    c, s = np.cos(rad)[:, None], np.sin(rad)[:, None]
    u, v = cols[None, :] * c + rows[None, :] * s, -cols[None, :] * s + rows[None, :] * c
    u0, u1, v0, v1 = u.min(axis=1), u.max(axis=1), v.min(axis=1), v.max(axis=1)
    headings = np.arange(rad.size)[:, None]

    def lined(near: NDArray[np.bool_], along: NDArray[np.float64], lo: NDArray[np.float64],
              hi: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per heading, the share of a side's cell-long stretches that cells within ``near`` line."""
        bins = np.floor(along - lo[:, None]).astype(np.intp)
        seen = np.zeros((rad.size, int(bins.max()) + 1), bool)
        seen[np.broadcast_to(headings, bins.shape)[near], bins[near]] = True
        return np.asarray(seen.sum(axis=1) / (np.floor(hi - lo) + 1), np.float64)

    cov = {("u", 0): lined(u - u0[:, None] <= 1.5, v, v0, v1), ("u", 1): lined(u1[:, None] - u <= 1.5, v, v0, v1),
           ("v", 0): lined(v - v0[:, None] <= 1.5, u, u0, u1), ("v", 1): lined(v1[:, None] - v <= 1.5, u, u0, u1)}
    fits = (np.minimum(u1 - u0, v1 - v0) >= min_side) & ((u1 - u0 + 1) * (v1 - v0 + 1) <= max_cells)
    best: tuple[float, Any] = (0.0, None)
    for fu in (0, 1):
        for fv in (0, 1):
            # (an L: the sides across from its faces are no faces; three faces and a wall are
            # :func:`_enclosed`'s, with its stricter outline)
            across = np.maximum(cov[("u", 1 - fu)], cov[("v", 1 - fv)]) < _BOX_FACE
            score = np.where(fits & across, np.minimum(cov[("u", fu)], cov[("v", fv)]), 0.0)
            k = int(np.argmax(score))
            if score[k] > best[0]:
                bounds = (float(u0[k]), float(u1[k]), float(v0[k]), float(v1[k]))
                far = (float(u0[k] if fu else u1[k]), float(v0[k] if fv else v1[k]))
                best = (float(score[k]), (bounds, float(c[k, 0]), float(s[k, 0]), far))
    return best[1] if best[0] >= _BOX_FACE else None


def _boxed(changed: NDArray[np.bool_], other_occ: NDArray[np.bool_], own_free: NDArray[np.bool_],
           other_free: NDArray[np.bool_], max_cells: float, min_side: float) -> NDArray[np.bool_]:
    """The inside of an obstacle seen on two faces that meet (an L of changed cells) against the
    other session's wall: a cabinet put against a wall and seen from one corner shows its front and
    one end; its other end faces away and its back stands a cell from the wall, so no face closes
    its inside for :func:`_enclosed`. The L's box (:func:`_l_box`) is filled when both faces line
    ``_BOX_FACE`` of their sides, each at least ``min_side`` cells long, and the sides across from
    them do not (an L, not a U), the other session's obstacles line ``_BOX_FACE`` of a side across
    from a face, the box holds at most ``max_cells``, its own session saw at most ``_BOX_SEEN`` of the
    inside free (solid: a room that two new walls and an old one bound was seen into) and the other
    session saw at least half of it free (the floor the obstacle now stands on). Only the cells behind
    the faces' cells that the other session saw free are returned, as for :func:`_enclosed`."""
    out = np.zeros(changed.shape, bool)
    if not changed.any():
        return out
    # (on the changes' bounding box: labelling a whole floor's grid costs more than the rest)
    pad = 4
    bx, by, bw, bh = cv2.boundingRect(changed.astype(np.uint8))
    whole = (slice(max(0, by - 2 * pad), by + bh + 2 * pad), slice(max(0, bx - 2 * pad), bx + bw + 2 * pad))
    out_all, changed, other_occ = out, changed[whole], other_occ[whole]
    own_free, other_free, out = own_free[whole], other_free[whole], out[whole]
    # (a face resampled into the common grid is dotted: its pieces are joined across a cell)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(_dilate(changed, 1.0).astype(np.uint8), connectivity=8)
    for k in range(1, n):
        x, y, w, h, _area = (int(v) for v in stats[k])
        if min(h, w) < min_side:
            continue  # (an L's box is at least min_side either way)
        win = (slice(max(0, y - pad), y + h + pad), slice(max(0, x - pad), x + w + pad))
        piece = changed[win] & (labels[win] == k)
        rows, cols = np.nonzero(piece)
        if rows.size < 2 * min_side:
            continue
        # (an L against a wall touches it: one face runs up to the wall)
        on_other = _dilate(other_occ[win], 2.0)
        if not (on_other & piece).any():
            continue
        box = _l_box(rows, cols, min_side, max_cells)
        if box is None:
            continue
        (u0, u1, v0, v1), c, sn, far = box
        rr, cc = np.mgrid[0:piece.shape[0], 0:piece.shape[1]]
        u, v = cc * c + rr * sn, -cc * sn + rr * c

        # the sides across from the L's two faces, one of which must stand along the other's wall
        if not (_side_lined(on_other, (u0, u1, v0, v1), c, sn, far[0], None)
                or _side_lined(on_other, (u0, u1, v0, v1), c, sn, None, far[1])):
            continue
        # (behind each face's cells: a face seen at an angle is jagged, a cell or two deep, and the
        # cells between its bumps on the outer side are floor)
        face_u, face_v = u0 + u1 - far[0], v0 + v1 - far[1]
        inside = ((u >= u0) & (u <= u1) & (v >= v0) & (v <= v1) & ~piece & ~other_occ[win]
                  & _behind(np.abs(u - face_u), v - v0, piece) & _behind(np.abs(v - face_v), u - u0, piece))
        if not inside.any() or own_free[win][inside].mean() > _BOX_SEEN or other_free[win][inside].mean() < 0.5:
            continue
        out[win] |= inside & other_free[win]
    return out_all


def _side_lined(mask: NDArray[np.bool_], bounds: tuple[float, float, float, float], c: float, s: float,
                at_u: float | None, at_v: float | None) -> bool:
    """``mask`` lines ``_BOX_FACE`` of a box's side: the side at u = ``at_u`` (or v = ``at_v``) of the
    box ``bounds`` (u0, u1, v0, v1) in the axes of heading cosine ``c`` and sine ``s``."""
    u0, u1, v0, v1 = bounds
    t = np.linspace(0.0, 1.0, 2 * int(max(u1 - u0, v1 - v0)) + 2)
    pu = np.full(t.shape, at_u) if at_u is not None else u0 + t * (u1 - u0)
    pv = np.full(t.shape, at_v) if at_v is not None else v0 + t * (v1 - v0)
    ci = np.clip(np.round(pu * c - pv * s).astype(int), 0, mask.shape[1] - 1)
    ri = np.clip(np.round(pu * s + pv * c).astype(int), 0, mask.shape[0] - 1)
    return bool(mask[ri, ci].mean() >= _BOX_FACE)


def _behind(depth: NDArray[np.float64], along: NDArray[np.float64], face: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Cells deeper into a box than its face's cells about them: per cell-long stretch along the face,
    the deepest of its cells within two cells of the side, over the stretch and two either side (a
    dotted face's gaps)."""
    bins = np.floor(along).astype(np.intp)
    band = face & (depth <= 2.5)
    deepest = np.zeros(int(bins.max()) + 1, np.float64)
    if band.any():
        np.maximum.at(deepest, bins[band], depth[band])
    deepest = ndimage.maximum_filter1d(deepest, 5)
    return np.asarray(depth > deepest[np.clip(bins, 0, deepest.size - 1)])


#: the share of a box's side its face (or the other session's wall) must line, and the most of its
#: inside its own session may have seen free
_BOX_FACE = 0.7
_BOX_SEEN = 0.3


def _with_insides(found: list[Change], ids: list[int], labels: NDArray[np.int32], inside: NDArray[np.bool_],
                  spec: GridSpec) -> list[Change]:
    """Each change grown by the insides its cells enclose (its area and centroid then cover the
    obstacle's footprint): an inside belongs to the change whose cells line most of its rim."""
    pos = {k: i for i, k in enumerate(ids)}
    grown = dict.fromkeys(range(len(found)), (0, 0.0, 0.0))
    lab, _ = ndimage.label(inside, structure=np.ones((3, 3), bool))
    for j, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is None:
            continue
        win = tuple(slice(max(0, s.start - 2), s.stop + 2) for s in sl)
        hole = lab[win] == j
        rim = labels[win][_dilate(hole, 1.5) & ~hole]
        rim = rim[rim > 0]
        if not rim.size:
            continue
        k = int(np.bincount(rim).argmax())
        if k not in pos:
            continue
        rr, cc = np.nonzero(hole)
        m, sr, sc = grown[pos[k]]
        grown[pos[k]] = (m + rr.size, sr + float((rr + win[0].start).sum()), sc + float((cc + win[1].start).sum()))
    out = []
    for i, c in enumerate(found):
        m, sr, sc = grown[i]
        if m:
            x = spec.origin_x + (sc / m + 0.5) * spec.resolution
            y = spec.origin_y + (sr / m + 0.5) * spec.resolution
            w = c.cells + m
            cx = (c.centroid[0] * c.cells + x * m) / w
            cy = (c.centroid[1] * c.cells + y * m) / w
            c = replace(c, centroid=(float(cx), float(cy)), area_m2=float(w * spec.resolution ** 2), cells=int(w))
        out.append(c)
    return out


def _grow_along(cells: NDArray[np.bool_], allowed: NDArray[np.bool_], steps: int) -> NDArray[np.bool_]:
    """``cells`` grown through 8-connected ``allowed`` cells, one cell a step, for up to ``steps`` steps."""
    out = cells.copy()
    if not allowed.any() or not cells.any():
        return out
    for _ in range(steps):
        grow = _dilate(out, 1.5) & allowed & ~out
        if not grow.any():
            break
        out |= grow
    return out
