"""A second session of any world: the same building a while later, for scoring ``semmap diff``.

``NAME:b`` (``random:7:b``, ``ward:b``, ``office:b2``...) is the world ``NAME`` after a recipe of
changes drawn from a seed (the world's own seed for ``random:SEED``, else 0; ``:bK`` adds K):

* furniture **removed** (1-2 pieces);
* furniture **moved and turned** (2-3 pieces, 0.3-2 m and up to ±90°), to free floor;
* furniture **added** (1-2 pieces: a chair, a plant, a table or a couch), half against a wall;
* a **new static obstacle** (a 0.8-1.4 m cabinet or shelf, static), against a wall;
* a **door closed** (a wall across a door gap the route does not use), when there is one;
* **other people**: half of the people gone, the rest at other moments of their walks, one new
  person standing for the whole tour;
* the tour **starts elsewhere**: the route driven the other way, so the robot starts at the far end
  facing another way.

Every change keeps the simulator's rules: furniture clear of walls, of other furniture (5 cm) and
of the robot's lane, the route collision-free with the same robot, people clear of furniture and
of the robot; a recipe that blocks the route is drawn again (up to five times). ``semmap simulate``
writes the truth of the changes against the base world (``ground_truth/changes.png``, ``changes.yaml``,
``changes.json``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError, SimulationError
from ..records import Mobility
from .scenarios import Scenario
from .world import Person, World, WorldObject, cabinet, chair, couch, potted_plant, table

__all__ = ["SESSION_SUFFIX", "parse_session_name", "session_b"]

SESSION_SUFFIX = ":b"
_RES = 0.02  # m per cell of the placement raster
_GAP = 0.05  # furniture keeps this far from other furniture and walls
_LANE = 0.55  # furniture keeps this far from the route's centre line (robot half-width + margin)
_TRIES = 60


def parse_session_name(name: str) -> tuple[str, int] | None:
    """``NAME:b`` or ``NAME:bK`` -> (``NAME``, K); None for any other name."""
    head, sep, tail = name.rpartition(":")
    if not sep or not head or not tail.startswith("b"):
        return None
    k = tail[1:]
    if k and not k.isdigit():
        return None
    return head, int(k or 0)


class _Floor:
    """A raster of what stands on the floor, to place furniture clear of everything."""

    def __init__(self, world: World) -> None:
        x0, y0, x1, y1 = world.bounds(margin=0.5)
        self.x0, self.y0 = x0, y0
        self.shape = (int(math.ceil((y1 - y0) / _RES)), int(math.ceil((x1 - x0) / _RES)))
        self.walls = np.zeros(self.shape, np.uint8)
        for o in world.objects:
            if o.mobility == Mobility.STATIC:
                for p in o.parts:
                    self._fill(self.walls, p.polygon)
        self.lane = np.zeros(self.shape, np.uint8)
        route = np.asarray(world.route, np.float64)
        if len(route) >= 2:
            pts = np.round((route - [x0, y0]) / _RES).astype(np.int32)
            cv2.polylines(self.lane, [pts], False, 1, thickness=max(1, int(round(2 * _LANE / _RES))))
        # inside the building: the flood fill from the route's start, walls as borders
        self.inside = np.zeros(self.shape, bool)
        if len(route):
            mask = np.zeros((self.shape[0] + 2, self.shape[1] + 2), np.uint8)
            img = self.walls.copy()
            seed = tuple(int(v) for v in np.round((route[0] - [x0, y0]) / _RES))
            cv2.floodFill(img, mask, seed, 2)
            self.inside = img == 2

    def _fill(self, img: NDArray[np.uint8], poly: NDArray[np.float64], value: int = 1) -> None:
        pts = np.round((np.asarray(poly) - [self.x0, self.y0]) / _RES * 16).astype(np.int32)
        cv2.fillPoly(img, [pts], value, lineType=cv2.LINE_8, shift=4)

    def footprint(self, obj: WorldObject) -> NDArray[np.bool_]:
        img = np.zeros(self.shape, np.uint8)
        for p in obj.parts:
            self._fill(img, p.polygon)
        return img > 0

    def fits(self, obj: WorldObject, furniture: list[WorldObject]) -> bool:
        """Inside the building, clear of walls and other furniture by 5 cm, off the robot's lane."""
        fp = self.footprint(obj)
        if not fp.any() or not np.all(self.inside[fp] | self.walls[fp].astype(bool)):
            return False
        grown = cv2.dilate(fp.astype(np.uint8), np.ones((2 * int(_GAP / _RES) + 1,) * 2, np.uint8)) > 0
        if (grown & (self.walls > 0)).any() or (fp & (self.lane > 0)).any():
            return False
        return all(not (o.id != obj.id and (grown & self.footprint(o)).any()) for o in furniture)

    def clearance(self, objects: list[WorldObject]) -> Callable[[tuple[float, float]], float]:
        """A function giving the distance (m) from a point to the nearest of ``objects``."""
        img = np.ones(self.shape, np.uint8)
        for o in objects:
            img[self.footprint(o)] = 0
        dist = cv2.distanceTransform(img, cv2.DIST_L2, 5) * _RES

        def at(xy: tuple[float, float]) -> float:
            c, r = int((xy[0] - self.x0) / _RES), int((xy[1] - self.y0) / _RES)
            return float(dist[r, c]) if 0 <= r < self.shape[0] and 0 <= c < self.shape[1] else 0.0

        return at

    def wall_spot(self, rng: np.random.Generator, depth: float) -> tuple[float, float, float] | None:
        """A point ``depth / 2`` + 3 cm in front of a wall face, and the yaw facing away from it."""
        dist = cv2.distanceTransform((self.walls == 0).astype(np.uint8), cv2.DIST_L2, 5) * _RES
        want = depth / 2 + 0.09  # from the wall's centre line: half its thickness (6 cm) and a 3 cm gap
        band = np.argwhere(self.inside & (np.abs(dist - want) < _RES) & (self.lane == 0))
        if not len(band):
            return None
        r, c = band[int(rng.integers(len(band)))]
        gy, gx = np.gradient(dist)
        yaw = math.atan2(float(gy[r, c]), float(gx[r, c])) - math.pi / 2  # local +y (the front) points away
        return self.x0 + (c + 0.5) * _RES, self.y0 + (r + 0.5) * _RES, yaw

    def free_spot(self, rng: np.random.Generator) -> tuple[float, float] | None:
        ok = np.argwhere(self.inside & (self.lane == 0))
        if not len(ok):
            return None
        r, c = ok[int(rng.integers(len(ok)))]
        return self.x0 + (c + 0.5) * _RES, self.y0 + (r + 0.5) * _RES


def _wall_axis(o: WorldObject) -> tuple[NDArray[np.float64], NDArray[np.float64], float] | None:
    """A straight wall's centre line (end points) and thickness; None for anything else."""
    if o.mobility != Mobility.STATIC or len(o.parts) != 1 or len(o.parts[0].polygon) != 4:
        return None
    p = o.parts[0].polygon
    e1, e2 = p[1] - p[0], p[2] - p[1]
    long_, short = (e1, e2) if np.linalg.norm(e1) >= np.linalg.norm(e2) else (e2, e1)
    if np.linalg.norm(short) > 0.3 or np.linalg.norm(long_) < 0.3:
        return None
    c = p.mean(axis=0)
    u = long_ / np.linalg.norm(long_)
    half = np.linalg.norm(long_) / 2
    return c - u * half, c + u * half, float(np.linalg.norm(short))


def _segments_cross(p: NDArray[np.float64], q: NDArray[np.float64], route: NDArray[np.float64],
                    margin: float) -> bool:
    """Whether the route passes within ``margin`` of the segment p-q."""
    n = max(2, int(np.linalg.norm(q - p) / 0.05) + 1)
    pts = np.linspace(p, q, n)
    for a, b in itertools.pairwise(route):
        ab = b - a
        t = np.clip(((pts - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        d = np.linalg.norm(pts - (a + t[:, None] * ab), axis=1)
        if d.min() < margin:
            return True
    return False


def _doors(world: World) -> list[tuple[NDArray[np.float64], NDArray[np.float64], float]]:
    """Door gaps: two collinear straight walls whose ends are 0.7-1.8 m apart."""
    axes = [a for a in (_wall_axis(o) for o in world.objects) if a is not None]
    out = []
    for i in range(len(axes)):
        for j in range(i + 1, len(axes)):
            (a0, a1, ta), (b0, b1, _) = axes[i], axes[j]
            u = (a1 - a0) / np.linalg.norm(a1 - a0)
            v = (b1 - b0) / np.linalg.norm(b1 - b0)
            if abs(float(u @ v)) < 0.999:
                continue
            nrm = np.array([-u[1], u[0]])
            if abs(float((b0 - a0) @ nrm)) > 0.02:
                continue
            ends = [(p, q) for p in (a0, a1) for q in (b0, b1)]
            p, q = min(ends, key=lambda e: float(np.linalg.norm(e[0] - e[1])))
            gap = float(np.linalg.norm(p - q))
            mid = 0.5 * (p + q)
            # the gap lies between the walls, not beside them
            if 0.7 <= gap <= 1.8 and all(np.linalg.norm(mid - e) >= gap / 2 - 1e-6 for e in (a0, a1, b0, b1)):
                out.append((p, q, ta))
    return out


def session_b(base: Scenario, seed: int, name: str | None = None) -> Scenario:
    """The world of ``base`` after the recipe of changes drawn from ``seed`` (see the module)."""
    from ..config import SimConfig, load_model, merge_overrides
    from .robot import check_clearance, people_clearance, plan_tour

    w = base.world
    cfg = load_model(SimConfig, merge_overrides(base.overrides, {}), f"scenario {w.name}")
    rng = np.random.default_rng([seed, 20])
    floor = _Floor(w)
    statics = [o for o in w.objects if o.mobility == Mobility.STATIC]
    furniture = [o for o in w.objects if o.mobility == Mobility.SEMI_STATIC]
    next_id = max([o.id for o in w.objects] + [p.id for p in w.people]) + 1
    done: list[str] = []

    # furniture removed
    order = list(rng.permutation(len(furniture)))
    removed = order[:int(rng.integers(1, 3))] if len(furniture) > 3 else []
    kept = [o for k, o in enumerate(furniture) if k not in removed]
    done += [f"removed {furniture[k].name}" for k in removed]
    # furniture moved and turned
    movers = [o for o in kept if o.cls in ("chair", "bed", "couch", "dining table", "potted plant", "tv", "bench")]
    n_moves = min(len(movers), int(rng.integers(2, 4)))
    for o in [movers[k] for k in rng.permutation(len(movers))]:
        if sum(d.startswith("moved") for d in done) >= n_moves:
            break
        for _ in range(_TRIES):
            dist = float(rng.uniform(0.3, 2.0))
            ang = float(rng.uniform(-math.pi, math.pi))
            turn = float(rng.uniform(-math.pi / 2, math.pi / 2)) if rng.random() < 0.6 else 0.0
            cand = o.moved(dist * math.cos(ang), dist * math.sin(ang), turn)
            if floor.fits(cand, kept):
                kept[kept.index(o)] = cand
                done.append(f"moved {o.name} {dist:.2f} m, turned {math.degrees(turn):.0f} deg")
                break
    # furniture added, half against a wall
    makers = [("chair", 0.5, chair),
              ("potted plant", 0.45, lambda i, pose: potted_plant(i, pose[0], pose[1])),
              ("dining table", 0.8, lambda i, pose: table(i, pose, 1.2, 0.7)),
              ("couch", 0.9, lambda i, pose: couch(i, pose, 1.8, 0.9))]
    for k in range(int(rng.integers(1, 3))):
        _cls, depth, make = makers[int(rng.integers(len(makers)))]
        for _ in range(_TRIES):
            spot = floor.wall_spot(rng, depth) if k % 2 == 0 else None
            if spot is None:
                free = floor.free_spot(rng)
                if free is None:
                    break
                spot = (free[0], free[1], float(rng.uniform(-math.pi, math.pi)))
            obj = make(next_id, spot)
            if floor.fits(obj, kept):
                kept.append(obj)
                next_id += 1
                done.append(f"added {obj.name}")
                break
    # a new static obstacle against a wall
    for _ in range(_TRIES):
        width = float(rng.uniform(0.8, 1.4))
        spot = floor.wall_spot(rng, 0.45)
        if spot is None:
            break
        obj = cabinet(next_id, spot, w=width, d=0.45)
        if floor.fits(obj, kept):
            statics.append(obj)
            next_id += 1
            done.append(f"added {obj.name} (static)")
            break
    # a door closed, when the route does not use it
    doors = [d for d in _doors(w) if not _segments_cross(d[0], d[1], np.asarray(w.route), 0.6)]
    if doors:
        p, q, thick = doors[int(rng.integers(len(doors)))]
        mid, v = 0.5 * (p + q), q - p
        length = float(np.linalg.norm(v))
        plug = cabinet(next_id, (float(mid[0]), float(mid[1]), math.atan2(v[1], v[0])), w=length + 0.02, d=thick,
                       h=2.4, cls="wall")
        plug = replace(plug, name=f"door_closed_{next_id}")
        statics.append(plug)
        next_id += 1
        done.append(f"closed the door at ({mid[0]:.1f}, {mid[1]:.1f})")
    # other people: half stay, at other moments of their walks; one more stands all tour
    people = [replace(p, phase_s=p.phase_s + float(rng.uniform(5.0, 40.0)))
              for k, p in enumerate(w.people) if rng.random() < 0.5]
    # the tour starts elsewhere: the route driven the other way
    route = np.asarray(w.route, np.float64)[::-1].copy()
    d0 = route[1] - route[0]
    world_b = replace(w, name=name or f"{w.name}:b", objects=tuple(statics + kept), people=tuple(people), route=route,
                      start_yaw=math.atan2(d0[1], d0[0]),
                      description=f"{w.name} later: " + "; ".join(done) + "; other people; the tour driven the "
                                                                          "other way.")
    try:
        traj = plan_tour(world_b, cfg.robot)
        check_clearance(world_b, traj, cfg.robot)
    except SimulationError as exc:
        raise SimulationError(f"{world_b.name}: the changed world blocks the route ({exc})") from None
    clear = floor.clearance(statics + kept)
    # people whose walks now cross moved or new furniture stay home
    walkers = []
    for person in world_b.people:
        period = max(person.period_s, 1.0)
        pts = [person.state(float(t))[:2] for t in np.arange(0.0, period, 0.25)]
        if min(clear((x, y)) for x, y in pts) >= 0.3:
            walkers.append(person)
    world_b = replace(world_b, people=tuple(walkers))
    for _ in range(_TRIES):
        at = floor.free_spot(rng)
        if at is None:
            break
        if clear(at) < 0.4:  # a body disc of 0.25 m and a gap
            continue
        person = Person(next_id, f"person_{next_id}_standing", np.array([at]))
        if people_clearance(replace(world_b, people=(person,)), traj, cfg.robot)[0] > 0.3:
            world_b = replace(world_b, people=(*world_b.people, person))
            break
    clearance = people_clearance(world_b, traj, cfg.robot)
    if clearance[0] <= 0.0:  # a walker whose old path now meets the robot: leave that one out
        world_b = replace(world_b, people=tuple(p for p in world_b.people if p.name != clearance[2]))
    return Scenario(world_b, base.overrides, base=w)


#: times the changes of a second session are drawn before its route is given up as blocked
_SESSION_ATTEMPTS = 5


def get_session(name: str) -> Scenario:
    """The scenario for a ``NAME:bK`` name (see the module)."""
    from .procedural import scenario_seed
    from .scenarios import get_scenario

    parsed = parse_session_name(name)
    if parsed is None:
        raise ConfigError(f"{name!r} is not a second-session name (NAME:b or NAME:bK, e.g. random:7:b)")
    base_name, k = parsed
    base = get_scenario(base_name)
    seed = (scenario_seed(base_name) or 0) + 7919 * k
    # a drawn change may block the robot's route (a cabinet where the tour's turn cuts a corner): the
    # changes are drawn again, from the next seed of a sequence of its own; a session that held at once
    # is the same as ever
    for attempt in range(_SESSION_ATTEMPTS):
        try:
            return session_b(base, seed + 104729 * attempt, name)
        except SimulationError:
            if attempt == _SESSION_ATTEMPTS - 1:
                raise
    raise AssertionError("unreachable")
