"""Properties that hold for every input, checked with hypothesis on random poses, cameras and scans.

* SE(2)/SE(3): composing a pose with its inverse is the identity, composition is associative,
  SE(2) poses survive the trip through 4x4 matrices, angles are wrapped into (-pi, pi].
* Projection: a point in front of the camera that lands in the image unprojects, at its true
  depth, back onto itself (pinhole with or without distortion, fisheye); points behind the camera
  are never in the image; the painter labels exactly the points that land in the image.
* Fusion: the cell a return ends in is never cleared by its own scan, cells well inside the
  scan's free space are cleared, and log-odds stay inside [l_min, l_max] after any number of
  scans, reaching the clamps instead of wrapping around the uint16 storage.

Examples are derandomised, so CI sees the same cases every run.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from semmap.classes import load_class_table
from semmap.config import GridConfig, OcclusionConfig, PaintConfig, SyncConfig
from semmap.geometry import (
    is_rotation,
    matrix_to_se2,
    project_points,
    se2_apply,
    se2_compose,
    se2_inverse,
    se2_to_matrix,
    se2_to_se3,
    se3_apply,
    se3_from_translation_quaternion,
    se3_from_xyz_rpy,
    se3_inverse,
    se3_to_se2,
    se3_to_translation_quaternion,
    unproject_pixels,
    wrap_angle,
)
from semmap.grid import SemanticGrid
from semmap.grid.fusion import LOG_ODDS_STEP
from semmap.paint.painter import Painter
from semmap.records import Calibration, CameraIntrinsics, Mobility, PaintedScan, Scan, Segmentation


def fast(n: int = 60):
    return settings(deadline=None, derandomize=True, max_examples=n, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def angle_diff(a, b):
    return np.abs(wrap_angle(np.asarray(a) - np.asarray(b)))


coord = st.floats(-1e3, 1e3)
yaw = st.floats(-50.0, 50.0)
pose2 = st.tuples(coord, coord, yaw).map(np.array)


# ---------------------------------------------------------------------------------------
# SE(2), SE(3), angles


def near_multiple_of_pi():
    """k pi nudged by a few ulps: where a modulo rounds up to 2 pi."""
    def nudge(args):
        k, ulps = args
        a = k * math.pi
        for _ in range(abs(ulps)):
            a = math.nextafter(a, math.inf if ulps > 0 else -math.inf)
        return a
    return st.tuples(st.integers(-1000, 1000), st.integers(-4, 4)).map(nudge)


@fast(300)
@given(st.one_of(st.floats(-1e6, 1e6), near_multiple_of_pi()))
def test_wrapped_angles_lie_in_half_open_interval_and_keep_their_direction(a):
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-9) and math.sin(w) == pytest.approx(math.sin(a), abs=1e-9)
    assert wrap_angle(np.array([a]))[0] == w  # the array path agrees with the scalar one


@fast()
@given(pose2)
def test_a_pose_composed_with_its_inverse_is_the_identity(a):
    for ident in (se2_compose(a, se2_inverse(a)), se2_compose(se2_inverse(a), a)):
        assert np.abs(ident[:2]).max() < 1e-9 and angle_diff(ident[2], 0.0) < 1e-12
        assert -math.pi < ident[2] <= math.pi
    # and as matrices
    assert np.allclose(se2_to_matrix(a) @ se2_to_matrix(se2_inverse(a)), np.eye(3), atol=1e-9)


@fast()
@given(pose2, pose2, pose2)
def test_composition_is_associative(a, b, c):
    left = se2_compose(se2_compose(a, b), c)
    right = se2_compose(a, se2_compose(b, c))
    assert np.allclose(left[:2], right[:2], atol=1e-8) and angle_diff(left[2], right[2]) < 1e-9
    # the batched path (arrays of poses) gives the same as one pose at a time
    batch = se2_compose(np.stack([a, b]), np.stack([b, c]))
    assert np.allclose(batch[0], se2_compose(a, b), atol=1e-9) and np.allclose(batch[1], se2_compose(b, c), atol=1e-9)
    assert np.allclose(se2_inverse(np.stack([a, b])), np.stack([se2_inverse(a), se2_inverse(b)]), atol=1e-9)


@fast()
@given(pose2, pose2, st.floats(-5, 5))
def test_se2_poses_survive_the_trip_through_4x4_matrices(a, b, z):
    t = se2_to_se3(a, z)
    assert is_rotation(t[:3, :3]) and t[2, 3] == z
    back = se3_to_se2(t)
    assert np.allclose(back[:2], a[:2]) and angle_diff(back[2], a[2]) < 1e-12
    assert -math.pi < back[2] <= math.pi
    # composing poses is multiplying their matrices
    ab = se2_compose(a, b)
    m = se2_to_se3(a) @ se2_to_se3(b)
    assert np.allclose(se3_to_se2(m)[:2], ab[:2], atol=1e-8) and angle_diff(se3_to_se2(m)[2], ab[2]) < 1e-9
    assert np.allclose(matrix_to_se2(se2_to_matrix(a))[:2], a[:2]) and angle_diff(matrix_to_se2(se2_to_matrix(a))[2],
                                                                                 a[2]) < 1e-12
    pts = np.array([[1.0, 2.0], [-3.0, 0.5]])
    assert np.allclose(se2_apply(a, pts), se3_apply(t, np.column_stack([pts, np.zeros(2)]))[:, :2])


xyz = st.tuples(*[st.floats(-100, 100)] * 3)
rpy = st.tuples(st.floats(-math.pi, math.pi), st.floats(-1.5, 1.5), st.floats(-math.pi, math.pi))


@fast()
@given(xyz, rpy, xyz, rpy)
def test_se3_inverse_and_quaternions_round_trip(t1, r1, t2, r2):
    a, b = se3_from_xyz_rpy(t1, r1), se3_from_xyz_rpy(t2, r2)
    assert is_rotation(a[:3, :3])
    assert np.allclose(a @ se3_inverse(a), np.eye(4), atol=1e-9)
    assert np.allclose(se3_inverse(a @ b), se3_inverse(b) @ se3_inverse(a), atol=1e-9)
    p = np.array([[0.3, -2.0, 7.0]])
    assert np.allclose(se3_apply(se3_inverse(a), se3_apply(a, p)), p, atol=1e-9)
    trans, quat = se3_to_translation_quaternion(a)
    assert np.allclose(se3_from_translation_quaternion(trans, quat), a, atol=1e-9)


# ---------------------------------------------------------------------------------------
# projection and unprojection


def distorted_radius_limit(d, model: str) -> float:
    """The largest distorted normalised radius (pixels from the principal point / f) a camera model
    reaches before its polynomial turns back (or, fisheye, at 85 deg): a calibrated camera's image
    lies inside it."""
    if model == "fisheye":
        theta = np.radians(np.linspace(0.0, 85.0, 2000))
        pts = np.column_stack([np.tan(theta), np.zeros_like(theta), np.ones_like(theta)])
        img, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.eye(3), d)
    else:
        r = np.tan(np.radians(np.linspace(0.0, 85.0, 2000)))
        pts = np.column_stack([r, np.zeros_like(r), np.ones_like(r)])
        img, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.eye(3), d)
    rd = img.reshape(-1, 2)[:, 0]
    turn = np.flatnonzero(np.diff(rd) <= 0)
    return float(rd[: turn[0] + 1].max() if turn.size else rd.max())


@st.composite
def pinhole(draw, distortion: bool = True):
    w = draw(st.integers(160, 1920))
    h = draw(st.integers(120, 1200))
    # what OpenCV calibrations of webcams and robot cameras report
    d = np.zeros(5)
    if distortion:
        k1 = draw(st.floats(-0.4, 0.3))
        k2 = draw(st.floats(-0.2, 0.2))
        p1, p2 = draw(st.floats(-0.003, 0.003)), draw(st.floats(-0.003, 0.003))
        k3 = draw(st.floats(-0.1, 0.1))
        rational = draw(st.booleans())
        d = np.array([k1, k2, p1, p2, k3] + ([draw(st.floats(-0.1, 0.1)) for _ in range(3)] if rational else []))
    # the image lies where the lens model is one-to-one, as it does for a calibrated camera
    f_min = 0.5 * math.hypot(w, h) / (0.9 * distorted_radius_limit(d, "pinhole"))
    f = max(draw(st.floats(0.4, 1.5)) * w, f_min)
    aspect = draw(st.floats(0.98, 1.02))
    cx = w / 2 + draw(st.floats(-0.05, 0.05)) * w
    cy = h / 2 + draw(st.floats(-0.05, 0.05)) * h
    K = np.array([[f, 0.0, cx], [0.0, f * aspect, cy], [0.0, 0.0, 1.0]])
    return CameraIntrinsics(w, h, K, d)


@st.composite
def fisheye(draw):
    w = draw(st.integers(320, 1920))
    h = draw(st.integers(240, 1200))
    d = np.array([draw(st.floats(-0.1, 0.1)), draw(st.floats(-0.05, 0.05)), draw(st.floats(-0.01, 0.01)),
                  draw(st.floats(-0.005, 0.005))])
    f_min = 0.5 * math.hypot(w, h) / (0.9 * distorted_radius_limit(d, "fisheye"))
    f = max(draw(st.floats(0.2, 0.5)) * w, f_min)
    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    return CameraIntrinsics(w, h, K, d, "fisheye")


def points_in_front(seed: int, n: int, spread: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.05, 60.0, n)
    return np.column_stack([rng.uniform(-spread, spread, n) * z, rng.uniform(-spread, spread, n) * z, z])


@fast(200)
@given(st.one_of(pinhole(distortion=False), pinhole(), fisheye()), st.integers(0, 2**32 - 1))
def test_a_projected_point_unprojects_at_its_depth_to_itself(cam, seed):
    spread = 4.0 if cam.model == "fisheye" else 1.6  # well past the field of view: those must stay out
    pts = points_in_front(seed, 400, spread)
    uv, inside = project_points(cam.K, cam.D, pts, cam.width, cam.height, cam.model)
    assert np.isfinite(uv[inside]).all()
    back = unproject_pixels(cam.K, cam.D, uv[inside], pts[inside, 2], cam.model)
    err = np.linalg.norm(back - pts[inside], axis=1) / pts[inside, 2]  # metres per metre of depth
    assert err.size == 0 or err.max() < 1e-6, f"worst point {pts[inside][np.argmax(err)]}: error {err.max():.2e}"
    # every pixel of the image is some point's projection: unproject it and project it again
    rng = np.random.default_rng(seed + 1)
    px = np.column_stack([rng.uniform(0, cam.width - 1, 50), rng.uniform(0, cam.height - 1, 50)])
    z = rng.uniform(0.5, 30.0, 50)
    ray = unproject_pixels(cam.K, cam.D, px, z, cam.model)
    uv2, inside2 = project_points(cam.K, cam.D, ray, cam.width, cam.height, cam.model)
    assert inside2.all() and np.abs(uv2 - px).max() < 1e-6


@fast(60)
@given(st.one_of(pinhole(distortion=False), pinhole(), fisheye()), st.integers(0, 2**32 - 1),
       st.floats(1e-3, 0.5))
def test_points_behind_the_camera_never_land_in_the_image(cam, seed, min_depth):
    rng = np.random.default_rng(seed)
    n = 300
    z = -rng.exponential(5.0, n)
    z[:10] = 0.0
    z[10:20] = rng.uniform(0, min_depth, 10)  # in front but nearer than min_depth
    pts = np.column_stack([rng.normal(0, 5, n), rng.normal(0, 5, n), z])
    uv, inside = project_points(cam.K, cam.D, pts, cam.width, cam.height, cam.model, min_depth=min_depth)
    assert not inside.any()
    assert np.isnan(uv).all()


# ---------------------------------------------------------------------------------------
# the painter: which beams take a label


@st.composite
def camera_on_lidar(draw):
    """A camera somewhere near the LiDAR, looking roughly along one of its beams."""
    cam = draw(st.one_of(pinhole(distortion=False), pinhole(), fisheye()))
    look = draw(st.floats(-math.pi, math.pi))
    tilt = draw(st.floats(-0.3, 0.3))
    roll = draw(st.floats(-0.2, 0.2))
    # optical frame (z forward, x right, y down) looking along the LiDAR's heading `look`
    t_lidar_cam = se3_from_xyz_rpy(draw(xyz.map(lambda v: np.asarray(v) / 200.0)),
                                   (-math.pi / 2 + tilt, roll, -math.pi / 2 + look))
    return Calibration(cam, se3_inverse(t_lidar_cam))


@fast(100)
@given(camera_on_lidar(), st.integers(0, 2**32 - 1))
def test_the_painter_labels_exactly_the_returns_that_land_in_the_image(calib, seed):
    cam = calib.intrinsics
    rng = np.random.default_rng(seed)
    n = 721
    angles = np.linspace(-math.pi, math.pi, n, endpoint=False)
    ranges = rng.uniform(0.2, 15.0, n).astype(np.float32)
    ranges[rng.random(n) < 0.05] = np.nan
    scan = Scan(0, "laser", float(angles[0]), float(angles[1] - angles[0]), ranges, 0.1, 20.0)
    # label k+1 on the pixel column band k, 8 px wide
    bands = (cam.width + 7) // 8
    label = np.tile((np.arange(cam.width) // 8 + 1).astype(np.uint16), (cam.height, 1))
    names = tuple(["chair"] * bands)
    painter = Painter(np.eye(4), calib, names, load_class_table(),
                      PaintConfig(occlusion=OcclusionConfig(filter=False)), SyncConfig(), 10.0)
    painted = painter.paint(scan, None, Segmentation(0, label, names)).painted

    hit = np.isfinite(ranges) & (ranges >= 0.1)
    pts = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles), np.zeros(n)])
    p_cam = se3_apply(calib.T_cam_lidar, pts)
    uv, inside = project_points(cam.K, cam.D, p_cam, cam.width, cam.height, cam.model,
                                min_depth=PaintConfig().min_depth)
    expect = hit & inside
    labelled = painted.mobility != Mobility.UNKNOWN
    # a pixel on the image's very edge may round either way between OpenCV and the fast path
    edge = np.isfinite(uv).all(axis=1) & (
        (np.abs(uv[:, 0] + 0.5) < 1e-6) | (np.abs(uv[:, 0] - cam.width + 0.5) < 1e-6)
        | (np.abs(uv[:, 1] + 0.5) < 1e-6) | (np.abs(uv[:, 1] - cam.height + 0.5) < 1e-6))
    assert not (labelled & (p_cam[:, 2] <= PaintConfig().min_depth)).any(), "a point behind the camera was painted"
    diff = (labelled != expect) & ~edge
    assert not diff.any(), f"beams {np.flatnonzero(diff)[:5]} at pixels {uv[diff][:5]}"
    # and the label is the one under the point's pixel
    col = np.rint(uv[labelled & expect, 0]).astype(int)
    on_band_edge = np.abs((uv[labelled & expect, 0] % 8) - 7.5) < 1e-6
    got = painted.class_id[labelled & expect]
    assert np.array_equal(got[~on_band_edge], (np.clip(col, 0, cam.width - 1) // 8)[~on_band_edge])


# ---------------------------------------------------------------------------------------
# fusion


@st.composite
def painted_scans(draw, max_beams: int = 400, all_hits: bool = False):
    n = draw(st.integers(0 if not all_hits else 3, max_beams))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    fov = draw(st.floats(0.1, 2 * math.pi))
    angles = np.linspace(-fov / 2, fov / 2, n) if draw(st.booleans()) else rng.uniform(-math.pi, math.pi, n)
    ranges = rng.uniform(0.01, draw(st.floats(0.05, 8.0)), n)
    origin = rng.uniform(-0.5, 0.5, 2)
    pts = origin + ranges[:, None] * np.column_stack([np.cos(angles), np.sin(angles)])
    hit = np.ones(n, bool) if all_hits else rng.random(n) < draw(st.floats(0.0, 1.0))
    if not all_hits and n:
        pts[rng.random(n) < 0.02] = np.nan  # invalid end points: ignored
    return PaintedScan(0, origin, pts, hit, rng.integers(0, 4, n), rng.integers(-1, 3, n), ("a", "b", "c"))


@st.composite
def grid_configs(draw):
    return GridConfig(resolution=draw(st.floats(0.02, 0.5)), tile_margin=draw(st.floats(0.1, 2.0)),
                      hit_free_margin=draw(st.floats(0.0, 0.2)), free_erode=draw(st.booleans()),
                      dropout_guard=draw(st.integers(0, 3)), max_range=draw(st.floats(0.5, 10.0)))


small_pose = st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-10, 10)).map(np.array)


def cell_is_unambiguous(spec, xy, tol=1e-7):
    """The point is not within ``tol`` cells of a cell edge (where rounding decides the cell)."""
    f = np.array([(xy[:, 0] - spec.origin_x) / spec.resolution, (xy[:, 1] - spec.origin_y) / spec.resolution])
    frac = f - np.floor(f)
    return ((frac > tol) & (frac < 1 - tol)).all(axis=0)


@fast(200)
@given(grid_configs(), painted_scans(), small_pose)
def test_a_return_never_clears_the_cell_it_ends_in(cfg, scan, pose):
    g = SemanticGrid(cfg, scan.class_names)
    g.integrate(pose, scan)
    assert g.n_scans == 1
    ok = scan.hit & np.isfinite(scan.points).all(axis=1)
    with np.errstate(invalid="ignore"):  # returns beyond max_range are no hits
        ok &= np.hypot(*(scan.points - scan.origin).T) <= cfg.max_range
    if g.spec is None:  # a scan without beams allocates nothing
        assert scan.n_beams == 0
        return
    lay = g.layers()
    ends = se2_apply(pose, scan.points[ok])
    ends = ends[cell_is_unambiguous(lay.spec, ends)]
    r, c = lay.spec.world_to_cell(ends).T
    assert ((r >= 0) & (r < lay.spec.height) & (c >= 0) & (c < lay.spec.width)).all()
    assert (lay.free[r, c] == 0).all(), "a return's end cell was cleared by its own scan"
    assert (lay.hits[r, c] == 1).all()
    assert np.allclose(lay.log_odds[r, c], round(cfg.l_occ / LOG_ODDS_STEP) * LOG_ODDS_STEP, atol=1e-6)
    # cells no return ended in gained no hit; no count exceeds one per scan
    assert lay.hits.sum() <= ok.sum() and lay.hits.max() <= 1 and lay.free.max() <= 1
    assert lay.log_odds.min() >= cfg.l_min - 1e-6 and lay.log_odds.max() <= cfg.l_max + 1e-6


@fast(100)
@given(grid_configs(), st.integers(0, 2**32 - 1), small_pose)
def test_cells_between_the_sensor_and_its_returns_are_cleared(cfg, seed, pose):
    """A 270 deg scan of a room (a circle around a point near the sensor): every cell well inside
    the scan's free-space polygon is cleared, whatever the resolution."""
    rng = np.random.default_rng(seed)
    n = 541
    angles = np.linspace(-0.75 * math.pi, 0.75 * math.pi, n)
    radius = rng.uniform(1.0, 8.0)
    centre = rng.uniform(-0.4, 0.4, 2) * radius
    d = np.column_stack([np.cos(angles), np.sin(angles)])
    # distance along each beam to the circle |p - centre| = radius
    b = d @ (-centre)
    ranges = -b + np.sqrt(b * b - (centre @ centre - radius * radius))
    scan = PaintedScan(0, np.zeros(2), ranges[:, None] * d, np.ones(n, bool), np.ones(n), np.full(n, -1))
    g = SemanticGrid(cfg)
    g.integrate(pose, scan)
    lay = g.layers()
    res = cfg.resolution
    # the free-space polygon: the sensor and each beam cleared up to hit_free_margin short of its return;
    # a return beyond max_range is no return: it clears to max_range
    free_len = np.where(ranges > cfg.max_range, cfg.max_range,
                        np.minimum(np.maximum(ranges - cfg.hit_free_margin, 0.0), cfg.max_range))
    poly = se2_apply(pose, np.vstack([[0.0, 0.0], free_len[:, None] * d]))
    # sample points along random beams
    k = rng.integers(0, n, 200)
    t = rng.uniform(0.0, 1.0, 200) * free_len[k]
    p = se2_apply(pose, t[:, None] * d[k])
    r, c = lay.spec.world_to_cell(p).T
    centres = np.column_stack([lay.spec.origin_x + (c + 0.5) * res, lay.spec.origin_y + (r + 0.5) * res])
    contour = poly.astype(np.float32).reshape(-1, 1, 2)
    depth = np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in centres])
    ends = lay.spec.world_to_cell(se2_apply(pose, scan.points))
    end_cells = set(map(tuple, ends.tolist()))
    deep = (depth > 2.5 * res) & np.array([(a, b_) not in end_cells for a, b_ in zip(r, c)])
    event(f"cells checked: {'none' if not deep.any() else 'some' if deep.sum() < 100 else '100+'}")
    assert (lay.free[r[deep], c[deep]] == 1).all(), "a cell well inside the scan's free space was not cleared"
    assert np.allclose(lay.log_odds[r[deep], c[deep]],
                       -min(round(cfg.l_free / LOG_ODDS_STEP) * LOG_ODDS_STEP, -cfg.l_min), atol=1.5e-3)


@st.composite
def clamps(draw):
    l_min = -draw(st.floats(1e-3, 30.0))
    l_max = draw(st.floats(1e-3, min(30.0, 65.535 + l_min)))
    # steps up to (and past) the whole range: they must saturate, not wrap around uint16
    l_occ = draw(st.one_of(st.floats(1e-3, 5.0), st.floats(5.0, 200.0)))
    l_free = draw(st.one_of(st.floats(1e-3, 5.0), st.floats(5.0, 200.0), st.just(65.536)))
    return GridConfig(l_min=l_min, l_max=l_max, l_occ=l_occ, l_free=l_free, tile_margin=0.5, resolution=0.1)


@fast(100)
@given(clamps(), st.integers(1, 60), st.integers(0, 2**32 - 1))
def test_log_odds_stay_within_the_clamps_and_saturate(cfg, n_scans, seed):
    rng = np.random.default_rng(seed)
    n = 181
    angles = np.linspace(-math.pi / 2, math.pi / 2, n)
    ranges = np.full(n, 3.0)
    d = np.column_stack([np.cos(angles), np.sin(angles)])
    scan = PaintedScan(0, np.zeros(2), ranges[:, None] * d, np.ones(n, bool), np.ones(n), np.full(n, -1))
    pose = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-math.pi, math.pi)])
    g = SemanticGrid(cfg)
    for _ in range(n_scans):
        g.integrate(pose, scan)
    lay = g.layers()
    lo = lay.log_odds.astype(np.float64)
    assert lo.min() >= cfg.l_min - 1e-6 and lo.max() <= cfg.l_max + 1e-6
    # the end cells gain l_occ each scan until the clamp (rounded to the storage step)
    r, c = lay.spec.world_to_cell(se2_apply(pose, scan.points)).T
    expect_hi = min(n_scans * max(round(cfg.l_occ / LOG_ODDS_STEP), 1) * LOG_ODDS_STEP, cfg.l_max)
    assert np.allclose(lo[r, c], expect_hi, atol=LOG_ODDS_STEP + 1e-6)
    # the sensor's surroundings lose l_free each scan until the clamp
    near = lay.spec.world_to_cell(se2_apply(pose, np.array([[1.0, 0.0], [1.5, 0.5], [1.5, -0.5]]))).T
    expect_lo = max(-n_scans * max(round(cfg.l_free / LOG_ODDS_STEP), 1) * LOG_ODDS_STEP, cfg.l_min)
    assert np.allclose(lo[near[0], near[1]], expect_lo, atol=LOG_ODDS_STEP + 1e-6)
    assert (lay.hits[r, c] == n_scans).all() and (lay.free[near[0], near[1]] == n_scans).all()
