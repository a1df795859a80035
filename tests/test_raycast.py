"""The ray caster behind the simulated LiDAR and camera."""

import math

import numpy as np
import pytest

from semmap.config import SimLidarConfig
from semmap.sim.raycast import PartSet, first_hit, part_intervals
from semmap.sim.sensors import LidarSim
from semmap.sim.world import Part, chair, rect, wall


def _set(objs):
    parts = [p for o in objs for p in o.parts]
    return PartSet.build(parts, [i for i, o in enumerate(objs) for _ in o.parts])


def test_beam_aimed_at_a_known_wall_returns_its_range():
    # wall face at x = 4.94 (centre line x = 5, 12 cm thick)
    ps = _set([wall(1, 5.0, -3.0, 5.0, 3.0)])
    cfg = SimLidarConfig(sweep=False, noise_std=0.0, dropout_prob=0.0)
    lidar = LidarSim(cfg)
    base = np.array([1.0, 0.5, 0.0])
    sweep = lidar.cast(base, ps)
    # the beam pointing along world +x: lidar yaw is +45 deg, so beam angle -45 deg
    k = int(np.argmin(np.abs(lidar.angles + math.pi / 4)))
    assert lidar.angles[k] == pytest.approx(-math.pi / 4)
    lidar_x = 1.0 + cfg.mount.xyz[0]
    assert sweep.ranges[k] == pytest.approx(4.94 - lidar_x, abs=1e-9)
    # an oblique beam: range = perpendicular distance / cos(angle to the normal)
    k2 = int(np.argmin(np.abs(lidar.angles - (-math.pi / 4 + math.radians(30)))))
    heading = math.pi / 4 + lidar.angles[k2]
    assert sweep.ranges[k2] == pytest.approx((4.94 - lidar_x) / math.cos(heading), abs=1e-9)


def test_lidar_sees_only_chair_legs():
    c = chair(1, (2.0, 0.0, 0.0))
    ps = _set([c])
    lidar = LidarSim(SimLidarConfig(sweep=False, noise_std=0.0, dropout_prob=0.0, mount={"xyz": (0, 0, 0.2)}))
    sweep = lidar.cast(np.zeros(3), ps)
    hit = np.isfinite(sweep.ranges)
    # every hit is on one of the 4 legs (3.5 cm posts under the seat), none on the seat or back
    assert hit.sum() > 0
    assert np.all(sweep.parts.z_max[sweep.part[hit]] < 0.45)
    assert len(np.unique(sweep.part[hit])) <= 4
    assert sweep.ranges[hit].min() > 2.0 - 0.23 - 1e-6


def test_sweeping_scan_follows_the_moving_robot():
    ps = _set([wall(1, 5.0, -3.0, 5.0, 3.0)])
    cfg = SimLidarConfig(noise_std=0.0, dropout_prob=0.0, mount={"xyz": (0, 0, 0.2)}, rate_hz=10.0)
    lidar = LidarSim(cfg)
    # the robot moves 1 m/s along +x while the beams sweep; each beam sees the wall from its own pose
    poses = np.column_stack([lidar.beam_dt * 1.0, np.zeros_like(lidar.beam_dt), np.zeros_like(lidar.beam_dt)])
    sweep = lidar.cast(poses, ps)
    k = int(np.argmin(np.abs(lidar.angles)))
    assert sweep.ranges[k] == pytest.approx(4.94 - lidar.beam_dt[k], abs=1e-9)


def test_part_intervals_enter_and_leave_a_box():
    box = Part(rect(3.0, 0.0, 2.0, 2.0), 0.0, 1.0)
    ps = PartSet.build([box], [0])
    t_in, t_out = part_intervals(np.array([0.0, 0.0]), np.array([[1.0, 0.0], [0.0, 1.0]]), ps)
    assert t_in[0, 0] == pytest.approx(2.0) and t_out[0, 0] == pytest.approx(4.0)
    assert np.isinf(t_in[1, 0])
    # from inside, the entry is at 0
    t_in, t_out = part_intervals(np.array([3.0, 0.0]), np.array([[1.0, 0.0]]), ps)
    assert t_in[0, 0] == 0.0 and t_out[0, 0] == pytest.approx(1.0)


def test_first_hit_picks_the_nearest_of_many():
    rng = np.random.default_rng(1)
    walls = [wall(i + 1, x, -2, x, 2) for i, x in enumerate(rng.uniform(2, 9, 8))]
    ps = _set(walls)
    dirs = np.array([[1.0, 0.0]])
    dist, _part, _ = first_hit(np.zeros(2), dirs, ps)
    nearest = min(p.polygon[:, 0].min() for o in walls for p in o.parts)
    assert dist[0] == pytest.approx(nearest)
