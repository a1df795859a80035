"""`semmap diff`'s alignment: B's map frame found in A's with no initial guess, on synthetic floor
plans at 5 cm whose true transform is known, despite the changes between the sessions; and maps
that cannot be aligned refused with one clear line."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from diff_plans import RES, Room

from semmap.compare.align import AlignInput, align_maps
from semmap.errors import AlignmentError
from semmap.geometry import se2_apply, se2_compose, se2_inverse, wrap_angle


def _plan() -> Room:
    """Three rooms off a hall, 16 m x 10 m, with doors; no two halves alike."""
    p = Room((16.0, 10.0))
    p.walls += [(6.0, 0.0, 6.0, 2.0), (6.0, 3.0, 6.0, 10.0),  # a door at y 2-3
                (11.0, 0.0, 11.0, 6.0), (11.0, 7.2, 11.0, 10.0),  # a door at y 6-7.2
                (11.0, 5.0, 13.0, 5.0), (14.0, 5.0, 16.0, 5.0),  # a door at x 13-14
                (0.0, 6.5, 2.5, 6.5)]  # a stub
    p.objects += [("bed", (3.0, 8.0), (2.0, 0.9), 0.0), ("chair", (8.5, 2.0), (0.5, 0.45), 0.4),
                  ("dining table", (13.5, 8.0), (1.6, 0.8), 0.0), ("couch", (13.5, 2.0), (2.0, 0.9), math.pi / 2)]
    return p


def _error(est, T_world_a, T_world_b, session_b):
    """RMS distance (m) between where the estimate and the truth put B's walls, and the yaw error (°)."""
    true = se2_compose(se2_inverse(T_world_a), T_world_b)
    rows, cols = np.nonzero(session_b.occupied)
    s = session_b.spec
    pts = np.stack([s.origin_x + (cols + 0.5) * RES, s.origin_y + (rows + 0.5) * RES], axis=1)
    gap = np.linalg.norm(se2_apply(est, pts) - se2_apply(true, pts), axis=1)
    return float(np.sqrt(np.mean(gap ** 2))), abs(math.degrees(float(wrap_angle(est[2] - true[2]))))


@pytest.mark.parametrize("T_world_b", [(9.0, 7.5, 2.6), (-3.0, 12.0, -1.9), (14.2, 0.7, math.pi)])
def test_b_started_anywhere_facing_anywhere_is_found_within_a_cell_and_half_a_degree(T_world_b):
    a_plan, b_plan = _plan(), _plan()
    # the changes between the sessions: the table moved and turned, a new partition, a person,
    # a room B never entered, a chair gone
    b_plan.objects = [o for o in b_plan.objects if o[0] != "chair"]
    b_plan.objects[1] = ("dining table", (12.8, 8.5), (1.6, 0.8), 0.6)
    b_plan.walls.append((2.0, 3.0, 4.5, 3.0))
    b_plan.people.append((8.0, 6.0))
    b_plan.unseen.append((11.0, 0.0, 16.0, 5.0))
    T_world_a = np.array([1.0, 0.5, 0.3])
    a, b = a_plan.session(T_world_a, "A"), b_plan.session(np.asarray(T_world_b), "B")
    al = align_maps(AlignInput.from_session(a), AlignInput.from_session(b))
    dist, yaw = _error(al.T_a_b, T_world_a, np.asarray(T_world_b), b)
    assert dist <= RES and yaw <= 0.5
    assert al.inlier_fraction > 0.8 and al.overlap > 0.8 and al.ambiguity < 0.75
    assert al.residual_m < RES


def test_maps_of_different_buildings_are_refused():
    a = _plan().session(np.zeros(3), "A")
    other = Room((30.0, 2.5))  # a long corridor
    other.walls += [(10.0, 0.0, 10.0, 1.0), (20.0, 1.5, 20.0, 2.5)]
    b = other.session(np.array([0.0, 0.0, 0.7]), "B")
    with pytest.raises(AlignmentError, match=r"overlap too little|do not match|ambiguous"):
        align_maps(AlignInput.from_session(a), AlignInput.from_session(b))


def test_a_bare_rectangular_room_is_ambiguous_not_silently_wrong():
    a = Room((8.0, 5.0)).session(np.zeros(3), "A")
    b = Room((8.0, 5.0)).session(np.array([3.0, 1.0, 0.4]), "B")
    with pytest.raises(AlignmentError, match=r"ambiguous: .* symmetric room"):
        align_maps(AlignInput.from_session(a), AlignInput.from_session(b))


def test_an_empty_map_is_refused_with_one_line():
    a = _plan().session(np.zeros(3), "A")
    b = _plan().session(np.zeros(3), "B")
    empty = AlignInput(b.spec, np.zeros(b.spec.shape, bool), b.free)
    with pytest.raises(AlignmentError, match=r"map B has 0 wall cells: too few to align on"):
        align_maps(AlignInput.from_session(a), empty)


def test_a_history_of_three_sessions_gathers_a_move_and_its_return_into_one_place():
    from semmap.compare.history import diff_history

    week1, week2, week3 = _plan(), _plan(), _plan()
    week2.objects[2] = ("dining table", (12.6, 8.4), (1.6, 0.8), 0.5)  # moved and turned
    week3.walls.append((2.0, 3.0, 4.5, 3.0))  # the table is back; a new partition
    poses = [np.array([1.0, 0.5, 0.3]), np.array([9.0, 7.5, 2.6]), np.array([-3.0, 12.0, -1.9])]
    sessions = [p.session(t, f"week{k + 1}") for k, (p, t) in enumerate(zip((week1, week2, week3), poses))]
    h = diff_history(sessions)
    assert [d.counts()["object_moved"] for d in h.steps] == [1, 1]
    assert [d.counts()["static_added"] for d in h.steps] == [0, 1]
    table = [p for p in h.places if any(e["type"] == "object_moved" for _, e in p.events)]
    assert len(table) == 1 and [k for k, _ in table[0].events] == [1, 2]  # week2 and week3
    # positions are in week1's frame: the table's home, where week1 saw it
    home = se2_apply(se2_inverse(poses[0]), np.array([[13.5, 8.0]]))[0]
    starts = [e["from"] for _, e in table[0].events]
    assert np.allclose(starts[0], home, atol=0.1)
    wall = [p for p in h.places if p.events[0][1]["type"] == "static_added"]
    assert len(wall) == 1 and wall[0].events[0][0] == 2
    assert h.as_dict()["places"][0]["changed_in"] == ["week2", "week3"]


def test_maps_of_two_tools_at_different_resolutions_align_and_show_the_new_wall(tmp_path):
    """A at 5 cm, B from another tool at 10 cm (occupied where any of its 5 cm cells was), turned 23°
    and shifted: the alignment holds within a cell of A and half a degree, and the one change found
    is B's new wall, where it stands in A's frame."""
    import cv2

    from semmap.compare import diff
    from semmap.io.mapserver import write_map
    from semmap.records import GridSpec

    res, n = 0.05, 300
    occ = np.zeros((n, n), np.uint8)
    for x in (10, 150, 290):
        cv2.line(occ, (x, 10), (x, 290), 1, 2)
    for y in (10, 160, 290):
        cv2.line(occ, (10, y), (290, y), 1, 2)
    occ[60:80, 150:153] = 0  # doors
    occ[160:163, 200:220] = 0
    for cx, cy in ((70, 80), (220, 230), (230, 60)):  # furniture legs
        occ[cy - 6:cy + 7:12, cx - 8:cx + 9:16] = 1
    known = np.zeros((n, n), bool)
    known[5:296, 5:296] = True
    occ_b = occ.copy()
    cv2.line(occ_b, (30, 230), (110, 230), 1, 2)  # B's new wall: x 1.5-5.5 m, y 11.5 m in A's frame
    yaw, shift = 23.0, (1.3, -0.7)
    m = cv2.getRotationMatrix2D((n / 2, n / 2), yaw, 1.0)
    m[:, 2] += (shift[0] / res, shift[1] / res)
    ob = cv2.warpAffine(occ_b, m, (n, n), flags=cv2.INTER_NEAREST) > 0
    kb = cv2.warpAffine(known.astype(np.uint8), m, (n, n), flags=cv2.INTER_NEAREST) > 0
    ob2 = ob.reshape(n // 2, 2, n // 2, 2).any(axis=(1, 3))
    kb2 = kb.reshape(n // 2, 2, n // 2, 2).any(axis=(1, 3))
    write_map(tmp_path / "a.yaml", GridSpec(res, 0.0, 0.0, n, n), occ > 0, known=known)
    b_origin = (3.0, -2.0)
    write_map(tmp_path / "b.yaml", GridSpec(0.1, b_origin[0], b_origin[1], n // 2, n // 2), ob2, known=kb2)
    r = diff(tmp_path / "a.yaml", tmp_path / "b.yaml")
    # the truth: A's cell centres carried by the warp into B's raster, then into B's map frame
    cells_a = np.random.default_rng(0).uniform(20, 280, size=(100, 2))
    cells_b = cells_a @ m[:, :2].T + m[:, 2]
    p_a = (cells_a + 0.5) * res
    p_b = (cells_b + 0.5) * res + np.asarray(b_origin)
    gap = np.linalg.norm(se2_apply(r.alignment.T_a_b, p_b) - p_a, axis=1)
    assert float(np.sqrt(np.mean(gap ** 2))) <= res
    assert abs(abs(math.degrees(float(r.alignment.T_a_b[2]))) - yaw) <= 0.5
    counts = r.counts()
    assert counts["static_added"] == 1 and counts["static_removed"] == 0, counts
    wall = next(c for c in r.changes if c.type == "static_added")
    assert abs(wall.centroid[0] - 3.5) < 0.25 and abs(wall.centroid[1] - 11.525) < 0.15


@pytest.mark.parametrize("yaw_deg", [37.0, -123.0])
def test_a_large_floor_of_look_alike_rooms_turned_off_the_search_lattice_is_found_within_a_cell(yaw_deg):
    """Headings are searched first on a field three times coarser than the coarse one (60 cm here),
    then only the best few again: a 75 m floor of 24 rooms that differ only in their doors and
    furniture must still come out within a cell and half a degree, and unambiguous."""
    rng = np.random.default_rng(3)
    plan = Room((75.0, 45.0))
    xs, ys = np.linspace(0.0, 75.0, 7), np.linspace(0.0, 45.0, 5)
    for x in xs[1:-1]:  # walls between the rooms, a door (0.9 m) in each room's stretch of wall
        for y0, y1 in itertools.pairwise(ys):
            d = float(rng.uniform(y0 + 1.0, y1 - 2.0))
            plan.walls += [(x, y0, x, d), (x, d + 0.9, x, y1)]
    for y in ys[1:-1]:
        for x0, x1 in itertools.pairwise(xs):
            d = float(rng.uniform(x0 + 1.0, x1 - 2.0))
            plan.walls += [(x0, y, d, y), (d + 0.9, y, x1, y)]
    for x0, x1 in itertools.pairwise(xs):
        for y0, y1 in itertools.pairwise(ys):
            c = (float(rng.uniform(x0 + 2.0, x1 - 2.0)), float(rng.uniform(y0 + 2.0, y1 - 2.0)))
            plan.objects.append(("dining table", c, (1.6, 0.8), float(rng.uniform(0.0, math.pi))))
    T_world_a, T_world_b = np.array([0.0, 0.0, 0.0]), np.array([20.0, -6.0, math.radians(yaw_deg)])
    a, b = plan.session(T_world_a, "A"), plan.session(T_world_b, "B")
    al = align_maps(AlignInput.from_session(a), AlignInput.from_session(b))
    dist, yaw = _error(al.T_a_b, T_world_a, T_world_b, b)
    assert dist <= RES and yaw <= 0.5
    assert al.ambiguity < 0.75
