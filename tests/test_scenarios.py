"""Built-in scenarios: collision-free tours, realistic odometry, ground truth that means what it says."""

import math

import numpy as np
import pytest

from semmap.errors import ConfigError
from semmap.geometry import se2_between, se2_compose
from semmap.records import GridSpec, Mobility
from semmap.sim.groundtruth import occupancy_layers, rasterise
from semmap.sim.robot import check_clearance, people_clearance, plan_tour, simulate_odometry
from semmap.sim.scenarios import SCENARIOS, get_scenario
from semmap.sim.tour import effective_config
from semmap.sim.world import load_world, world_from_dict, world_to_dict


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_tour_is_smooth_and_collision_free(name):
    sc = get_scenario(name)
    cfg = effective_config(sc, None)
    traj = plan_tour(sc.world, cfg.robot)
    assert check_clearance(sc.world, traj, cfg.robot) >= cfg.robot.clearance
    gap, _, _ = people_clearance(sc.world, traj, cfg.robot)
    assert gap > 0.05  # people never walk into the robot
    t = np.arange(0.0, traj.duration, 0.02)
    v = traj.velocity(t)
    assert np.abs(v[:, 0]).max() <= cfg.robot.max_speed * 1.02
    assert np.abs(v[:, 2]).max() <= cfg.robot.max_yaw_rate * 1.05
    assert np.abs(v[:, 1]).max() < 0.01  # a differential drive does not slide sideways
    # people: realistic walking speeds, and at least one who stands still
    speeds = [p.speed for p in sc.world.people if len(p.waypoints) > 1]
    assert all(0.4 <= s <= 1.5 for s in speeds)
    if name == "loop":  # once round a 120 m ring and on past the start: twice ward's route
        assert 180.0 <= traj.duration <= 240.0
        assert traj.length() >= 1.9 * plan_tour(get_scenario("ward").world, cfg.robot).length()
    elif name != "occlusion":
        assert 20.0 <= traj.duration <= 130.0


def test_demo_is_small():
    traj = plan_tour(get_scenario("demo").world, effective_config(get_scenario("demo"), None).robot)
    assert traj.duration < 40.0


def test_wheel_odometry_error_is_realistic():
    sc = get_scenario("ward")
    cfg = effective_config(sc, None)
    traj = plan_tour(sc.world, cfg.robot)
    odo = simulate_odometry(traj, cfg.odometry, np.random.default_rng(0))
    true = traj.pose(odo.t)
    # compare each 10 m stretch: relative translation error of wheel odometry is about 1-3 %
    step = int(10.0 / 0.6 * cfg.odometry.rate_hz)
    errs = []
    for i in range(0, len(odo.t) - step, step):
        d_true = se2_between(true[i], true[i + step])
        d_odo = se2_between(odo.pose[i], odo.pose[i + step])
        dist = np.hypot(*d_true[:2])
        if dist > 3.0:
            errs.append(np.hypot(*(d_odo[:2] - d_true[:2])) / dist)
    assert 0.005 < np.median(errs) < 0.06
    end_err = np.hypot(*(se2_compose(true[0], odo.pose[-1])[:2] - true[-1, :2]))
    assert end_err > 0.3  # odometry alone drifts visibly over a 66 m tour


def test_chairs_and_tables_are_only_legs_at_lidar_height():
    world = get_scenario("office").world
    spec = GridSpec.covering(*world.bounds(1.0), 0.05)
    layers = occupancy_layers(world, spec, 0.2)
    for cls in ("chair", "dining table", "bed"):
        objs = [o for o in world.objects if o.cls == cls]
        if not objs:
            continue
        footprint = rasterise(spec, [p.polygon for o in objs for p in o.parts]).sum()
        at_lidar = (rasterise(spec, [p.polygon for o in objs for p in o.parts if p.spans(0.2)])).sum()
        assert at_lidar < 0.2 * footprint, cls
    assert not (layers["static"] & layers["semi_static"]).any()


def test_change_scenarios_move_remove_and_add():
    sc = get_scenario("ward_b")
    assert sc.base is not None and sc.base.name == "ward"
    base_ids = {o.id for o in sc.base.objects}
    ids = {o.id for o in sc.world.objects}
    assert base_ids - ids  # removed furniture
    new = [o for o in sc.world.objects if o.id not in base_ids]
    assert len(new) == 1 and new[0].mobility == Mobility.STATIC  # one new static obstacle
    walls_a = sorted(o.name for o in sc.base.objects if o.cls == "wall")
    walls_b = sorted(o.name for o in sc.world.objects if o.cls == "wall")
    assert walls_a == walls_b  # same building
    assert {p.id for p in sc.base.people}.isdisjoint({p.id for p in sc.world.people})
    ta = plan_tour(sc.base, effective_config(get_scenario("ward"), None).robot)
    tb = plan_tour(sc.world, effective_config(sc, None).robot)
    # B starts elsewhere, facing another way
    assert np.hypot(tb.x[0] - ta.x[0], tb.y[0] - ta.y[0]) > 5.0
    assert abs(math.remainder(tb.yaw[0] - ta.yaw[0], 2 * math.pi)) > 1.0


def test_world_yaml_roundtrip(tmp_path):
    world = get_scenario("office").world
    again = world_from_dict(world_to_dict(world), "test")
    assert [o.name for o in again.objects] == [o.name for o in world.objects]
    for a, b in zip(again.objects, world.objects):
        assert all(np.allclose(p.polygon, q.polygon, atol=1e-5) for p, q in zip(a.parts, b.parts))
    assert again.people[0].state(12.3) == pytest.approx(world.people[0].state(12.3), abs=1e-4)


def test_world_file_errors_name_the_problem(tmp_path):
    bad = tmp_path / "w.yaml"
    bad.write_text("name: x\nobjects:\n  - {id: 1, class: chair, mobility: sometimes, parts: []}\n")
    with pytest.raises(ConfigError, match=r"w.yaml: objects.0.mobility: unknown mobility 'sometimes'"):
        load_world(bad)
    bad.write_text("name: x\ncolour: red\n")
    with pytest.raises(ConfigError, match="w.yaml: colour: unknown key"):
        load_world(bad)


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_people_walk_around_furniture_not_through_it(name):
    from semmap.sim.groundtruth import people_swept

    sc = get_scenario(name)
    cfg = effective_config(sc, None)
    traj = plan_tour(sc.world, cfg.robot)
    spec = GridSpec.covering(*sc.world.bounds(1.0), 0.05)
    swept = people_swept(sc.world, spec, traj.duration, radius=0.18, step_s=0.2)
    solid = rasterise(spec, [p.polygon for o in sc.world.objects for p in o.parts if p.z_min < 0.9])
    assert (swept & solid).sum() == 0
