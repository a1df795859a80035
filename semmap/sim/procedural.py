"""Procedural worlds: ``random:SEED`` builds a new building, tour, furniture, people and sensor rig.

Every seed gives another fair test of a semantic mapper, one it was never tuned on:

- **Building**: a rectangular outline 10–24 m a side (sometimes with one corner cut off by a
  diagonal wall), split into 3–7 rooms, often along a corridor, by walls with 1.0–1.6 m doors.
- **Route**: planned first, through the doors' centres, room after room, until the tour takes
  60–150 s. It is proved collision-free (:func:`~semmap.sim.robot.check_clearance`) with a margin.
- **Furniture**, kept off a lane around the planned tour and off the doorways: beds with the
  headboard (sometimes a long side) against a wall, couches against a wall or in a corner with a
  low table, dining tables with chairs, counters, desks with a chair and a monitor, cabinets,
  plants and screens, most of them within 3 cm of a wall face. Pillars now and then.
- **People**, each with a role in their name (:func:`person_role`): ``standing`` all tour (one at
  a bed or table, sometimes one by a wall), ``standing_unseen`` beside or behind the route where
  the forward camera rarely looks, ``pauser`` (walks, then stands 20–60 s), a ``guide`` who walks
  1.5–2 m ahead of the robot and stops where it turns away, ``pacer`` (back and forth along a wall),
  and sometimes a ``walker``. None of them walks through furniture or into the robot.
- **Sensor rig** (:attr:`Scenario.overrides`): the LiDAR at the front-left or front-right corner
  or the front centre, 0.15–0.3 m high; camera rate, image and label encodings, topic and frame
  names drawn from what real robots use.

The same seed always gives the same world (``numpy.random.default_rng(seed)``). The knobs are the
module constants below.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..config import SimConfig, load_model
from ..errors import SimulationError
from ..geometry import se2_compose, wrap_angle
from .robot import Trajectory, check_clearance, people_clearance, plan_tour
from .scenarios import IdCounter, Scenario, WallSegment, walls_with_doors
from .sensors import mount_se2
from .world import (
    Person,
    World,
    WorldObject,
    bed,
    cabinet,
    chair,
    couch,
    monitor,
    pillar,
    potted_plant,
    screen,
    table,
)

__all__ = ["PERSON_ROLES", "SCENARIO_PREFIX", "person_role", "random_world", "scenario_seed"]

log = logging.getLogger(__name__)

#: ``get_scenario("random:SEED")``
SCENARIO_PREFIX = "random:"
PERSON_ROLES = ("standing", "standing_unseen", "pauser", "guide", "pacer", "walker")

# ---- building ----------------------------------------------------------------------------
SIDE_M = (10.0, 24.0)  # outline side lengths
ROOMS = (3, 7)  # rooms, not counting the corridor
CORRIDOR_PROB = 0.5
CORRIDOR_WIDTH_M = (1.8, 2.4)
MIN_ROOM_M = 3.0  # smallest room side (wall centre lines)
DOOR_WIDTH_M = (1.0, 1.6)  # clear opening
DOOR_MARGIN_M = 0.45  # door edge to the nearest wall junction
EXTRA_DOOR_PROB = 0.25  # a door between rooms that the spanning tree does not need
CHAMFER_PROB = 0.4  # one outline corner cut by a diagonal wall
CHAMFER_M = (1.2, 2.6)
WALL_THICKNESS_M = 0.12
WALL_HEIGHT_M = 2.6
PILLARS = (0, 3)
PILLAR_PROB = 0.5  # chance of any pillars at all
PILLAR_SPACING_M = 2.5

# ---- route ------------------------------------------------------------------------------
TOUR_S = (60.0, 150.0)  # tour duration at the default speed
MIN_VISITED = 0.6  # share of the rooms the robot enters
APPROACH_M = 1.0  # route points this far either side of a door (less in a narrow corridor)
ROOM_POINT_MARGIN_M = 1.1  # route points inside rooms keep this far from the walls
ROUTE_CLEARANCE_M = 0.15  # robot footprint to anything below its body height
LANE_MARGIN_M = 0.22  # furniture keeps this far from the robot footprint along the planned tour
DOOR_KEEPOUT_M = 1.0  # nothing stands this deep in front of a door, either side

# ---- furniture --------------------------------------------------------------------------
WALL_GAP_M = (0.0, 0.03)  # furniture "against a wall": this far from its face
FURNITURE_GAP_M = 0.05  # between pieces of furniture
BED_W_M, BED_D_M = (0.9, 1.1), (1.9, 2.2)
COUCH_W_M, COUCH_D_M = (1.6, 2.4), (0.8, 0.95)
TABLE_W_M, TABLE_D_M = (1.1, 1.8), (0.7, 1.0)
COUNTER_W_M, COUNTER_D_M = (1.8, 3.0), (0.55, 0.7)
ROOM_KINDS = ("bedroom", "lounge", "dining", "office")

# ---- people -----------------------------------------------------------------------------
PERSON_ID0 = 1001
STANDING = (1, 3)
STANDING_ROUTE_M = (1.0, 4.0)  # whole-tour standers are this far from the robot's path
AT_FURNITURE_M = (0.25, 0.35)  # centre of a person standing at a bed or table, from its edge
AT_WALL_M = (0.3, 0.42)  # centre of a person standing by a wall, from its face
UNSEEN_PROB = 0.6
UNSEEN_CAMERA_SHARE = 0.05  # at most this share of camera images may see them
UNSEEN_LIDAR_SCANS = 45  # at least this many scans must
SEEN_S = 3.0  # the other standers are in the camera's view this long, or longer
PAUSERS = (1, 2)
PAUSE_S = (20.0, 60.0)
GUIDE_GAP_M = (1.5, 1.65)  # the guide walks this far ahead (path length; waits make up the rest)
GUIDE_CHECK_M = (1.3, 2.3)  # the distance the guide keeps from the robot centre while walking
GUIDE_WALK_M = (3.0, 10.0)
PACERS = (1, 2)
PACER_LANE_M = (2.0, 4.0)
PACER_WALL_M = (0.3, 0.8)
PACER_ROUTE_M = (5.0, 12.0)  # preferred distance from the robot's path
PACER_SCANS_S = 4.0  # preferred: the LiDAR has the lane in view this long, or longer
WALKER_PROB = 0.4
PERSON_CLEAR_M = 0.3  # people's waypoints and paths keep this far from walls and furniture
PEOPLE_ROBOT_GAP_M = 0.1  # body disc to robot footprint, at every moment
PEOPLE_GAP_M = 0.55  # between two people's centres, at every moment
LONG_PAUSE_S = 100_000.0  # "stands for the rest of the tour"

# ---- sensor rig -------------------------------------------------------------------------
LIDAR_MOUNTS = {  # (x, y) on the base, yaw
    "front-left": ((0.38, 0.23), math.pi / 4),
    "front-right": ((0.38, -0.23), -math.pi / 4),
    "front-centre": ((0.4, 0.0), 0.0),
}
LIDAR_HEIGHT_M = (0.15, 0.3)
CAMERA_RATES_HZ = (2.0, 3.0, 5.0)
IMAGE_FORMATS = ("raw", "jpeg")
LABEL_ENCODINGS = ("mono16", "mono8")
SCAN_TOPICS = ("/scan", "/front_scan", "/lidar/scan")
CAMERA_TOPICS = (("/camera/image_raw", "/camera/camera_info"),
                 ("/camera/color/image_raw", "/camera/color/camera_info"))
LABEL_TOPICS = ("/camera/labels", "/segmentation/labels")
LIDAR_FRAMES = ("laser", "base_laser", "front_laser_link")
CAMERA_FRAMES = ("camera_optical_frame", "camera_color_optical_frame")

MAX_TRIES = 40  # worlds drawn per seed before giving up
_DT = 0.05  # time step of the people checks, s
_RES = 0.05  # keep-out raster, m per cell

_SHIRTS = [(180, 40, 40), (40, 120, 180), (230, 200, 60), (90, 160, 90), (240, 240, 240), (120, 60, 140),
           (200, 110, 50), (70, 70, 80), (20, 150, 150), (220, 120, 160)]
_TROUSERS = [(40, 45, 70), (30, 30, 32), (90, 80, 60), (60, 70, 90), (110, 110, 115), (50, 40, 35)]
_SKIN = [(224, 172, 140), (198, 140, 100), (140, 95, 65), (96, 64, 44), (240, 200, 170)]

_ROLE_RE = re.compile(r"^(" + "|".join(sorted(PERSON_ROLES, key=len, reverse=True)) + r")_\d+$")


def person_role(name: str) -> str | None:
    """The role a procedural world gave a person (from its name, ``guide_1003``), else None."""
    m = _ROLE_RE.match(name)
    return m.group(1) if m else None


class _Retry(Exception):
    """This draw failed a check; draw again from the same random stream."""


# ---------------------------------------------------------------------------------------
# Geometry


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / max(float(np.hypot(v[0], v[1])), 1e-12)


def _ccw(poly: NDArray[np.float64]) -> NDArray[np.float64]:
    x, y = poly[:, 0], poly[:, 1]
    area = float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return poly if area >= 0 else poly[::-1].copy()


def _hull(obj: WorldObject) -> NDArray[np.float64]:
    """The convex outline of an object's parts on the floor, CCW."""
    pts = np.concatenate([p.polygon for p in obj.parts]).astype(np.float32)
    return _ccw(cv2.convexHull(pts).reshape(-1, 2).astype(np.float64))


def _sat_gap(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """A lower bound of the distance between two convex polygons (negative: they overlap)."""
    best = -math.inf
    for poly in (a, b):
        e = np.roll(poly, -1, axis=0) - poly
        nrm = np.column_stack([e[:, 1], -e[:, 0]])
        nrm /= np.maximum(np.hypot(nrm[:, 0], nrm[:, 1]), 1e-12)[:, None]
        pa, pb = a @ nrm.T, b @ nrm.T
        gap = np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0))
        best = max(best, float(gap.max()))
    return best


def _edge_dist(poly: NDArray[np.float64], pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed distances (M, E) of points to the edge lines of a convex CCW polygon (positive inside)."""
    e = np.roll(poly, -1, axis=0) - poly
    n = np.column_stack([-e[:, 1], e[:, 0]]) / np.hypot(e[:, 0], e[:, 1])[:, None]
    return np.einsum("mek,ek->me", np.atleast_2d(pts)[:, None, :] - poly[None], n)


def _clip(poly: NDArray[np.float64], n: NDArray[np.float64], k: float) -> NDArray[np.float64]:
    """The part of a convex polygon where n·p ≥ k."""
    out = []
    m = len(poly)
    for i in range(m):
        p, q = poly[i], poly[(i + 1) % m]
        fp, fq = float(n @ p) - k, float(n @ q) - k
        if fp >= 0:
            out.append(p)
        if fp * fq < 0:
            out.append(p + (q - p) * (fp / (fp - fq)))
    return np.asarray(out)


def _yaw_facing(v: NDArray[np.float64]) -> float:
    """The yaw that turns an object's local +y axis (its front) to the direction ``v``."""
    return math.atan2(-float(v[0]), float(v[1]))


class _Obstacles:
    """Exact distances from points to a set of convex polygons (0 inside one)."""

    def __init__(self, polys: Sequence[NDArray[np.float64]], tags: Sequence[int]) -> None:
        self.tags = np.asarray(tags)
        self.a = np.concatenate(polys)
        self.e = np.concatenate([np.roll(p, -1, axis=0) for p in polys]) - self.a
        self.len2 = np.maximum(np.einsum("ek,ek->e", self.e, self.e), 1e-12)
        self.starts = np.concatenate([[0], np.cumsum([len(p) for p in polys])[:-1]])

    def dist(self, pts: NDArray[np.float64], exclude: Sequence[int] = ()) -> NDArray[np.float64]:
        pts = np.atleast_2d(np.asarray(pts, np.float64))
        out = np.empty(len(pts))
        keep = ~np.isin(self.tags, list(exclude)) if exclude else np.ones(len(self.tags), bool)
        for c0 in range(0, len(pts), 256):
            p = pts[c0:c0 + 256, None, :] - self.a[None]
            t = np.clip(np.einsum("mek,ek->me", p, self.e) / self.len2, 0.0, 1.0)
            d = np.hypot(p[..., 0] - t * self.e[:, 0], p[..., 1] - t * self.e[:, 1])
            cross = self.e[:, 0] * p[..., 1] - self.e[:, 1] * p[..., 0]
            dmin = np.minimum.reduceat(d, self.starts, axis=1)
            inside = np.minimum.reduceat(cross, self.starts, axis=1) >= 0
            dmin[inside] = 0.0
            out[c0:c0 + 256] = dmin[:, keep].min(axis=1) if keep.any() else np.inf
        return out

    def segment_clear(self, p: NDArray[np.float64], q: NDArray[np.float64], clear: float,
                      exclude: Sequence[int] = ()) -> bool:
        n = max(int(math.ceil(float(np.hypot(*(q - p))) / 0.05)), 1)
        s = np.linspace(0.0, 1.0, n + 1)[:, None]
        return bool(self.dist(p + s * (q - p), exclude).min() >= clear)


class _Raster:
    """A boolean keep-out grid over the building."""

    def __init__(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.x0, self.y0 = x0, y0
        self.img = np.zeros((int(math.ceil((y1 - y0) / _RES)) + 1, int(math.ceil((x1 - x0) / _RES)) + 1), np.uint8)

    def _px(self, poly: NDArray[np.float64]) -> NDArray[np.int32]:
        return np.round((poly - [self.x0, self.y0]) / _RES * 16).astype(np.int32)

    def fill(self, poly: NDArray[np.float64]) -> None:
        cv2.fillPoly(self.img, [self._px(poly)], 1, lineType=cv2.LINE_8, shift=4)

    def hits(self, poly: NDArray[np.float64]) -> bool:
        px = (poly - [self.x0, self.y0]) / _RES
        c0, r0 = np.floor(px.min(axis=0)).astype(int) - 1
        c1, r1 = np.ceil(px.max(axis=0)).astype(int) + 2
        h, w = self.img.shape
        c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, w), min(r1, h)
        if c1 <= c0 or r1 <= r0:
            return False
        crop = np.zeros((r1 - r0, c1 - c0), np.uint8)
        cv2.fillPoly(crop, [np.round((px - [c0, r0]) * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
        return bool((crop & self.img[r0:r1, c0:c1]).any())


# ---------------------------------------------------------------------------------------
# Building


@dataclass
class _Room:
    rect: tuple[float, float, float, float]  # x0, y0, x1, y1 of the wall centre lines
    poly: NDArray[np.float64]  # convex, CCW (a rectangle, or a pentagon where a corner is cut)
    corridor: bool = False
    kind: str = ""

    @property
    def area(self) -> float:
        x, y = self.poly[:, 0], self.poly[:, 1]
        return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


@dataclass
class _Door:
    a: int  # room indices; ``n`` points from room a into room b
    b: int
    centre: NDArray[np.float64]
    u: NDArray[np.float64]  # along the wall
    n: NDArray[np.float64]
    width: float
    tree: bool  # on the spanning tree the route follows

    def other(self, room: int) -> int:
        return self.b if room == self.a else self.a


@dataclass
class _Building:
    width: float
    height: float
    rooms: list[_Room]
    doors: list[_Door]
    walls: list[WorldObject]
    outline: NDArray[np.float64]
    chamfered: bool
    corridor: int | None  # index of the corridor room
    ids: IdCounter = field(default_factory=lambda: IdCounter(0))


def _split(rng: np.random.Generator, r: tuple[float, float, float, float], axis: int) -> tuple[
        tuple[float, float, float, float], tuple[float, float, float, float], tuple[tuple[float, float], ...]]:
    x0, y0, x1, y1 = r
    lo, hi = (x0, x1) if axis == 0 else (y0, y1)
    c = lo + (hi - lo) * rng.uniform(0.35, 0.65)
    c = round(float(np.clip(c, lo + MIN_ROOM_M, hi - MIN_ROOM_M)), 2)
    if axis == 0:
        return (x0, y0, c, y1), (c, y0, x1, y1), ((c, y0), (c, y1))
    return (x0, y0, x1, c), (x0, c, x1, y1), ((x0, c), (x1, c))


def _rect_poly(r: tuple[float, float, float, float]) -> NDArray[np.float64]:
    x0, y0, x1, y1 = r
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64)


def _building(rng: np.random.Generator) -> _Building:
    w = round(float(rng.uniform(*SIDE_M)), 1)
    h = round(float(rng.uniform(*SIDE_M)), 1)
    n_rooms = int(rng.integers(ROOMS[0], ROOMS[1] + 1))
    segments: list[tuple[tuple[float, float], ...]] = []
    rooms: list[tuple[float, float, float, float]] = []
    corridor_rect = None
    if rng.random() < CORRIDOR_PROB:
        cw = round(float(rng.uniform(*CORRIDOR_WIDTH_M)), 2)
        along_x = w >= h
        short = h if along_x else w
        if short - cw >= 2 * MIN_ROOM_M + 0.5:
            c0 = round(float(rng.uniform(MIN_ROOM_M + 0.25, short - cw - MIN_ROOM_M - 0.25)), 2)
            c1 = c0 + cw
            if along_x:
                rooms += [(0.0, 0.0, w, c0), (0.0, c1, w, h)]
                corridor_rect = (0.0, c0, w, c1)
                segments += [((0.0, c0), (w, c0)), ((0.0, c1), (w, c1))]
            else:
                rooms += [(0.0, 0.0, c0, h), (c1, 0.0, w, h)]
                corridor_rect = (c0, 0.0, c1, h)
                segments += [((c0, 0.0), (c0, h)), ((c1, 0.0), (c1, h))]
    if not rooms:
        rooms = [(0.0, 0.0, w, h)]
    while len(rooms) < n_rooms:
        splittable = [i for i, r in enumerate(rooms) if max(r[2] - r[0], r[3] - r[1]) >= 2 * MIN_ROOM_M]
        if not splittable:
            break
        area = np.array([(rooms[i][2] - rooms[i][0]) * (rooms[i][3] - rooms[i][1]) for i in splittable])
        i = splittable[int(rng.choice(len(splittable), p=area**2 / (area**2).sum()))]
        r = rooms[i]
        rw, rh = r[2] - r[0], r[3] - r[1]
        axis = 0 if rw >= rh else 1
        other = 1 - axis
        if rng.random() < 0.2 and (rw, rh)[other] >= 2 * MIN_ROOM_M:
            axis = other
        a, b, seg = _split(rng, r, axis)
        rooms[i:i + 1] = [a, b]
        segments.append(seg)
    if len(rooms) < ROOMS[0]:
        raise _Retry("too few rooms")
    leaves = [_Room(r, _rect_poly(r)) for r in rooms]
    corridor = None
    if corridor_rect is not None:
        corridor = len(leaves)
        leaves.append(_Room(corridor_rect, _rect_poly(corridor_rect), corridor=True, kind="corridor"))

    # the outline, perhaps with one corner cut off by a diagonal wall
    outline = _rect_poly((0.0, 0.0, w, h))
    chamfered = False
    if rng.random() < CHAMFER_PROB:
        k = int(rng.integers(4))
        corner = outline[k]
        owner = next(i for i, r in enumerate(leaves) if not r.corridor
                     and np.any(np.all(np.abs(r.poly - corner) < 1e-9, axis=1)))
        r = leaves[owner].rect
        limit = min(r[2] - r[0], r[3] - r[1]) - 1.8
        if limit >= CHAMFER_M[0]:
            size = round(float(rng.uniform(CHAMFER_M[0], min(CHAMFER_M[1], limit))), 2)
            inward = _unit(np.array([w / 2, h / 2]) - corner)
            sx, sy = np.sign(inward)
            nrm = np.array([sx, sy]) / math.sqrt(2.0)
            kk = float(nrm @ corner) + size / math.sqrt(2.0)
            outline = _clip(outline, nrm, kk)
            leaves[owner].poly = _clip(leaves[owner].poly, nrm, kk)
            chamfered = True

    # doors: every pair of rooms sharing enough wall is a candidate; a random spanning tree
    # (through the corridor first) plus a few extra doors
    cands: list[tuple[int, int, NDArray[np.float64], NDArray[np.float64], float, float]] = []
    for i in range(len(leaves)):
        for j in range(i + 1, len(leaves)):
            a, b = leaves[i].rect, leaves[j].rect
            for ax in (0, 1):
                o = 1 - ax
                for lo_r, hi_r, sign in ((a, b, 1.0), (b, a, -1.0)):
                    if abs(lo_r[2 + ax] - hi_r[ax]) > 1e-6:
                        continue
                    s0, s1 = max(a[o], b[o]), min(a[2 + o], b[2 + o])
                    if s1 - s0 < DOOR_WIDTH_M[0] + 2 * DOOR_MARGIN_M:
                        continue
                    n = np.zeros(2)
                    n[ax] = sign  # from room i into room j
                    cands.append((i, j, n, np.array([lo_r[2 + ax], s0, s1]), s0, s1))
    parent = list(range(len(leaves)))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    order = list(rng.permutation(len(cands)))
    if corridor is not None:
        order.sort(key=lambda c: 0 if corridor in cands[c][:2] else 1)
    doors: list[_Door] = []
    for c in order:
        i, j, n, line, s0, s1 = cands[c]
        joined = find(i) != find(j)
        if not joined and rng.random() >= EXTRA_DOOR_PROB:
            continue
        if joined:
            parent[find(i)] = find(j)
        dw = round(float(rng.uniform(*DOOR_WIDTH_M)), 2)
        dw = min(dw, s1 - s0 - 2 * DOOR_MARGIN_M)
        lo_c = s0 + DOOR_MARGIN_M + dw / 2
        # a door as wide as the wall leaves one place for it (the bounds may cross by a rounding error)
        sc = float(rng.uniform(lo_c, max(lo_c, s1 - DOOR_MARGIN_M - dw / 2)))
        ax = int(np.argmax(np.abs(n)))
        centre = np.zeros(2)
        centre[ax], centre[1 - ax] = line[0], sc
        u = np.zeros(2)
        u[1 - ax] = 1.0
        doors.append(_Door(i, j, centre, u, n, dw, joined))
    if len({find(i) for i in range(len(leaves))}) != 1:
        raise _Retry("rooms not connected")

    ids = IdCounter(0)
    segs: list[WallSegment] = []
    m = len(outline)
    for k in range(m):
        p0, p1 = outline[k], outline[(k + 1) % m]
        segs.append(((float(p0[0]), float(p0[1])), (float(p1[0]), float(p1[1])), []))
    for p0, p1 in segments:
        pa, pb = np.asarray(p0), np.asarray(p1)
        u = _unit(pb - pa)
        cuts = []
        for d in doors:
            rel = d.centre - pa
            if abs(float(rel[0] * u[1] - rel[1] * u[0])) < 1e-6 and -1e-6 <= float(rel @ u) <= np.hypot(*(pb - pa)):
                cuts.append((float(rel @ u), d.width + WALL_THICKNESS_M))
        segs.append((p0, p1, cuts))
    walls = walls_with_doors(ids, segs, WALL_THICKNESS_M, WALL_HEIGHT_M)
    return _Building(w, h, leaves, doors, walls, outline, chamfered, corridor, ids)


def _room_of(b: _Building, p: NDArray[np.float64]) -> int | None:
    for i, r in enumerate(b.rooms):
        if _edge_dist(r.poly, p).min() >= 0:
            return i
    return None


def _depth(room: _Room, p: NDArray[np.float64], d: NDArray[np.float64]) -> float:
    """How far a ray from ``p`` (on or in the room) along ``d`` runs inside the room's wall lines."""
    e = np.roll(room.poly, -1, axis=0) - room.poly
    n = np.column_stack([-e[:, 1], e[:, 0]]) / np.hypot(e[:, 0], e[:, 1])[:, None]
    f0 = np.einsum("ek,ek->e", p - room.poly, n)
    nd = n @ d
    t = np.where(nd < -1e-9, -f0 / np.where(nd < -1e-9, nd, -1.0), np.inf)
    t = t[t > 1e-6]
    return float(t.min()) if t.size else 0.0


def _approach(b: _Building, d: _Door, room: int) -> NDArray[np.float64]:
    v = d.n if room == d.b else -d.n
    depth = _depth(b.rooms[room], d.centre, v)
    return d.centre + v * min(APPROACH_M, 0.5 * depth)


def _room_point(rng: np.random.Generator, room: _Room, margin: float,
                away: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    x0, y0, x1, y1 = room.rect
    best, best_d = None, -math.inf
    for _ in range(60):
        p = np.array([rng.uniform(x0 + margin, max(x1 - margin, x0 + margin + 1e-3)),
                      rng.uniform(y0 + margin, max(y1 - margin, y0 + margin + 1e-3))])
        d = float(_edge_dist(room.poly, p).min())
        if away is not None and np.hypot(*(p - away)) < 1.2:
            continue
        if d >= margin:
            return p
        if d > best_d:
            best, best_d = p, d
    if best is None:
        raise _Retry("no room point")
    return best


# ---------------------------------------------------------------------------------------
# Route


def _plan_route(rng: np.random.Generator, b: _Building, extra: int) -> tuple[list[NDArray[np.float64]],
                                                                              list[tuple[int, int]]]:
    """Route points (a depth-first walk of the door tree) and marks (end index, rooms entered so far)."""
    tree: dict[int, list[_Door]] = {i: [] for i in range(len(b.rooms))}
    for d in b.doors:
        if d.tree:
            tree[d.a].append(d)
            tree[d.b].append(d)
    if b.corridor is not None:
        start = b.corridor
        x0, y0, x1, y1 = b.rooms[start].rect
        along_x = (x1 - x0) >= (y1 - y0)
        end = int(rng.integers(2))
        if along_x:
            p = np.array([x0 + 1.2 if end == 0 else x1 - 1.2, 0.5 * (y0 + y1)])
        else:
            p = np.array([0.5 * (x0 + x1), y0 + 1.2 if end == 0 else y1 - 1.2])
        pts = [p]
    else:
        start = int(rng.integers(len(b.rooms)))
        pts = [_room_point(rng, b.rooms[start], ROOM_POINT_MARGIN_M)]
    visited = {start}
    marks: list[tuple[int, int]] = []

    def visit(r: int) -> None:
        kids = [d for d in tree[r] if d.other(r) not in visited]
        while kids:
            cur = pts[-1]
            kids.sort(key=lambda d: float(np.hypot(*(_approach(b, d, r) - cur))))
            d = kids.pop(0)
            o = d.other(r)
            if o in visited:
                continue
            visited.add(o)
            pts.extend([_approach(b, d, r), d.centre.copy(), _approach(b, d, o)])
            has_kids = any(dd.other(o) not in visited for dd in tree[o])
            n_in = (0 if has_kids and rng.random() < 0.5 else 1) + int(rng.integers(0, extra + 1))
            if b.rooms[o].area < 14.0:
                n_in = min(n_in, 1)
            for _ in range(n_in):
                pts.append(_room_point(rng, b.rooms[o], ROOM_POINT_MARGIN_M, away=pts[-1]))
            marks.append((len(pts), len([v for v in visited if not b.rooms[v].corridor])))
            visit(o)
            pts.extend([_approach(b, d, o), d.centre.copy(), _approach(b, d, r)])

    visit(start)
    if marks:  # the whole walk, back to where it started
        marks.append((len(pts), marks[-1][1]))
    return pts, marks


def _route_world(b: _Building, route: NDArray[np.float64], name: str) -> World:
    return World(name, tuple(b.walls), (), route)


def _choose_route(rng: np.random.Generator, b: _Building, cfg: SimConfig, name: str) -> tuple[
        NDArray[np.float64], Trajectory, int]:
    n_rooms = len([r for r in b.rooms if not r.corridor])
    need = max(3, math.ceil(MIN_VISITED * n_rooms))
    target = float(rng.uniform(TOUR_S[0] + 20.0, TOUR_S[1]))  # the longest tour up to this
    for extra in (2, 1, 0):
        pts, marks = _plan_route(rng, b, extra)
        for end, seen in reversed(marks):
            if seen < need:
                break
            route = np.asarray(pts[:end])
            length = float(np.sum(np.hypot(*np.diff(route, axis=0).T)))
            if length / cfg.robot.max_speed > target:
                continue
            traj = plan_tour(_route_world(b, route, name), cfg.robot)
            if traj.duration > target:
                continue
            if traj.duration < TOUR_S[0]:
                break
            return route, traj, seen
    raise _Retry("no route of the right length")


# ---------------------------------------------------------------------------------------
# Furniture


class _Placer:
    """Places furniture: inside its room, off the keep-out raster, clear of other furniture."""

    def __init__(self, b: _Building, keepout: _Raster) -> None:
        self.b = b
        self.keepout = keepout
        self.objects: list[WorldObject] = []
        self.hulls: list[NDArray[np.float64]] = []
        self.wall_hulls = [p.polygon for o in b.walls for p in o.parts]

    def fits(self, obj: WorldObject, room: _Room, skip: Sequence[int] = ()) -> bool:
        hull = _hull(obj)
        if _edge_dist(room.poly, hull).min() < 0.5 * WALL_THICKNESS_M - 1e-6:
            return False
        if self.keepout.hits(hull):
            return False
        lo, hi = hull.min(axis=0), hull.max(axis=0)
        for o, h in zip(self.objects, self.hulls):
            if o.id in skip:
                continue
            if np.any(h.min(axis=0) > hi + FURNITURE_GAP_M) or np.any(h.max(axis=0) < lo - FURNITURE_GAP_M):
                continue
            if _sat_gap(hull, h) < FURNITURE_GAP_M:
                return False
        for w in self.wall_hulls:
            if np.any(w.min(axis=0) > hi + 0.01) or np.any(w.max(axis=0) < lo - 0.01):
                continue
            if _sat_gap(hull, w) < -1e-6:
                return False
        return True

    def add(self, obj: WorldObject, room: _Room, skip: Sequence[int] = ()) -> bool:
        if not self.fits(obj, room, skip):
            return False
        self.objects.append(obj)
        self.hulls.append(_hull(obj))
        return True

    def remove(self, ids: Sequence[int]) -> None:
        keep = [k for k, o in enumerate(self.objects) if o.id not in ids]
        self.objects = [self.objects[k] for k in keep]
        self.hulls = [self.hulls[k] for k in keep]


def _wall_slot(rng: np.random.Generator, room: _Room, along: float, depth: float,
               corner: bool = False) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """A spot against one of the room's walls for a piece ``along`` wide and ``depth`` deep:
    (centre, inward normal n, direction u along the wall)."""
    poly = room.poly
    m = len(poly)
    edges = []
    for k in range(m):
        a, b = poly[k], poly[(k + 1) % m]
        length = float(np.hypot(*(b - a)))
        if length >= along + WALL_THICKNESS_M + 0.1:
            edges.append((k, length))
    if not edges:
        return None
    lengths = np.array([e[1] for e in edges])
    k, length = edges[int(rng.choice(len(edges), p=lengths / lengths.sum()))]
    a = poly[k]
    u = _unit(poly[(k + 1) % m] - a)
    n = np.array([-u[1], u[0]])
    half_t = 0.5 * WALL_THICKNESS_M
    lo, hi = half_t + along / 2 + 0.01, length - half_t - along / 2 - 0.01
    if hi < lo:
        return None
    if corner:
        g = float(rng.uniform(*WALL_GAP_M))
        s = lo - 0.01 + g if rng.random() < 0.5 else hi + 0.01 - g
    else:
        s = float(rng.uniform(lo, hi))
    gap = float(rng.uniform(*WALL_GAP_M))
    centre = a + u * s + n * (half_t + gap + depth / 2)
    return centre, n, u


def _free_spot(rng: np.random.Generator, room: _Room, margin: float) -> tuple[NDArray[np.float64], float]:
    """A spot in the room and a yaw along one of its walls (now and then turned a little)."""
    x0, y0, x1, y1 = room.rect
    for _ in range(30):
        p = np.array([rng.uniform(x0 + margin, max(x1 - margin, x0 + margin + 1e-3)),
                      rng.uniform(y0 + margin, max(y1 - margin, y0 + margin + 1e-3))])
        if _edge_dist(room.poly, p).min() >= margin:
            break
    yaw = float(rng.integers(4)) * math.pi / 2
    if rng.random() < 0.25:
        yaw += float(rng.uniform(-0.5, 0.5))
    return p, yaw


def _chairs_around(rng: np.random.Generator, pl: _Placer, room: _Room, tab: WorldObject, w: float, d: float,
                   yaw: float, against_wall: bool, n_max: int) -> int:
    """Chairs around a table (or along its free side when it stands against a wall)."""
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s], [s, c]])
    centre = _hull(tab).mean(axis=0)
    slots = []
    xs = (-w / 4, w / 4) if w >= 1.2 else (0.0,)
    sides = (1.0,) if against_wall else (1.0, -1.0)
    for side in sides:
        for x in xs:
            slots.append((np.array([x, side * (d / 2 + 0.23 + rng.uniform(0.06, 0.14))]), side))
    if not against_wall:
        for side in (1.0, -1.0):
            slots.append((np.array([side * (w / 2 + 0.23 + rng.uniform(0.06, 0.14)), 0.0]), 2 * side))
    rng.shuffle(slots)
    n = 0
    for local, _side in slots:
        if n >= n_max:
            break
        p = centre + rot @ local
        v = _unit(centre - p)
        ch = chair(pl.b.ids(), (float(p[0]), float(p[1]), _yaw_facing(v)), color=_chair_colour(rng))
        if pl.add(ch, room):
            n += 1
    return n


def _chair_colour(rng: np.random.Generator) -> tuple[int, int, int]:
    cols = [(60, 90, 150), (150, 60, 50), (70, 120, 80), (105, 108, 118), (180, 150, 90)]
    return cols[int(rng.integers(len(cols)))]


def _against(rng: np.random.Generator, pl: _Placer, room: _Room, make: Any, along: float, depth: float,
             front_to_room: bool = True, corner: bool = False, tries: int = 25) -> WorldObject | None:
    """Place ``make(pose)`` against a wall; its local +y faces the room (or the wall)."""
    for _ in range(tries):
        slot = _wall_slot(rng, room, along, depth, corner)
        if slot is None:
            return None
        p, n, _ = slot
        obj = make((float(p[0]), float(p[1]), _yaw_facing(n if front_to_room else -n)))
        if pl.add(obj, room):
            return obj
    return None


def _furnish_bedroom(rng: np.random.Generator, pl: _Placer, room: _Room) -> None:
    ids = pl.b.ids
    _beds(rng, pl, room, 1 + int(room.area > 14) + int(room.area > 24 and rng.random() < 0.6))
    if rng.random() < 0.6:
        cw, cd = float(rng.uniform(0.6, 1.2)), float(rng.uniform(0.4, 0.6))
        _against(rng, pl, room, lambda pose: cabinet(ids(), pose, cw, cd, float(rng.uniform(1.2, 2.0))), cw, cd)
    if rng.random() < 0.4:
        _against(rng, pl, room, lambda pose: potted_plant(ids(), pose[0], pose[1]), 0.7, 0.7, corner=True)
    if rng.random() < 0.5:
        _against(rng, pl, room, lambda pose: chair(ids(), pose, _chair_colour(rng)), 0.46, 0.46)


def _beds(rng: np.random.Generator, pl: _Placer, room: _Room, n_beds: int) -> int:
    """Beds against the walls, each perhaps with a visitor's chair; how many were placed."""
    ids = pl.b.ids
    placed = 0
    for _ in range(n_beds):
        bw, bd = float(rng.uniform(*BED_W_M)), float(rng.uniform(*BED_D_M))
        if rng.random() < 0.75:  # headboard (+y) against the wall
            obj = _against(rng, pl, room, lambda pose, bw=bw, bd=bd: bed(ids(), pose, bw, bd), bw, bd,
                           front_to_room=False)
        else:  # a long side along the wall: local x along the normal
            obj = None
            for _ in range(25):
                slot = _wall_slot(rng, room, bd, bw, corner=rng.random() < 0.5)
                if slot is None:
                    break
                p, n, _ = slot
                yaw = math.atan2(n[1], n[0]) + (math.pi if rng.random() < 0.5 else 0.0)
                cand = bed(ids(), (float(p[0]), float(p[1]), yaw), bw, bd)
                if pl.add(cand, room):
                    obj = cand
                    break
        if obj is None:
            continue
        placed += 1
        if rng.random() < 0.7:  # a visitor's chair beside it
            cen = _hull(obj).mean(axis=0)
            for _ in range(10):
                p = cen + np.array([rng.uniform(-1.3, 1.3), rng.uniform(-1.3, 1.3)])
                ch = chair(ids(), (float(p[0]), float(p[1]), _yaw_facing(_unit(cen - p))), _chair_colour(rng))
                if pl.add(ch, room):
                    break
    return placed


def _couch(rng: np.random.Generator, pl: _Placer, room: _Room) -> WorldObject | None:
    """A couch with its back against a wall, sometimes in a corner."""
    ids = pl.b.ids
    cw, cd = float(rng.uniform(*COUCH_W_M)), float(rng.uniform(*COUCH_D_M))
    colours = [(105, 108, 118), (80, 60, 50), (60, 90, 150), (150, 120, 90), (110, 40, 40)]
    col = colours[int(rng.integers(len(colours)))]
    return _against(rng, pl, room, lambda pose: couch(ids(), pose, cw, cd, col), cw, cd, corner=rng.random() < 0.4)


def _furnish_lounge(rng: np.random.Generator, pl: _Placer, room: _Room) -> None:
    ids = pl.b.ids
    obj = _couch(rng, pl, room)
    if obj is not None:
        yaw = _yaw_from_obj(obj)
        front = np.array([-math.sin(yaw), math.cos(yaw)])
        cd = float(np.ptp(_hull(obj) @ front))  # the couch's depth
        # a low table in front of it
        tw, td = float(rng.uniform(0.8, 1.2)), float(rng.uniform(0.5, 0.7))
        p = _hull(obj).mean(axis=0) + front * (cd / 2 + float(rng.uniform(0.35, 0.5)) + td / 2)
        pl.add(table(ids(), (float(p[0]), float(p[1]), yaw), tw, td), room)
        if rng.random() < 0.7:  # a screen against a wall
            sw = float(rng.uniform(0.9, 1.3))
            _against(rng, pl, room, lambda pose: screen(ids(), pose, sw), max(sw, 0.5), 0.35)
    if rng.random() < 0.5:
        p, yaw = _free_spot(rng, room, 0.8)
        pl.add(chair(ids(), (float(p[0]), float(p[1]), yaw), _chair_colour(rng)), room)
    for _ in range(int(rng.integers(1, 3))):
        _against(rng, pl, room, lambda pose: potted_plant(ids(), pose[0], pose[1]), 0.7, 0.7, corner=True)


def _yaw_from_obj(obj: WorldObject) -> float:
    """The yaw of a couch: its back (the tallest part) is at local -y."""
    back = max(obj.parts, key=lambda p: p.z_max).polygon.mean(axis=0)
    centre = _hull(obj).mean(axis=0)
    return _yaw_facing(_unit(centre - back))


def _table_group(rng: np.random.Generator, pl: _Placer, room: _Room, against_wall: bool) -> bool:
    ids = pl.b.ids
    tw, td = float(rng.uniform(*TABLE_W_M)), float(rng.uniform(*TABLE_D_M))
    for _ in range(20):
        if against_wall:
            slot = _wall_slot(rng, room, tw, td)
            if slot is None:
                return False
            p, n, _ = slot
            yaw = _yaw_facing(n)
        else:
            p, yaw = _free_spot(rng, room, 1.2)
            yaw = round(yaw / (math.pi / 2)) * (math.pi / 2)
        tab = table(ids(), (float(p[0]), float(p[1]), yaw), tw, td)
        if not pl.add(tab, room):
            continue
        n_chairs = _chairs_around(rng, pl, room, tab, tw, td, yaw, against_wall, int(rng.integers(2, 5)))
        if n_chairs >= 2 or (against_wall and n_chairs >= 1):
            return True
        pl.remove([o.id for o in pl.objects if o.id >= tab.id])
    return False


def _furnish_dining(rng: np.random.Generator, pl: _Placer, room: _Room) -> None:
    ids = pl.b.ids
    for _ in range(1 + int(room.area > 22 and rng.random() < 0.6)):
        _table_group(rng, pl, room, against_wall=rng.random() < 0.4)
    if rng.random() < 0.75:  # a counter: a long table against a wall, with a stool or two
        cw, cd = float(rng.uniform(*COUNTER_W_M)), float(rng.uniform(*COUNTER_D_M))
        obj = _against(rng, pl, room, lambda pose: table(ids(), pose, cw, cd, (200, 200, 205)), cw, cd)
        if obj is not None:
            _chairs_around(rng, pl, room, obj, cw, cd, _yaw_from_table(obj), True, int(rng.integers(0, 3)))
    if rng.random() < 0.5:
        cw, cd = float(rng.uniform(0.8, 1.4)), float(rng.uniform(0.4, 0.6))
        _against(rng, pl, room, lambda pose: cabinet(ids(), pose, cw, cd), cw, cd)
    for _ in range(int(rng.integers(0, 3))):
        _against(rng, pl, room, lambda pose: chair(ids(), pose, _chair_colour(rng)), 0.46, 0.46)
    if rng.random() < 0.5:
        _against(rng, pl, room, lambda pose: potted_plant(ids(), pose[0], pose[1]), 0.7, 0.7, corner=True)
    if rng.random() < 0.3:
        sw = float(rng.uniform(0.9, 1.3))
        _against(rng, pl, room, lambda pose: screen(ids(), pose, sw), max(sw, 0.5), 0.35)


def _yaw_from_table(obj: WorldObject) -> float:
    """The yaw of a table placed by :func:`_against` (its long side along local x)."""
    top = max(obj.parts, key=lambda p: p.z_max).polygon
    e = top[1] - top[0]
    return math.atan2(e[1], e[0])


def _furnish_office(rng: np.random.Generator, pl: _Placer, room: _Room) -> None:
    ids = pl.b.ids
    for _ in range(1 + int(room.area > 12) + int(room.area > 22)):
        dw, dd = float(rng.uniform(1.2, 1.6)), float(rng.uniform(0.7, 0.8))
        desk = _against(rng, pl, room, lambda pose, dw=dw, dd=dd: table(ids(), pose, dw, dd), dw, dd)
        if desk is None:
            continue
        yaw = _yaw_from_table(desk)
        c, s = math.cos(yaw), math.sin(yaw)
        centre = _hull(desk).mean(axis=0)
        # the room side of the desk: local +y (it was placed facing the room)
        front = np.array([-s, c])
        p = centre + front * (dd / 2 + 0.3 + float(rng.uniform(0.0, 0.1)))
        pl.add(chair(ids(), (float(p[0]), float(p[1]), _yaw_facing(-front)), _chair_colour(rng)), room)
        if rng.random() < 0.7:
            q = centre - front * 0.15
            pl.add(monitor(ids(), (float(q[0]), float(q[1]), yaw + math.pi)), room, skip=[desk.id])
    if rng.random() < 0.7:
        cw, cd = float(rng.uniform(0.8, 1.4)), float(rng.uniform(0.4, 0.6))
        _against(rng, pl, room, lambda pose: cabinet(ids(), pose, cw, cd), cw, cd)
    if rng.random() < 0.5:
        _against(rng, pl, room, lambda pose: potted_plant(ids(), pose[0], pose[1]), 0.7, 0.7, corner=True)


def _furnish_corridor(rng: np.random.Generator, pl: _Placer, room: _Room) -> None:
    ids = pl.b.ids
    for _ in range(int(rng.integers(0, 4))):
        _against(rng, pl, room, lambda pose: chair(ids(), pose, _chair_colour(rng)), 0.46, 0.46)
    if rng.random() < 0.5:
        _against(rng, pl, room, lambda pose: potted_plant(ids(), pose[0], pose[1]), 0.7, 0.7)
    if rng.random() < 0.3:
        cw, cd = float(rng.uniform(0.8, 1.2)), 0.45
        _against(rng, pl, room, lambda pose: cabinet(ids(), pose, cw, cd), cw, cd)
    if rng.random() < 0.3:
        _against(rng, pl, room, lambda pose: screen(ids(), pose, 1.0), 1.0, 0.35)


_FURNISH = {"bedroom": _furnish_bedroom, "lounge": _furnish_lounge, "dining": _furnish_dining,
            "office": _furnish_office, "corridor": _furnish_corridor}


def _keepout(b: _Building, traj: Trajectory, cfg: SimConfig) -> _Raster:
    """The robot's lane along the planned tour and the space in front of every door."""
    r = _Raster(-1.0, -1.0, b.width + 1.0, b.height + 1.0)
    poses = traj.pose(np.arange(0.0, traj.duration, 0.02))
    step = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1])) + 0.3 * np.abs(wrap_angle(np.diff(poses[:, 2])))
    keep = np.nonzero(np.diff(np.concatenate([[0.0], np.cumsum(step)]) // 0.04, prepend=-1.0))[0]
    hl = cfg.robot.length / 2 + LANE_MARGIN_M
    hw = cfg.robot.width / 2 + LANE_MARGIN_M
    box = np.array([[-hl, -hw], [hl, -hw], [hl, hw], [-hl, hw]])
    polys = []
    for x, y, yaw in poses[keep]:
        cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
        polys.append(r._px(box @ np.array([[cos_yaw, sin_yaw], [-sin_yaw, cos_yaw]]) + [x, y]))
    cv2.fillPoly(r.img, polys, 1, lineType=cv2.LINE_8, shift=4)
    for d in b.doors:
        half = 0.5 * d.width + 0.15
        c = d.centre
        r.fill(np.array([c - d.u * half - d.n * DOOR_KEEPOUT_M, c + d.u * half - d.n * DOOR_KEEPOUT_M,
                         c + d.u * half + d.n * DOOR_KEEPOUT_M, c - d.u * half + d.n * DOOR_KEEPOUT_M]))
    return r


def _pillars(rng: np.random.Generator, b: _Building, pl: _Placer) -> None:
    if rng.random() >= PILLAR_PROB:
        return
    for _ in range(int(rng.integers(1, PILLARS[1] + 1))):
        cands = [r for r in b.rooms if r.area > 16]
        if not cands:
            return
        room = cands[int(rng.integers(len(cands)))]
        for _ in range(15):
            p, _ = _free_spot(rng, room, 0.9)
            if any(float(np.hypot(*(p - o.centroid()))) < PILLAR_SPACING_M for o in pl.objects if o.cls == "pillar"):
                continue
            obj = pillar(b.ids(), float(p[0]), float(p[1]), round(float(rng.uniform(0.3, 0.5)), 2),
                         WALL_HEIGHT_M, round_=bool(rng.random() < 0.4))
            if pl.add(obj, room):
                break


# ---------------------------------------------------------------------------------------
# People


@dataclass
class _Scene:
    """What the people are placed into, and where the sensors look during the tour."""

    b: _Building
    objects: tuple[WorldObject, ...]
    route: NDArray[np.float64]
    traj: Trajectory
    cfg: SimConfig
    obstacles: _Obstacles
    walls_raster: NDArray[np.uint8]
    raster_origin: tuple[float, float]
    path_xy: NDArray[np.float64]  # the robot's path, every ~5 cm
    times: NDArray[np.float64]  # the people check times
    people: list[Person] = field(default_factory=list)
    tracks: list[NDArray[np.float64]] = field(default_factory=list)
    pid: int = PERSON_ID0
    hfov: float = field(init=False)  # the camera's horizontal field of view, rad
    cams: NDArray[np.float64] = field(init=False)  # camera floor poses at the camera images
    lidars: NDArray[np.float64] = field(init=False)  # LiDAR floor poses at the scans
    lidar_half_fov: float = field(init=False)

    def __post_init__(self) -> None:
        cfg = self.cfg
        cam_t = np.arange(0.047, self.traj.duration, 1.0 / cfg.camera.rate_hz)
        scan_t = np.arange(0.013, self.traj.duration, 1.0 / cfg.lidar.rate_hz)
        k = np.asarray(cfg.camera.K)
        self.hfov = 2 * math.atan(min(k[0, 2], cfg.camera.width - k[0, 2]) / k[0, 0])
        cam_mount = np.array([cfg.camera.mount.xyz[0], cfg.camera.mount.xyz[1], 0.0])  # looks along base +x
        self.cams = se2_compose(self.traj.pose(cam_t), cam_mount)
        self.lidars = se2_compose(self.traj.pose(scan_t), mount_se2(cfg.lidar.mount.xyz, cfg.lidar.mount.rpy))
        self.lidar_half_fov = math.radians(cfg.lidar.fov_deg) / 2

    def route_dist(self, pts: NDArray[np.float64]) -> NDArray[np.float64]:
        pts = np.atleast_2d(pts)
        out = np.empty(len(pts))
        for k in range(len(pts)):
            out[k] = float(np.min(np.hypot(self.path_xy[:, 0] - pts[k, 0], self.path_xy[:, 1] - pts[k, 1])))
        return out

    def los(self, a: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether walls leave the straight line from each point ``a`` (M, 2) to ``q`` free."""
        s = np.linspace(0.02, 0.98, 80)
        pts = a[:, None, :] + s[None, :, None] * (q - a)[:, None, :]
        ix = np.clip(((pts[..., 0] - self.raster_origin[0]) / _RES).astype(int), 0, self.walls_raster.shape[1] - 1)
        iy = np.clip(((pts[..., 1] - self.raster_origin[1]) / _RES).astype(int), 0, self.walls_raster.shape[0] - 1)
        return ~self.walls_raster[iy, ix].astype(bool).any(axis=1)

    def _in_view(self, poses: NDArray[np.float64], q: NDArray[np.float64], half: float,
                 near: float, far: float) -> NDArray[np.bool_]:
        rel = q - poses[:, :2]
        dist = np.hypot(rel[:, 0], rel[:, 1])
        off = np.abs(wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - poses[:, 2]))
        seen = (off < half) & (dist > near) & (dist < far)
        if seen.any():
            seen[seen] = self.los(poses[seen, :2], q)
        return seen

    def camera_images(self, q: NDArray[np.float64], margin_deg: float = -3.0, far: float = 8.0) -> NDArray[np.bool_]:
        """Camera images whose view holds the point ``q`` (walls block; furniture and people do not)."""
        return self._in_view(self.cams, q, self.hfov / 2 + math.radians(margin_deg), 0.8, far)

    def lidar_scans(self, q: NDArray[np.float64], far: float = 12.0) -> NDArray[np.bool_]:
        """Scans whose field of view holds the point ``q`` (walls block)."""
        return self._in_view(self.lidars, q, self.lidar_half_fov, 0.1, far)

    def seen_enough(self, q: NDArray[np.float64]) -> bool:
        """A person standing at ``q`` is in the camera's view for ``SEEN_S`` or more of the tour."""
        return int(self.camera_images(q).sum()) >= SEEN_S * self.cfg.camera.rate_hz

    def accept(self, p: Person, robot_gap: float = PEOPLE_ROBOT_GAP_M) -> bool:
        """Add the person if they keep clear of the robot and of everyone else all tour."""
        track = np.array([p.state(float(t))[:2] for t in self.times])
        for other in self.tracks:
            if float(np.min(np.hypot(*(track - other).T))) < PEOPLE_GAP_M:
                return False
        gap, _, _ = people_clearance(World("check", (), (p,), self.route), self.traj, self.cfg.robot)
        if gap < robot_gap:
            return False
        self.people.append(p)
        self.tracks.append(track)
        return True


def _body(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "leg_radius": round(float(rng.uniform(0.05, 0.08)), 3),
        "hip_half_width": round(float(rng.uniform(0.08, 0.12)), 3),
        "stride": round(float(rng.uniform(0.28, 0.4)), 3),
        "height": round(float(rng.uniform(1.55, 1.92)), 2),
        "shirt": _SHIRTS[int(rng.integers(len(_SHIRTS)))],
        "trousers": _TROUSERS[int(rng.integers(len(_TROUSERS)))],
        "skin": _SKIN[int(rng.integers(len(_SKIN)))],
    }


def _make(sc: _Scene, role: str, waypoints: Sequence[NDArray[np.float64]] | NDArray[np.float64], body: dict[str, Any],
          **kw: Any) -> Person:
    pid = sc.pid
    return Person(id=pid, name=f"{role}_{pid}", waypoints=np.round(np.asarray(waypoints, float), 4), **body, **kw)


def _commit(sc: _Scene, p: Person, robot_gap: float = PEOPLE_ROBOT_GAP_M) -> bool:
    if sc.accept(p, robot_gap):
        sc.pid += 1
        return True
    return False


def _place_standing(rng: np.random.Generator, sc: _Scene, q: NDArray[np.float64]) -> bool:
    """Place a whole-tour standing person at ``q`` if the route passes at the right distance and the
    camera sees the spot long enough."""
    if not STANDING_ROUTE_M[0] <= float(sc.route_dist(q)[0]) <= STANDING_ROUTE_M[1]:
        return False
    if not sc.seen_enough(q):
        return False
    return _commit(sc, _make(sc, "standing", [q], _body(rng)))


def _standing_at_furniture(rng: np.random.Generator, sc: _Scene) -> bool:
    targets = [o for o in sc.objects if o.cls in ("bed", "dining table")]
    order = rng.permutation(len(targets))
    for k in order:
        o = targets[int(k)]
        hull = _hull(o)
        m = len(hull)
        for _ in range(12):
            i = int(rng.integers(m))
            a, b = hull[i], hull[(i + 1) % m]
            length = float(np.hypot(*(b - a)))
            if length < 0.5:
                continue
            u = (b - a) / length
            out = np.array([u[1], -u[0]])  # outward for a CCW hull
            q = a + u * float(rng.uniform(0.2, 0.8)) * length + out * float(rng.uniform(*AT_FURNITURE_M))
            if float(sc.obstacles.dist(q, exclude=[o.id])[0]) < PERSON_CLEAR_M:
                continue
            if not AT_FURNITURE_M[0] - 0.01 <= float(sc.obstacles.dist(q)[0]) <= AT_FURNITURE_M[1] + 0.01:
                continue
            if _place_standing(rng, sc, q):
                return True
    return False


def _standing_at_wall(rng: np.random.Generator, sc: _Scene) -> bool:
    for _ in range(80):
        room = sc.b.rooms[int(rng.integers(len(sc.b.rooms)))]
        poly = room.poly
        k = int(rng.integers(len(poly)))
        a, b = poly[k], poly[(k + 1) % len(poly)]
        u = _unit(b - a)
        n = np.array([-u[1], u[0]])
        q = a + (b - a) * float(rng.uniform(0.1, 0.9)) + n * (0.5 * WALL_THICKNESS_M + float(rng.uniform(*AT_WALL_M)))
        if float(sc.obstacles.dist(q)[0]) < PERSON_CLEAR_M:
            continue
        if _place_standing(rng, sc, q):
            return True
    return False


def _standing_free(rng: np.random.Generator, sc: _Scene) -> bool:
    for _ in range(80):
        k = int(rng.integers(len(sc.path_xy)))
        ang = float(rng.uniform(-math.pi, math.pi))
        q = sc.path_xy[k] + float(rng.uniform(*STANDING_ROUTE_M)) * np.array([math.cos(ang), math.sin(ang)])
        if _room_of(sc.b, q) is None or float(sc.obstacles.dist(q)[0]) < PERSON_CLEAR_M + 0.1:
            continue
        if _place_standing(rng, sc, q):
            return True
    return False


def _standing_unseen(rng: np.random.Generator, sc: _Scene) -> bool:
    """Someone beside or behind the route: the 270° LiDAR sees them, the forward camera rarely."""
    for _ in range(60):
        i = int(rng.integers(len(sc.traj.t)))
        x, y, yaw = sc.traj.pose(sc.traj.t[i])
        bearing = float(rng.uniform(math.radians(80), math.radians(160))) * (1 if rng.random() < 0.5 else -1)
        r = float(rng.uniform(1.0, 3.0))
        q = np.array([x + r * math.cos(yaw + bearing), y + r * math.sin(yaw + bearing)])
        if _room_of(sc.b, q) is None or float(sc.obstacles.dist(q)[0]) < PERSON_CLEAR_M + 0.1:
            continue
        if float(sc.route_dist(q)[0]) < 1.0:
            continue
        if sc.camera_images(q, margin_deg=6.0, far=15.0).mean() > UNSEEN_CAMERA_SHARE:
            continue
        if int(sc.lidar_scans(q, far=10.0).sum()) < UNSEEN_LIDAR_SCANS:
            continue
        if _commit(sc, _make(sc, "standing_unseen", [q], _body(rng))):
            return True
    return False

def _free_points(rng: np.random.Generator, sc: _Scene, room: _Room, n: int, clear: float,
                 min_leg: float) -> list[NDArray[np.float64]] | None:
    pts: list[NDArray[np.float64]] = []
    for _ in range(40 * n):
        p = _room_point(rng, room, 0.35)
        if float(sc.obstacles.dist(p)[0]) < clear + 0.05:
            continue
        if pts and (float(np.hypot(*(p - pts[-1]))) < min_leg or not sc.obstacles.segment_clear(pts[-1], p, clear)):
            continue
        pts.append(p)
        if len(pts) == n:
            if n > 2 and not sc.obstacles.segment_clear(pts[-1], pts[0], clear):
                pts.pop()
                continue
            return pts
    return None


def _pick_room(rng: np.random.Generator, sc: _Scene, min_area: float) -> _Room | None:
    visited = {_room_of(sc.b, p) for p in sc.path_xy[::20]}
    cands = [r for i, r in enumerate(sc.b.rooms) if i in visited and r.area >= min_area]
    if not cands:
        cands = [r for r in sc.b.rooms if r.area >= min_area]
    return cands[int(rng.integers(len(cands)))] if cands else None


def _pauser(rng: np.random.Generator, sc: _Scene) -> bool:
    for _ in range(25):
        room = _pick_room(rng, sc, 8.0)
        if room is None:
            return False
        n = 2 if rng.random() < 0.5 else 3
        pts = _free_points(rng, sc, room, n, PERSON_CLEAR_M, 1.5)
        if pts is None:
            continue
        body = _body(rng)
        speed = round(float(rng.uniform(0.6, 1.2)), 2)
        pause = ((int(rng.integers(n)), round(float(rng.uniform(*PAUSE_S)), 1)),)
        for _ in range(4):
            p = _make(sc, "pauser", pts, body, speed=speed, pauses=pause, loop=n > 2)
            p = replace(p, phase_s=round(float(rng.uniform(0.0, p.period_s)), 2))
            if _commit(sc, p):
                return True
    return False


def _walker(rng: np.random.Generator, sc: _Scene) -> bool:
    for _ in range(15):
        room = _pick_room(rng, sc, 12.0)
        if room is None:
            return False
        pts = _free_points(rng, sc, room, 2 + int(rng.integers(2)), PERSON_CLEAR_M, 2.0)
        if pts is None:
            continue
        body = _body(rng)
        speed = round(float(rng.uniform(0.9, 1.3)), 2)
        for _ in range(4):
            p = _make(sc, "walker", pts, body, speed=speed, loop=len(pts) > 2)
            p = replace(p, phase_s=round(float(rng.uniform(0.0, p.period_s)), 2))
            if _commit(sc, p):
                return True
    return False


def _pacer(rng: np.random.Generator, sc: _Scene) -> bool:
    fallback = None
    for attempt in range(160):
        room = sc.b.rooms[int(rng.integers(len(sc.b.rooms)))]
        poly = room.poly
        k = int(rng.integers(len(poly)))
        a, b = poly[k], poly[(k + 1) % len(poly)]
        length = float(np.hypot(*(b - a)))
        lane = float(rng.uniform(*PACER_LANE_M))
        if length < lane + 1.0:
            continue
        u = (b - a) / length
        n = np.array([-u[1], u[0]])
        s = float(rng.uniform(0.5, length - lane - 0.5))
        off = 0.5 * WALL_THICKNESS_M + float(rng.uniform(*PACER_WALL_M))
        p0 = a + u * s + n * off
        p1 = p0 + u * lane
        if min(float(sc.obstacles.dist(p0)[0]), float(sc.obstacles.dist(p1)[0])) < PERSON_CLEAR_M:
            continue
        if not sc.obstacles.segment_clear(p0, p1, PERSON_CLEAR_M):
            continue
        d = float(sc.route_dist(np.linspace(p0, p1, 9)).min())
        in_view = int(sc.lidar_scans(0.5 * (p0 + p1)).sum()) >= PACER_SCANS_S * sc.cfg.lidar.rate_hz
        if not (PACER_ROUTE_M[0] <= d <= PACER_ROUTE_M[1] and in_view):
            if d >= 2.0 and fallback is None:
                fallback = (p0, p1)
            if attempt < 120 or fallback is None:
                continue
            p0, p1 = fallback
        body = _body(rng)
        speed = round(float(rng.uniform(0.5, 1.0)), 2)
        pauses = tuple((i, round(float(rng.uniform(0.5, 3.0)), 1)) for i in (0, 1) if rng.random() < 0.6)
        for _ in range(3):
            p = _make(sc, "pacer", [p0, p1], body, speed=speed, pauses=pauses, loop=False)
            p = replace(p, phase_s=round(float(rng.uniform(0.0, p.period_s)), 2))
            if _commit(sc, p):
                return True
    return False


def _guide(rng: np.random.Generator, sc: _Scene) -> bool:
    """A person who walks 1.5–2 m ahead of the robot, then stops where the robot turns away.

    The guide walks the robot's own path ``gap`` ahead of it, a little faster than the robot and
    waiting a moment at each waypoint (1 m apart) until the robot is ``gap`` behind, so the
    distance holds while the robot speeds up and slows down. Where the robot turns by 60° or
    more the guide goes straight on, stops, and stands for the rest of the tour.
    """
    cfg = sc.cfg
    t = np.arange(0.0, sc.traj.duration, _DT)
    poses = sc.traj.pose(t)
    xy, yaw = poses[:, :2], np.unwrap(poses[:, 2])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    v = np.gradient(s, _DT)
    spin = (v < 0.02) & (np.abs(np.gradient(yaw, _DT)) > 0.05)  # turning in place
    route = sc.route
    # the time the robot passes each route vertex, in order
    k_of = [0]
    for i in range(1, len(route)):
        k0 = k_of[-1]
        seg = float(np.hypot(*(route[i] - route[i - 1])))
        hi = int(np.searchsorted(s, s[k0] + seg + 1.0))
        win = np.hypot(*(xy[k0:hi + 1] - route[i]).T)
        k_of.append(k0 + int(np.argmin(win)) if win.size else k0)
    gap = float(rng.uniform(*GUIDE_GAP_M))
    windows = []  # (first robot sample, last robot sample before the turn, incoming direction)
    for i in range(1, len(route) - 1):
        d_in, d_out = route[i] - route[i - 1], route[i + 1] - route[i]
        if np.hypot(*d_in) < 1e-6 or np.hypot(*d_out) < 1e-6:
            continue
        turn = abs(float(wrap_angle(math.atan2(d_out[1], d_out[0]) - math.atan2(d_in[1], d_in[0]))))
        if turn < math.radians(60):
            continue
        d_in = _unit(d_in)
        h_in = math.atan2(d_in[1], d_in[0])
        kb = k_of[i]
        while kb > 0 and abs(float(wrap_angle(yaw[kb] - h_in))) > math.radians(2):
            kb -= 1
        # the guide's point for each robot sample before kb, and whether it is 1.4-gap m in front
        k_lo = kb
        while k_lo > 0 and not spin[k_lo - 1]:
            k_lo -= 1
        ks = np.arange(k_lo, kb + 1)
        g = _guide_point(s[ks] + gap, s, xy, kb, d_in)
        rel = g - xy[ks]
        dist = np.hypot(rel[:, 0], rel[:, 1])
        ahead = rel[:, 0] * np.cos(yaw[ks]) + rel[:, 1] * np.sin(yaw[ks])
        ok = (dist >= GUIDE_CHECK_M[0] + 0.1) & (ahead >= 0.35 * dist)
        bad = np.nonzero(~ok)[0]
        ka = int(ks[bad[-1] + 1]) if bad.size else k_lo
        if ka > kb or s[kb] - s[ka] < GUIDE_WALK_M[0]:
            continue
        windows.append((ka, kb, d_in))
    if not windows:
        return False
    # prefer walks of 5 m or more, early in the tour (the guide waits less)
    windows.sort(key=lambda w: (s[w[1]] - s[w[0]] < 5.0, w[0]))
    v_g = cfg.robot.max_speed * 1.04
    for ka, kb, d_in in windows[:6]:
        walk = s[kb] - s[ka]
        if walk > GUIDE_WALK_M[1]:
            ka = int(np.searchsorted(s, s[kb] - float(rng.uniform(0.6, 1.0)) * GUIDE_WALK_M[1]))
        for extra in (0.0, 0.4):  # then stop, or walk on a little
            sig = np.arange(s[ka] + gap, s[kb] + gap + extra + 1e-9, 1.0)
            if sig[-1] < s[kb] + gap + extra - 1e-6:
                sig = np.append(sig, s[kb] + gap + extra)
            pts = _guide_point(sig, s, xy, kb, d_in)
            # when the robot is ``gap`` behind each point
            due = t[np.minimum(np.searchsorted(s[ka:], sig - gap, side="left") + ka, len(t) - 1)]
            due[0] = t[ka]
            pauses: list[tuple[int, float]] = []
            if due[0] > 1e-3:
                pauses.append((0, round(float(due[0]), 3)))
            clock = float(due[0])
            for j in range(1, len(pts)):
                clock += float(np.hypot(*(pts[j] - pts[j - 1]))) / v_g
                if due[j] > clock + 1e-3:
                    pauses.append((j, round(float(due[j] - clock), 3)))
                    clock = float(due[j])
            if pauses and pauses[-1][0] == len(pts) - 1:
                pauses.pop()
            pauses.append((len(pts) - 1, LONG_PAUSE_S))  # then stands for the rest of the tour
            if float(sc.obstacles.dist(pts).min()) < PERSON_CLEAR_M:
                continue
            if not all(sc.obstacles.segment_clear(pts[j - 1], pts[j], PERSON_CLEAR_M) for j in range(1, len(pts))):
                continue
            p = _make(sc, "guide", pts, _body(rng), speed=round(v_g, 4), pauses=tuple(pauses), loop=False)
            # while the guide walks, the robot is 1.3-2.3 m behind and the guide in front of it
            st = np.array([p.state(float(tt)) for tt in t])
            walking = st[:, 3] > 0
            if not walking.any():
                continue
            rel = st[walking, :2] - xy[walking]
            dist = np.hypot(rel[:, 0], rel[:, 1])
            ahead = rel[:, 0] * np.cos(yaw[walking]) + rel[:, 1] * np.sin(yaw[walking])
            if dist.min() < GUIDE_CHECK_M[0] or dist.max() > GUIDE_CHECK_M[1] or ahead.min() < 0.5:
                continue
            if _commit(sc, p, robot_gap=0.15):
                return True
    return False


def _guide_point(sig: NDArray[np.float64], s: NDArray[np.float64], xy: NDArray[np.float64], kb: int,
                 d_in: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points at path lengths ``sig`` along the robot's path up to sample ``kb``, then straight on."""
    out = np.empty((len(sig), 2))
    on = sig <= s[kb]
    out[on, 0] = np.interp(sig[on], s[:kb + 1], xy[:kb + 1, 0])
    out[on, 1] = np.interp(sig[on], s[:kb + 1], xy[:kb + 1, 1])
    out[~on] = xy[kb] + (sig[~on] - s[kb])[:, None] * d_in
    return out


# ---------------------------------------------------------------------------------------
# Sensor rig


def _rig(rng: np.random.Generator) -> tuple[dict[str, Any], str]:
    names = list(LIDAR_MOUNTS)
    where = names[int(rng.integers(len(names)))]
    (mx, my), myaw = LIDAR_MOUNTS[where]
    z = round(float(rng.uniform(*LIDAR_HEIGHT_M)), 3)
    cam_topic, info_topic = CAMERA_TOPICS[int(rng.integers(len(CAMERA_TOPICS)))]

    def pick(xs: Sequence[Any]) -> Any:
        return xs[int(rng.integers(len(xs)))]

    over = {
        "lidar": {"topic": pick(SCAN_TOPICS), "frame_id": pick(LIDAR_FRAMES), "fov_deg": 270.0,
                  "mount": {"xyz": [mx, my, z], "rpy": [0.0, 0.0, myaw]}},
        "camera": {"rate_hz": float(pick(CAMERA_RATES_HZ)), "image_format": pick(IMAGE_FORMATS),
                   "label_encoding": pick(LABEL_ENCODINGS), "image_topic": cam_topic, "info_topic": info_topic,
                   "label_topic": pick(LABEL_TOPICS), "frame_id": pick(CAMERA_FRAMES)},
    }
    c = over["camera"]
    text = (f"LiDAR {where} at {z:.2f} m on {over['lidar']['topic']}; camera {c['rate_hz']:g} Hz "
            f"{c['image_format']}, labels {c['label_encoding']} on {c['label_topic']}")
    return over, text


# ---------------------------------------------------------------------------------------
# The world


def random_world(seed: int) -> Scenario:
    """A new world for every seed: building, tour, furniture, people and sensor rig (module doc)."""
    seed = int(seed)
    if seed < 0:
        raise SimulationError(f"random world seeds are whole numbers from 0, got {seed}")
    rng = np.random.default_rng(seed)
    overrides, rig_text = _rig(rng)
    cfg = load_model(SimConfig, overrides, f"random:{seed}")
    why: list[str] = []
    for _ in range(MAX_TRIES):
        try:
            world = _draw(rng, f"random_{seed}", cfg, rig_text)
        except _Retry as exc:
            log.debug("random:%d: draw again (%s)", seed, exc)
            why.append(str(exc))
            continue
        return Scenario(world, overrides)
    raise SimulationError(f"random:{seed}: no valid world in {MAX_TRIES} draws (last: {', '.join(why[-3:])})")


def _draw(rng: np.random.Generator, name: str, cfg: SimConfig, rig_text: str) -> World:
    b = _building(rng)
    route, traj, seen = _choose_route(rng, b, cfg, name)
    try:
        check_clearance(_route_world(b, route, name), traj, cfg.robot)
    except SimulationError as exc:
        raise _Retry(f"walls too close to the route ({exc})") from None

    # room kinds: at least one bedroom, lounge and dining room
    rooms = [r for r in b.rooms if not r.corridor]
    kinds = ["bedroom", "lounge", "dining"]
    kinds += [ROOM_KINDS[int(rng.integers(len(ROOM_KINDS)))] for _ in range(len(rooms) - 3)]
    for r, k in zip(rooms, rng.permutation(kinds)):
        r.kind = str(k)
    pl = _Placer(b, _keepout(b, traj, cfg))
    _pillars(rng, b, pl)
    for r in sorted(b.rooms, key=lambda r: ROOM_KINDS.index(r.kind) if r.kind in ROOM_KINDS else 9):
        _FURNISH[r.kind](rng, pl, r)
    # where the robot's lane left no wall for the beds or the couch, another room gets one
    if not any(o.cls == "bed" for o in pl.objects):
        for r in sorted(rooms, key=lambda r: -r.area):
            if _beds(rng, pl, r, 1):
                break
    if not any(o.cls == "couch" for o in pl.objects):
        for r in sorted(rooms, key=lambda r: -r.area):
            if _couch(rng, pl, r) is not None:
                break
    walls = [p.polygon for o in b.walls for p in o.parts]
    against = [o for o, h in zip(pl.objects, pl.hulls) if o.cls in ("bed", "couch")
               and min(_sat_gap(h, w) for w in walls) < 0.04]
    if not against:
        raise _Retry("no bed or couch against a wall")
    objects = tuple(b.walls) + tuple(pl.objects)
    world = World(name, objects, (), route)
    try:
        clearance = check_clearance(world, traj, cfg.robot)
    except SimulationError as exc:
        raise _Retry(str(exc)) from None
    if clearance < ROUTE_CLEARANCE_M:
        raise _Retry(f"clearance {clearance:.2f} m")

    # people
    r0 = (-1.0, -1.0)
    wr = _Raster(r0[0], r0[1], b.width + 1.0, b.height + 1.0)
    for o in b.walls:
        for p in o.parts:
            wr.fill(p.polygon)
    obstacles = _Obstacles([_hull(o) for o in objects], [o.id for o in objects])
    path = np.column_stack([traj.x, traj.y])
    step = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    keep = np.concatenate([[True], np.diff(step // 0.05) > 0])
    sc = _Scene(b, objects, route, traj, cfg, obstacles, wr.img, r0, path[keep],
                np.arange(0.0, traj.duration, 0.1))
    if not _guide(rng, sc):
        raise _Retry("no guide")
    n_standing = int(rng.integers(STANDING[0], STANDING[1] + 1))
    if not _standing_at_furniture(rng, sc):
        raise _Retry("nobody can stand at furniture")
    for k in range(1, n_standing):
        (_standing_at_wall if k == 1 and rng.random() < 0.6 else _standing_free)(rng, sc)
    if rng.random() < UNSEEN_PROB:
        _standing_unseen(rng, sc)
    n_pausers = int(rng.integers(PAUSERS[0], PAUSERS[1] + 1))
    if sum(_pauser(rng, sc) for _ in range(n_pausers)) < 1:
        raise _Retry("no pauser")
    n_pacers = int(rng.integers(PACERS[0], PACERS[1] + 1))
    if sum(_pacer(rng, sc) for _ in range(n_pacers)) < 1:
        raise _Retry("no pacer")
    if rng.random() < WALKER_PROB:
        _walker(rng, sc)

    desc = _describe(b, pl.objects, sc.people, seen, traj, rig_text)
    return World(name, objects, tuple(sc.people), route, description=desc)


def _describe(b: _Building, furniture: Sequence[WorldObject], people: Sequence[Person], seen: int,
              traj: Trajectory, rig_text: str) -> str:
    n_rooms = len([r for r in b.rooms if not r.corridor])
    kinds: dict[str, int] = {}
    for r in b.rooms:
        if not r.corridor:
            kinds[r.kind] = kinds.get(r.kind, 0) + 1
    cls: dict[str, int] = {}
    for o in furniture:
        cls[o.cls] = cls.get(o.cls, 0) + 1
    roles: dict[str, int] = {}
    for p in people:
        role = person_role(p.name) or "person"
        roles[role] = roles.get(role, 0) + 1
    parts = [f"Random building {b.width:g} x {b.height:g} m{' (one corner cut diagonally)' if b.chamfered else ''}: "
             f"{n_rooms} rooms ({', '.join(f'{v} {k}' for k, v in sorted(kinds.items()))})"
             f"{' along a corridor' if b.corridor is not None else ''}, {len(b.doors)} doors; "
             f"the robot enters {seen} rooms in {traj.duration:.0f} s.",
             "Furniture: " + ", ".join(f"{v} {k}" for k, v in sorted(cls.items())) + ".",
             "People: " + ", ".join(f"{v} {k}" for k, v in sorted(roles.items())) + ".",
             rig_text + "."]
    return " ".join(parts)


def scenario_seed(name: str) -> int | None:
    """The seed of a ``random:SEED`` scenario name, else None."""
    if not name.startswith(SCENARIO_PREFIX):
        return None
    text = name[len(SCENARIO_PREFIX):].strip()
    if not text.isdigit():
        return None
    return int(text)

