"""The odometry's clock offset, estimated from the tour (sync.odometry_offset: auto)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from test_register import synthetic_scan

from semmap.config import RegistrationConfig, SyncConfig
from semmap.register.timing import estimate_odometry_offset

DATA = Path(os.environ.get("SEMMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def _turning_tour(n=240, rate_hz=10.0):
    """A robot that drives and turns back and forth in the synthetic room: poses at the scans' stamps."""
    t = np.arange(n) / rate_hz
    yaw = 0.8 * np.sin(0.6 * t) + 0.3 * np.sin(1.7 * t)
    x = -2.0 + 0.15 * t * np.cos(0.2 * t)
    y = -1.0 + 0.6 * np.sin(0.25 * t)
    return (t * 1e9).astype(np.int64), np.column_stack([x, y, yaw])


def _scans(poses):
    rng = np.random.default_rng(0)
    return [s.points[s.hit] for s in (synthetic_scan(p, rng) for p in poses)]


@pytest.mark.parametrize("true_offset", [0.0, 0.15, -0.08])
def test_the_offset_of_odometry_stamped_early_or_late_is_found(true_offset):
    stamps, poses = _turning_tour()
    points = _scans(poses)
    # odometry at 50 Hz on its own clock: what the robot did at time t is stamped t - offset
    ot = np.arange(-1.0, 26.0, 0.02)
    true_t = ot + true_offset
    yaw = np.interp(true_t, stamps * 1e-9, np.unwrap(poses[:, 2]))
    est = estimate_odometry_offset(stamps, points, (ot * 1e9).astype(np.int64), yaw, RegistrationConfig())
    if true_offset == 0.0:
        assert not est.used and est.offset_s == 0.0  # nothing to correct: stamps kept
    else:
        assert est.used
        assert est.offset_s == pytest.approx(true_offset, abs=0.015)
        assert est.rms_at_best < 0.5 * est.rms_at_zero


def test_no_offset_is_claimed_without_turns():
    stamps, _ = _turning_tour(120)
    poses = np.column_stack([np.linspace(-3, 3, 120), np.zeros(120), np.zeros(120)])
    points = _scans(poses)
    ot = np.arange(-1.0, 14.0, 0.02)
    est = estimate_odometry_offset(stamps, points, (ot * 1e9).astype(np.int64), np.zeros(ot.size),
                                   RegistrationConfig())
    assert not est.used and "turned" in est.reason


def test_the_setting_takes_auto_or_seconds():
    assert SyncConfig().odometry_offset == "auto"
    assert SyncConfig(odometry_offset=0.12).odometry_offset == pytest.approx(0.12)
    with pytest.raises(ValueError):
        SyncConfig(odometry_offset=30.0)
    with pytest.raises(ValueError):
        SyncConfig(odometry_offset="soon")


def test_a_simulated_tour_keeps_its_stamps(demo_map):
    from semmap.io.yamlio import read_yaml

    cfg = read_yaml(demo_map.out / "config.yaml")
    assert cfg["sync"]["odometry_offset"] == 0.0  # the simulator's clocks agree: auto applies nothing


@pytest.mark.skipif(not (DATA / "hokuyo_odom_bags").is_dir(), reason="../shared/data/hokuyo_odom_bags is absent")
def test_the_hokuyo_bags_odometry_is_stamped_early():
    from semmap.io.bag import read_bag
    from semmap.paint.stream import open_build_tour, sample_scans_and_odometry

    bag_path = DATA / "hokuyo_odom_bags" / "2018_may9_editted_after1.bag"
    with read_bag(bag_path, lazy=True) as bag:
        tinfo, cfg = open_build_tour(bag_path, None, None, {}, source=bag)
        stamps, points, ot, op = sample_scans_and_odometry(tinfo, bag)
    est = estimate_odometry_offset(stamps, points, ot, op[:, 2], cfg.registration)
    # measured by hand too (turn rates of ICP against the odometry's, from the sweeps' starts): 0.10-0.15 s
    assert est.used and 0.10 < est.offset_s < 0.20


def test_the_estimate_does_not_search_for_loops_when_the_build_will(monkeypatch):
    # the pre-pass needs scan matching's turn rates only; with loop closure on, it used to search
    # its scans for loops and verify them, all of it thrown away
    from semmap.config import LoopClosureConfig
    from semmap.register.loops import LoopCloser

    def refuse(*_a, **_k):
        raise AssertionError("the offset estimate searched for loops")

    monkeypatch.setattr(LoopCloser, "add", refuse)
    stamps, poses = _turning_tour()
    points = _scans(poses)
    ot = np.arange(-1.0, 26.0, 0.02)
    yaw = np.interp(ot + 0.15, stamps * 1e-9, np.unwrap(poses[:, 2]))
    cfg = RegistrationConfig(loop_closure=LoopClosureConfig(enabled=True))
    est = estimate_odometry_offset(stamps, points, (ot * 1e9).astype(np.int64), yaw, cfg)
    assert est.used and est.offset_s == pytest.approx(0.15, abs=0.015)
