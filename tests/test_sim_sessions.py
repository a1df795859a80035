"""Second sessions of a world (``NAME:b``) for scoring `semmap diff`: every change of the recipe
happens, keeps the simulator's rules, and is the same for the same name."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semmap.config import SimConfig, load_model, merge_overrides
from semmap.errors import ConfigError
from semmap.records import Mobility
from semmap.sim.robot import check_clearance, people_clearance, plan_tour
from semmap.sim.scenarios import get_scenario
from semmap.sim.sessions import parse_session_name
from semmap.sim.tour import _change_list
from semmap.sim.world import world_to_dict


@pytest.fixture(scope="module", params=["random:120", "random:121", "ward"])
def pair(request):
    base = get_scenario(request.param)
    return base, get_scenario(f"{request.param}:b")


def test_the_recipe_happens_and_is_listed_as_truth(pair):
    base, b = pair
    assert b.base is base.world or world_to_dict(b.base) == world_to_dict(base.world)
    changes = _change_list(base.world, b.world)
    kinds = {(c["type"], c["mobility"]) for c in changes}
    assert ("moved", "semi_static") in kinds and ("removed", "semi_static") in kinds
    assert ("added", "static") in kinds  # the new cabinet (and a closed door, where there is one)
    for c in changes:
        if c["type"] == "moved":
            assert 0.29 <= c["displacement_m"] <= 2.01 or abs(c["rotation_deg"]) > 1.0
            assert abs(c["rotation_deg"]) <= 90.5
    # the tour starts elsewhere: the route the other way round
    assert np.allclose(b.world.route, base.world.route[::-1])
    assert b.overrides == base.overrides  # the same robot and sensors


def test_the_changed_world_keeps_the_simulators_rules(pair):
    base, b = pair
    cfg = load_model(SimConfig, merge_overrides(b.overrides, {}), "test")
    traj = plan_tour(b.world, cfg.robot)
    assert check_clearance(b.world, traj, cfg.robot) >= cfg.robot.clearance
    assert people_clearance(b.world, traj, cfg.robot)[0] > 0.0
    # furniture clear of other furniture and of walls (convex parts: a vertex inside another's hull)
    import cv2

    objs = [o for o in b.world.objects if o.mobility == Mobility.SEMI_STATIC]
    statics = [o for o in b.world.objects if o.mobility == Mobility.STATIC]
    moved_or_new = {c["id"] for c in _change_list(base.world, b.world) if c["type"] in ("moved", "added")}
    for o in (o for o in objs if o.id in moved_or_new):
        hull = cv2.convexHull(np.concatenate([p.polygon for p in o.parts]).astype(np.float32))
        for other in objs + statics:
            if other.id == o.id:
                continue
            for part in other.parts:
                inside = [cv2.pointPolygonTest(hull, (float(x), float(y)), False) > 0 for x, y in part.polygon]
                assert not any(inside), f"{o.name} overlaps {other.name}"


def test_same_name_same_world_other_variant_other_world():
    a1, a2 = get_scenario("random:122:b"), get_scenario("random:122:b")
    assert world_to_dict(a1.world) == world_to_dict(a2.world)
    b2 = get_scenario("random:122:b2")
    assert world_to_dict(b2.world) != world_to_dict(a1.world)


def test_names():
    assert parse_session_name("random:7:b") == ("random:7", 0)
    assert parse_session_name("ward:b3") == ("ward", 3)
    assert parse_session_name("ward_b") is None and parse_session_name("random:7") is None
    with pytest.raises(ConfigError, match="unknown scenario 'nowhere'"):
        get_scenario("nowhere:b")


def test_a_turn_is_in_the_truth():
    base = get_scenario("ward").world
    bed = next(o for o in base.objects if o.cls == "bed")
    turned = base.replace_objects([bed.moved(0.5, 0.0, math.radians(30)) if o.id == bed.id else o
                                   for o in base.objects])
    (c,) = _change_list(base, turned)
    assert c["type"] == "moved" and c["rotation_deg"] == pytest.approx(30.0, abs=0.01)
    assert c["displacement_m"] == pytest.approx(0.5, abs=0.001)


def test_a_recipe_that_blocks_the_route_is_drawn_again():
    # random:162:b first drew changes that put an obstacle 2 cm from the robot's path; the session is the
    # next draw, which keeps the simulator's rules
    from semmap.sim.sessions import get_session

    sc = get_session("random:162:b")
    assert sc.world.name == "random:162:b" and "later:" in sc.world.description
