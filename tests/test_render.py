"""The simulated camera: label images line up with the RGB image and with the LiDAR."""


import numpy as np
import pytest

from semmap.config import SimCameraConfig, SimLidarConfig
from semmap.geometry import project_points, se3_apply, se3_from_xyz_rpy, se3_inverse
from semmap.sim.raycast import PartSet
from semmap.sim.sensors import CameraSim, LidarSim
from semmap.sim.world import Person, table, wall


def _scene():
    objs = [wall(1, 6.0, -4.0, 6.0, 4.0), table(2, (3.0, -1.2, 0.0))]
    person = Person(3, "p", np.array([[2.5, 0.6]]))
    parts = [p for o in objs for p in o.parts] + list(person.parts_at(0.0))
    owners = [0] * 1 + [1] * len(objs[1].parts) + [2] * 4
    return PartSet.build(parts, owners)


def _render(ps):
    cfg = SimCameraConfig(noise_std=0.0)
    cam = CameraSim(cfg, 2.6, np.random.default_rng(0))
    labels = np.array([0, 61, 1], np.uint16)  # wall: none, table: 'dining table' (61), person (1)
    return cfg, cam.render(np.zeros(3), ps, labels, np.random.default_rng(0))


def test_label_image_lines_up_with_rgb():
    _, frame = _render(_scene())
    person = frame.label == 1
    assert person.sum() > 2000
    # every column where the person mask starts or ends is also an RGB edge
    rgb = frame.rgb.astype(int)
    rows, cols = np.nonzero(person[:, 1:] != person[:, :-1])
    jumps = np.abs(rgb[rows, cols + 1] - rgb[rows, cols]).sum(axis=1)
    assert np.median(jumps) > 40
    # and inside the mask the RGB is the person's colours, not the wall's
    wall_px = frame.rgb[(frame.label == 0) & (frame.depth > 5.0)]
    assert np.abs(frame.rgb[person].mean(axis=0) - wall_px.mean(axis=0)).sum() > 60


def test_depth_of_the_wall_at_the_image_centre():
    ps = PartSet.build(_scene_wall_only(), [0])
    cfg, frame = _render(ps)
    cx, cy = round(cfg.K[0][2]), round(cfg.K[1][2])
    # optical depth of the wall face (x = 5.94) seen from the camera at x = 0.42
    assert frame.depth[cy, cx] == pytest.approx(5.94 - cfg.mount.xyz[0], abs=1e-3)


def _scene_wall_only():
    return list(wall(1, 6.0, -4.0, 6.0, 4.0).parts)


def test_lidar_points_on_the_person_project_onto_the_person_mask():
    ps = _scene()
    cfg_cam, frame = _render(ps)
    lcfg = SimLidarConfig(sweep=False, noise_std=0.0, dropout_prob=0.0)
    lidar = LidarSim(lcfg)
    sweep = lidar.cast(np.zeros(3), ps)
    on_person = (sweep.part >= 0) & (sweep.parts.owner[np.maximum(sweep.part, 0)] == 2)
    assert on_person.sum() >= 4
    r, a = sweep.ranges[on_person], lidar.angles[on_person]
    pts = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)])
    t_cam_lidar = se3_inverse(se3_from_xyz_rpy(cfg_cam.mount.xyz, cfg_cam.mount.rpy)) @ se3_from_xyz_rpy(
        lcfg.mount.xyz, lcfg.mount.rpy)
    uv, ok = project_points(np.asarray(cfg_cam.K), np.zeros(5), se3_apply(t_cam_lidar, pts), 640, 480)
    assert ok.all()
    px = np.round(uv).astype(int)
    assert np.all(frame.label[px[:, 1], px[:, 0]] == 1)


def test_table_top_is_seen_from_above_and_legs_below():
    _, frame = _render(_scene())
    table = frame.label == 61
    rows = np.nonzero(table.any(axis=1))[0]
    # the camera is at 0.5 m, below the 0.76 m top: the table spans the horizon (top above, legs below)
    assert rows.min() < 240 < rows.max()
