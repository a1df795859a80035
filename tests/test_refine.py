"""Point-to-line refinement of ICP results (``registration.refine``).

A map sampled along the walls at one phase and a scan sampled at another: a point's nearest map point
lies up to half a sample along the wall from it, which point-to-point matching reads as motion and
point-to-line does not. A corridor leaves the direction along it to the start pose.
"""

from __future__ import annotations

import numpy as np
from test_register import ROOM, _run, _truth_in_map

from semmap.config import RefineConfig, RegistrationConfig
from semmap.geometry import se2_apply, se2_between, se2_inverse
from semmap.register.refine import LineRefiner


def _sample(segments, spacing, phase):
    """Points every ``spacing`` m along each segment (x0, y0, x1, y1), the first ``phase`` m in."""
    out = []
    for x0, y0, x1, y1 in segments:
        length = float(np.hypot(x1 - x0, y1 - y0))
        t = np.arange(phase, length, spacing) / length
        out.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.concatenate(out)


def _scan_of(world_points, pose, rng, noise=0.005):
    """World points seen from ``pose`` (base frame), with range-free Gaussian noise."""
    p = se2_apply(se2_inverse(pose), world_points)
    return p + rng.normal(0.0, noise, p.shape)


def test_refinement_removes_the_along_wall_offset_of_a_sparse_map():
    rng = np.random.default_rng(3)
    map_pts = _sample(ROOM, 0.15, 0.0)
    truth = np.array([0.7, -0.4, 0.3])
    scan = _scan_of(_sample(ROOM, 0.05, 0.07), truth, rng)
    start = truth + np.array([0.04, -0.03, 0.01])
    ref = LineRefiner()
    ref.set_map(map_pts)
    out = ref.refine(scan, start, kernel=0.1, max_distance=0.3)
    assert out is not None and out.matched > 100
    err = se2_between(truth, out.pose)
    assert np.hypot(err[0], err[1]) < 0.003  # from 5 cm
    assert abs(err[2]) < 0.001  # from 10 mrad


def test_a_corridor_keeps_its_axis_from_the_start_pose():
    rng = np.random.default_rng(4)
    walls = np.array([[-20.0, -1.0, 20.0, -1.0], [-20.0, 1.0, 20.0, 1.0]])
    truth = np.array([0.0, 0.0, 0.0])
    scan = _scan_of(_sample(walls, 0.05, 0.02) * np.array([[0.5, 1.0]]), truth, rng, noise=0.003)
    start = np.array([0.10, 0.04, 0.01])
    ref = LineRefiner()
    ref.set_map(_sample(walls, 0.075, 0.0))
    out = ref.refine(scan, start, kernel=0.1, max_distance=0.3)
    assert out is not None
    assert abs(out.pose[1]) < 0.003 and abs(out.pose[2]) < 0.001  # across and heading: corrected
    assert abs(out.pose[0] - 0.10) < 0.002  # along: nothing to see, left where it started


def test_refinement_gives_nothing_without_lines():
    ref = LineRefiner()
    assert ref.refine(np.zeros((50, 2)), np.zeros(3), 0.1, 0.3) is None  # no map yet
    ref.set_map(np.random.default_rng(0).uniform(-5, 5, (400, 2)))  # clutter: no point has a line
    assert ref.refine(np.random.default_rng(1).uniform(-5, 5, (200, 2)), np.zeros(3), 0.1, 0.3) is None


def test_registrar_refines_every_icp_result_when_enabled():
    t = np.linspace(0.0, 1.0, 25)
    poses = np.column_stack([-2.0 + 3.0 * t, -1.0 + 1.5 * t, 0.8 * t])
    cfg = RegistrationConfig(mode="icp", refine=RefineConfig(enabled=True))
    est, reg = _run(cfg, poses)
    assert reg.stats["icp_refined"] == len(poses) - 1
    err = se2_between(_truth_in_map(poses), est)
    assert np.max(np.hypot(err[:, 0], err[:, 1])) < 0.02
    _, off = _run(RegistrationConfig(mode="icp"), poses)
    assert off.stats["icp_refined"] == 0
