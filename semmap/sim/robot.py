"""The simulated robot: a smooth, time-parameterised tour and its wheel odometry.

The route is a polyline of waypoints. Corners are rounded with circular fillets;
near-U-turns become a stop and a turn in place, as a differential-drive base
does. Speed respects the robot's linear, lateral and yaw-rate limits, with
trapezoidal acceleration. :func:`check_clearance` proves the tour collision-free.
A long tour drives the route for several laps (``World.laps``), waiting between laps
until the people are out of the way.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..config import SimOdometryConfig, SimRobotConfig
from ..errors import SimulationError
from ..geometry import se2_between, se2_compose, wrap_angle
from .world import Person, World

__all__ = ["OdometryTrace", "Trajectory", "check_clearance", "plan_tour", "simulate_odometry"]

_DS = 0.01  # path sampling step, m


@dataclass(frozen=True)
class Trajectory:
    """Dense samples of the true base_link pose in the world frame.

    ``yaw`` is unwrapped so linear interpolation is valid; :meth:`pose` wraps it.
    """

    t: NDArray[np.float64]  # (K,) seconds from the tour start, increasing
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    yaw: NDArray[np.float64]

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def pose(self, t: NDArray[np.floating[Any]] | float) -> NDArray[np.float64]:
        """(…, 3) poses at times ``t`` (clamped to the tour)."""
        tt = np.asarray(t, dtype=np.float64)
        out = np.stack(
            [np.interp(tt, self.t, self.x), np.interp(tt, self.t, self.y),
             wrap_angle(np.interp(tt, self.t, self.yaw))],
            axis=-1,
        )
        return out

    def velocity(self, t: NDArray[np.float64] | float, dt: float = 0.01) -> NDArray[np.float64]:
        """(…, 3) body-frame twist (vx, vy, wz) at times ``t`` by central differences."""
        tt = np.asarray(t, dtype=np.float64)
        a = self.pose(tt - dt / 2)
        b = self.pose(tt + dt / 2)
        d = se2_between(a, b)
        return d / dt

    def length(self) -> float:
        return float(np.sum(np.hypot(np.diff(self.x), np.diff(self.y))))


def _fillet_path(route: NDArray[np.float64], cfg: SimRobotConfig) -> list[tuple[str, NDArray[np.float64]]]:
    """Split the route into pieces: ('move', (N,4) x,y,heading,curvature) and ('turn', [h0,h1])."""
    pieces: list[tuple[str, NDArray[np.float64]]] = []
    pts = [route[0]]
    for p in route[1:]:
        if np.linalg.norm(p - pts[-1]) > 1e-6:
            pts.append(p)
    pts_a = np.asarray(pts)
    if len(pts_a) < 2:
        return pieces
    seg = np.diff(pts_a, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    heads = np.arctan2(seg[:, 1], seg[:, 0])
    n = len(seg)
    # per interior corner: trim distance and fillet radius (0 for stop-and-turn)
    trim = np.zeros(n + 1)
    radius = np.zeros(n + 1)
    turn = np.zeros(n + 1)
    for i in range(1, n):
        phi = float(wrap_angle(heads[i] - heads[i - 1]))
        turn[i] = phi
        if abs(phi) < 1e-6 or abs(phi) > math.radians(150):
            continue
        tmax = 0.45 * min(lengths[i - 1], lengths[i])
        r = min(cfg.corner_radius, tmax / math.tan(abs(phi) / 2))
        radius[i] = r
        trim[i] = r * math.tan(abs(phi) / 2)
    current: list[NDArray[np.float64]] = []

    def flush() -> None:
        if current:
            pieces.append(("move", np.concatenate(current)))
            current.clear()

    for i in range(n):
        a = pts_a[i] + (seg[i] / lengths[i]) * trim[i]
        b = pts_a[i + 1] - (seg[i] / lengths[i]) * trim[i + 1]
        length = float(np.linalg.norm(b - a))
        k = max(int(math.ceil(length / _DS)), 1)
        s = np.linspace(0.0, 1.0, k + 1)[:-1] if i < n - 1 else np.linspace(0.0, 1.0, k + 1)
        line = np.column_stack([a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]),
                                np.full_like(s, heads[i]), np.zeros_like(s)])
        current.append(line)
        j = i + 1
        if j < n and radius[j] > 0:
            phi = turn[j]
            r = radius[j]
            sgn = 1.0 if phi > 0 else -1.0
            h0 = heads[i]
            centre = b + r * np.array([-math.sin(h0), math.cos(h0)]) * sgn
            m = max(int(math.ceil(abs(phi) * r / _DS)), 2)
            hh = h0 + np.linspace(0.0, phi, m + 1)[:-1]
            arc = np.column_stack([centre[0] + r * np.sin(hh) * sgn, centre[1] - r * np.cos(hh) * sgn,
                                   hh, np.full_like(hh, sgn / r)])
            current.append(arc)
        elif j < n and abs(turn[j]) > 1e-6:
            current.append(np.array([[b[0], b[1], heads[i], 0.0]]))
            flush()
            pieces.append(("turn", np.array([heads[i], heads[i] + turn[j]])))
    flush()
    return pieces


def _time_move(path: NDArray[np.float64], cfg: SimRobotConfig) -> NDArray[np.float64]:
    """Times along a moving piece, starting and ending at rest."""
    d = np.hypot(np.diff(path[:, 0]), np.diff(path[:, 1]))
    kappa = np.abs(path[:, 3])
    with np.errstate(divide="ignore"):
        vlim = np.minimum.reduce([
            np.full_like(kappa, cfg.max_speed),
            np.where(kappa > 0, cfg.max_yaw_rate / np.maximum(kappa, 1e-12), np.inf),
            np.where(kappa > 0, np.sqrt(cfg.max_lateral_accel / np.maximum(kappa, 1e-12)), np.inf),
        ])
    v = vlim.copy()
    v[0] = v[-1] = 0.0
    for i in range(1, len(v)):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * cfg.max_accel * d[i - 1]))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * cfg.max_accel * d[i]))
    vm = 0.5 * (v[1:] + v[:-1])
    dt = np.where(vm > 1e-9, d / np.maximum(vm, 1e-9), 0.0)
    # the first and last steps start/end at rest: use constant acceleration over the step
    for i in (0, len(d) - 1):
        if d[i] > 0:
            dt[i] = math.sqrt(2 * d[i] / cfg.max_accel) if vm[i] < 1e-9 else 2 * d[i] / (v[i] + v[i + 1])
    return np.concatenate([[0.0], np.cumsum(dt)])


def _turn_profile(h0: float, h1: float, cfg: SimRobotConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Trapezoidal turn in place from heading h0 to h1 (unwrapped): times and headings."""
    dist = abs(h1 - h0)
    w, a = cfg.max_yaw_rate, cfg.max_yaw_accel
    if dist < 1e-9:
        return np.array([0.0]), np.array([h0])
    if dist < w * w / a:  # triangular
        t_acc = math.sqrt(dist / a)
        total = 2 * t_acc
        w = a * t_acc
    else:
        t_acc = w / a
        total = dist / w + t_acc
    t = np.linspace(0.0, total, max(int(total / 0.02), 2) + 1)
    s = np.where(
        t < t_acc, 0.5 * a * t**2,
        np.where(t <= total - t_acc, 0.5 * a * t_acc**2 + w * (t - t_acc),
                 dist - 0.5 * a * (total - t) ** 2),
    )
    return t, h0 + math.copysign(1.0, h1 - h0) * s


#: a lap after the first waits at the route's end, in steps of this, until people keep clear of it
_LAP_WAIT_STEP_S = 1.0
_LAP_WAIT_MAX_S = 300.0
#: how far (m) people must keep from the robot's footprint during a lap after the first
_LAP_PEOPLE_GAP_M = 0.1
_PEOPLE_STEP_S = 0.05  # time step of the people checks


def _drive(pieces: list[tuple[str, NDArray[np.float64]]], cfg: SimRobotConfig, t0: float, x_prev: float,
           y_prev: float, h_prev: float, emit: Callable[..., None]) -> tuple[float, float, float, float]:
    """Time the pieces one after another from ``t0`` and the pose (x, y, unwrapped heading); the end state."""
    for kind, data in pieces:
        if kind == "move":
            tt = _time_move(data, cfg)
            # unwrap headings continuously from the previous piece
            h = h_prev + np.unwrap(data[:, 2] - data[0, 2]) + float(wrap_angle(data[0, 2] - h_prev))
            emit(t0 + tt[1:], data[1:, 0], data[1:, 1], h[1:])
            t0 += float(tt[-1])
            h_prev, x_prev, y_prev = float(h[-1]), float(data[-1, 0]), float(data[-1, 1])
        else:
            delta = float(wrap_angle(data[1] - data[0]))
            tt, hh = _turn_profile(h_prev, h_prev + delta, cfg)
            emit(t0 + tt[1:], np.full(len(tt) - 1, x_prev), np.full(len(tt) - 1, y_prev), hh[1:])
            t0 += float(tt[-1])
            h_prev = h_prev + delta
    return t0, x_prev, y_prev, h_prev


def _footprint_gap(poses: NDArray[np.float64], xy: NDArray[np.float64], cfg: SimRobotConfig,
                   person: Person) -> NDArray[np.float64]:
    """Distance (m) from a person's body disc at ``xy`` (..., 2) to the robot footprint at ``poses`` (..., 3)."""
    c, s = np.cos(poses[..., 2]), np.sin(poses[..., 2])
    dx, dy = xy[..., 0] - poses[..., 0], xy[..., 1] - poses[..., 1]
    lx, ly = c * dx + s * dy, -s * dx + c * dy
    ox = np.maximum(np.abs(lx) - cfg.length / 2, 0.0)
    oy = np.maximum(np.abs(ly) - cfg.width / 2, 0.0)
    return np.hypot(ox, oy) - (person.hip_half_width + person.leg_radius)


def _lap_wait(world: World, lap: Trajectory, stand: NDArray[np.float64], t_now: float, lap_no: int,
              cfg: SimRobotConfig) -> float:
    """How long the robot, standing at ``stand`` from ``t_now``, waits before driving ``lap`` (times from
    0), so that people keep ``_LAP_PEOPLE_GAP_M`` from it while it waits and drives (they do not yield).

    The first lap of every scenario is tuned against its people; later laps meet them at other
    times, and a few seconds' wait puts the robot between them again.
    """
    if not world.people:
        return 0.0
    step = int(round(_LAP_WAIT_STEP_S / _PEOPLE_STEP_S))
    n_wait = int(round(_LAP_WAIT_MAX_S / _LAP_WAIT_STEP_S))
    n_lap = int(math.ceil(lap.duration / _PEOPLE_STEP_S)) + 1
    k = np.arange(n_wait * step + n_lap)
    times = t_now + k * _PEOPLE_STEP_S
    lap_poses = lap.pose(np.arange(n_lap) * _PEOPLE_STEP_S)
    lap_gap = np.full((n_wait + 1, n_lap), np.inf)  # per candidate wait, per lap sample
    stand_gap = np.full(len(k), np.inf)
    for p in world.people:
        xy = np.array([p.state(float(t))[:2] for t in times])
        stand_gap = np.minimum(stand_gap, _footprint_gap(stand, xy, cfg, p))
        # candidate w starts the lap at sample w * step: gather those windows
        idx = (np.arange(n_wait + 1) * step)[:, None] + np.arange(n_lap)[None, :]
        lap_gap = np.minimum(lap_gap, _footprint_gap(lap_poses[None, :, :], xy[idx], cfg, p))
    stand_min = np.minimum.accumulate(stand_gap)  # the closest approach while waiting up to each sample
    for w in range(n_wait + 1):
        waited = stand_min[w * step] if w > 0 else np.inf
        if min(waited, float(lap_gap[w].min())) > _LAP_PEOPLE_GAP_M:
            return w * _LAP_WAIT_STEP_S
    raise SimulationError(f"world {world.name}: no wait up to {_LAP_WAIT_MAX_S:.0f} s keeps lap {lap_no} "
                          f"{_LAP_PEOPLE_GAP_M} m clear of the people walking there")


def plan_tour(world: World, cfg: SimRobotConfig) -> Trajectory:
    """A smooth, time-parameterised tour along the world's route.

    With ``world.laps`` > 1 the robot drives the route again and again: at the end of a lap it
    stands, drives straight back to the route's first waypoint (turning in place where the
    headings differ) and on into the next lap. Before each lap after the first it waits, whole
    seconds, until that lap keeps clear of the people (who walk their own loops and do not
    yield), so every lap is as collision-free as the first.
    """
    route = world.route
    if route.shape[0] < 2:
        raise SimulationError(f"world {world.name}: the robot route needs at least two waypoints")
    pieces = _fillet_path(route, cfg)
    ts: list[NDArray[np.float64]] = []
    xs: list[NDArray[np.float64]] = []
    ys: list[NDArray[np.float64]] = []
    hs: list[NDArray[np.float64]] = []
    t0 = 0.0
    first = pieces[0][1]
    h_prev = float(first[0, 2]) if pieces[0][0] == "move" else float(first[0])
    x_prev, y_prev = float(route[0, 0]), float(route[0, 1])

    def emit(t: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64], h: NDArray[np.float64]) -> None:
        ts.append(t)
        xs.append(x)
        ys.append(y)
        hs.append(h)

    # stand still, then turn to the start heading if one is given
    emit(np.array([0.0, cfg.settle_s]), np.full(2, x_prev), np.full(2, y_prev), np.full(2, h_prev))
    t0 = cfg.settle_s
    if world.start_yaw is not None:
        start = world.start_yaw
        h_prev = start
        target = float(first[0, 2]) if pieces[0][0] == "move" else float(first[0])
        delta = float(wrap_angle(target - start))
        hs[-1] = np.full(2, start)
        tt, hh = _turn_profile(start, start + delta, cfg)
        emit(t0 + tt[1:], np.full(len(tt) - 1, x_prev), np.full(len(tt) - 1, y_prev), hh[1:])
        t0 += float(tt[-1])
        h_prev = start + delta
    t0, x_prev, y_prev, h_prev = _drive(pieces, cfg, t0, x_prev, y_prev, h_prev, emit)
    if world.laps > 1:
        again = _fillet_path(np.concatenate([route[-1:], route]), cfg)  # back to the start, then the route
        head = float(again[0][1][0, 2])
        for lap_no in range(2, world.laps + 1):
            if world.duration_s is not None and t0 >= world.duration_s:
                break  # the tour is cut before this lap
            lap_pieces = list(again)
            if abs(float(wrap_angle(head - h_prev))) > 1e-6:  # a closed route: turn in place first
                lap_pieces.insert(0, ("turn", np.array([h_prev, head])))
            lt: list[list[NDArray[np.float64]]] = [[np.zeros(1)], [np.full(1, x_prev)], [np.full(1, y_prev)],
                                                   [np.full(1, h_prev)]]

            def emit_lap(t: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64],
                         h: NDArray[np.float64], lt: list[list[NDArray[np.float64]]] = lt) -> None:
                for acc, v in zip(lt, (t, x, y, h)):
                    acc.append(v)

            _, x_end, y_end, h_end = _drive(lap_pieces, cfg, 0.0, x_prev, y_prev, h_prev, emit_lap)
            lap = Trajectory(*(np.concatenate(a) for a in lt))
            wait = _lap_wait(world, lap, np.array([x_prev, y_prev, h_prev]), t0, lap_no, cfg)
            if wait > 0:
                emit(np.array([t0 + wait]), np.array([x_prev]), np.array([y_prev]), np.array([h_prev]))
            emit(t0 + wait + lap.t[1:], lap.x[1:], lap.y[1:], lap.yaw[1:])
            t0 += wait + lap.duration
            x_prev, y_prev, h_prev = x_end, y_end, h_end
    end = max(t0 + cfg.settle_s, world.duration_s or 0.0)
    emit(np.array([end]), np.array([x_prev]), np.array([y_prev]), np.array([h_prev]))
    t = np.concatenate(ts)
    keep = np.concatenate([[True], np.diff(t) > 1e-9])
    traj = Trajectory(t[keep], np.concatenate(xs)[keep], np.concatenate(ys)[keep], np.concatenate(hs)[keep])
    if world.duration_s is not None and world.duration_s < traj.duration:
        k = int(np.searchsorted(traj.t, world.duration_s)) + 1
        traj = Trajectory(traj.t[:k], traj.x[:k], traj.y[:k], traj.yaw[:k])
    return traj


def check_clearance(world: World, traj: Trajectory, cfg: SimRobotConfig, resolution: float = 0.02) -> float:
    """Smallest distance (m) between the robot footprint and any obstacle below body height.

    Raises :class:`SimulationError` when it falls under ``cfg.clearance``.
    """
    polys = [p.polygon for o in world.objects for p in o.parts if p.z_min < cfg.body_height]
    x0, y0, x1, y1 = world.bounds(margin=1.0)
    w = int(math.ceil((x1 - x0) / resolution))
    h = int(math.ceil((y1 - y0) / resolution))
    free = np.full((h, w), 255, np.uint8)
    cv2.fillPoly(free, [np.round((p - [x0, y0]) / resolution * 16).astype(np.int32) for p in polys], 0,
                 lineType=cv2.LINE_8, shift=4)
    dist = cv2.distanceTransform(free, cv2.DIST_L2, 5) * resolution
    # footprint outline, sampled every 5 cm, at poses every 2 cm / 1 degree
    hl, hw = cfg.length / 2, cfg.width / 2
    n_l, n_w = int(cfg.length / 0.05) + 1, int(cfg.width / 0.05) + 1
    lx = np.linspace(-hl, hl, n_l)
    wy = np.linspace(-hw, hw, n_w)
    outline = np.concatenate([np.column_stack([lx, np.full(n_l, -hw)]), np.column_stack([lx, np.full(n_l, hw)]),
                              np.column_stack([np.full(n_w, -hl), wy]), np.column_stack([np.full(n_w, hl), wy])])
    step = np.hypot(np.diff(traj.x), np.diff(traj.y)) + 0.3 * np.abs(np.diff(traj.yaw))
    bins = np.concatenate([[0.0], np.cumsum(step)]) // 0.02
    keep = np.nonzero(np.diff(bins, prepend=-1.0))[0]
    poses = np.column_stack([traj.x[keep], traj.y[keep], traj.yaw[keep]])
    c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
    px = poses[:, 0:1] + c * outline[:, 0] - s * outline[:, 1]
    py = poses[:, 1:2] + s * outline[:, 0] + c * outline[:, 1]
    ix = np.clip(((px - x0) / resolution).astype(int), 0, w - 1)
    iy = np.clip(((py - y0) / resolution).astype(int), 0, h - 1)
    d = dist[iy, ix]
    worst = float(d.min()) - resolution  # rasterisation can be off by a cell
    if worst < cfg.clearance:
        k = np.unravel_index(np.argmin(d), d.shape)[0]
        raise SimulationError(
            f"world {world.name}: the robot passes {max(worst, 0.0):.2f} m from an obstacle at "
            f"({poses[k, 0]:.2f}, {poses[k, 1]:.2f}); move the route or the furniture"
        )
    return worst


@dataclass(frozen=True)
class OdometryTrace:
    """Wheel odometry at its publishing rate: odom-frame poses and body twists."""

    t: NDArray[np.float64]  # (K,) seconds
    pose: NDArray[np.float64]  # (K, 3) odom→base_link
    twist: NDArray[np.float64]  # (K, 3) vx, vy, wz
    scale_error: float
    yaw_scale_error: float
    yaw_drift_rad_per_m: float


def simulate_odometry(traj: Trajectory, cfg: SimOdometryConfig, rng: np.random.Generator) -> OdometryTrace:
    """Integrate noisy wheel increments: per-run scale errors, heading drift per metre, noise."""
    dt = 1.0 / cfg.rate_hz
    t = np.arange(0.0, traj.duration + 1e-9, dt)
    true = traj.pose(t)
    inc = se2_between(true[:-1], true[1:])  # body-frame increments
    ks = rng.uniform(*cfg.scale_error) * rng.choice([-1.0, 1.0])
    kw = rng.uniform(*cfg.yaw_scale_error) * rng.choice([-1.0, 1.0])
    drift = math.radians(cfg.yaw_drift_deg_per_m) * rng.choice([-1.0, 1.0])
    dist = np.hypot(inc[:, 0], inc[:, 1])
    meas = inc.copy()
    meas[:, 0] = inc[:, 0] * (1 + ks) + rng.normal(0.0, cfg.noise_dist, len(inc)) * np.sqrt(dist)
    meas[:, 1] = inc[:, 1] * (1 + ks)
    ang = np.abs(inc[:, 2])
    meas[:, 2] = (inc[:, 2] * (1 + kw) + drift * dist
                  + rng.normal(0.0, math.radians(cfg.noise_yaw_deg), len(inc)) * np.sqrt(dist + ang))
    pose = np.zeros((len(t), 3))
    pose[0] = [0.0, 0.0, 0.0]  # odometry starts at its own origin
    for i in range(len(inc)):
        pose[i + 1] = se2_compose(pose[i], meas[i])
    twist = np.vstack([np.zeros((1, 3)), meas / dt])  # velocity over the last interval
    return OdometryTrace(t, pose, twist, ks, kw, drift)


def people_clearance(world: World, traj: Trajectory, cfg: SimRobotConfig,
                     step_s: float = 0.05) -> tuple[float, float, str]:
    """Closest approach between the robot footprint and any person's body disc.

    Returns (distance m, time s, person name); ``inf`` when the world has no people.
    People walk their own paths without yielding, so built-in scenarios are tuned to
    keep this positive; user worlds get a warning when it is not.
    """
    best = (math.inf, 0.0, "")
    if not world.people:
        return best
    t = np.arange(0.0, traj.duration, step_s)
    poses = traj.pose(t)
    for p in world.people:
        xy = np.array([p.state(float(ti))[:2] for ti in t])
        d = _footprint_gap(poses, xy, cfg, p)  # the person's body disc to the footprint rectangle
        k = int(np.argmin(d))
        if d[k] < best[0]:
            best = (float(d[k]), float(t[k]), p.name)
    return best
