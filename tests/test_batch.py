"""`semmap batch`: a manifest of three small simulated sites, built on Ray (or in one process), resumed
after a failure, and stopped mid-run.

The three sites' tours are short demo tours with different seeds. Each test writes its own manifest.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from test_faults import _running

from semmap.batch import load_manifest, run_batch
from semmap.cli.main import main
from semmap.errors import ConfigError, OutputError

try:
    import ray  # noqa: F401

    HAVE_RAY = True
except ImportError:  # pragma: no cover - CI installs it
    HAVE_RAY = False

needs_ray = pytest.mark.skipif(not HAVE_RAY, reason="Ray is not installed (pip install 'semmap[fleet]')")

#: the files of a map folder that do not depend on when and how fast it was built
MAP_FILES = ("map.pgm", "map.yaml", "semantic.png", "semi_static.pgm", "semi_static.yaml",
             "semi_static_objects.json", "grid.npz", "trajectory.tum", "odometry.tum", "config.yaml")


@pytest.fixture(scope="module")
def tours(tmp_path_factory):
    """Three 8 s demo tours (seeds 0-2), and a broken bag."""
    from semmap.sim.scenarios import demo
    from semmap.sim.tour import simulate

    root = tmp_path_factory.mktemp("fleet")
    world = replace(demo().world, duration_s=8.0)
    for seed, name in enumerate(("ward", "office", "depot")):
        simulate(world, root / "tours" / name, seed=seed)
    (root / "broken.bag").write_bytes(b"not a bag at all\n")
    return root


@pytest.fixture(scope="module")
def single(tours, tmp_path_factory):
    """Each tour built alone with `semmap build`."""
    out = tmp_path_factory.mktemp("single")
    for name in ("ward", "office", "depot"):
        assert main(["build", str(tours / "tours" / name), "--out", str(out / name), "-q"]) == 0
    return out


def _manifest(root: Path, text: str, name: str = "fleet.yaml") -> Path:
    path = root / name
    path.write_text(text)
    return path


THREE_SITES = """
sites:
  - name: st-marys
    tours: [tours/ward]
  - name: hq
    tours:
      - {tour: tours/office, name: floor2}
  - name: depot
    tours: [tours/depot]
"""


def _same_maps(a: Path, b: Path) -> None:
    for f in MAP_FILES:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f"{a / f} differs from {b / f}"


@pytest.mark.parametrize("engine", [pytest.param("ray", marks=needs_ray), "local"])
def test_three_sites_build_as_single_builds_do_and_report(tours, single, tmp_path, engine):
    out = tmp_path / "out"
    result = run_batch(_manifest(tours, THREE_SITES, f"three-{engine}.yaml"), out, engine=engine, workers=2)
    assert result.ok and result.engine == engine
    assert [r["key"] for r in result.rows] == ["st-marys/ward", "hq/floor2", "depot/depot"]
    # each map is what `semmap build` makes of the tour alone, byte for byte
    _same_maps(out / "st-marys" / "maps" / "ward", single / "ward")
    _same_maps(out / "hq" / "maps" / "floor2", single / "office")
    _same_maps(out / "depot" / "maps" / "depot", single / "depot")
    report = json.loads((out / "report.json").read_text())
    assert report["complete"] and report["engine"] == engine
    for row in report["tours"]:
        assert row["build"]["status"] == "built"
        summary = json.loads((Path(row["map"]) / "summary.json").read_text())
        assert row["build"]["scores"]["occupied_cells"] == summary["map"]["occupied_cells"] > 0
        assert row["build"]["scores"]["scans"] == summary["counts"]["scans"] > 0
        assert "diff" not in row  # no previous session given
    md = (out / "report.md").read_text()
    assert "| st-marys | ward | built |" in md and "3 tours, 0 failed; complete" in md


def test_a_failed_tour_does_not_stop_the_others_and_a_rerun_resumes(tours, tmp_path, capsys):
    """One tour fails (a broken bag): the others are built, the exit status says so and the report
    names the error. Run again: the built maps are kept untouched; the failed tour is tried again and,
    its bag fixed, built; a changed config rebuilds only the tours it applies to."""
    root = tmp_path
    (root / "tours").symlink_to(tours / "tours")
    (root / "incoming").mkdir()
    (root / "incoming" / "night.bag").write_bytes((tours / "broken.bag").read_bytes())
    manifest = _manifest(root, """
sites:
  - name: st-marys
    tours: [tours/ward, incoming/night.bag]
  - name: depot
    tours: [tours/depot]
""")
    out = root / "out"
    assert main(["batch", str(manifest), "--out", str(out), "--engine", "local", "-q"]) == 1
    err = capsys.readouterr().err
    assert "1 of 3 tours failed: st-marys/night" in err and "Traceback" not in err
    report = json.loads((out / "report.json").read_text())
    status = {r["key"]: r["build"]["status"] for r in report["tours"]}
    assert status == {"st-marys/ward": "built", "st-marys/night": "failed", "depot/depot": "built"}
    assert "not a ROS1 bag" in (out / "report.md").read_text()
    assert not (out / "st-marys" / "maps" / "night").exists()
    ward = out / "st-marys" / "maps" / "ward" / "map.pgm"
    mtime = ward.stat().st_mtime_ns

    # the bag arrives whole; run again
    (root / "incoming" / "night.bag").unlink()
    (root / "incoming" / "night.bag").symlink_to(tours / "tours" / "office" / "demo.bag")
    result = run_batch(manifest, out, engine="local")
    assert result.ok
    status = {r["key"]: r["build"]["status"] for r in result.rows}
    assert status == {"st-marys/ward": "up to date", "st-marys/night": "built", "depot/depot": "up to date"}
    assert ward.stat().st_mtime_ns == mtime
    assert (out / "st-marys" / "maps" / "night" / "map.yaml").is_file()

    # a new config for one site: its tours are built again, the other site's are not
    (root / "coarse.yaml").write_text("grid:\n  resolution: 0.1\n")
    manifest.write_text(manifest.read_text().replace("tours: [tours/depot]",
                                                     "config: coarse.yaml\n    tours: [tours/depot]"))
    result = run_batch(manifest, out, engine="local")
    status = {r["key"]: r["build"]["status"] for r in result.rows}
    assert status == {"st-marys/ward": "up to date", "st-marys/night": "up to date", "depot/depot": "built"}
    assert "resolution: 0.1" in (out / "depot" / "maps" / "depot" / "map.yaml").read_text()


@pytest.mark.parametrize("engine", [pytest.param("ray", marks=needs_ray), "local"])
def test_each_tour_is_diffed_against_its_previous_session(tours, single, tmp_path, engine):
    """Last week's maps as the previous sessions: a site-level folder of maps by tour name, and one
    tour's own; the same tours again change nothing, another tour in its place does."""
    (tmp_path / "tours").symlink_to(tours / "tours")
    last_week = tmp_path / "last_week"
    (last_week / "st-marys").mkdir(parents=True)
    (last_week / "st-marys" / "ward").symlink_to(single / "ward")
    manifest = _manifest(tmp_path, f"""
sites:
  - name: st-marys
    previous: last_week/st-marys
    tours: [tours/ward]
  - name: depot
    tours:
      - {{tour: tours/depot, previous: {single / 'ward'}}}
""")
    result = run_batch(manifest, tmp_path / "out", engine=engine)
    assert result.ok
    ward, depot = result.rows
    assert ward["diff"]["status"] == "done" and ward["diff"]["changes"] == {}
    assert (tmp_path / "out" / "st-marys" / "diffs" / "ward" / "changes.json").is_file()
    assert depot["diff"]["status"] == "done"
    assert depot["diff"]["alignment"]["residual_m"] < 0.05
    changes = json.loads((tmp_path / "out" / "depot" / "diffs" / "depot" / "changes.json").read_text())
    n = sum(depot["diff"]["changes"].values())
    assert n == len(changes["changes"])
    assert "no change" in (tmp_path / "out" / "report.md").read_text()


def test_a_bad_manifest_is_one_line_naming_the_field(tmp_path, capsys):
    cases = {
        "sites:\n  - name: a\n    tours: [x.bag]\n    colour: blue\n": "sites.0.colour: unknown key",
        "sites:\n  - name: a\n    tours: [x.bag]\n  - name: a\n    tours: [y.bag]\n": "listed twice",
        "sites:\n  - name: ../up\n    tours: [x.bag]\n": "not a usable folder name",
        "sites:\n  - name: a\n    tours: [x.bag, other/x.bag]\n": "named 'x'",
        "sites: []\n": "sites",
        "sites:\n  - name: a\n    tours: []\n": "sites.0.tours",
    }
    for i, (text, message) in enumerate(cases.items()):
        path = _manifest(tmp_path, text, f"m{i}.yaml")
        with pytest.raises(ConfigError, match=message):
            load_manifest(path, tmp_path / "out")
        assert main(["batch", str(path), "--out", str(tmp_path / f"out{i}")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(path) in err[0] and "Traceback" not in err[0]
        assert not (tmp_path / f"out{i}").exists()


def test_the_output_must_be_new_or_an_earlier_batch(tours, tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("keep me")
    with pytest.raises(OutputError, match="not a semmap batch folder"):
        run_batch(_manifest(tours, THREE_SITES, "three-out.yaml"), tmp_path / "notes", engine="local")
    assert (tmp_path / "notes" / "todo.txt").read_text() == "keep me"
    with pytest.raises(ConfigError, match="inside the output folder"):
        run_batch(_manifest(tours, THREE_SITES, "three-in.yaml"), tours, engine="local")
    with pytest.raises(ConfigError, match="--workers sizes a local Ray"):
        run_batch(_manifest(tours, THREE_SITES, "three-w.yaml"), tmp_path / "w", workers=2, address="auto")
    assert not (tmp_path / "w").exists()


def _descendants(pid: int) -> set[int]:
    out: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            with contextlib.suppress(OSError):
                for k in (task / "children").read_text().split():
                    if int(k) not in out:
                        out.add(int(k))
                        todo.append(int(k))
    return out


def _alive(pid: int) -> bool:
    return _running(pid)


@needs_ray
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_mid_run_leaves_no_process_and_no_half_written_map(tours, tmp_path, sig):
    """SIGTERM or Ctrl-C while Ray builds: the batch stops within seconds with 128 + the signal, every
    Ray process it started is gone, no hidden half-written map folder is left, and a map finished
    before the signal is whole (resumable)."""
    (tmp_path / "tours").symlink_to(tours / "tours")
    manifest = _manifest(tmp_path, THREE_SITES)
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "semmap", "batch", str(manifest), "--out", str(out),
                             "--engine", "ray", "--workers", "1"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # noqa: PLW1509
    seen: set[int] = set()
    end = time.monotonic() + 120
    try:
        while time.monotonic() < end:  # until a build is writing its map folder
            seen |= _descendants(proc.pid)
            if any(out.glob("*/maps/.*.partial")):
                break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        else:
            raise AssertionError("no build started")
        seen |= _descendants(proc.pid)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err
    assert seen, "Ray started no process"
    deadline = time.monotonic() + 15  # Ray's processes leave as the driver shuts them down
    while any(_alive(p) for p in seen) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [p for p in seen if _alive(p)]
    assert not left, [Path(f"/proc/{p}/cmdline").read_bytes()[:80] for p in left]
    # nothing half-written; a map that is there is whole (and the folder is gone if none was finished)
    assert not list(tmp_path.glob("**/.*.partial"))
    for folder in out.glob("*/maps/*"):
        assert (folder / "summary.json").is_file()


def _ray_build_workers() -> dict[int, set[int]]:
    """Ray worker processes running a build, and their children (the build's own workers)."""
    out: dict[int, set[int]] = {}
    for proc in Path("/proc").glob("[0-9]*"):
        with contextlib.suppress(OSError):
            if proc.joinpath("cmdline").read_bytes().startswith(b"ray::run_build"):
                out[int(proc.name)] = _descendants(int(proc.name))
    return out


@needs_ray
def test_a_ray_worker_killed_mid_build_is_retried_and_leaves_nothing(tours, single, tmp_path):
    """The out-of-memory killer takes a Ray worker in the middle of a build (SIGKILL): the build's own
    worker processes die with it, its half-written map folder is swept away, Ray runs the task again,
    and the batch ends with every map, equal to a single build's."""
    (tmp_path / "tours").symlink_to(tours / "tours")
    manifest = _manifest(tmp_path, THREE_SITES)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "semmap", "batch", str(manifest), "--out", str(out),
                             "--engine", "ray", "--workers", "1", "-q"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        end = time.monotonic() + 120
        victim: tuple[int, set[int]] | None = None
        while victim is None and time.monotonic() < end:
            assert proc.poll() is None, proc.communicate()
            if any(out.glob("*/maps/.*.partial")):
                victim = next(((p, kids) for p, kids in _ray_build_workers().items() if kids), None)
            time.sleep(0.02)
        assert victim is not None, "no build with worker processes was seen"
        os.kill(victim[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err
    deadline = time.monotonic() + 10
    while any(_alive(p) for p in victim[1]) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [p for p in victim[1] if _alive(p)], "the killed build's workers outlived it"
    assert not list(tmp_path.glob("**/.*.partial"))
    report = json.loads((out / "report.json").read_text())
    assert [r["build"]["status"] for r in report["tours"]] == ["built"] * 3
    _same_maps(out / "st-marys" / "maps" / "ward", single / "ward")
    _same_maps(out / "hq" / "maps" / "floor2", single / "office")
    _same_maps(out / "depot" / "maps" / "depot", single / "depot")


@needs_ray
def test_a_model_runs_in_a_gpu_task_of_its_own_and_the_build_reads_its_labels(tours, tmp_path, data_dir):
    """With --gpus-per-segment the tour whose config runs a model is segmented in a Ray task asking for a
    GPU (here the real selfie model, on a local Ray offering one GPU), and built from its labels in a
    task asking for none; the map folder's config says so; a rerun keeps both."""
    pytest.importorskip("ai_edge_litert")
    import yaml

    model = data_dir / "models" / "selfie_segmentation.tflite"
    (tmp_path / "tours").symlink_to(tours / "tours")
    (tmp_path / "selfie.yaml").write_text(f"segmentation:\n  backend: mediapipe-selfie\n  model: {model}\n")
    manifest = _manifest(tmp_path, """
sites:
  - name: st-marys
    config: selfie.yaml
    tours: [tours/ward]
  - name: depot
    tours: [tours/depot]
""")
    out = tmp_path / "out"
    result = run_batch(manifest, out, engine="ray", gpus_per_segment=1, local_gpus=1)
    assert result.ok
    ward, depot = result.rows
    assert ward["segment"]["status"] == "done" and ward["segment"]["images"] > 0
    assert ward["build"]["status"] == "built" and depot["build"]["status"] == "built"
    assert "segment" not in depot  # its labels come from the bag: nothing for a GPU to do
    labels = out / "st-marys" / "labels" / "ward" / "labels"
    assert (labels / "classes.json").is_file()
    assert len(list(labels.glob("*.png"))) == ward["segment"]["images"]
    cfg = yaml.safe_load((out / "st-marys" / "maps" / "ward" / "config.yaml").read_text())
    assert cfg["segmentation"]["backend"] == "folder"
    again = run_batch(manifest, out, engine="ray", gpus_per_segment=1, local_gpus=1)
    assert [r["build"]["status"] for r in again.rows] == ["up to date", "up to date"]
    # a GPU the cluster does not have is one clear error, before anything runs
    with pytest.raises(ConfigError, match="Ray sees 0 GPUs"):
        run_batch(manifest, tmp_path / "out2", engine="ray", gpus_per_segment=1, local_gpus=0)
    assert not (tmp_path / "out2").exists()
