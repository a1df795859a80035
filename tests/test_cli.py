"""The command line as a user meets it: clear one-line errors, exit codes, no half-written output."""

import json
import shutil
import subprocess
import sys
from dataclasses import replace

import pytest

from semmap.cli.main import main
from semmap.sim.scenarios import demo
from semmap.sim.tour import simulate

LEG_BAGS = {
    "positive_1_extracted.bag": {"/training_scan": 197, "/leg_cluster_positions": 197},
    "positive_2_extracted.bag": {"/training_scan": 83, "/leg_cluster_positions": 83},
    "positive_3_extracted.bag": {"/training_scan": 175, "/leg_cluster_positions": 175},
    "positive_4_extracted.bag": {"/training_scan": 295, "/leg_cluster_positions": 295},
    "negative_2.bag": {"/left_scan": 435, "/rear_scan": 435, "/right_scan": 434},
}


@pytest.mark.parametrize("name", list(LEG_BAGS))
def test_info_reads_real_ros1_bags(data_dir, capsys, name):
    bag = data_dir / "leg_tracker" / name
    assert main(["info", str(bag), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    counts = {t["topic"]: t["count"] for t in info["topics"]}
    for topic, n in LEG_BAGS[name].items():
        assert counts[topic] == n
    assert info["storage"] == "ros1"
    types = {t["topic"]: t["type"] for t in info["topics"]}
    assert all(types[t] == "sensor_msgs/msg/LaserScan" for t in LEG_BAGS[name] if "scan" in t)


def test_info_on_a_tour_folder(short_tour, capsys):
    assert main(["info", str(short_tour.out)]) == 0
    out = capsys.readouterr().out
    assert "/scan" in out and "15.00 Hz" in out and "sensor_msgs/msg/LaserScan" in out


def _one_line_error(capsys, code, expected_code, *needles):
    err = capsys.readouterr().err.strip()
    assert code == expected_code
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in err


def test_info_missing_bag(capsys, tmp_path):
    code = main(["info", str(tmp_path / "nope.bag")])
    _one_line_error(capsys, code, 3, "nope.bag", "no such file")


def test_info_truncated_bag(capsys, tmp_path, short_tour):
    """A bag cut short (a robot's battery died): one clear line, exit 3, for every storage."""
    if short_tour.format == "ros1":
        cut = tmp_path / "cut.bag"
        data = short_tour.bag.read_bytes()
        cut.write_bytes(data[: len(data) // 3])
    else:
        cut = tmp_path / "cut"
        shutil.copytree(short_tour.bag, cut)
        storage = next(f for f in cut.iterdir() if f.suffix in (".mcap", ".db3"))
        data = storage.read_bytes()
        storage.write_bytes(data[: len(data) // 3])
    code = main(["info", str(cut)])
    _one_line_error(capsys, code, 3, "cut")


def test_simulate_refuses_to_overwrite(capsys, tmp_path):
    out = tmp_path / "t"
    out.mkdir()
    code = main(["simulate", "--scenario", "demo", "--out", str(out)])
    _one_line_error(capsys, code, 4, str(out), "--force")


def test_simulate_bad_config_key_names_it_and_writes_nothing(capsys, tmp_path):
    cfg = tmp_path / "sim.yaml"
    cfg.write_text("lidar:\n  rate_hz: 20\n  fov: 270\n")
    code = main(["simulate", "--scenario", "demo", "--out", str(tmp_path / "t"), "--config", str(cfg)])
    _one_line_error(capsys, code, 2, "sim.yaml", "lidar.fov", "unknown key")
    assert not (tmp_path / "t").exists()
    assert not list(tmp_path.glob(".t.*"))


def test_simulate_unknown_scenario(capsys, tmp_path):
    code = main(["simulate", "--scenario", "moon", "--out", str(tmp_path / "t")])
    _one_line_error(capsys, code, 2, "moon", "ward")


def test_interrupted_simulation_leaves_nothing(tmp_path):
    def interrupt(done, total):
        if done > 100:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        simulate(replace(demo().world, duration_s=5.0), tmp_path / "t", progress=interrupt)
    assert list(tmp_path.iterdir()) == []


def test_force_replaces_an_existing_tour(tmp_path):
    world = replace(demo().world, duration_s=2.0)
    first = simulate(world, tmp_path / "t", seed=1)
    (first.out / "stale.txt").write_text("old")
    simulate(world, tmp_path / "t", seed=2, force=True)
    assert not (tmp_path / "t" / "stale.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t"]


def test_console_script_runs_without_traceback(tmp_path):
    exe = shutil.which("semmap")
    cmd = [exe] if exe else [sys.executable, "-m", "semmap"]
    res = subprocess.run([*cmd, "info", str(tmp_path / "missing.bag")], capture_output=True, text=True, check=False)
    assert res.returncode == 3
    assert res.stderr.startswith("semmap info: error:")
    assert "Traceback" not in res.stderr
    res = subprocess.run([*cmd, "--version"], capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stdout.startswith("semmap ")
