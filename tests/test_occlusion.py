"""The occlusion filter on scenes built by hand: the camera at the origin looking along +x,
a label image whose column c shows bearing atan((c0 - c) / f), and LiDAR points in the plane.

A background point the camera cannot see must lose the mask's label; a point it can see
must keep it, under range noise, sparse sampling, partial objects and several objects.
"""

import math

import numpy as np
import pytest

from semmap.config import OcclusionConfig
from semmap.paint.occlusion import hidden_points

W, H, F = 640, 480, 320.0  # image size, focal length (px)
ROW = 300  # the pixel row every point lands on (one row is enough: the filter reads rows)
PERSON, CHAIR = 1, 2


def column(xy):
    """Pixel column of points seen from the origin looking along +x (y to the left)."""
    return W / 2 - F * xy[:, 1] / xy[:, 0]


def scene(points, label_of_column, beam_spacing_deg=0.25):
    """Inputs of hidden_points for points (K, 2); label_of_column(c) gives each pixel column's label."""
    xy = np.asarray(points, float)
    u = column(xy)
    img = np.zeros((H, W), np.uint16)
    cols = np.arange(W)
    img[:, :] = np.asarray([label_of_column(c) for c in cols], np.uint16)[None, :]
    uv = np.column_stack([np.clip(u, 0, W - 1), np.full(len(xy), ROW, float)])
    labels = img[ROW, np.rint(uv[:, 0]).astype(int)].astype(np.intp)
    footprint = np.hypot(xy[:, 0], xy[:, 1]) * math.radians(beam_spacing_deg)
    return xy, labels, uv, footprint, img


DEFAULT = OcclusionConfig()


def run(points, label_of_column, params=DEFAULT, **kw):
    xy, labels, uv, footprint, img = scene(points, label_of_column, **kw)
    targets = labels > 0
    return hidden_points(xy, np.zeros(2), labels, uv, targets, footprint, img, params), labels


def person_at(x, half_width=0.15, n=13, y0=0.0):
    return [(x, y0 + y) for y in np.linspace(-half_width, half_width, n)]


def wall_at(x, y_from, y_to, step=0.02):
    return [(x, y) for y in np.arange(y_from, y_to, step)]


def mask_between(u0, u1, label=PERSON):
    return lambda c: label if u0 <= c <= u1 else 0


def test_wall_points_behind_a_person_lose_the_person_label_and_the_person_keeps_it():
    person = person_at(2.0)
    wall = wall_at(5.0, -0.5, 0.5)
    u = column(np.array(person))
    hidden, labels = run(person + wall, mask_between(u.min(), u.max()))
    n_p = len(person)
    on_mask_wall = labels[n_p:] == PERSON
    assert on_mask_wall.sum() > 10  # the fault: wall points painted "person"
    assert hidden[n_p:][on_mask_wall].all()  # every one of them removed
    assert not hidden[:n_p].any()  # the person itself stays a person
    assert not hidden[n_p:][~on_mask_wall].any()  # off the mask nothing changes


def test_range_noise_does_not_make_a_surface_hide_itself():
    rng = np.random.default_rng(3)
    person = np.array(person_at(2.0, n=25))
    person[:, 0] += rng.normal(0, 0.03, len(person))  # 3 cm range noise
    wall = np.array(wall_at(4.0, -0.6, 0.6))
    wall[:, 0] += rng.normal(0, 0.03, len(wall))
    # a mask as wide as the wall: the wall is a "person" too (say a poster), seen, nothing hides it
    hidden, _ = run(np.vstack([wall]), lambda c: PERSON)
    assert not hidden.any()
    u = column(person)
    pts = by_bearing(np.vstack([person, wall]))
    is_person = pts[:, 0] < 3.0
    hidden, labels = run(pts, mask_between(u.min(), u.max()))
    assert not hidden[is_person].any()
    assert hidden[~is_person & (labels == PERSON)].all()


def test_sparse_scan_points_still_hide_what_lies_between_them():
    # a far person sampled every 1 degree, background 3 m behind it sampled densely
    person = [(4.0 * math.cos(a), 4.0 * math.sin(a)) for a in np.radians([-2, -1, 0, 1, 2])]
    wall = wall_at(7.0, -0.3, 0.3, step=0.01)
    u = column(np.array(person))
    hidden, labels = run(person + wall, mask_between(u.min() - 3, u.max() + 3), beam_spacing_deg=1.0)
    behind = labels[len(person):] == PERSON
    assert behind.sum() > 20
    assert hidden[len(person):][behind].mean() >= 0.95


def test_a_gap_between_legs_is_bridged_only_where_the_mask_joins_them():
    legs = person_at(2.0, half_width=0.03, n=4, y0=-0.15) + person_at(2.0, half_width=0.03, n=4, y0=0.15)
    wall = wall_at(4.5, -0.2, 0.2)
    u = column(np.array(legs))
    # the mask covers the whole body, legs and the gap between them
    hidden, labels = run(legs + wall, mask_between(u.min(), u.max()))
    behind = labels[len(legs):] == PERSON
    assert behind.sum() > 5 and hidden[len(legs):][behind].all()
    # the mask shows two separate legs: wall points between them are visible and not on the mask
    leg_cols = [(u[:4].min(), u[:4].max()), (u[4:].min(), u[4:].max())]
    hidden, labels = run(legs + wall, lambda c: PERSON if any(a <= c <= b for a, b in leg_cols) else 0)
    assert not hidden.any()


def test_a_wall_point_on_the_mask_between_objects_too_far_apart_is_left_alone():
    # two people 2.6 m apart (beyond max_gap): the wall between them stays as painted
    a, b = person_at(3.0, n=7, y0=-1.3), person_at(3.0, n=7, y0=1.3)
    wall = wall_at(6.0, -0.3, 0.3)
    hidden, _labels = run(a + b + wall, lambda c: PERSON, OcclusionConfig(line_step=0))
    assert not hidden[14:].any()


def test_an_occluder_of_another_class_does_not_decide_for_the_mask():
    chair_legs = person_at(2.0, half_width=0.02, n=3)
    wall = wall_at(5.0, -0.3, 0.3)
    u = column(np.array(chair_legs))
    # the legs are on a chair mask; the wall points happen to land on a person mask beside them
    label = lambda c: CHAIR if u.min() <= c <= u.max() else PERSON  # noqa: E731
    hidden, labels = run(chair_legs + wall, label)
    on_person = labels == PERSON
    assert on_person.sum() > 10 and not hidden[on_person].any()
    assert hidden[len(chair_legs):][labels[len(chair_legs):] == CHAIR].all()  # behind the legs, on their mask


def test_a_mask_spilling_past_the_object_edge_loses_the_background_it_spills_over():
    person = person_at(2.0)
    wall = wall_at(5.0, -0.5, 0.5, step=0.01)
    u = column(np.array(person))
    hidden, labels = run(person + wall, mask_between(u.min() - 6, u.max() + 6))  # 6 px of bleed each side
    on_mask = labels[len(person):] == PERSON
    assert hidden[len(person):][on_mask].all()
    assert not hidden[:len(person)].any()


def test_several_objects_overlapping_each_hide_only_their_background():
    near = person_at(1.5, half_width=0.12, n=9, y0=0.1)  # a person in front
    chair = person_at(2.6, half_width=0.2, n=11, y0=-0.25)  # a chair beside and behind, partly covered
    wall = wall_at(5.0, -0.8, 0.8)
    pts = near + chair + wall
    un, uc = column(np.array(near)), column(np.array(chair))

    def label(c):
        if un.min() <= c <= un.max():
            return PERSON  # the person is in front where they overlap
        return CHAIR if uc.min() <= c <= uc.max() else 0

    hidden, labels = run(pts, label)
    n1, n2 = len(near), len(near) + len(chair)
    assert not hidden[:n1].any()
    chair_pts = labels[n1:n2]
    # chair points behind the person land on the person mask: hidden; the rest keep "chair"
    assert hidden[n1:n2][chair_pts == PERSON].all() and not hidden[n1:n2][chair_pts == CHAIR].any()
    wall_lab = labels[n2:]
    assert hidden[n2:][wall_lab > 0].all() and (wall_lab == CHAIR).sum() > 3


@pytest.mark.parametrize("margin", [0.25, 0.6])
def test_the_depth_margin_decides_how_far_behind_counts_as_hidden(margin):
    person = person_at(2.0)
    behind = wall_at(2.45, -0.1, 0.1)  # 0.45 m behind the person
    u = column(np.array(person))
    params = OcclusionConfig(depth_margin=margin, depth_margin_rel=0.0)
    hidden, _ = run(person + behind, mask_between(u.min(), u.max()), params)
    assert hidden[len(person):].all() == (margin < 0.45)


def by_bearing(points):
    """Scan order: points sorted by bearing, as a LiDAR at the camera would sweep them."""
    pts = np.asarray(points, float)
    return pts[np.argsort(np.arctan2(pts[:, 1], pts[:, 0]))]


def test_a_wall_behind_a_bed_pushed_against_it_loses_the_bed_label():
    # the bed's legs stand 0.3 m in front of the wall (under the depth margin); its frame above LiDAR
    # height covers the wall in the image; the wall runs on beyond the bed's mask
    legs = person_at(2.7, half_width=0.03, n=3, y0=-0.4) + person_at(2.7, half_width=0.03, n=3, y0=0.4)
    wall = [q for q in wall_at(3.0, -1.2, 1.2) if abs(abs(q[1]) - 0.4 * 3.0 / 2.7) > 0.05]
    pts = by_bearing(legs + wall)
    u_bed = column(np.array([(2.7, -0.45), (2.7, 0.45)]))
    hidden, labels = run(pts, mask_between(u_bed.min(), u_bed.max()))
    is_wall = pts[:, 0] > 2.9
    assert (labels[is_wall] == PERSON).sum() > 30
    assert hidden[is_wall & (labels == PERSON)].all()
    assert not hidden[~is_wall].any()  # the legs keep their label


def test_a_chair_rear_leg_seen_between_the_front_legs_keeps_its_label():
    front = person_at(2.0, half_width=0.015, n=3, y0=-0.2) + person_at(2.0, half_width=0.015, n=3, y0=0.2)
    rear = person_at(2.45, half_width=0.015, n=3, y0=0.0)
    wall = [q for q in wall_at(5.0, -1.0, 1.0) if min(abs(q[1] - y * 2.5) for y in (-0.1, 0.0, 0.1)) > 0.1]
    pts = by_bearing(front + rear + wall)
    u = column(np.array([(2.0, -0.25), (2.0, 0.25)]))
    hidden, labels = run(pts, mask_between(u.min(), u.max(), CHAIR))  # a blobby chair mask over the gap
    is_rear = (pts[:, 0] > 2.4) & (pts[:, 0] < 2.5)
    assert (labels[is_rear] == CHAIR).all() and not hidden[is_rear].any()
    assert hidden[(pts[:, 0] > 4.9) & (labels == CHAIR)].all()  # the wall behind the chair does lose it


def test_mask_regions_filled_on_demand_join_exactly_the_pixels_connected_components_join():
    """The filter's "one connected region of the mask" test, asked scan after scan of one image,
    including past the 255 regions its flood fill numbers before it labels the whole mask at once."""
    import cv2

    from semmap.paint.occlusion import _Components

    rng = np.random.default_rng(7)
    img = (rng.random((90, 120)) < 0.33).astype(np.uint16) * PERSON  # hundreds of small 8-connected pieces
    n, ref = cv2.connectedComponents(img.astype(np.uint8), connectivity=8)
    assert n - 1 > 300
    rows, cols = np.nonzero(np.ones_like(img))
    uv = np.column_stack([cols, rows])
    labels = img[rows, cols].astype(np.intp)
    seen = 0
    for _ in range(12):  # one scan each, the same image (its regions are kept between scans)
        comp = _Components(img, uv, labels)
        a = rng.choice(np.flatnonzero(labels > 0), 200)
        near = np.clip(a + rng.integers(-3, 4, a.size) * img.shape[1] + rng.integers(-3, 4, a.size), 0, img.size - 1)
        b = np.where(rng.random(a.size) < 0.5, near, rng.integers(0, img.size, a.size))
        want = ref.reshape(-1)[a] == ref.reshape(-1)[b]
        np.testing.assert_array_equal(comp.joined(a, b), want)
        seen += int(want.sum())
    assert 0 < seen < 12 * 200  # both outcomes were asked about


BED = 3


def test_a_cabinet_seen_under_a_bed_from_across_the_room_loses_the_bed_label():
    """A bed on legs 3 m away, one leg in the LiDAR's sight; under its frame the LiDAR sees a cabinet
    10 m away, standing 0.5 m in front of the wall beside it, all of it on the bed's mask. No other
    rule reaches it (the cabinet is nearer than the wall on either side, so to the LiDAR it is an
    object of its own); a bed spans no more than 1.5 x 2.3 m, so the cabinet cannot be the bed."""
    leg = person_at(3.0, half_width=0.03, n=3, y0=0.3)
    cabinet = wall_at(10.0, -1.6, -0.4)
    wall = wall_at(10.5, -3.0, -1.75) + wall_at(10.5, -0.25, 1.0)
    pts = by_bearing(leg + cabinet + wall)
    u_bed = column(np.array([(3.0, -0.6), (3.0, 0.35)]))
    xy, labels, uv, footprint, img = scene(pts, mask_between(u_bed.min(), u_bed.max(), BED))
    is_cab = (pts[:, 0] > 9.9) & (pts[:, 0] < 10.1)
    on_bed = is_cab & (labels == BED)
    assert on_bed.sum() > 10 and (on_bed == is_cab).all()
    extent = np.array([np.inf, np.inf, 0.75, 1.5 * 2.3])  # per label value: none, person, chair, bed
    hidden = hidden_points(xy, np.zeros(2), labels, uv, labels > 0, footprint, img, OcclusionConfig(), extent)
    assert hidden[on_bed].all()
    assert not hidden[pts[:, 0] < 3.1].any()  # the bed's leg keeps its label
    # without the object's extent nothing hides the cabinet
    before = hidden_points(xy, np.zeros(2), labels, uv, labels > 0, footprint, img, OcclusionConfig())
    assert not before[on_bed].any()


def test_a_far_chair_seen_between_the_legs_of_a_near_one_keeps_its_label():
    """Two chairs 2 m apart on one chair mask: the far chair's legs, farther from the near chair than
    a chair spans, are legs seen through the gap (a run no wider than a leg), not background."""
    near = person_at(2.0, half_width=0.015, n=3, y0=-0.2) + person_at(2.0, half_width=0.015, n=3, y0=0.2)
    far = person_at(4.0, half_width=0.015, n=3, y0=0.05)
    wall = [q for q in wall_at(6.0, -1.0, 1.0) if min(abs(q[1] - y * 1.5) for y in (-0.1, 0.0, 0.1, 0.2)) > 0.1]
    pts = by_bearing(near + far + wall)
    u = column(np.array([(2.0, -0.25), (2.0, 0.25)]))
    xy, labels, uv, footprint, img = scene(pts, mask_between(u.min(), u.max(), CHAIR))
    extent = np.array([np.inf, np.inf, 0.75, 1.5 * 2.3])
    hidden = hidden_points(xy, np.zeros(2), labels, uv, labels > 0, footprint, img, OcclusionConfig(), extent)
    is_far = (pts[:, 0] > 3.9) & (pts[:, 0] < 4.1)
    assert (labels[is_far] == CHAIR).all() and not hidden[is_far].any()


def test_what_a_corner_lidar_sees_past_a_walls_end_is_unknown_and_walls_at_a_grazing_angle_stay():
    """Off every mask (label 0, painted static): the LiDAR at the robot's left corner (0.23 m beside the
    camera) sees past the end of a wall on the right a person the camera cannot see (its rays to them hit
    that wall), who would be painted as the wall; they are hidden. The wall itself, a long wall seen at a
    grazing angle (its nearer points on nearly the same rays as its farther ones, all on one line) and a
    wall in the open are not."""
    side = np.array([(x, -0.5) for x in np.arange(1.0, 3.0, 0.02)])  # a wall on the right, ending at x = 3
    person = np.array([(6.0 + 0.06 * math.cos(a), -1.15 + 0.06 * math.sin(a)) for a in np.linspace(2.2, 4.1, 6)])
    grazing = np.array([(x, 0.6) for x in np.arange(2.0, 20.0, 0.05)])  # down the corridor on the left
    open_wall = np.array(wall_at(8.0, -0.3, 0.1))  # ahead, nothing in front of it
    kind = np.concatenate([np.full(len(a), k) for k, a in enumerate((side, person, grazing, open_wall))])
    pts = np.vstack([side, person, grazing, open_wall])
    lidar = np.array([0.0, 0.23])
    order = np.argsort(np.arctan2(pts[:, 1] - lidar[1], pts[:, 0] - lidar[0]))  # the LiDAR's scan order
    pts, kind = pts[order], kind[order]
    # (the camera's ray to the person crosses the wall's line at x = 2.6, on the wall; the LiDAR's at 3.2)
    xy, labels, uv, footprint, img = scene(pts, lambda c: 0)
    everything = np.ones(len(pts), bool)
    hidden = hidden_points(xy, np.zeros(2), labels, uv, everything, footprint, img, DEFAULT)
    assert (kind == 2).sum() > 300
    assert hidden[kind == 1].all()
    assert not hidden[kind != 1].any()
    # the rule is the filter's: off, the person keeps its (wrong) static label
    assert not hidden_points(xy, np.zeros(2), labels, uv, everything, footprint, img,
                             OcclusionConfig(background=False)).any()
