"""semmap eval-traj: RPE and ATE against reference poses, computed by evo, checked on trajectories whose
errors are known by construction."""

import json
import math

import numpy as np
import pytest

from semmap.cli.main import main
from semmap.geometry import se2_compose
from semmap.io.tum import write_tum
from semmap.register.evaluate import trajectory_errors

pytest.importorskip("evo")


def _reference(n=60, seed=0):
    rng = np.random.default_rng(seed)
    poses = [np.zeros(3)]
    steps = []
    for _ in range(n - 1):
        s = np.array([rng.uniform(0.2, 0.4), 0.0, rng.uniform(-0.3, 0.3)])
        steps.append(s)
        poses.append(se2_compose(poses[-1], s))
    return np.arange(n, dtype=np.int64) * 100_000_000 + 10**9, np.array(poses), np.array(steps)


def test_rpe_is_the_error_of_each_step_and_ate_ignores_a_rigid_offset():
    t, ref, steps = _reference()
    # every step 5 cm too long, straight ahead: RPE at step 1 is 5 cm exactly, and no rotation error
    est = [np.zeros(3)]
    for s in steps:
        est.append(se2_compose(est[-1], s + [0.05, 0.0, 0.0]))
    e = trajectory_errors(t, np.array(est), t, ref)
    assert e.rpe[1]["trans_mean"] == pytest.approx(0.05, abs=1e-6)
    assert e.rpe[1]["trans_std"] == pytest.approx(0.0, abs=1e-6)
    assert e.rpe[1]["rot_mean_deg"] == pytest.approx(0.0, abs=1e-4)
    assert e.rpe[10]["pairs"] == len(t) - 10  # every pair ten scans apart
    # the same trajectory moved and turned as a whole: ATE and RPE vanish
    T = np.array([3.0, -2.0, 0.7])
    moved = np.array([se2_compose(T, p) for p in ref])
    e2 = trajectory_errors(t, moved, t, ref)
    assert e2.ate_rmse < 1e-6 and e2.rpe[10]["trans_mean"] < 1e-6
    # a heading error of 1 degree on every step: RPE rotation 1 degree at step 1, 10 at step 10
    est3 = [np.zeros(3)]
    for s in steps:
        est3.append(se2_compose(est3[-1], s + [0.0, 0.0, math.radians(1.0)]))
    e3 = trajectory_errors(t, np.array(est3), t, ref)
    assert e3.rpe[1]["rot_mean_deg"] == pytest.approx(1.0, abs=1e-3)
    assert e3.rpe[10]["rot_mean_deg"] == pytest.approx(10.0, abs=1e-2)
    assert e3.ate_rmse > 0.05


def test_cli_on_a_map_folder_and_a_tour_folder(tmp_path, capsys):
    t, ref, steps = _reference()
    (tmp_path / "map").mkdir()
    (tmp_path / "tour").mkdir()
    write_tum(tmp_path / "tour" / "reference.tum", t, ref)
    noisy = ref + np.random.default_rng(1).normal(0, 0.01, ref.shape)
    write_tum(tmp_path / "map" / "trajectory.tum", t, noisy)
    odo = [np.zeros(3)]
    for s in steps:
        odo.append(se2_compose(odo[-1], s * [1.03, 1.0, 1.05]))
    write_tum(tmp_path / "map" / "odometry.tum", t, np.array(odo))
    assert main(["eval-traj", str(tmp_path / "map"), "--ref", str(tmp_path / "tour"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) == {"reference", "trajectory", "odometry"}
    assert doc["odometry"]["rpe"]["10"]["trans_mean"] > doc["trajectory"]["rpe"]["10"]["trans_mean"]
    assert main(["eval-traj", str(tmp_path / "map"), "--ref", str(tmp_path / "tour")]) == 0
    text = capsys.readouterr().out
    assert "trajectory" in text and "odometry" in text and "ATE" in text


def test_cli_errors(tmp_path, capsys):
    t, ref, _ = _reference()
    write_tum(tmp_path / "ref.tum", t, ref)
    write_tum(tmp_path / "late.tum", t + 10**12, ref)
    assert main(["eval-traj", str(tmp_path / "late.tum"), "--ref", str(tmp_path / "ref.tum")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pair" in err
    assert main(["eval-traj", str(tmp_path), "--ref", str(tmp_path / "ref.tum")]) == 2
    assert "trajectory.tum" in capsys.readouterr().err
