"""Long tours: the robot drives its route for several laps, still collision-free, still clear of people."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from semmap.errors import ConfigError
from semmap.sim.robot import check_clearance, people_clearance, plan_tour
from semmap.sim.scenarios import demo, ward
from semmap.sim.tour import effective_config, simulate
from semmap.sim.world import load_world, world_from_dict, world_to_dict


def _limits_hold(traj, cfg):
    t = np.arange(0.0, traj.duration, 0.02)
    v = traj.velocity(t)
    assert np.abs(v[:, 0]).max() <= cfg.max_speed * 1.02
    assert np.abs(v[:, 2]).max() <= cfg.max_yaw_rate * 1.05  # no jump in heading between laps
    assert np.abs(v[:, 1]).max() < 0.01


def test_two_laps_of_the_ward_are_collision_free_and_twice_as_long():
    sc = ward()
    cfg = effective_config(sc, None).robot
    one = plan_tour(sc.world, cfg)
    world = replace(sc.world, laps=2)
    two = plan_tour(world, cfg)
    assert check_clearance(world, two, cfg) >= cfg.clearance
    gap, _, _ = people_clearance(world, two, cfg)
    assert gap > 0.05  # the second lap meets the people at other times, and still keeps clear of them
    _limits_hold(two, cfg)
    # the route twice, plus the drive from its last waypoint back to its first
    back = float(np.hypot(*(world.route[-1] - world.route[0])))
    assert two.length() == pytest.approx(2 * one.length() + back, rel=1e-3)
    # twice as long, give or take the drive back, a turn and the wait for people (seconds, not minutes)
    assert 2 * one.duration - cfg.settle_s <= two.duration <= 2 * one.duration + 20.0
    # the robot is back at the start once more
    at_start = np.hypot(two.x - world.route[0, 0], two.y - world.route[0, 1]) < 0.01
    assert np.count_nonzero(np.diff(at_start.astype(int)) == 1) == 1


def test_a_thirty_minute_ward_tour_keeps_clear_of_people_in_every_lap():
    sc = ward()
    cfg = effective_config(sc, None).robot
    world = replace(sc.world, laps=16, duration_s=1800.0)
    traj = plan_tour(world, cfg)
    assert traj.duration == pytest.approx(1800.0, abs=0.05)  # cut at the duration, mid-lap
    assert check_clearance(world, traj, cfg) >= cfg.clearance
    gap, _, _ = people_clearance(world, traj, cfg)
    assert gap > 0.05
    # 14 whole laps and most of a 15th: the waits for people cost seconds per lap
    assert traj.length() > 14.5 * plan_tour(sc.world, cfg).length()


def test_a_closed_route_turns_in_place_between_laps():
    sc = demo()
    route = np.vstack([sc.world.route, sc.world.route[:1]])  # ends where it starts, heading another way
    world = replace(sc.world, route=route, laps=3)
    cfg = effective_config(sc, None).robot
    traj = plan_tour(world, cfg)
    assert check_clearance(world, traj, cfg) >= cfg.clearance
    _limits_hold(traj, cfg)
    one = plan_tour(replace(world, laps=1), cfg)
    assert traj.length() == pytest.approx(3 * one.length(), rel=1e-3)


def test_laps_round_trip_through_world_yaml_and_are_checked(tmp_path):
    world = replace(ward().world, laps=5, duration_s=600.0)
    path = tmp_path / "world.yaml"
    path.write_text(yaml.safe_dump(world_to_dict(world)))
    again = load_world(path)
    assert again.laps == 5 and again.duration_s == 600.0
    data = world_to_dict(ward().world)
    assert world_from_dict(data).laps == 1
    for bad in (0, -1, 1.5, "two", True):
        with pytest.raises(ConfigError, match="laps"):
            world_from_dict({**data, "laps": bad})


def test_a_two_lap_tour_bag_holds_twice_the_scans(tmp_path):
    world = replace(demo().world, laps=2)
    cfg = {"camera": {"rate_hz": 1.0, "image_format": "jpeg", "label_encoding": "mono8"}}
    one = simulate(demo().world, tmp_path / "one", config=cfg)
    two = simulate(world, tmp_path / "two", config=cfg)
    manifest = yaml.safe_load((two.out / "tour.yaml").read_text())
    assert manifest["min_people_clearance_m"] > 0.05
    n1, n2 = one.topics["/scan"], two.topics["/scan"]
    assert 2 * n1 - 15 <= n2 <= 2 * n1 + 15 * 20  # 15 Hz: twice, plus at most 20 s between laps
    assert load_world(two.out / "ground_truth" / "world.yaml").laps == 2
