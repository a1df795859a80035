"""A 2.5D indoor world: floor-plan polygons extruded between two heights.

Every object has a class name (COCO names for objects; ``wall`` and ``pillar`` for
structure), a mobility and one or more convex *parts*. A part is a convex
polygon on the floor extruded from ``z_min`` to ``z_max``: a chair is four legs,
a seat and a back, so at LiDAR height it is only its legs, as in real tours.

People are dynamic: they walk waypoint loops at their own speed, pause, or stand
still for the whole tour. Their legs swing while they walk.

The robot drives the world's route once, or ``laps`` times for a long tour (see
:func:`semmap.sim.robot.plan_tour`); ``duration_s`` cuts the tour short or holds the
robot still at its end.

The world is written beside every simulated bag as ``world.yaml`` and can be
read back with :func:`load_world` (``semmap simulate --scenario my_world.yaml``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, PrivateAttr, field_validator, model_validator

from ..config import load_model
from ..errors import ConfigError
from ..io.yamlio import read_yaml
from ..records import Mobility

__all__ = [
    "Part",
    "Person",
    "World",
    "WorldFile",
    "WorldObject",
    "bed",
    "cabinet",
    "chair",
    "circle",
    "couch",
    "load_world",
    "monitor",
    "pillar",
    "place",
    "potted_plant",
    "rect",
    "screen",
    "table",
    "wall",
    "world_from_dict",
    "world_to_dict",
]

RGB = tuple[int, int, int]


# ---------------------------------------------------------------------------------------
# Geometry primitives


def rect(cx: float, cy: float, w: float, d: float) -> NDArray[np.float64]:
    """Axis-aligned rectangle centred on (cx, cy), ``w`` along x and ``d`` along y, CCW."""
    hx, hy = 0.5 * w, 0.5 * d
    return np.array(
        [[cx - hx, cy - hy], [cx + hx, cy - hy], [cx + hx, cy + hy], [cx - hx, cy + hy]],
        dtype=np.float64,
    )


_UNIT_CIRCLES: dict[int, NDArray[np.float64]] = {}


def circle(cx: float, cy: float, r: float, n: int = 12) -> NDArray[np.float64]:
    """Regular n-gon approximating a circle, CCW."""
    unit = _UNIT_CIRCLES.get(n)
    if unit is None:
        a = np.arange(n) * (2.0 * np.pi / n)
        unit = _UNIT_CIRCLES.setdefault(n, np.stack([np.cos(a), np.sin(a)], axis=1))
    return unit * r + (cx, cy)


def place(poly: NDArray[np.float64], x: float, y: float, yaw: float) -> NDArray[np.float64]:
    """Move a polygon from an object's local frame to the world pose (x, y, yaw)."""
    c, s = math.cos(yaw), math.sin(yaw)
    out = np.empty_like(poly)
    out[:, 0] = x + c * poly[:, 0] - s * poly[:, 1]
    out[:, 1] = y + s * poly[:, 0] + c * poly[:, 1]
    return out


def _signed_area(poly: NDArray[np.float64]) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _is_convex(poly: NDArray[np.float64]) -> bool:
    e = np.roll(poly, -1, axis=0) - poly
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    return bool(np.all(cross >= -1e-12) or np.all(cross <= 1e-12))


# ---------------------------------------------------------------------------------------
# Records


@dataclass(frozen=True)
class Part:
    """A convex polygon (N, 2) in metres, counter-clockwise, extruded over [z_min, z_max]."""

    polygon: NDArray[np.float64]
    z_min: float
    z_max: float
    color: RGB = (160, 160, 160)

    def __post_init__(self) -> None:
        p = np.array(self.polygon, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
            raise ConfigError(f"a part polygon needs at least 3 (x, y) vertices, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ConfigError("a part polygon has NaN or inf vertices")
        if not self.z_max > self.z_min:
            raise ConfigError(f"part heights must satisfy z_min < z_max, got {self.z_min}, {self.z_max}")
        area = _signed_area(p)
        if abs(area) < 1e-10:
            raise ConfigError("a part polygon has zero area")
        if area < 0:
            p = p[::-1].copy()
        if not _is_convex(p):
            raise ConfigError("part polygons must be convex; split concave shapes into parts")
        p.setflags(write=False)
        object.__setattr__(self, "polygon", p)

    def spans(self, z: float) -> bool:
        """True if a horizontal plane at height ``z`` cuts this part."""
        return self.z_min <= z <= self.z_max


@dataclass(frozen=True)
class WorldObject:
    """One object instance: walls and pillars are static; furniture semi-static."""

    id: int
    name: str
    cls: str
    mobility: Mobility
    parts: tuple[Part, ...]

    def moved(self, dx: float, dy: float, dyaw: float = 0.0, about: Sequence[float] | None = None) -> WorldObject:
        """A copy rotated by ``dyaw`` about ``about`` (default: its centroid), then shifted."""
        c = np.asarray(about if about is not None else self.centroid(), dtype=np.float64)
        cs, sn = math.cos(dyaw), math.sin(dyaw)
        rot = np.array([[cs, -sn], [sn, cs]])
        parts = tuple(
            replace(p, polygon=(p.polygon - c) @ rot.T + c + np.array([dx, dy])) for p in self.parts
        )
        return replace(self, parts=parts)

    def centroid(self) -> NDArray[np.float64]:
        pts = np.concatenate([p.polygon for p in self.parts])
        return 0.5 * (pts.min(axis=0) + pts.max(axis=0))


_TORSO = np.stack([0.13 * np.cos(np.linspace(0, 2 * np.pi, 10, endpoint=False)),
                   0.21 * np.sin(np.linspace(0, 2 * np.pi, 10, endpoint=False))], axis=1)


@dataclass(frozen=True)
class Person:
    """A person walking a waypoint loop (or standing still, with one waypoint).

    ``pauses`` maps waypoint indices to standing times in seconds; ``phase_s``
    shifts where on the loop the person is at t = 0.
    """

    id: int
    name: str
    waypoints: NDArray[np.float64]
    speed: float = 1.2
    pauses: tuple[tuple[int, float], ...] = ()
    phase_s: float = 0.0
    loop: bool = True
    shirt: RGB = (180, 40, 40)
    trousers: RGB = (40, 45, 70)
    skin: RGB = (224, 172, 140)
    # body dimensions (metres)
    leg_radius: float = 0.065
    hip_half_width: float = 0.1
    stride: float = 0.32
    height: float = 1.72

    def __post_init__(self) -> None:
        w = np.array(self.waypoints, dtype=np.float64).reshape(-1, 2)
        if w.shape[0] < 1 or not np.all(np.isfinite(w)):
            raise ConfigError(f"person {self.name}: needs at least one finite waypoint")
        if self.speed <= 0:
            raise ConfigError(f"person {self.name}: speed must be positive")
        w.setflags(write=False)
        object.__setattr__(self, "waypoints", w)
        object.__setattr__(self, "_timeline", self._build_timeline())

    # -- motion -------------------------------------------------------------------------
    def _build_timeline(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Knot times, knot positions and the heading of each span between knots."""
        wp = self.waypoints
        pause = dict(self.pauses)
        if wp.shape[0] == 1:
            return np.array([0.0, 1.0]), np.repeat(wp, 2, axis=0), np.zeros(1)
        order = list(range(wp.shape[0]))
        order += [0] if self.loop else list(range(wp.shape[0] - 2, -1, -1))  # loop or ping-pong
        times, pts = [0.0], [wp[order[0]]]
        for i, idx in enumerate(order[:-1]):
            if pause.get(idx, 0.0) > 0:
                times.append(times[-1] + pause[idx])
                pts.append(wp[idx])
            nxt = wp[order[i + 1]]
            times.append(times[-1] + float(np.linalg.norm(nxt - wp[idx])) / self.speed)
            pts.append(nxt)
        p = np.asarray(pts)
        d = np.diff(p, axis=0)
        moving = np.hypot(d[:, 0], d[:, 1]) > 0
        heading = np.arctan2(d[:, 1], d[:, 0])
        # while standing, keep facing the way the person last walked
        last = heading[np.argmax(moving)] if moving.any() else 0.0
        for k in range(len(heading)):
            if moving[k]:
                last = heading[k]
            else:
                heading[k] = last
        return np.asarray(times), p, heading

    @property
    def period_s(self) -> float:
        return float(self._timeline[0][-1])  # type: ignore[attr-defined]

    def state(self, t: float) -> tuple[float, float, float, float]:
        """(x, y, heading, walking speed) at time ``t`` seconds."""
        times, pts, heading = self._timeline  # type: ignore[attr-defined]
        if self.waypoints.shape[0] == 1:
            p = self.waypoints[0]
            return float(p[0]), float(p[1]), 0.0, 0.0
        tau = (t + self.phase_s) % times[-1]
        k = min(max(int(np.searchsorted(times, tau, side="right")) - 1, 0), len(times) - 2)
        a, b = pts[k], pts[k + 1]
        dt = times[k + 1] - times[k]
        f = 0.0 if dt <= 0 else (tau - times[k]) / dt
        pos = a + f * (b - a)
        speed = self.speed if np.any(b != a) else 0.0
        return float(pos[0]), float(pos[1]), float(heading[k]), speed

    def body(self, t: float) -> list[tuple[NDArray[np.float64], float, float, RGB]]:
        """The body at time ``t`` as (polygon, z_min, z_max, colour): two legs, torso, head."""
        x, y, h, v = self.state(t)
        c, s = math.cos(h), math.sin(h)
        # gait: legs swing in anti-phase while walking, side by side while standing
        swing = 0.0
        if v > 0:
            cadence = v / (2.0 * self.stride)  # stride cycles per second
            swing = 0.5 * self.stride * math.sin(2.0 * math.pi * cadence * (t + self.phase_s))
        leg_top = 0.47 * self.height
        torso_top = 0.83 * self.height
        out = []
        for side in (1.0, -1.0):
            lx = x + side * (self.hip_half_width * -s + swing * c)
            ly = y + side * (self.hip_half_width * c + swing * s)
            out.append((circle(lx, ly, self.leg_radius, 8), 0.0, leg_top, self.trousers))
        out.append((place(_TORSO, x, y, h), leg_top, torso_top, self.shirt))
        out.append((circle(x, y, 0.1, 10), torso_top + 0.03, self.height, self.skin))
        return out

    def parts_at(self, t: float) -> tuple[Part, ...]:
        """The person's body at time ``t`` as validated parts."""
        return tuple(Part(p, z0, z1, col) for p, z0, z1, col in self.body(t))

    def footprint(self, t: float, radius: float = 0.25) -> NDArray[np.float64]:
        """The floor area the person's body covers at time ``t`` (a disc)."""
        x, y, _, _ = self.state(t)
        return circle(x, y, radius, 16)


@dataclass(frozen=True)
class World:
    """A complete scenario: structure, furniture, people and the robot's route."""

    name: str
    objects: tuple[WorldObject, ...]
    people: tuple[Person, ...] = ()
    route: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    start_yaw: float | None = None
    duration_s: float | None = None  # None: the time the route takes
    ceiling_height: float = 2.6
    frame_id: str = "world"
    description: str = ""
    laps: int = 1  # times the robot drives the route; between laps it returns to the route's start

    def __post_init__(self) -> None:
        if isinstance(self.laps, bool) or not isinstance(self.laps, (int, np.integer)) or self.laps < 1:
            raise ConfigError(f"world {self.name}: laps must be a whole number of at least 1, got {self.laps!r}")
        r = np.array(self.route, dtype=np.float64).reshape(-1, 2)
        r.setflags(write=False)
        object.__setattr__(self, "route", r)
        ids = [o.id for o in self.objects] + [p.id for p in self.people]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"world {self.name}: object and person ids must be unique")
        if any(i <= 0 for i in ids):
            raise ConfigError(f"world {self.name}: ids must be positive (0 means 'nothing')")

    def bounds(self, margin: float = 0.0) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of everything static, plus a margin."""
        pts = np.concatenate([p.polygon for o in self.objects for p in o.parts])
        lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    def object(self, name: str) -> WorldObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)

    def replace_objects(self, objects: Iterable[WorldObject]) -> World:
        return replace(self, objects=tuple(objects))


# ---------------------------------------------------------------------------------------
# Object factories. Poses are (x, y, yaw) of the object's centre; the local x axis
# points along its width, the local y axis to its front (where a chair's user sits).

_WALL: RGB = (214, 206, 188)
_PILLAR: RGB = (190, 190, 198)
_WOOD: RGB = (150, 105, 62)
_METAL: RGB = (125, 128, 134)
_FABRIC_BLUE: RGB = (60, 90, 150)
_FABRIC_GREY: RGB = (105, 108, 118)
_MATTRESS: RGB = (236, 238, 242)
_GREEN: RGB = (56, 128, 52)
_POT: RGB = (160, 82, 45)
_SCREEN: RGB = (22, 22, 26)


def wall(oid: int, x0: float, y0: float, x1: float, y1: float, thickness: float = 0.12,
         height: float = 2.6, name: str | None = None) -> WorldObject:
    """A straight wall between two points on its centre line."""
    a, b = np.array([x0, y0]), np.array([x1, y1])
    d = b - a
    length = float(np.linalg.norm(d))
    if length <= 0:
        raise ConfigError("a wall needs two distinct end points")
    u = d / length
    n = np.array([-u[1], u[0]]) * 0.5 * thickness
    e = u * 0.5 * thickness  # extend by half the thickness so corners close
    poly = np.array([a - e - n, b + e - n, b + e + n, a - e + n])
    return WorldObject(oid, name or f"wall_{oid}", "wall", Mobility.STATIC, (Part(poly, 0.0, height, _WALL),))


def pillar(oid: int, x: float, y: float, size: float = 0.4, height: float = 2.6,
           round_: bool = False) -> WorldObject:
    poly = circle(x, y, 0.5 * size, 16) if round_ else rect(x, y, size, size)
    return WorldObject(oid, f"pillar_{oid}", "pillar", Mobility.STATIC, (Part(poly, 0.0, height, _PILLAR),))


def _legs(w: float, d: float, leg: float, inset: float, top: float,
          color: RGB) -> list[tuple[NDArray[np.float64], float, float, RGB]]:
    xs = (-0.5 * w + inset + 0.5 * leg, 0.5 * w - inset - 0.5 * leg)
    ys = (-0.5 * d + inset + 0.5 * leg, 0.5 * d - inset - 0.5 * leg)
    return [(rect(x, y, leg, leg), 0.0, top, color) for x in xs for y in ys]


def _obj(oid: int, cls: str, mobility: Mobility, pose: Sequence[float],
         local_parts: list[tuple[NDArray[np.float64], float, float, RGB]], name: str | None = None) -> WorldObject:
    x, y, yaw = pose
    parts = tuple(Part(place(p, x, y, yaw), z0, z1, col) for p, z0, z1, col in local_parts)
    return WorldObject(oid, name or f"{cls.replace(' ', '_')}_{oid}", cls, mobility, parts)


def chair(oid: int, pose: Sequence[float], color: RGB = _FABRIC_BLUE) -> WorldObject:
    """A four-legged chair, 0.46 m square; at LiDAR height only its legs."""
    w = 0.46
    parts = _legs(w, w, 0.035, 0.02, 0.44, _METAL)
    parts.append((rect(0, 0, w, w), 0.44, 0.49, color))
    parts.append((rect(0, -0.5 * w + 0.025, w, 0.05), 0.49, 0.92, color))
    return _obj(oid, "chair", Mobility.SEMI_STATIC, pose, parts)


def table(oid: int, pose: Sequence[float], w: float = 1.4, d: float = 0.8,
          color: RGB = _WOOD) -> WorldObject:
    """A table (COCO 'dining table'): a top at 0.72–0.76 m on four legs."""
    parts = _legs(w, d, 0.05, 0.04, 0.72, _METAL)
    parts.append((rect(0, 0, w, d), 0.72, 0.76, color))
    return _obj(oid, "dining table", Mobility.SEMI_STATIC, pose, parts)


def bed(oid: int, pose: Sequence[float], w: float = 1.0, d: float = 2.1, solid: bool = False) -> WorldObject:
    """A bed, headboard at +y: a hospital bed on wheeled legs with a frame and mattress from 0.32 m,
    or (``solid``) a divan whose base reaches the floor, so a 2D LiDAR sees its whole outline."""
    parts = [(rect(0, 0, w, d), 0.0, 0.3, _FABRIC_GREY)] if solid else _legs(w, d, 0.07, 0.05, 0.32, _METAL)
    parts.append((rect(0, 0, w, d), 0.32, 0.6, _MATTRESS))
    parts.append((rect(0, 0.5 * d - 0.03, w, 0.06), 0.32, 1.05, _METAL))
    return _obj(oid, "bed", Mobility.SEMI_STATIC, pose, parts)


def couch(oid: int, pose: Sequence[float], w: float = 2.0, d: float = 0.9,
          color: RGB = _FABRIC_GREY) -> WorldObject:
    """A couch: a solid base down to the floor, a back at -y and two arms."""
    parts = [(rect(0, 0.1, w - 0.4, d - 0.2), 0.0, 0.45, color)]
    parts.append((rect(0, -0.5 * d + 0.1, w, 0.2), 0.0, 0.85, color))
    parts.append((rect(-0.5 * w + 0.1, 0.1, 0.2, d - 0.2), 0.0, 0.62, color))
    parts.append((rect(0.5 * w - 0.1, 0.1, 0.2, d - 0.2), 0.0, 0.62, color))
    return _obj(oid, "couch", Mobility.SEMI_STATIC, pose, parts)


def potted_plant(oid: int, x: float, y: float) -> WorldObject:
    parts = [(circle(0, 0, 0.16), 0.0, 0.42, _POT), (circle(0, 0, 0.34), 0.42, 1.35, _GREEN)]
    return _obj(oid, "potted plant", Mobility.SEMI_STATIC, (x, y, 0.0), parts)


def screen(oid: int, pose: Sequence[float], w: float = 1.1) -> WorldObject:
    """A TV screen on a floor stand (COCO 'tv'); at LiDAR height only its pole."""
    parts = [(rect(0, 0, 0.5, 0.35), 0.0, 0.03, _METAL), (rect(0, 0, 0.07, 0.07), 0.03, 1.05, _METAL),
             (rect(0, 0.05, w, 0.07), 1.05, 1.7, _SCREEN)]
    return _obj(oid, "tv", Mobility.SEMI_STATIC, pose, parts)


def monitor(oid: int, pose: Sequence[float], z: float = 0.76) -> WorldObject:
    """A desk monitor standing on a table top at height ``z`` (COCO 'tv')."""
    parts = [(rect(0, 0, 0.06, 0.06), z, z + 0.12, _METAL), (rect(0, 0.03, 0.6, 0.04), z + 0.12, z + 0.5, _SCREEN)]
    return _obj(oid, "tv", Mobility.SEMI_STATIC, pose, parts)


def cabinet(oid: int, pose: Sequence[float], w: float = 1.0, d: float = 0.5, h: float = 1.9,
            cls: str = "cabinet", mobility: Mobility = Mobility.STATIC, color: RGB = (170, 160, 150)) -> WorldObject:
    """A solid block to the floor: a built-in cabinet, partition or new static obstacle."""
    return _obj(oid, cls, mobility, pose, [(rect(0, 0, w, d), 0.0, h, color)], name=f"cabinet_{oid}")


# ---------------------------------------------------------------------------------------
# YAML round trip


def world_to_dict(world: World) -> dict[str, Any]:
    """A plain dict of the world, for ``world.yaml``."""

    def r(x: float) -> float:
        return round(float(x), 5)

    return {
        "name": world.name,
        "description": world.description,
        "frame_id": world.frame_id,
        "ceiling_height": r(world.ceiling_height),
        "start_yaw": None if world.start_yaw is None else r(world.start_yaw),
        "duration_s": None if world.duration_s is None else r(world.duration_s),
        "laps": int(world.laps),
        "route": [[r(x), r(y)] for x, y in world.route],
        "objects": [
            {
                "id": o.id,
                "name": o.name,
                "class": o.cls,
                "mobility": o.mobility.label,
                "parts": [
                    {
                        "polygon": [[r(x), r(y)] for x, y in p.polygon],
                        "z": [r(p.z_min), r(p.z_max)],
                        "color": list(p.color),
                    }
                    for p in o.parts
                ],
            }
            for o in world.objects
        ],
        "people": [
            {
                "id": p.id,
                "name": p.name,
                "waypoints": [[r(x), r(y)] for x, y in p.waypoints],
                "speed": r(p.speed),
                "pauses": [[int(i), r(s)] for i, s in p.pauses],
                "phase_s": r(p.phase_s),
                "loop": p.loop,
                "shirt": list(p.shirt),
                "trousers": list(p.trousers),
                "skin": list(p.skin),
                "leg_radius": r(p.leg_radius),
                "hip_half_width": r(p.hip_half_width),
                "stride": r(p.stride),
                "height": r(p.height),
            }
            for p in world.people
        ],
    }


# The schema of ``world.yaml``. Pydantic turns a ValueError into one line naming the file and the field
# (semmap.config.load_model); the records (Part, Person, World) check shapes and ids, and their
# ConfigError becomes a ValueError at the object, part or person it is about.

_Point = tuple[float, float]
_Colour = tuple[Annotated[int, Field(ge=0, le=255)], Annotated[int, Field(ge=0, le=255)],
                Annotated[int, Field(ge=0, le=255)]]


def _null_is_empty(v: Any) -> Any:
    return [] if v is None else v


def _mobility(v: Any) -> Mobility:
    return v if isinstance(v, Mobility) else Mobility.parse(str(v))


def _whole(v: Any) -> Any:
    if isinstance(v, bool):  # an int to pydantic, but no number of laps
        raise ValueError(f"must be a whole number of at least 1, got {v!r}")
    return v


def _checked(build: Callable[[], Any]) -> Any:
    """A record built from validated fields; its own check's ConfigError as the ValueError pydantic reports."""
    try:
        return build()
    except ConfigError as exc:
        raise ValueError(str(exc)) from None


class _WorldModel(BaseModel):
    # a typo in a hand-written world is an error that names the key, as in a config file
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class PartFile(_WorldModel):
    """One convex part of an object: a floor polygon extruded over ``z`` = [z_min, z_max]."""

    polygon: list[_Point]
    z: tuple[float, float]
    color: _Colour = (160, 160, 160)
    _part: Part = PrivateAttr()

    @model_validator(mode="after")
    def _record(self) -> PartFile:
        self._part = _checked(lambda: Part(np.asarray(self.polygon, dtype=np.float64), self.z[0], self.z[1],
                                           self.color))
        return self

    @property
    def part(self) -> Part:
        return self._part


class ObjectFile(_WorldModel):
    """An object: its id (> 0, unique), class name, mobility and parts."""

    id: int
    name: str | None = None
    cls: str = Field(alias="class")
    mobility: Annotated[Mobility, BeforeValidator(_mobility)]
    parts: list[PartFile]

    @property
    def world_object(self) -> WorldObject:
        return WorldObject(self.id, self.name or f"obj_{self.id}", self.cls, self.mobility,
                           tuple(p.part for p in self.parts))


class PersonFile(_WorldModel):
    """A person walking a waypoint loop (see :class:`Person`)."""

    id: int
    name: str | None = None
    waypoints: list[_Point]
    speed: float = Field(1.2, gt=0)
    pauses: list[tuple[int, float]] = []
    phase_s: float = 0.0
    loop: bool = True
    shirt: _Colour = (180, 40, 40)
    trousers: _Colour = (40, 45, 70)
    skin: _Colour = (224, 172, 140)
    leg_radius: float = Field(0.065, gt=0)
    hip_half_width: float = Field(0.1, gt=0)
    stride: float = Field(0.32, gt=0)
    height: float = Field(1.72, gt=0)
    _person: Person = PrivateAttr()

    _nulls = field_validator("pauses", mode="before")(_null_is_empty)

    @model_validator(mode="after")
    def _record(self) -> PersonFile:
        fields = self.model_dump(exclude={"id", "name", "waypoints", "pauses"})
        self._person = _checked(lambda: Person(
            id=self.id, name=self.name or f"person_{self.id}", waypoints=np.asarray(self.waypoints, dtype=np.float64),
            pauses=tuple(self.pauses), **fields))
        return self

    @property
    def person(self) -> Person:
        return self._person


class WorldFile(_WorldModel):
    """``world.yaml``: what :func:`world_to_dict` writes and :func:`load_world` reads."""

    name: str = "world"
    description: str = ""
    frame_id: str = "world"
    ceiling_height: float = Field(2.6, gt=0)
    start_yaw: float | None = None
    duration_s: float | None = Field(None, gt=0, description="None: the time the route takes")
    laps: Annotated[int, BeforeValidator(_whole), Field(ge=1)] = 1
    route: list[_Point] = []
    objects: list[ObjectFile] = []
    people: list[PersonFile] = []
    _world: World = PrivateAttr()

    _nulls = field_validator("route", "objects", "people", mode="before")(_null_is_empty)

    @model_validator(mode="after")
    def _record(self) -> WorldFile:
        self._world = _checked(lambda: World(
            name=self.name, description=self.description, frame_id=self.frame_id,
            ceiling_height=self.ceiling_height, start_yaw=self.start_yaw, duration_s=self.duration_s, laps=self.laps,
            route=np.asarray(self.route, dtype=np.float64).reshape(-1, 2),
            objects=tuple(o.world_object for o in self.objects), people=tuple(p.person for p in self.people)))
        return self

    @property
    def world(self) -> World:
        return self._world


def world_from_dict(data: Any, source: str = "<world>") -> World:
    """Build a :class:`World` from a dict as written by :func:`world_to_dict`."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a world file must be a mapping")
    world: World = load_model(WorldFile, data, source).world
    return world


def load_world(path: str | Path) -> World:
    """Read a ``world.yaml`` (safe YAML only)."""
    return world_from_dict(read_yaml(path, "world"), str(path))
