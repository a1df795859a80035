"""Built-in scenarios: ``demo``, ``ward``, ``office``, ``occlusion``, ``loop``, ``ward_b``, ``office_b``, and
``random:SEED``.

Each returns a :class:`Scenario`: the world, configuration overrides for the
simulator, and for the ``_b`` variants the base world they change. Geometry is
fixed per scenario; the seed only drives sensor noise and odometry error.

``random:SEED`` (for example ``random:7``) is a procedural world, new for every seed: a building
of 3–7 rooms, a tour through them, furniture against the walls, people with roles and a random
sensor rig (:func:`semmap.sim.procedural.random_world`). It is not listed in :data:`SCENARIOS`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ConfigError
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
    wall,
)

__all__ = ["SCENARIOS", "IdCounter", "Scenario", "WallSegment", "get_scenario", "walls_with_doors"]


@dataclass(frozen=True)
class Scenario:
    world: World
    overrides: dict[str, Any] = field(default_factory=dict)
    base: World | None = None  # for change scenarios: the world before the changes


class IdCounter:
    """Object ids of a world, counted up from ``start``."""

    def __init__(self, start: int) -> None:
        self.n = start

    def __call__(self) -> int:
        self.n += 1
        return self.n


# a straight wall from p0 to p1 with its door gaps: (p0, p1, [(centre along, width), ...])
WallSegment = tuple[tuple[float, float], tuple[float, float], list[tuple[float, float]]]


def walls_with_doors(ids: IdCounter, segments: Iterable[WallSegment],
                     thickness: float = 0.12, height: float = 2.6) -> list[WorldObject]:
    """Straight walls with door gaps: each segment is (p0, p1, [(centre along, width), ...])."""
    out = []
    for p0, p1, doors in segments:
        a, b = np.asarray(p0, float), np.asarray(p1, float)
        length = float(np.linalg.norm(b - a))
        u = (b - a) / length
        cuts = [0.0]
        for centre, width in sorted(doors):
            cuts += [centre - width / 2, centre + width / 2]
        cuts.append(length)
        for s0, s1 in zip(cuts[::2], cuts[1::2]):
            if s1 - s0 > 1e-6:
                q0, q1 = a + u * s0, a + u * s1
                out.append(wall(ids(), q0[0], q0[1], q1[0], q1[1], thickness, height))
    return out


_SHIRTS = [(180, 40, 40), (40, 120, 180), (230, 200, 60), (90, 160, 90), (240, 240, 240), (120, 60, 140),
           (200, 110, 50), (70, 70, 80)]


def _person(pid: int, k: int, waypoints: list[tuple[float, float]], **kw: Any) -> Person:
    return Person(id=pid, name=f"person_{pid}", waypoints=np.asarray(waypoints, float),
                  shirt=_SHIRTS[k % len(_SHIRTS)], **kw)


# ---------------------------------------------------------------------------------------
# demo: one 8 m x 6 m room, about 35 s


def demo() -> Scenario:
    ids = IdCounter(0)
    objs = walls_with_doors(ids, [((0, 0), (8, 0), []), ((8, 0), (8, 6), []), ((8, 6), (0, 6), []),
                        ((0, 6), (0, 0), [(3.0, 1.0)])])
    objs += [
        pillar(ids(), 2.5, 4.5),
        table(ids(), (5.0, 4.2, 0.0)),
        chair(ids(), (4.6, 3.4, 0.0)),
        chair(ids(), (5.4, 3.4, 0.0)),
        couch(ids(), (2.2, 0.65, 0.0)),
        potted_plant(ids(), 7.4, 0.6),
        screen(ids(), (0.45, 4.0, -math.pi / 2)),
    ]
    people = (
        _person(501, 0, [(3.0, 1.45), (6.3, 1.45)], speed=1.1, loop=False),
        _person(502, 1, [(6.0, 2.95)]),  # stands still beside the route the whole tour
    )
    route = [(1.2, 2.2), (7.0, 2.2), (7.0, 5.3), (1.2, 5.3), (1.2, 2.8)]
    return Scenario(World("demo", tuple(objs), people, np.asarray(route, float), start_yaw=0.0,
                          description="A small room: table, chairs, couch, plant, screen, one walking "
                                      "and one standing person."))


# ---------------------------------------------------------------------------------------
# ward: a hospital corridor with patient rooms on both sides


def _ward_building(ids: IdCounter) -> list[WorldObject]:
    doors = [(3.0 + 6.0 * i, 1.4) for i in range(5)]
    segs: list[WallSegment] = [
        ((0, 0), (30, 0), doors),  # corridor south wall
        ((0, 2.4), (30, 2.4), doors),  # corridor north wall
        ((0, -5.0), (0, 7.4), []),
        ((30, -5.0), (30, 7.4), []),
        ((0, 7.4), (30, 7.4), []),
        ((0, -5.0), (30, -5.0), []),
    ]
    segs += [((6.0 * i, 2.4), (6.0 * i, 7.4), []) for i in range(1, 5)]
    segs += [((6.0 * i, 0.0), (6.0 * i, -5.0), []) for i in range(1, 5)]
    return walls_with_doors(ids, segs)


def _ward_furniture(ids: IdCounter) -> list[WorldObject]:
    objs: list[WorldObject] = []
    for i in range(5):
        xr = 6.0 * i
        # north room i: beds with headboards on the north wall, a chair between them
        objs += [bed(ids(), (xr + 1.6, 6.24, 0.0)), bed(ids(), (xr + 4.4, 6.24, 0.0)),
                 chair(ids(), (xr + 3.0, 6.7, math.pi)), potted_plant(ids(), xr + 0.45, 2.95)]
        # south room i: mirrored
        objs += [bed(ids(), (xr + 1.6, -3.84, math.pi)), bed(ids(), (xr + 4.4, -3.84, math.pi)),
                 chair(ids(), (xr + 3.0, -4.3, 0.0))]
    # waiting chairs along the corridor's north wall, a plant and a screen in the corridor
    for x in (4.6, 5.15, 16.6, 17.15):
        objs.append(chair(ids(), (x, 2.08, math.pi)))
    objs.append(potted_plant(ids(), 12.0, 2.0))
    objs.append(screen(ids(), (23.8, 2.15, math.pi)))
    return objs


def _ward_people(variant: int) -> tuple[Person, ...]:
    if variant == 0:
        return (
            _person(501, 0, [(2.0, 0.5), (28.5, 0.5)], speed=1.3, loop=False, phase_s=4.0),
            _person(502, 1, [(10.3, 4.6)]),  # a visitor standing by a bed in room N2
            _person(503, 2, [(2.4, 1.25), (14.6, 1.25), (15.0, 4.6), (15.0, 4.6)], speed=0.85, loop=False,
                    pauses=((2, 120.0),)),  # walks just ahead of the robot, then into room N3
            _person(504, 3, [(19.0, -0.8), (19.0, -2.5)], speed=0.6, loop=False, pauses=((0, 5.0), (1, 5.0))),
            _person(505, 4, [(26.5, 0.45), (27.0, 0.1), (27.0, -3.0)], speed=1.0, loop=False,
                    pauses=((0, 45.0), (2, 200.0))),
            _person(506, 5, [(25.9, 0.5)]),  # chatting with 505, stays
        )
    return (
        _person(511, 6, [(28.5, 0.55), (2.0, 0.55)], speed=1.2, loop=False, phase_s=2.0),
        _person(512, 7, [(22.4, -2.0)]),
        _person(513, 0, [(13.0, 0.5), (13.0, 0.5)], pauses=((0, 30.0),)),
        _person(514, 1, [(7.3, 3.1), (7.3, 4.6)], speed=0.7, loop=False, pauses=((0, 4.0),)),
    )


def _ward_route(reverse: bool) -> list[tuple[float, float]]:
    route = [(1.0, 1.2), (9.0, 1.2), (9.0, 4.3), (9.0, 1.2), (21.0, 1.2), (21.0, -1.9), (21.0, 1.2),
             (28.8, 1.2), (27.0, 1.2), (1.6, 1.2)]
    if reverse:
        route = [(28.8, 1.2), (21.0, 1.2), (21.0, -1.9), (21.0, 1.2), (9.0, 1.2), (9.0, 4.3), (9.0, 1.2),
                 (1.0, 1.2), (3.0, 1.2), (27.5, 1.2)]
    return route


def ward() -> Scenario:
    ids = IdCounter(0)
    objs = _ward_building(ids) + _ward_furniture(ids)
    return Scenario(World("ward", tuple(objs), _ward_people(0), np.asarray(_ward_route(False), float),
                          start_yaw=0.0,
                          description="Hospital corridor, 30 m, with ten patient rooms (beds, chairs, plants), "
                                      "waiting chairs, a screen, and six people: walking, standing for the "
                                      "whole tour, pausing, and walking just ahead of the robot."))


def ward_b() -> Scenario:
    base = ward().world
    objs = {o.name: o for o in base.objects}
    # beds in room N2 and S4 rolled, one corridor chair taken away, plant and screen moved
    moved = {
        "bed_33": objs["bed_33"].moved(0.0, -0.9),  # room N2, second bed pulled from the wall
        "bed_50": objs["bed_50"].moved(-0.7, 0.5),  # room S4, first bed
        "potted_plant_64": objs["potted_plant_64"].moved(1.2, 0.0),  # corridor plant
        "tv_65": objs["tv_65"].moved(-2.3, 0.0),  # corridor screen
    }
    removed = {"chair_60", "chair_61"}  # two waiting chairs
    new_objs = [moved.get(o.name, o) for o in base.objects if o.name not in removed]
    new_objs.append(cabinet(900, (19.6, 2.1, 0.0), w=1.2, d=0.45))  # a new built-in cabinet
    world = World("ward_b", tuple(new_objs), _ward_people(1), np.asarray(_ward_route(True), float),
                  start_yaw=math.pi,
                  description="The ward a week later: two beds moved, two waiting chairs gone, a plant and "
                              "the screen moved, a new cabinet in the corridor, other people; the tour "
                              "starts from the east end.")
    return Scenario(world, base=base)


# ---------------------------------------------------------------------------------------
# office: open plan with pillars, desks, a lounge


def _office_objects(ids: IdCounter, variant: int) -> list[WorldObject]:
    objs = walls_with_doors(ids, [((0, 0), (20, 0), []), ((20, 0), (20, 14), []), ((20, 14), (0, 14), []),
                        ((0, 14), (0, 0), [(7.0, 1.2)])])
    objs += [pillar(ids(), x, y, 0.5) for x in (5.0, 10.0, 15.0) for y in (4.5, 9.5)]
    for x in (4.0, 7.5, 11.0, 14.5):  # south desks, users face north
        objs += [table(ids(), (x, 2.6, 0.0), 1.6, 0.8), chair(ids(), (x - 0.4, 1.8, 0.0)),
                 chair(ids(), (x + 0.4, 1.8, 0.0)), monitor(ids(), (x, 2.8, 0.0))]
    for x in (4.0, 7.5, 11.0):  # north desks, users face south
        objs += [table(ids(), (x, 11.6, 0.0), 1.6, 0.8), chair(ids(), (x - 0.4, 12.4, math.pi)),
                 chair(ids(), (x + 0.4, 12.4, math.pi)), monitor(ids(), (x, 11.4, math.pi))]
    objs += [
        couch(ids(), (16.5, 13.3, math.pi)),
        table(ids(), (16.5, 12.0, 0.0), 1.0, 0.6),
        potted_plant(ids(), 19.3, 13.3),
        potted_plant(ids(), 0.7, 13.3),
        potted_plant(ids(), 19.3, 0.7),
        screen(ids(), (19.55, 11.8, math.pi / 2)),
    ]
    return objs


def _office_people(variant: int) -> tuple[Person, ...]:
    if variant == 0:
        return (
            _person(501, 2, [(3.0, 7.95), (17.0, 7.95)], speed=1.3, loop=False),
            _person(502, 3, [(5.75, 2.4)]),  # standing between desks the whole tour
            _person(503, 4, [(12.5, 6.0), (12.5, 8.6), (7.5, 8.6), (7.5, 6.0)], speed=1.1),
            _person(504, 5, [(17.6, 11.5)]),  # standing in the lounge
            _person(505, 6, [(9.25, 11.0), (12.8, 11.0)], speed=0.9, loop=False, pauses=((0, 20.0), (1, 20.0))),
        )
    return (
        _person(511, 7, [(16.0, 8.0), (3.5, 8.0)], speed=1.2, loop=False),
        _person(512, 0, [(9.25, 2.4)]),
        _person(513, 1, [(2.6, 12.0), (2.6, 5.0)], speed=0.8, loop=False, pauses=((1, 10.0),)),
    )


_OFFICE_ROUTE = [(1.6, 7.0), (18.2, 7.0), (18.2, 10.4), (1.8, 10.4), (1.8, 3.6), (17.0, 3.6), (8.0, 3.6)]


def office() -> Scenario:
    ids = IdCounter(0)
    objs = _office_objects(ids, 0)
    return Scenario(World("office", tuple(objs), _office_people(0), np.asarray(_OFFICE_ROUTE, float),
                          start_yaw=0.0,
                          description="Open-plan office, 20 m x 14 m: six pillars, seven desks with chairs and "
                                      "monitors, a lounge with couch, plants and a screen, five people."))


def office_b() -> Scenario:
    base = office().world
    objs = {o.name: o for o in base.objects}
    moved = {name: objs[name].moved(1.6, -0.3) for name in ("dining_table_24", "chair_25", "chair_26", "tv_27")}
    moved |= {
        "chair_13": objs["chair_13"].moved(-0.6, -0.3),
        "couch_40": objs["couch_40"].moved(-2.2, 0.0),
        "potted_plant_43": objs["potted_plant_43"].moved(0.0, -1.5),
    }
    removed = {"chair_21", "chair_22"}
    new_objs = [moved.get(o.name, o) for o in base.objects if o.name not in removed]
    new_objs.append(cabinet(900, (9.25, 13.7, 0.0), w=1.2, d=0.45))
    route = [(18.2, 5.5), (18.2, 10.4), (1.8, 10.4), (1.8, 3.6), (16.5, 3.6), (16.5, 7.0), (4.5, 7.0)]
    world = World("office_b", tuple(new_objs), _office_people(1), np.asarray(route, float), start_yaw=math.pi / 2,
                  description="The office later: a desk moved with its chairs and monitor, chairs moved or gone, "
                              "the couch and a plant "
                              "moved, a new cabinet, other people; the tour starts in the south-east.")
    return Scenario(world, base=base)


# ---------------------------------------------------------------------------------------
# occlusion: people and chairs close in front of the robot, walls behind


def occlusion() -> Scenario:
    ids = IdCounter(0)
    objs = walls_with_doors(ids, [((0, 0), (12, 0), []), ((12, 0), (12, 4), []), ((12, 4), (0, 4), []),
                        ((0, 4), (0, 0), [])])
    objs += [
        chair(ids(), (3.2, 2.1, math.pi)),
        chair(ids(), (5.6, 2.4, math.pi * 0.8)),
        chair(ids(), (7.4, 0.35, 0.0)),
        table(ids(), (9.0, 2.6, 0.0), 1.2, 0.7),
        chair(ids(), (9.0, 2.05, 0.0)),
        potted_plant(ids(), 11.5, 3.5),
    ]
    people = (
        _person(501, 0, [(2.2, 2.2)]),
        _person(502, 1, [(4.4, 2.0)]),
        _person(503, 2, [(6.2, 0.45)]),
        _person(504, 3, [(8.0, 2.3)]),
        _person(505, 4, [(11.1, 1.2)]),  # right in front of the route's end, the end wall behind
        _person(506, 5, [(3.0, 3.3), (10.0, 3.3)], speed=0.5, loop=False),
    )
    route = [(0.8, 1.2), (10.2, 1.2), (2.0, 1.2)]
    return Scenario(World("occlusion", tuple(objs), people, np.asarray(route, float), start_yaw=0.0,
                          description="People and chairs 1-2 m in front of the robot with walls behind them: "
                                      "with the corner LiDAR, background points land on foreground masks."),
                    overrides={"robot": {"max_speed": 0.4}})


# ---------------------------------------------------------------------------------------
# loop: a ring corridor round a block of rooms, driven once round and on past the start

_LOOP_HALF = 1.4  # half the ring corridor's width (2.8 m between the walls' centre lines)
# the ring's centre line: 40 m x 20 m, corners (0, 0) and (40, 20)
_LOOP_ROUTE = [(3.0, 0.0), (40.0, 0.0), (40.0, 20.0), (0.0, 20.0), (0.0, 0.0), (18.0, 0.0)]


def _loop_building(ids: IdCounter) -> list[WorldObject]:
    h = _LOOP_HALF
    lo, hi = -h, 40.0 + h  # outer walls along x
    lo_y, hi_y = -h, 20.0 + h  # outer walls along y
    door = 1.2

    def doors_at(x0: float, xs: Iterable[float]) -> list[tuple[float, float]]:
        return [(x - x0, door) for x in xs]

    segs: list[WallSegment] = [
        # outer ring wall; the west side has a 3 m deep lounge alcove (y 6..14)
        ((lo, lo_y), (hi, lo_y), doors_at(lo, (6.0, 14.0, 22.0, 30.0))),  # south, doors to rooms S1..S4
        ((lo, hi_y), (hi, hi_y), doors_at(lo, (8.5, 20.0, 31.5))),  # north, doors to rooms N1..N3
        ((hi, lo_y), (hi, hi_y), []),  # east
        ((lo, lo_y), (lo, 6.0), []), ((lo, 6.0), (lo - 3.0, 6.0), []), ((lo - 3.0, 6.0), (lo - 3.0, 14.0), []),
        ((lo - 3.0, 14.0), (lo, 14.0), []), ((lo, 14.0), (lo, hi_y), []),
        # rooms outside the ring: four to the south, three to the north
        ((2.0, lo_y - 5.0), (34.0, lo_y - 5.0), []),
        ((3.0, hi_y + 5.0), (37.0, hi_y + 5.0), []),
    ]
    segs += [((x, lo_y), (x, lo_y - 5.0), []) for x in (2.0, 10.0, 18.0, 26.0, 34.0)]
    segs += [((x, hi_y), (x, hi_y + 5.0), []) for x in (3.0, 14.0, 26.0, 37.0)]
    # the central block: 37.2 m x 17.2 m, eight rooms, five of them with a door onto the ring
    b0, b1 = h, 40.0 - h
    c0, c1 = h, 20.0 - h
    segs += [
        ((b0, c0), (b1, c0), doors_at(b0, (5.5, 25.0))),
        ((b0, c1), (b1, c1), doors_at(b0, (15.0, 34.5))),
        ((b0, c0), (b0, c1), [(14.0 - c0, door)]),
        ((b1, c0), (b1, c1), [(6.0 - c0, door)]),
        ((b0, 10.0), (b1, 10.0), []),
    ]
    segs += [((x, c0), (x, c1), []) for x in (10.0, 20.0, 30.0)]
    objs = walls_with_doors(ids, segs)
    # pilasters along the east wall: something for scan matching on the ring's short side
    objs += [pillar(ids(), hi, y, 0.4) for y in (4.0, 8.0, 12.0, 16.0)]
    return objs


def _loop_furniture(ids: IdCounter) -> list[WorldObject]:
    h = _LOOP_HALF
    objs: list[WorldObject] = []
    # south corridor: waiting chairs and a plant against the outer wall, a screen at the east end
    objs += [chair(ids(), (x, -h + 0.3, 0.0)) for x in (10.0, 10.55, 18.0, 18.55)]
    objs += [potted_plant(ids(), 26.5, -h + 0.5), screen(ids(), (34.5, -h + 0.25, 0.0))]
    # north corridor: chairs and a table against the block, plants against the outer wall
    objs += [chair(ids(), (x, 20.0 - h + 0.3, 0.0)) for x in (24.0, 24.55)]
    objs += [table(ids(), (27.0, 20.0 - h + 0.4, 0.0), 1.2, 0.6)]
    objs += [potted_plant(ids(), x, 20.0 + h - 0.45) for x in (12.0, 36.0)]
    # west lounge alcove: a couch facing the ring, plants in its corners, an armchair
    objs += [couch(ids(), (-h - 3.0 + 0.53, 10.0, -math.pi / 2)),
             potted_plant(ids(), -h - 2.55, 6.5), potted_plant(ids(), -h - 2.55, 13.5),
             chair(ids(), (-h - 0.9, 7.9, -math.pi / 2))]
    # rooms south of the ring: a meeting table, beds, a cabinet, desks
    objs += [table(ids(), (6.0 - 2.4, -4.0, math.pi / 2), 1.6, 0.8),
             chair(ids(), (6.0 - 1.75, -3.6, math.pi / 2)), chair(ids(), (6.0 - 1.75, -4.4, math.pi / 2))]
    objs += [bed(ids(), (12.3, -5.25, math.pi)), bed(ids(), (15.7, -5.25, math.pi))]
    objs += [cabinet(ids(), (22.0, -6.05, 0.0), 1.4, 0.5)]
    objs += [table(ids(), (30.0, -5.5, 0.0), 1.4, 0.7), chair(ids(), (30.0, -4.85, math.pi))]
    # rooms north of the ring: a couch, a bed, a desk
    objs += [couch(ids(), (8.5, 20.0 + h + 4.45, math.pi)), bed(ids(), (22.0, 20.0 + h + 3.8, 0.0))]
    objs += [table(ids(), (31.5, 20.0 + h + 4.2, 0.0), 1.4, 0.7), chair(ids(), (31.5, 20.0 + h + 3.5, 0.0))]
    # rooms in the central block, seen through their doors
    objs += [table(ids(), (5.5, 6.0, 0.0), 1.6, 0.8), chair(ids(), (5.1, 5.3, 0.0)), chair(ids(), (5.9, 5.3, 0.0)),
             potted_plant(ids(), 9.3, 2.1)]
    objs += [bed(ids(), (27.5, 6.5, 0.0)), chair(ids(), (23.0, 8.8, math.pi))]
    objs += [table(ids(), (35.0, 6.0, math.pi / 2), 1.4, 0.8), potted_plant(ids(), 37.9, 2.1)]
    objs += [couch(ids(), (5.0, 17.8, math.pi)), potted_plant(ids(), 2.1, 10.8)]
    objs += [bed(ids(), (17.0, 13.5, 0.0)), cabinet(ids(), (34.5, 11.0, 0.0), 1.2, 0.45)]
    return objs


def loop() -> Scenario:
    ids = IdCounter(0)
    objs = _loop_building(ids) + _loop_furniture(ids)
    people = (
        # walks west towards the robot along the south corridor, then into room S1 and stays
        _person(501, 0, [(30.0, 0.75), (6.0, 0.75), (6.0, -3.3)], speed=1.2, loop=False, pauses=((2, 1000.0),)),
        _person(502, 1, [(22.0, 20.0 + _LOOP_HALF - 0.5)]),  # stands in the north corridor the whole tour
        _person(503, 2, [(40.8, 4.6), (40.8, 15.4)], speed=0.8, loop=False,  # paces the east corridor
                pauses=((0, 6.0), (1, 6.0))),
        _person(504, 3, [(25.0, 5.0)]),  # stands in a room of the block, seen through its door
    )
    return Scenario(World("loop", tuple(objs), people, np.asarray(_LOOP_ROUTE, float), start_yaw=0.0,
                          description="A 2.8 m wide ring corridor, 40 m x 20 m, round a block of eight rooms, "
                                      "seven more rooms outside, a lounge alcove: driven once round (120 m) "
                                      "and 15 m on past the start, 135 m in all, twice ward's route. Four "
                                      "people: walking, pacing, standing. For loop closure: give it "
                                      "drifting odometry (tools/bench_loops.py)."))


SCENARIOS: dict[str, Callable[[], Scenario]] = {
    "demo": demo,
    "ward": ward,
    "ward_b": ward_b,
    "office": office,
    "office_b": office_b,
    "occlusion": occlusion,
    "loop": loop,
}


def get_scenario(name: str) -> Scenario:
    """A built-in scenario by name, ``random:SEED`` for a procedural world, or ``NAME:b`` / ``NAME:bK``
    for a second session of another (:mod:`semmap.sim.sessions`)."""
    from .sessions import parse_session_name  # imports this module

    if parse_session_name(name) is not None:
        from .sessions import get_session

        return get_session(name)
    if name.startswith("random:"):
        from .procedural import random_world, scenario_seed  # imports this module

        seed = scenario_seed(name)
        if seed is None:
            raise ConfigError(f"unknown scenario {name!r}: a random world is random:SEED with a whole number "
                              f"SEED of 0 or more, e.g. random:7")
        return random_world(seed)
    factory = SCENARIOS.get(name)
    if factory is None:
        known = ", ".join(SCENARIOS)
        raise ConfigError(f"unknown scenario {name!r} (built in: {known}, random:SEED, NAME:b for a second "
                          f"session; or give a world .yaml file)")
    return factory()
