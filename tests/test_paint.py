"""Point painting: projection, label lookup, mobility, deskew and motion compensation."""

import math

import numpy as np
import pytest

from semmap.classes import load_class_table
from semmap.config import PaintConfig, SimCameraConfig, SimLidarConfig, SyncConfig
from semmap.geometry import se3_from_xyz_rpy, se3_inverse
from semmap.paint.motion import OdomTrack
from semmap.paint.painter import Painter
from semmap.records import REGION_BASE, Calibration, CameraIntrinsics, Mobility, Scan, Segmentation
from semmap.sim.raycast import PartSet
from semmap.sim.sensors import CameraSim, LidarSim
from semmap.sim.world import Person, chair, wall

COCO = load_class_table().names("coco")


def _world():
    objs = [wall(1, 6.0, -6.0, 6.0, 6.0), wall(2, -6.0, 6.0, 6.0, 6.0), wall(3, -6.0, -6.0, 6.0, -6.0),
            chair(4, (3.5, -1.0, 0.0))]
    person = Person(5, "p", np.array([[3.0, 0.6]]))
    parts = [p for o in objs for p in o.parts] + list(person.parts_at(0.0))
    owners = [i for i, o in enumerate(objs) for _ in o.parts] + [len(objs)] * 4
    labels = np.array([0, 0, 0, COCO.index("chair") + 1, COCO.index("person") + 1], np.uint16)
    return PartSet.build(parts, owners), labels


def _rig(sweep=False):
    lcfg = SimLidarConfig(sweep=sweep, noise_std=0.0, dropout_prob=0.0, rate_hz=10.0)
    ccfg = SimCameraConfig(noise_std=0.0)
    t_base_lidar = se3_from_xyz_rpy(lcfg.mount.xyz, lcfg.mount.rpy)
    t_base_cam = se3_from_xyz_rpy(ccfg.mount.xyz, ccfg.mount.rpy)
    intr = CameraIntrinsics(640, 480, np.asarray(ccfg.K), np.zeros(5))
    calib = Calibration(intr, se3_inverse(t_base_cam) @ t_base_lidar)
    return lcfg, ccfg, t_base_lidar, calib


def _painter(t_base_lidar, calib, **sync):
    return Painter(t_base_lidar, calib, COCO, load_class_table(), PaintConfig(), SyncConfig(**sync), 10.0)


def _scan(lidar, ranges, stamp_ns, lcfg):
    return Scan(stamp_ns, "laser", lidar.angle_min, lidar.angle_increment, ranges.astype(np.float32),
                lcfg.range_min, lcfg.range_max, lidar.time_increment, 1.0 / lcfg.rate_hz)


def _capture(ps, labels):
    """One scan and one camera image from the origin: (T_base_lidar, calibration, frame, scan, the
    object-table row each beam hit)."""
    lcfg, ccfg, t_base_lidar, calib = _rig()
    lidar, cam = LidarSim(lcfg), CameraSim(ccfg, 2.6, np.random.default_rng(0))
    sweep = lidar.cast(np.zeros(3), ps)
    frame = cam.render(np.zeros(3), ps, labels, np.random.default_rng(0))
    owner = np.where(sweep.part >= 0, sweep.parts.owner[np.maximum(sweep.part, 0)], -1)
    return t_base_lidar, calib, frame, _scan(lidar, sweep.ranges, 0, lcfg), owner


def test_points_take_the_class_and_mobility_of_their_mask():
    t_base_lidar, calib, frame, scan, owner = _capture(*_world())
    painted = _painter(t_base_lidar, calib).paint(scan, None, Segmentation(0, frame.label, COCO)).painted
    person, chair_, walls = owner == 4, owner == 3, (owner >= 0) & (owner <= 2)
    assert person.sum() >= 4 and chair_.sum() >= 2
    assert np.all(painted.mobility[person] == Mobility.DYNAMIC)
    assert np.all(np.asarray(COCO)[painted.class_id[person]] == "person")
    assert np.all(painted.mobility[chair_] == Mobility.SEMI_STATIC)
    # wall points in view are static, except those the corner LiDAR sees behind the person and the
    # chair, which land on their masks (the "double line" the occlusion filter removes)
    in_view = walls & (painted.mobility != Mobility.UNKNOWN)
    assert in_view.sum() > 50
    assert np.mean(painted.mobility[in_view] == Mobility.STATIC) > 0.75
    # the 270 deg scan mostly lies outside the 56 deg camera view: unknown

    assert (painted.mobility == Mobility.UNKNOWN).mean() > 0.6
    # points come out in the base frame: the chair legs (3.3-3.7 m ahead of the base centre)
    assert painted.points[chair_, 0].min() > 3.2 and painted.points[chair_, 0].max() < 3.8


def _turning(omega, t_scan, t_img):
    """Scan and label image taken at different times while the robot turns on the spot."""
    ps, labels = _world()
    lcfg, ccfg, t_base_lidar, calib = _rig()
    lidar, cam = LidarSim(lcfg), CameraSim(ccfg, 2.6, np.random.default_rng(0))
    sweep = lidar.cast(np.array([0.0, 0.0, omega * t_scan]), ps)
    frame = cam.render(np.array([0.0, 0.0, omega * t_img]), ps, labels, np.random.default_rng(0))
    odom = OdomTrack()
    for t in np.arange(-0.5, 0.5, 0.02):
        odom.add(int(round(t * 1e9)), np.array([0.0, 0.0, omega * t]))
    scan = _scan(lidar, sweep.ranges, int(round(t_scan * 1e9)), lcfg)
    seg = Segmentation(int(round(t_img * 1e9)), frame.label, COCO)
    owner = np.where(sweep.part >= 0, sweep.parts.owner[np.maximum(sweep.part, 0)], -1)
    return scan, seg, odom, owner == 4, t_base_lidar, calib


def test_motion_compensation_brings_the_scan_to_the_image_time():
    # turning at 60 deg/s, the image is 80 ms after the scan: 4.8 deg, a person-width at 3 m
    scan, seg, odom, person, t_base_lidar, calib = _turning(math.radians(60), 0.0, 0.08)
    with_mc = _painter(t_base_lidar, calib).paint(scan, odom, seg).painted
    without = _painter(t_base_lidar, calib, motion_compensation=False).paint(scan, odom, seg).painted
    right = lambda p: np.mean(p.mobility[person] == Mobility.DYNAMIC)  # noqa: E731
    assert right(with_mc) == 1.0
    assert right(without) < 0.5


def test_deskew_undoes_motion_during_the_sweep():
    ps, _ = _world()
    lcfg, _, t_base_lidar, calib = _rig(sweep=True)
    lidar = LidarSim(lcfg)
    omega = math.radians(90)
    poses = np.column_stack([np.zeros(lidar.angles.size), np.zeros(lidar.angles.size), omega * lidar.beam_dt])
    sweep = lidar.cast(poses, ps)
    odom = OdomTrack()
    for t in np.arange(-0.2, 0.4, 0.02):
        odom.add(int(round(t * 1e9)), np.array([0.0, 0.0, omega * t]))
    scan = _scan(lidar, sweep.ranges, 0, lcfg)
    painted = _painter(t_base_lidar, calib).paint(scan, odom, None).painted
    raw = _painter(t_base_lidar, calib, deskew=False).paint(scan, odom, None).painted
    # the wall at x = 5.94 is straight once deskewed; the raw sweep bends it (seen from the reference pose)
    ref_yaw = omega * (painted.stamp_ns * 1e-9)
    c, s = math.cos(ref_yaw), math.sin(ref_yaw)

    def wall_x(p):
        w = p.hit & (np.abs(p.points[:, 1]) < 3.0) & (p.points[:, 0] > 4)
        world_x = c * p.points[w, 0] - s * p.points[w, 1]
        return np.abs(world_x - 5.94).max()

    assert wall_x(painted) < 0.01
    assert wall_x(raw) > 0.05


def test_invalid_ranges_clear_nothing_and_no_return_clears_to_the_limit():
    lcfg, _, t_base_lidar, calib = _rig()
    lidar = LidarSim(lcfg)
    r = np.full(lidar.angles.size, 3.0)
    r[:10] = np.nan
    r[10:20] = np.inf
    r[20:30] = 0.0  # Hokuyo-style invalid
    r[30:40] = -np.inf
    painted = _painter(t_base_lidar, calib).paint(_scan(lidar, r, 0, lcfg), None, None).painted
    d = np.hypot(*(painted.points - painted.origin).T)
    assert not painted.hit[:40].any() and painted.hit[40:].all()
    assert np.allclose(d[:10], 0) and np.allclose(d[20:40], 0)
    assert np.allclose(d[10:20], 10.0)  # max_free_range
    assert np.allclose(d[40:], 3.0)


def test_odometry_track_interpolates_and_respects_gaps():
    odom = OdomTrack(max_gap_s=0.5)
    odom.add(0, np.array([0.0, 0.0, 3.0]))
    odom.add(100_000_000, np.array([1.0, 0.0, -3.0]))  # yaw wraps through pi
    odom.add(100_000_000, np.array([9.0, 9.0, 0.0]))  # repeated stamp: dropped and counted
    odom.add(2_000_000_000, np.array([2.0, 0.0, -3.0]))
    p = odom.interpolate(50_000_000)
    assert p[0] == pytest.approx(0.5)
    assert abs(p[2]) == pytest.approx(math.pi, abs=1e-9)
    assert odom.out_of_order == 1
    assert odom.interpolate(1_000_000_000) is None  # inside a 1.9 s gap
    assert odom.interpolate(-1) is None


def test_fast_pinhole_projection_agrees_with_opencv():
    ps, labels = _world()
    lcfg, ccfg, t_base_lidar, calib = _rig()
    lidar, cam = LidarSim(lcfg), CameraSim(ccfg, 2.6, np.random.default_rng(0))
    sweep = lidar.cast(np.zeros(3), ps)
    frame = cam.render(np.zeros(3), ps, labels, np.random.default_rng(0))
    scan = _scan(lidar, sweep.ranges, 0, lcfg)
    seg = Segmentation(0, frame.label, COCO)
    fast = _painter(t_base_lidar, calib).paint(scan, None, seg).painted
    tiny = Calibration(CameraIntrinsics(640, 480, calib.intrinsics.K, [0, 0, 0, 0, 1e-12]), calib.T_cam_lidar)
    slow = _painter(t_base_lidar, tiny).paint(scan, None, seg).painted
    assert not _painter(t_base_lidar, tiny)._pinhole_no_distortion
    assert np.array_equal(fast.mobility, slow.mobility) and np.array_equal(fast.class_id, slow.class_id)


def test_fisheye_camera_paints_like_opencv_projects():
    """A fisheye calibration: labels are read where cv2.fisheye.projectPoints puts the points."""
    import cv2

    lcfg, ccfg, t_base_lidar, _ = _rig()
    k = np.array([[300.0, 0, 320], [0, 300.0, 240], [0, 0, 1]])
    d = np.array([0.05, -0.01, 0.002, 0.0])
    t_base_cam = se3_from_xyz_rpy(ccfg.mount.xyz, ccfg.mount.rpy)
    calib = Calibration(CameraIntrinsics(640, 480, k, d, "fisheye"), se3_inverse(t_base_cam) @ t_base_lidar)
    lidar = LidarSim(lcfg)
    ranges = np.full(lidar.angles.size, 3.0)
    scan = _scan(lidar, ranges, 0, lcfg)
    # a label image whose value encodes the pixel column band (10 px wide)
    label = np.tile((np.arange(640) // 10 + 1).astype(np.uint16), (480, 1))
    names = tuple(["chair"] * 64)
    painted = Painter(t_base_lidar, calib, names, load_class_table(), PaintConfig(), SyncConfig(), 10.0).paint(
        scan, None, Segmentation(0, label, names)).painted
    seen = painted.mobility != Mobility.UNKNOWN
    assert seen.sum() > 50
    pts = np.column_stack([ranges * np.cos(lidar.angles), ranges * np.sin(lidar.angles), np.zeros_like(ranges)])
    p_cam = (calib.T_cam_lidar[:3, :3] @ pts.T).T + calib.T_cam_lidar[:3, 3]
    uv, _ = cv2.fisheye.projectPoints(p_cam[seen].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, d)
    expected = np.clip(np.rint(uv.reshape(-1, 2)[:, 0]).astype(int), 0, 639) // 10
    assert np.array_equal(painted.class_id[seen], expected)


def _two_chairs():
    objs = [wall(1, 6.0, -6.0, 6.0, 6.0), wall(2, -6.0, 6.0, 6.0, 6.0), wall(3, -6.0, -6.0, 6.0, -6.0),
            chair(4, (3.5, -1.0, 0.0)), chair(5, (3.5, 1.0, 0.0))]
    parts = [p for o in objs for p in o.parts]
    owners = [i for i, o in enumerate(objs) for _ in o.parts]
    labels = np.array([0, 0, 0, COCO.index("chair") + 1, COCO.index("chair") + 1], np.uint16)
    return PartSet.build(parts, owners), labels


def test_furniture_points_name_the_object_the_camera_saw_them_on():
    """Two chairs of one class: without instance masks, each chair's points share the number of its mask
    region, and the two differ; with the backend's instance image, the points take its instances."""
    t_base_lidar, calib, frame, scan, owner = _capture(*_two_chairs())
    a, b = owner == 3, owner == 4
    assert a.sum() >= 2 and b.sum() >= 2

    painted = _painter(t_base_lidar, calib).paint(scan, None, Segmentation(0, frame.label, COCO)).painted
    ka, kb = np.unique(painted.instance[a]), np.unique(painted.instance[b])
    assert ka.size == 1 and kb.size == 1 and ka[0] != kb[0]
    assert min(ka[0], kb[0]) >= REGION_BASE  # regions: they may join objects, never tell them apart
    assert np.all(painted.instance[~(a | b)] == -1)  # walls are not furniture

    instance = np.where(frame.label > 0, frame.owner + 1, 0).astype(np.uint16)
    seg = Segmentation(0, frame.label, COCO, instance=instance)
    painted = _painter(t_base_lidar, calib).paint(scan, None, seg).painted
    assert set(painted.instance[a]) == {4} and set(painted.instance[b]) == {5}


def test_odometry_at_the_very_stamp_needs_no_neighbour_within_the_gap():
    """Sparse odometry published at the scan stamps (a CARMEN import, a slow driver): a scan whose stamp has
    an odometry sample takes it, however far the samples beside it are; between them the gap rule holds."""
    odom = OdomTrack(max_gap_s=0.5)
    odom.add(1_000_000_000, np.array([0.0, 0.0, 0.0]))
    odom.add(4_000_000_000, np.array([1.0, 0.5, 0.3]))
    assert np.allclose(odom.interpolate(4_000_000_000), [1.0, 0.5, 0.3])
    assert np.allclose(odom.interpolate(1_000_000_000), [0.0, 0.0, 0.0])
    assert odom.interpolate(2_000_000_000) is None  # 3 s between samples: not interpolated
    assert odom.interpolate(np.array([1_000_000_000, 4_000_000_000])).shape == (2, 3)


def test_a_skipped_frame_labels_from_memory_only_the_returns_its_camera_sees():
    # with every frame segmented a return out of the camera's view is unknown; a scan paired with a frame
    # the selection skipped must not label more: else a wall or a bed leg behind the robot gathers a
    # label from every skipped frame, many times what segmenting them would have given it
    from dataclasses import replace

    from semmap.paint.painter import LabelMemory
    from semmap.segment.select import SkippedFrame

    t_base_lidar, calib, frame, scan, owner = _capture(*_world())
    painter = Painter(t_base_lidar, calib, COCO, load_class_table(), PaintConfig(), SyncConfig(), 10.0,
                      memory=LabelMemory(0.05))
    track = OdomTrack()  # standing still
    for t in range(-2, 12):
        track.add(t * 10**8, np.zeros(3))
    res = painter.paint(scan, track, Segmentation(0, frame.label, COCO))
    first = res.painted
    painted = [first]
    for k in (1, 2):  # two more frames agree: the cells' labels now transfer
        later = replace(scan, stamp_ns=k * 10**8)
        painted.append(painter.paint(later, track, Segmentation(k * 10**8, frame.label, COCO)).painted)
    # the whole room, behind the robot too, as if an earlier pass had looked everywhere
    behind = first.hit.copy()
    behind[res.view.beams] = False  # the returns out of the image
    # and someone standing behind the robot a moment ago (one frame's word, kept for a few seconds)
    person = np.flatnonzero(behind)[-8:]
    behind[person] = False
    xy = first.points[behind]
    for t in (5, 6):
        painter.memory.add(t * 10**8, xy, np.full(len(xy), Mobility.STATIC, np.uint8), np.full(len(xy), -1, np.int16))
    painter.memory.add(65 * 10**7, first.points[person], np.full(8, Mobility.DYNAMIC, np.uint8), np.zeros(8, np.int16))
    skipped = replace(scan, stamp_ns=7 * 10**8)
    out = painter.paint(skipped, track, SkippedFrame(7 * 10**8)).painted
    in_view = first.hit & (first.mobility != Mobility.UNKNOWN)
    assert in_view.sum() > 50 and behind.sum() > 100
    # what the camera sees takes the segmented frames' labels: the chair stays a chair
    assert np.mean(out.mobility[in_view] == first.mobility[in_view]) > 0.9
    assert np.all(out.mobility[(owner == 3) & in_view] == Mobility.SEMI_STATIC)
    # what it does not see stays unknown, whatever the memory holds there, but for a person: the map must
    # drop them, and the selection may have seen them once
    assert np.all(out.mobility[behind] == Mobility.UNKNOWN)
    assert np.all(out.mobility[person] == Mobility.DYNAMIC)
    assert painter.stats.points_transferred == int(np.count_nonzero(out.mobility != Mobility.UNKNOWN))
