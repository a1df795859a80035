"""Random worlds (``random:SEED``): new buildings, furniture, people and sensor rigs per seed, each a
collision-free, well-posed test of a semantic mapper; and the ground truth every tour carries.

Seeds of 1000 and above are kept for scoring: these tests (and any tuning) use seeds 0-9 only.
"""

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from semmap.classes import load_class_table
from semmap.config import SimConfig, load_model
from semmap.errors import ConfigError
from semmap.io.mapserver import read_map
from semmap.io.yamlio import read_yaml
from semmap.sim.groundtruth import rasterise, standing_stretches
from semmap.sim.procedural import ROUTE_CLEARANCE_M, person_role, random_world
from semmap.sim.robot import check_clearance, people_clearance, plan_tour
from semmap.sim.scenarios import Scenario, get_scenario
from semmap.sim.tour import effective_config, simulate
from semmap.sim.world import circle, world_from_dict, world_to_dict

SEEDS = list(range(10))


@pytest.fixture(scope="module")
def worlds():
    out = {}
    for seed in SEEDS:
        sc = random_world(seed)
        cfg = effective_config(sc, None)
        out[seed] = (sc, cfg, plan_tour(sc.world, cfg.robot))
    return out


def _gap(a, b):
    """Distance between two convex polygons (0 when they touch or overlap)."""
    def inside(p, poly):
        e = np.roll(poly, -1, axis=0) - poly
        c = e[:, 0] * (p[1] - poly[:, 1]) - e[:, 1] * (p[0] - poly[:, 0])
        return bool(np.all(c >= -1e-9) or np.all(c <= 1e-9))

    def seg(p, a0, a1):
        d = a1 - a0
        t = np.clip(np.dot(p - a0, d) / max(np.dot(d, d), 1e-12), 0.0, 1.0)
        return float(np.hypot(*(p - a0 - t * d)))

    if any(inside(p, b) for p in a) or any(inside(p, a) for p in b):
        return 0.0
    best = math.inf
    for x, y in ((a, b), (b, a)):
        for p in x:
            for k in range(len(y)):
                best = min(best, seg(p, y[k], y[(k + 1) % len(y)]))
    return best  # edges crossing without a vertex inside cannot happen for our boxes and circles


def _point_gaps(points, polys):
    """Distance from each point to the nearest of many convex CCW polygons (0 inside one)."""
    a = np.concatenate(polys)
    e = np.concatenate([np.roll(q, -1, axis=0) for q in polys]) - a
    starts = np.concatenate([[0], np.cumsum([len(q) for q in polys])[:-1]])
    rel = np.asarray(points, float)[:, None, :] - a[None]
    t = np.clip(np.einsum("mek,ek->me", rel, e) / np.einsum("ek,ek->e", e, e), 0.0, 1.0)
    d = np.hypot(rel[..., 0] - t * e[:, 0], rel[..., 1] - t * e[:, 1])
    inside = np.minimum.reduceat(e[:, 0] * rel[..., 1] - e[:, 1] * rel[..., 0], starts, axis=1) >= 0
    d = np.minimum.reduceat(d, starts, axis=1)
    d[inside] = 0.0
    return d.min(axis=1)


def _overlap(a, b, tol=1e-6):
    """Convex polygons overlap by more than ``tol`` (separating axis test)."""
    for poly in (a, b):
        e = np.roll(poly, -1, axis=0) - poly
        n = np.column_stack([e[:, 1], -e[:, 0]]) / np.hypot(e[:, 0], e[:, 1])[:, None]
        pa, pb = a @ n.T, b @ n.T
        if np.any((pa.max(axis=0) <= pb.min(axis=0) + tol) | (pb.max(axis=0) <= pa.min(axis=0) + tol)):
            return False
    return True


def test_the_same_seed_gives_the_same_world_and_other_seeds_other_worlds(worlds):
    again = random_world(4)
    assert world_to_dict(again.world) == world_to_dict(worlds[4][0].world)
    assert again.overrides == worlds[4][0].overrides
    layouts = [json.dumps(world_to_dict(worlds[s][0].world)["objects"]) for s in SEEDS]
    assert len(set(layouts)) == len(SEEDS)
    assert len({json.dumps(worlds[s][0].overrides, sort_keys=True) for s in SEEDS}) >= 5


def test_random_seed_is_a_scenario_name():
    sc = get_scenario("random:2")
    assert isinstance(sc, Scenario) and sc.world.name == "random_2"
    for bad in ("random:", "random:x", "random:-1", "random:1.5"):
        with pytest.raises(ConfigError):
            get_scenario(bad)


@pytest.mark.parametrize("seed", SEEDS)
def test_the_tour_keeps_clear_and_takes_one_to_three_minutes(worlds, seed):
    sc, cfg, traj = worlds[seed]
    assert check_clearance(sc.world, traj, cfg.robot) >= ROUTE_CLEARANCE_M - 0.02
    gap, _, who = people_clearance(sc.world, traj, cfg.robot)
    assert gap >= 0.05, who
    assert 55.0 <= traj.duration <= 155.0


@pytest.mark.parametrize("seed", SEEDS)
def test_furniture_stands_against_walls_and_never_overlaps(worlds, seed):
    world = worlds[seed][0].world
    walls = [p for o in world.objects if o.cls == "wall" for p in o.parts]
    furniture = [o for o in world.objects if o.cls not in ("wall",)]
    # at least one bed or couch within 5 cm of a wall face
    against = [o for o in furniture if o.cls in ("bed", "couch")
               and min(_gap(p.polygon, w.polygon) for p in o.parts for w in walls) < 0.05]
    assert against, "no bed or couch against a wall"
    # no two objects' parts share floor and height (a monitor stands on its desk: touching only)
    parts = [(o.id, p) for o in furniture for p in o.parts] + [(0, w) for w in walls]
    for i, (ia, pa) in enumerate(parts):
        if ia == 0:
            continue
        for ib, pb in parts[i + 1:]:
            if ia == ib or min(pa.z_max, pb.z_max) - max(pa.z_min, pb.z_min) <= 1e-6:
                continue
            assert not _overlap(pa.polygon, pb.polygon), (ia, ib)


@pytest.mark.parametrize("seed", SEEDS)
def test_people_play_their_roles(worlds, seed):
    sc, _cfg, _traj = worlds[seed]
    people = sc.world.people
    roles = [person_role(p.name) for p in people]
    standing = [p for p, r in zip(people, roles) if r == "standing"]
    assert standing and all(len(p.waypoints) == 1 for p in standing)
    assert any(max(s for _, s in p.pauses) >= 20.0 for p, r in zip(people, roles) if r == "pauser")
    assert roles.count("guide") == 1 and "pacer" in roles
    ids = [o.id for o in sc.world.objects] + [p.id for p in people]
    assert len(set(ids)) == len(ids) and min(ids) > 0
    # one of the standers is at a bed or table, 0.25-0.35 m from its edge
    tables = [o for o in sc.world.objects if o.cls in ("bed", "dining table")]
    near = _point_gaps([p.waypoints[0] for p in standing], [part.polygon for o in tables for part in o.parts])
    assert near.min() <= 0.36
    # nobody's waypoint is inside or against furniture or a wall
    solid = [part.polygon for o in sc.world.objects for part in o.parts]
    for p in people:
        assert _point_gaps(p.waypoints, solid).min() >= 0.2, p.name


@pytest.mark.parametrize("seed", SEEDS)
def test_the_guide_walks_ahead_of_the_robot_then_stands(worlds, seed):
    sc, _cfg, traj = worlds[seed]
    guide = next(p for p in sc.world.people if person_role(p.name) == "guide")
    t = np.arange(0.0, traj.duration, 0.05)
    st = np.array([guide.state(float(x)) for x in t])
    walking = st[:, 3] > 0
    assert walking.sum() * 0.05 >= 3.0  # walks a while
    pose = traj.pose(t[walking])
    rel = st[walking, :2] - pose[:, :2]
    dist = np.hypot(rel[:, 0], rel[:, 1])
    ahead = rel[:, 0] * np.cos(pose[:, 2]) + rel[:, 1] * np.sin(pose[:, 2])
    assert dist.min() >= 1.2 and dist.max() <= 2.5
    assert ahead.min() > 0.0
    last = np.nonzero(walking)[0][-1]
    assert not walking[last + 1:].any()  # then stands for the rest of the tour


@pytest.mark.parametrize("seed", SEEDS)
def test_classes_are_known_and_the_world_round_trips(worlds, seed):
    sc, cfg, _ = worlds[seed]
    table = load_class_table()
    assert {o.cls for o in sc.world.objects} <= set(table.mobility)
    d = world_to_dict(sc.world)
    assert world_to_dict(world_from_dict(d)) == d
    assert sc.world.description.startswith("Random building")
    assert cfg.lidar.mount.xyz[2] >= 0.15 and cfg.camera.rate_hz in (2.0, 3.0, 5.0)


def test_a_short_random_tour_carries_standing_and_object_truth(tmp_path):
    sc = get_scenario("random:3")
    short = Scenario(replace(sc.world, duration_s=20.0), sc.overrides)
    out = tmp_path / "r3"
    simulate(short, out, seed=1)
    gt = out / "ground_truth"
    standing = read_map(gt / "people_standing.yaml")
    occupancy = read_map(gt / "occupancy.yaml")
    truth = json.loads((gt / "objects.json").read_text())
    assert len(truth["objects"]) == len(sc.world.objects) and len(truth["people"]) == len(sc.world.people)
    # a person who stands all tour: their legs at LiDAR height are standing truth, not the floor around
    stander = next(p for p in sc.world.people if person_role(p.name) == "standing")
    height = load_model(SimConfig, read_yaml(out / "config.yaml"), "config.yaml").lidar.mount.xyz[2]
    legs = rasterise(standing.spec, [poly for poly, z0, z1, _ in stander.body(0.0) if z0 <= height <= z1])
    legs &= ~occupancy.occupied
    disc = rasterise(standing.spec, [circle(*stander.waypoints[0], 0.25, 16)])
    assert legs.sum() >= 4 and standing.occupied[legs].all()
    assert standing.occupied[disc & ~legs].sum() == 0
    entry = next(e for e in truth["people"] if e["id"] == stander.id)
    assert entry["role"] == "standing" and entry["standing_s"] == pytest.approx(20.0, abs=0.2)
    assert entry["standing_s"] == pytest.approx(sum(b - a for a, b, _, _ in standing_stretches(stander, 20.0)))
    # walls are hit by the LiDAR; some furniture is seen by the camera and its hits could be painted
    walls = [e for e in truth["objects"] if e["class"] == "wall"]
    assert sum(e["lidar_hits"] for e in walls) > 1000 and all(e["cells"] > 0 for e in walls)
    seen = [e for e in truth["objects"] if e["camera_images"] > 0]
    assert seen and all(e["painted_hits"] <= e["lidar_hits"] for e in truth["objects"])
    manifest = (out / "tour.yaml").read_text()
    assert "people_standing: ground_truth/people_standing.yaml" in manifest
    assert "objects: ground_truth/objects.json" in manifest


def test_a_door_as_wide_as_its_wall_has_one_place():
    # seed 160: a door narrowed to its wall's length left a zero-width range for its centre, whose
    # bounds a rounding error crossed (numpy refused to draw from it)
    sc = random_world(160)
    assert sc.world.objects and sc.world.name == "random_160"
