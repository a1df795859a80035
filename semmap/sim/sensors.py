"""Simulated sensors: a sweeping 2D LiDAR and a ray-cast RGB camera with exact labels.

Both cast rays against the same 2.5D world. The LiDAR sees parts cut by its
scan plane (chair legs, not seats). The camera casts one ray per image column
(exact for a level camera) and resolves every pixel of that column against the
height interval of each part the ray crosses, with a depth buffer, so table tops
are seen from above and people are seen between table legs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..config import SimCameraConfig, SimLidarConfig
from ..geometry import se2_compose, se3_from_xyz_rpy
from .raycast import PartSet, first_hit, part_intervals

__all__ = ["CameraImage", "CameraSim", "LidarSim", "LidarSweep", "mount_se2", "mount_turn"]


def mount_se2(xyz: tuple[float, float, float], rpy: tuple[float, float, float]) -> NDArray[np.float64]:
    """The floor pose (x, y, yaw) of a sensor mount given as ``T_base_sensor``."""
    t = se3_from_xyz_rpy(xyz, rpy)
    return np.array([t[0, 3], t[1, 3], math.atan2(t[1, 0], t[0, 0])])


def mount_turn(rpy: tuple[float, float, float]) -> float:
    """+1 for a LiDAR mounted upright, -1 for one mounted upside down (rolled half a turn, as under a
    bumper): its beam at angle a in its own frame points at yaw - a in the base frame, not yaw + a."""
    t = se3_from_xyz_rpy((0.0, 0.0, 0.0), rpy)
    return 1.0 if t[2, 2] >= 0 else -1.0


@dataclass(frozen=True)
class LidarSweep:
    """One simulated scan before noise: true ranges and what each beam hit."""

    ranges: NDArray[np.float64]  # (N,) true range, inf where nothing within range_max
    part: NDArray[np.intp]  # (N,) index into the PartSet used, -1 on a miss
    parts: PartSet


class LidarSim:
    """A 2D LiDAR; beams are fired over the scan period when ``cfg.sweep`` is set."""

    def __init__(self, cfg: SimLidarConfig) -> None:
        self.cfg = cfg
        n = cfg.n_beams
        half = math.radians(cfg.fov_deg) / 2
        self.angle_min = -half
        self.angle_increment = math.radians(cfg.fov_deg) / (n - 1)
        self.angles = self.angle_min + self.angle_increment * np.arange(n)
        self.mount = mount_se2(cfg.mount.xyz, cfg.mount.rpy)
        #: each beam's angle from the mount's heading in the base frame (mirrored when upside down)
        self.base_angles = mount_turn(cfg.mount.rpy) * self.angles
        self.height = float(cfg.mount.xyz[2])
        # a rotating scanner fires all beams of a full turn within one period
        self.time_increment = (1.0 / cfg.rate_hz) / (2 * math.pi / self.angle_increment) if cfg.sweep else 0.0
        self.beam_dt = self.time_increment * np.arange(n)

    def cast(self, base_poses: NDArray[np.float64], parts: PartSet) -> LidarSweep:
        """Cast all beams. ``base_poses`` is (N, 3), one base pose per beam (or (3,))."""
        lidar = se2_compose(np.atleast_2d(base_poses), self.mount)
        if lidar.shape[0] == 1:
            lidar = np.repeat(lidar, self.angles.size, axis=0)
        heading = lidar[:, 2] + self.base_angles
        dirs = np.column_stack([np.cos(heading), np.sin(heading)])
        origin = lidar[:, :2]
        centre = origin[origin.shape[0] // 2]
        near = parts.at_height(self.height).near(centre, self.cfg.range_max + 1.0)
        same = np.allclose(origin, origin[0], atol=1e-9)
        dist, part, _ = first_hit(origin[0] if same else origin, dirs, near)
        miss = ~(dist <= self.cfg.range_max)
        dist = np.where(miss, np.inf, dist)
        part = np.where(miss, -1, part)
        return LidarSweep(dist, part, near)

    def measure(self, sweep: LidarSweep, rng: np.random.Generator) -> NDArray[np.float32]:
        """Add range noise and dropouts; REP-117 values: +inf no return, -inf too close."""
        cfg = self.cfg
        r = sweep.ranges + rng.normal(0.0, cfg.noise_std, sweep.ranges.size)
        r = np.where(np.isfinite(sweep.ranges), r, np.inf)
        r = np.where(rng.random(r.size) < cfg.dropout_prob, np.inf, r)
        r = np.where(r > cfg.range_max, np.inf, r)
        r = np.where(r < cfg.range_min, -np.inf, r)
        return r.astype(np.float32)


@dataclass(frozen=True)
class CameraImage:
    """A rendered frame: RGB, label image (class list values) and per-pixel depth (optical z, m)."""

    rgb: NDArray[np.uint8]
    label: NDArray[np.uint16]
    depth: NDArray[np.float32]
    owner: NDArray[np.intp]  # (H, W) object-table row per pixel, -1 for floor/ceiling


_FLOOR_A = np.array([176, 170, 160], np.float32)
_FLOOR_B = np.array([150, 146, 138], np.float32)
_CEILING = np.array([232, 232, 228], np.float32)


class CameraSim:
    """A level pinhole camera rendered by casting one ray per column."""

    def __init__(self, cfg: SimCameraConfig, ceiling_height: float, rng: np.random.Generator) -> None:
        self.cfg = cfg
        k = np.asarray(cfg.K, dtype=np.float64)
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        w, h = cfg.width, cfg.height
        self.xn = (np.arange(w) - cx) / fx  # optical x per column
        yn = (np.arange(h) - cy) / fy
        self.norm = np.sqrt(1.0 + self.xn**2)  # horizontal distance / optical depth
        slope = -yn[:, None] / self.norm[None, :]  # dz/dd per pixel
        slope = np.where(np.abs(slope) < 1e-9, 1e-9, slope)
        self.slope = slope.astype(np.float32)
        self.inv_slope = (1.0 / slope).astype(np.float32)
        # ray azimuth in the camera's floor frame (x forward, y left); optical x points right
        self.local_dirs = np.column_stack([1.0 / self.norm, -self.xn / self.norm])
        t = se3_from_xyz_rpy(cfg.mount.xyz, cfg.mount.rpy)
        # the floor pose of the optical axis (optical z), which the config keeps level
        self.mount = np.array([t[0, 3], t[1, 3], math.atan2(t[1, 2], t[0, 2])])
        self.height = float(cfg.mount.xyz[2])
        self.ceiling = ceiling_height
        self.hfov = 2 * math.atan(max(cx, w - cx) / fx)
        self._floor_rows = slice(int(max(0, math.floor(cy))), h)  # rows that can see the floor
        self._noise = (rng.normal(0.0, cfg.noise_std, (4, h, w, 3))).astype(np.float32) if cfg.noise_std > 0 else None

    def render(self, base_pose: NDArray[np.float64], parts: PartSet, label_of_owner: NDArray[np.uint16],
               rng: np.random.Generator) -> CameraImage:
        """Render the view from ``base_pose`` (world frame)."""
        cam = se2_compose(base_pose, self.mount)
        origin = cam[:2]
        cos_yaw, sin_yaw = math.cos(cam[2]), math.sin(cam[2])
        dirs = self.local_dirs @ np.array([[cos_yaw, sin_yaw], [-sin_yaw, cos_yaw]])
        # cull to the field of view (bounding circles)
        rel = parts.centre - origin
        dist = np.hypot(rel[:, 0], rel[:, 1])
        ang = np.abs(np.arctan2(rel[:, 1], rel[:, 0]) - cam[2])
        ang = np.minimum(ang, 2 * np.pi - ang)
        margin = np.arcsin(np.clip(parts.radius / np.maximum(dist, 1e-9), 0.0, 1.0))
        vis = (dist <= parts.radius) | (ang <= self.hfov / 2 + margin)
        ps = parts.select(vis & (parts.z_max > 0.0) & (parts.z_min < self.ceiling))

        h, w = self.slope.shape
        hc = self.height
        # background: floor, ceiling, then full-height structure (walls, pillars)
        below = self.slope < 0
        depth = np.where(below, np.float32(-hc) * self.inv_slope, np.float32(self.ceiling - hc) * self.inv_slope)
        pid = np.where(below, -1, -2).astype(np.int32)  # -1 floor, -2 ceiling
        shade = np.ones((h, w), np.float32)
        full = (ps.z_min <= 1e-6) & (ps.z_max >= self.ceiling - 1e-6)
        walls = ps.select(full)
        wall_index = np.nonzero(full)[0]
        t_wall, wpart, wedge = first_hit(origin, dirs, walls)
        if walls.n_parts:
            hit = t_wall[None, :] < depth
            depth = np.where(hit, t_wall[None, :].astype(np.float32), depth)
            pid = np.where(hit, np.where(wpart >= 0, wall_index[np.maximum(wpart, 0)], -2)[None, :], pid)
            e = walls.b[np.maximum(wedge, 0)] - walls.a[np.maximum(wedge, 0)]
            n = np.column_stack([e[:, 1], -e[:, 0]]) / np.maximum(np.hypot(e[:, 0], e[:, 1]), 1e-12)[:, None]
            lam = np.abs(np.sum(n * dirs, axis=1))
            shade = np.where(hit, (0.45 + 0.55 * lam)[None, :].astype(np.float32), shade)
        # objects in front of the structure, resolved per pixel with a depth buffer
        objs = np.nonzero(~full)[0]
        if objs.size:
            sub = ps.select(~full)
            t_in, t_out = part_intervals(origin, dirs, sub)
            cand = np.where(t_in < t_wall[:, None], t_in, np.inf)
            n_layers = int(np.isfinite(cand).sum(axis=1).max())
            if n_layers:
                order = np.argsort(cand, axis=1)[:, :n_layers]
                cols = np.arange(w)
                zmin = (sub.z_min - hc).astype(np.float32)
                zmax = (sub.z_max - hc).astype(np.float32)
                for k in range(n_layers):
                    idx_all = order[:, k]
                    tin_all = cand[cols, idx_all]
                    c = np.nonzero(np.isfinite(tin_all))[0]  # columns with a k-th candidate part
                    if c.size == 0:
                        break
                    idx = idx_all[c]
                    tin = tin_all[c].astype(np.float32)
                    tout = t_out[c, idx].astype(np.float32)
                    inv = self.inv_slope[:, c]
                    lo = zmin[idx] * inv
                    hi = zmax[idx] * inv
                    entry = np.maximum(tin, np.minimum(lo, hi))
                    d_sub = depth[:, c]
                    hit = (entry <= np.minimum(tout, np.maximum(lo, hi))) & (entry < d_sub)
                    if not hit.any():
                        continue
                    depth[:, c] = np.where(hit, entry, d_sub)
                    pid[:, c] = np.where(hit, objs[idx].astype(np.int32), pid[:, c])
                    face = np.where(entry <= tin + 1e-6, np.float32(0.82),
                                    np.where(inv < 0, np.float32(1.0), np.float32(0.55)))
                    shade[:, c] = np.where(hit, face, shade[:, c])

        # colour: one palette gather; index 0 ceiling, 1-2 floor tiles, 3+ parts
        palette = np.concatenate([np.stack([_CEILING, _FLOOR_A, _FLOOR_B]), ps.color.astype(np.float32)])
        index = pid + 3
        index[pid == -2] = 0
        rows = self._floor_rows
        floor = pid[rows] == -1
        if floor.any():
            d = depth[rows]
            gx = np.floor((origin[0] + d * dirs[None, :, 0].astype(np.float32)) * np.float32(1 / 0.6))
            gy = np.floor((origin[1] + d * dirs[None, :, 1].astype(np.float32)) * np.float32(1 / 0.6))
            tile = (gx + gy).astype(np.int32) & 1
            index[rows] = np.where(floor, 1 + tile, index[rows])
        scale = shade * (np.float32(0.35) + np.float32(0.65) / (np.float32(1.0) + np.float32(0.025) * depth))
        img = palette[index] * scale[:, :, None]
        if self._noise is not None:
            img += self._noise[int(rng.integers(len(self._noise)))]
        rgb = np.clip(img, 0, 255).astype(np.uint8)

        owner_lut = np.concatenate([[-1, -1, -1], ps.owner])
        owner = owner_lut[index]
        label_lut = np.concatenate([[0, 0, 0], label_of_owner[ps.owner]]).astype(np.uint16)
        label = label_lut[index]
        zdepth = depth / self.norm[None, :].astype(np.float32)
        return CameraImage(rgb=rgb, label=label, depth=zdepth, owner=owner)
