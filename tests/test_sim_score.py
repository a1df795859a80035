"""Scoring maps of simulated tours: what each score counts, and the naive true-pose baseline."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from semmap.records import GridSpec
from semmap.sim.groundtruth import rasterise
from semmap.sim.score import GroundTruth, TruthObject, load_truth, match_objects, naive_map, score_masks
from semmap.sim.world import rect

SPEC = GridSpec(0.05, 0.0, 0.0, 80, 60)  # 4 m x 3 m, row 0 = lowest y


def _cells(*polys):
    return rasterise(SPEC, [np.asarray(p, float) for p in polys])


@pytest.fixture()
def room() -> GroundTruth:
    """A wall along y = 0..0.15 m, a chair whose front legs touch it, a person who stood still
    at (3, 2) and walked along y = 1."""
    static = _cells(rect(2.0, 0.075, 4.0, 0.15))
    legs = [rect(x, y, 0.05, 0.05) for x in (1.0, 1.4) for y in (0.175, 0.575)]
    semi = _cells(*legs) & ~static
    standing = _cells(rect(3.0, 2.0, 0.5, 0.5))
    swept = standing | _cells(rect(2.0, 1.0, 3.0, 0.5))
    chair = TruthObject(1, "chair_1", "chair", rect(1.2, 0.375, 0.45, 0.45), lidar_hits=40, painted_hits=12)
    return GroundTruth(tour=None, spec=SPEC, occupancy=static | semi, static=static, semi_static=semi,
                       swept=swept, standing=standing, observable=static | semi, semi_labelled=semi,
                       objects=(chair,), objects_source="objects.json",
                       stamps_ns=np.zeros(0, np.int64), poses=np.zeros((0, 3)))


def test_a_map_equal_to_the_truth_scores_perfectly(room):
    chair = {"class": "chair", "centroid": [1.2, 0.375]}
    s = score_masks(None, SPEC, room.occupancy, room.semi_static, [chair], truth=room)
    assert s["f1"] == s["precision"] == s["recall"] == 1.0
    assert s["ghost_rate"] == 0.0 and s["standing_left"] == 0.0 and s["walls_flagged"] == 0
    assert s["semi_precision"] == s["semi_recall"] == s["semi_recall_all"] == 1.0
    assert (s["objects_truth"], s["objects_found"], s["objects_matched"], s["objects_split"],
            s["objects_spurious"]) == (1, 1, 1, 0, 0)
    assert s["objects_count_error"] == 0.0 and s["objects_class_right"] == 1.0


def test_a_person_left_standing_in_the_map_is_counted(room):
    s = score_masks(None, SPEC, room.occupancy | room.standing, room.semi_static, truth=room)
    assert s["standing_left"] == 1.0
    assert s["ghost_rate"] == pytest.approx(room.standing.sum() / room.swept.sum())
    assert s["precision"] < 1.0 and s["recall"] == 1.0  # the person is an obstacle that is not there
    # the cells left of x = 3 m still there: about half the person
    left = room.standing & (SPEC.cell_centres()[0] < 3.0)
    s = score_masks(None, SPEC, room.occupancy | left, room.semi_static, truth=room)
    assert s["standing_left"] == pytest.approx(left.sum() / room.standing.sum()) == pytest.approx(0.5, abs=0.05)
    # a tour without the standing layer cannot tell
    s = score_masks(None, SPEC, room.occupancy, room.semi_static, truth=replace(room, standing=None))
    assert np.isnan(s["standing_left"])


def test_wall_flags_count_the_wall_not_the_chair_leg_against_it(room):
    row, col = SPEC.world_to_cell(np.array([3.0, 0.1]))  # a wall cell 1.6 m from the chair
    wall = np.zeros(SPEC.shape, bool)
    wall[row, col] = True
    s = score_masks(None, SPEC, room.occupancy, room.semi_static | wall, truth=room)
    assert s["walls_flagged"] == 1
    assert s["semi_precision"] == pytest.approx(room.semi_static.sum() / (room.semi_static.sum() + 1))
    # the wall cell behind the chair's front leg: a leg touching the wall, not a wall flag
    rows, cols = np.nonzero(room.semi_static)
    row, col = rows.min() - 1, cols[rows.argmin()]  # just below the lowest leg cell
    behind = np.zeros(SPEC.shape, bool)
    behind[row, col] = True
    assert room.static[row, col] and SPEC.cell_centres()[0][row, col] == pytest.approx(0.975)
    s = score_masks(None, SPEC, room.occupancy, room.semi_static | behind, truth=room)
    assert s["walls_flagged"] == 0
    # carried into the truth frame with T_gt_map: a map shifted by 1 m in x flags the same wall cell
    shifted = GridSpec(0.05, -1.0, 0.0, 80, 60)
    s = score_masks(None, shifted, room.occupancy, wall, T_gt_map=[1.0, 0.0, 0.0], truth=room)
    assert s["walls_flagged"] == 1


def test_object_list_split_spurious_and_count_error():
    table_legs = [rect(x, y, 0.05, 0.05) for x in (1.35, 2.65) for y in (1.65, 2.35)]
    table = TruthObject(1, "table_1", "dining table", np.array([[1.325, 1.625], [2.675, 1.625],
                                                                   [2.675, 2.375], [1.325, 2.375]]))
    chair = TruthObject(2, "chair_2", "chair", rect(2.0, 1.2, 0.46, 0.46))
    assert table.distance([2.0, 2.0]) == 0.0 and table.distance([2.0, 2.675]) == pytest.approx(0.3, abs=1e-5)
    assert len(table_legs) == 4
    # the map frame is the truth frame turned by 90 degrees: (x, y)_gt = (-y, x)_map
    T_gt_map = [0.0, 0.0, np.pi / 2]

    def in_map(x, y):
        return [y, -x]

    found = [
        {"class": "dining table", "centroid": in_map(1.4, 2.0)},  # the table's left legs ...
        {"class": "chair", "centroid": in_map(2.65, 2.0)},  # ... and its right legs, named wrong
        {"class": "chair", "centroid": in_map(2.0, 1.25)},
        {"class": "potted plant", "centroid": in_map(4.0, 4.0)},  # nothing there
    ]
    s = match_objects(found, [table, chair], T_gt_map)
    assert (s["objects_truth"], s["objects_found"]) == (2, 4)
    assert s["objects_count_error"] == pytest.approx(1.0)  # twice as many as there are
    assert s["objects_split"] == 1 and s["objects_spurious"] == 1 and s["objects_matched"] == 2
    assert s["objects_class_right"] == 1.0  # the table matched its nearest half, named right
    # a centroid 0.31 m from the footprint matches nothing; none found is a count error of -100 %
    far = match_objects([{"class": "chair", "centroid": in_map(2.0, 0.659)}], [chair], T_gt_map)
    assert far["objects_matched"] == 0 and far["objects_spurious"] == 1
    none = match_objects([], [table, chair])
    assert none["objects_count_error"] == -1.0 and np.isnan(none["objects_class_right"])


@pytest.fixture(scope="module")
def short_demo(tmp_path_factory):
    """The demo room for 8 s: the robot drives towards a person standing beside its route."""
    from semmap.sim.scenarios import demo
    from semmap.sim.tour import simulate

    world = replace(demo().world, duration_s=8.0)
    return simulate(world, tmp_path_factory.mktemp("score") / "demo", seed=0)


def _standing_person(tour):
    from semmap.sim.world import load_world

    world = load_world(tour / "ground_truth" / "world.yaml")
    return next(p for p in world.people if p.waypoints.shape[0] == 1)  # stands the whole tour


@pytest.fixture(scope="module")
def short_demo_truth(short_demo) -> GroundTruth:
    truth = load_truth(short_demo.out)
    if truth.standing is None:  # a simulator that does not write people_standing.yaml yet
        person = _standing_person(short_demo.out)
        truth = replace(truth, standing=rasterise(truth.spec, [person.footprint(0.0, 0.25)]) & ~truth.occupancy)
    return truth


def test_naive_true_pose_map_keeps_the_standing_person(short_demo, short_demo_truth):
    from semmap.grid.metrics import ghost_rate

    truth = short_demo_truth
    nm = naive_map(short_demo.out)
    assert nm.n_scans == short_demo.topics["/scan"] == 120  # every recorded scan
    assert not nm.semi_static.any() and nm.objects == ()
    s = score_masks(short_demo.out, nm.spec, nm.occupied, nm.semi_static, truth=truth)
    assert s["f1"] > 0.9 and s["precision"] > 0.9
    # the person's legs stay in the map (the faces the LiDAR saw: most of their cells); legs are
    # a fifth of the body disc (0.25 m) people_standing holds, so that is ten times the 2 % target
    person = _standing_person(short_demo.out)
    legs = rasterise(truth.spec, [b[0] for b in person.body(0.0) if b[1] <= 0.2 <= b[2]])
    assert ghost_rate(nm.occupied, nm.spec, legs, truth.spec) > 0.5
    assert s["standing_left"] > 0.15
    assert s["walls_flagged"] == 0 and s["objects_found"] == 0 and s["objects_count_error"] == -1.0
    assert s["semi_recall_all"] == 0.0 and np.isnan(s["semi_precision"])


def test_semmap_drops_the_person_the_naive_map_keeps(short_demo, short_demo_truth, tmp_path):
    from semmap.pipeline import build
    from semmap.sim.score import score_map

    truth = short_demo_truth
    res = build(short_demo.out, tmp_path / "map")
    s = score_map(short_demo.out, res.out, truth=truth)
    nm = naive_map(short_demo.out)
    naive = score_masks(None, nm.spec, nm.occupied, nm.semi_static, truth=truth)
    assert s["ate_rmse_m"] < 0.03
    assert s["standing_left"] < 0.02 < 0.15 < naive["standing_left"]
    assert s["ghost_rate"] < 0.01 < naive["ghost_rate"]
    assert s["f1"] > 0.95 and naive["f1"] > 0.98
    # furniture flagged and listed, the naive map has none
    assert s["semi_precision"] > 0.85 and naive["semi_recall_all"] == 0.0
    assert s["objects_matched"] >= 4 and naive["objects_matched"] == 0
