"""The user's files are safe: --out is checked before any work, --force replaces only semmap's own
folders and never an input, and a folder half-written by a killed run is cleaned up by the next."""

import json
import os
import subprocess
import time
from dataclasses import replace

import pytest

from semmap.cli.main import main
from semmap.sim.scenarios import demo
from semmap.sim.tour import simulate


@pytest.fixture(scope="module")
def tour(tmp_path_factory):
    return simulate(replace(demo().world, duration_s=4.0), tmp_path_factory.mktemp("tour") / "demo", seed=1)


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def test_existing_out_fails_before_any_work(capsys, tour, tmp_path):
    (tmp_path / "m").mkdir()
    t0 = time.perf_counter()
    assert main(["build", str(tour.out), "--out", str(tmp_path / "m")]) == 4
    assert time.perf_counter() - t0 < 1.0
    assert "m: already exists (use --force" in _err(capsys)


def test_unwritable_out_fails_before_any_work_and_names_the_users_path(capsys, tour):
    out = "/proc/semmap-test/map"  # not even root can create folders here
    t0 = time.perf_counter()
    assert main(["build", str(tour.out), "--out", out]) == 4
    assert time.perf_counter() - t0 < 1.0
    err = _err(capsys)
    assert out in err and ".partial" not in err


@pytest.mark.parametrize("where", ["the tour folder", "its parent", "the bag"])
def test_force_never_replaces_the_tour_being_read(capsys, tour, tmp_path, where):
    import shutil

    copy = tmp_path / "tours" / "demo"
    shutil.copytree(tour.out, copy)
    out = {"the tour folder": copy, "its parent": copy.parent, "the bag": copy / "demo.bag"}[where]
    assert main(["build", str(copy), "--out", str(out), "--force"]) == 4
    assert "input" in _err(capsys)
    assert (copy / "demo.bag").stat().st_size == tour.bag.stat().st_size


def test_force_replaces_only_a_map_folder(capsys, tour, tmp_path):
    f = tmp_path / "notes.txt"
    f.write_text("mine")
    assert main(["build", str(tour.out), "--out", str(f), "--force"]) == 4
    assert "is not a folder" in _err(capsys) and f.read_text() == "mine"
    d = tmp_path / "photos"
    d.mkdir()
    (d / "cat.jpg").write_bytes(b"x")
    assert main(["build", str(tour.out), "--out", str(d), "--force"]) == 4
    assert "not a semmap map folder" in _err(capsys) and (d / "cat.jpg").exists()
    # a map folder is replaced, whole
    cfg = tmp_path / "c.yaml"
    cfg.write_text("workers: false\n")
    m = tmp_path / "m"
    assert main(["build", str(tour.out), "--out", str(m), "--config", str(cfg), "-q"]) == 0
    (m / "stale.txt").write_text("old")
    assert main(["build", str(tour.out), "--out", str(m), "--config", str(cfg), "-q", "--force"]) == 0
    assert not (m / "stale.txt").exists() and (m / "map.yaml").exists()


def test_a_partial_folder_of_a_killed_run_is_cleaned_up(tour, tmp_path):
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = tmp_path / ".m.abc123.partial"
    stale.mkdir()
    (stale / "map.pgm").write_bytes(b"half")
    (stale / ".semmap-owner").write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename}))
    busy = tmp_path / ".m.def456.partial"  # another build, still running, writing the same map
    busy.mkdir()
    (busy / ".semmap-owner").write_text(json.dumps({"pid": 1, "host": os.uname().nodename}))
    cfg = tmp_path / "c.yaml"
    cfg.write_text("workers: false\n")
    assert main(["build", str(tour.out), "--out", str(tmp_path / "m"), "--config", str(cfg), "-q"]) == 0
    assert not stale.exists() and busy.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [".m.def456.partial", "c.yaml", "m"]


def test_simulate_force_replaces_only_a_tour_folder(capsys, tmp_path):
    d = tmp_path / "data"
    d.mkdir()
    (d / "thesis.pdf").write_bytes(b"x")
    assert main(["simulate", "--scenario", "demo", "--out", str(d), "--force"]) == 4
    assert "not a semmap tour folder" in _err(capsys) and (d / "thesis.pdf").exists()


def test_calibrate_check_refuses_to_overwrite_without_force(capsys, tour, tmp_path):
    png = tmp_path / "check.png"
    png.write_bytes(b"mine")
    args = ["calibrate", "check", "--bag", str(tour.out), "--out", str(png)]
    assert main(args) == 4
    assert "already exists (use --force" in _err(capsys) and png.read_bytes() == b"mine"
    assert main([*args, "--force", "-q"]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
