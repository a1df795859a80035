"""The `occlusion` scenario reproduces the research's "double line" fault, and only with the corner LiDAR."""

import numpy as np

from semmap.geometry import project_points, se3_apply, se3_from_xyz_rpy, se3_inverse
from semmap.records import Mobility
from semmap.sim.raycast import PartSet
from semmap.sim.robot import plan_tour
from semmap.sim.scenarios import get_scenario
from semmap.sim.sensors import CameraSim, LidarSim
from semmap.sim.tour import effective_config


def background_on_foreground(mount=None, step_s=1.0):
    """Fraction of in-view wall points whose projection lands on a person or furniture mask."""
    sc = get_scenario("occlusion")
    over = {"lidar": {"sweep": False, "noise_std": 0.0, "dropout_prob": 0.0}}
    if mount:
        over["lidar"]["mount"] = mount
    cfg = effective_config(sc, over)
    w = sc.world
    traj = plan_tour(w, cfg.robot)
    row_mob = np.array([int(o.mobility) for o in w.objects] + [int(Mobility.DYNAMIC)] * len(w.people))
    static = PartSet.build([p for o in w.objects for p in o.parts],
                           [i for i, o in enumerate(w.objects) for _ in o.parts])
    lidar = LidarSim(cfg.lidar)
    cam = CameraSim(cfg.camera, w.ceiling_height, np.random.default_rng(0))
    t_cam_lidar = se3_inverse(se3_from_xyz_rpy(cfg.camera.mount.xyz, cfg.camera.mount.rpy)) @ se3_from_xyz_rpy(
        cfg.lidar.mount.xyz, cfg.lidar.mount.rpy)
    wrong = seen = 0
    for t in np.arange(1.0, traj.duration, step_s):
        body, owners = [], []
        for i, p in enumerate(w.people):
            b = p.body(t)
            body += b
            owners += [len(w.objects) + i] * len(b)
        ps = PartSet.concat([static, PartSet.from_raw(body, owners)])
        pose = traj.pose(t)
        sweep = lidar.cast(pose, ps)
        frame = cam.render(pose, ps, row_mob.astype(np.uint16), np.random.default_rng(0))  # label = mobility
        hit = sweep.part >= 0
        mob = np.where(hit, row_mob[sweep.parts.owner[np.maximum(sweep.part, 0)]], 0)
        r = np.where(hit, sweep.ranges, 0.0)
        pts = np.column_stack([r * np.cos(lidar.angles), r * np.sin(lidar.angles), np.zeros_like(r)])
        uv, ok = project_points(np.asarray(cfg.camera.K), np.zeros(5), se3_apply(t_cam_lidar, pts), 640, 480)
        ok &= hit & (mob == Mobility.STATIC)
        px = np.round(uv[ok]).astype(int)
        lab = frame.label[np.clip(px[:, 1], 0, 479), np.clip(px[:, 0], 0, 639)]
        seen += int(ok.sum())
        wrong += int(np.count_nonzero(lab >= Mobility.SEMI_STATIC))
    return wrong / seen


def test_corner_lidar_paints_walls_with_foreground_masks():
    corner = background_on_foreground()
    centred = background_on_foreground({"xyz": [0.42, 0.0, 0.2], "rpy": [0.0, 0.0, 0.0]})
    assert corner > 0.05  # measured about 12 %
    assert centred < 0.02  # measured about 0.4 %: only what shows under table tops
    assert corner > 5 * centred
