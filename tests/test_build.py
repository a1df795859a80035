"""`semmap build` end to end: the map folder, its quality against ground truth, and its errors."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from semmap.cli.main import main
from semmap.errors import BagError
from semmap.io.mapserver import read_map
from semmap.io.tum import read_tum
from semmap.mapfolder.report import loops_line
from semmap.pipeline import build
from semmap.sim.scenarios import demo
from semmap.sim.score import score_map
from semmap.sim.tour import simulate

MAP_FILES = {"map.yaml", "map.pgm", "semantic.png", "semi_static.yaml", "semi_static.pgm",
             "semi_static_objects.json", "grid.npz", "trajectory.tum", "odometry.tum", "config.yaml",
             "summary.json", "report.md", "report/trajectory.png", "report/classes.png"}


def test_map_folder_has_every_file_and_loads_like_map_server(demo_map):
    files = {p.relative_to(demo_map.out).as_posix() for p in demo_map.out.rglob("*") if p.is_file()}
    assert files >= MAP_FILES
    m = read_map(demo_map.out / "map.yaml")
    assert m.spec.resolution == 0.05 and m.occupied.sum() > 500 and m.free.sum() > 10 * m.occupied.sum()
    grid = np.load(demo_map.out / "grid.npz")  # no pickle needed
    assert grid["log_odds"].shape == m.spec.shape and grid["mobility"].shape[0] == 4
    summary = json.loads((demo_map.out / "summary.json").read_text())
    assert summary["counts"]["scans"] == 418 and summary["painting"]["scans_painted"] == 418
    assert summary["registration"]["icp_rejected"] <= 2
    objs = json.loads((demo_map.out / "semi_static_objects.json").read_text())["objects"]
    assert {"chair", "couch"} <= {o["class"] for o in objs}
    # the sightings the object list was grouped by: scans in range, cells on the flagged furniture
    s = grid["sightings"]
    assert s.shape[1] == 4 and s.shape[0] > 1000
    assert s[:, 0].min() >= 0 and s[:, 0].max() < 418
    near = grid["semi_static"][s[:, 2], s[:, 3]]
    assert near.mean() > 0.8
    assert max(o["views"] for o in objs) <= 418


def test_demo_map_matches_the_ground_truth(demo_tour, demo_map):
    s = score_map(demo_tour.out, demo_map.out)
    assert s["ate_rmse_m"] < 0.03
    assert s["precision"] > 0.95 and s["recall"] > 0.9
    assert s["ghost_rate"] < 0.01  # the standing person and the walking one are gone


def test_worker_processes_and_one_process_build_the_same_map(demo_tour, demo_map, tmp_path):
    single = build(demo_tour.out, tmp_path / "single", overrides={"workers": False})
    a, b = np.load(demo_map.out / "grid.npz"), np.load(single.out / "grid.npz")
    assert np.array_equal(a["log_odds"], b["log_odds"]) and np.array_equal(a["mobility"], b["mobility"])
    assert np.array_equal(a["sightings"], b["sightings"])
    assert read_tum(demo_map.out / "trajectory.tum")[1] == pytest.approx(read_tum(single.out / "trajectory.tum")[1])
    # CPU time per process: every worker did its share (raw label images are read in the main process,
    # with no frame worker); one process does it all itself
    cpu = json.loads((demo_map.out / "summary.json").read_text())["cpu_s"]
    assert set(cpu) == {"main", "registration", "fusion", "total", "per_scan_ms"}
    assert min(cpu["registration"], cpu["fusion"]) > 0
    assert cpu["total"] == pytest.approx(cpu["main"] + cpu["registration"] + cpu["fusion"], abs=0.01)
    assert cpu["per_scan_ms"] == pytest.approx(1000 * cpu["total"] / 418, rel=0.01)
    assert set(single.summary.cpu_s) == {"main", "total", "per_scan_ms"}

def test_loop_closure_in_the_fusion_worker_gives_the_map_one_process_gives(demo_tour, tmp_path):
    # with workers, the loop closer runs in the fusion worker (off the registration's critical path),
    # fed each scan's points by the registration worker, and the grid is fused from the corrected poses
    # by two processes (the fusion worker the first half of the tour, this process the rest): the same
    # graph, poses and grid, every layer of it, as in one process
    lc = {"registration": {"loop_closure": {"enabled": True}}}
    two = build(demo_tour.out, tmp_path / "workers", overrides=lc)
    one = build(demo_tour.out, tmp_path / "single", overrides={**lc, "workers": False})
    a, b = np.load(two.out / "grid.npz"), np.load(one.out / "grid.npz")
    assert sorted(a.files) == sorted(b.files)
    for k in a.files:
        assert np.array_equal(a[k], b[k]), k
    assert read_tum(two.out / "trajectory.tum")[1] == pytest.approx(read_tum(one.out / "trajectory.tum")[1])
    loops = [json.loads((r.out / "summary.json").read_text())["registration"]["loop_closure"] for r in (two, one)]
    assert loops[0]["keyframes"] == loops[1]["keyframes"] > 10
    assert loops[0]["rematched"] == loops[1]["rematched"] > 0 and loops[0]["loops"] == loops[1]["loops"]
    # the loop closer's time counts as registration's
    reg = json.loads((two.out / "summary.json").read_text())["registration"]
    assert reg["seconds"] >= loops[0]["seconds_search"] + loops[0]["seconds_rematch"]
    # and the report says what it did
    assert f"Loop closure: {loops_line(reg)}." in (two.out / "report.md").read_text()


def test_the_loop_closure_line_says_whether_loops_closed_and_why_not():
    stats = {"keyframes": 40, "candidates": 14, "verified": 12, "loops": [[1, 35], [2, 36]],
             "max_correction_m": 0.213, "max_correction_rad": 0.04, "rematched": 30, "rematch_kept": 9}
    assert loops_line({"mode": "fused"}) is None  # loop closure off
    # (the steps re-fitted are those whose re-fit was taken, not those that kept the registration's step)
    assert loops_line({"loop_closure": stats}) == ("2 loops closed (12 places verified among 40 keyframes), largest "
                                                   "correction 0.21 m and 2.3°; 30 of 39 keyframe steps re-fitted "
                                                   "to the keyframe before")
    assert loops_line({"loop_closure": {**stats, "loops": [], "rematched": 0}}) == (
        "no loop found (12 places verified among 40 keyframes, none matched well enough)")
    # places found, each beyond the gate before any ICP: the tour did come back near them
    assert loops_line({"loop_closure": {**stats, "loops": [], "verified": 0, "rematched": 0}}) == (
        "no loop found (0 places verified among 40 keyframes, none matched well enough)")
    assert loops_line({"loop_closure": {**stats, "loops": [], "candidates": 0, "verified": 0, "rematched": 0}}) == (
        "no loop found (the tour came back to no place it had passed: 40 keyframes)")



@pytest.mark.parametrize("fmt", ["mcap", "sqlite3"])
def test_ros2_tours_with_jpeg_images_and_mono8_labels(tmp_path, fmt):
    world = replace(demo().world, duration_s=8.0)
    tour = simulate(world, tmp_path / "tour", fmt=fmt, seed=1,
                    config={"camera": {"image_format": "jpeg", "label_encoding": "mono8"}})
    res = build(tour.out, tmp_path / "map")
    assert res.summary.tour.topics.image == "/camera/labels"
    assert res.summary.painting.hits_by_mobility["dynamic"] > 50
    assert res.summary.painting.hits_by_class["person"] > 50


def test_calibration_for_another_image_size_is_a_one_line_error(capsys, demo_tour, tmp_path):
    from semmap.io.yamlio import read_yaml

    calib = read_yaml(demo_tour.out / "calibration.yaml")
    calib["intrinsics"]["width"], calib["intrinsics"]["height"] = 1280, 960  # the camera's full resolution
    path = tmp_path / "calib_1280.yaml"
    path.write_text(yaml.safe_dump(calib))
    code = main(["build", str(demo_tour.out), "--out", str(tmp_path / "m"), "--calibration", str(path)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 3 and "Traceback" not in "".join(lines)
    assert lines[0].startswith("WARNING") and "/camera/camera_info says 640x480" in lines[0]  # seen early
    err = lines[-1]  # then one error line
    assert len(lines) == 2 and err.startswith("semmap build: error:")
    assert "/camera/labels" in err and "640x480" in err and "1280x960" in err
    assert not (tmp_path / "m").exists()


def test_missing_topic_is_a_clear_error(demo_tour, tmp_path):
    with pytest.raises(BagError, match="topic /front_scan .*not in the bag"):
        build(demo_tour.out, tmp_path / "map", overrides={"topics": {"scan": "/front_scan"}})


def test_cli_build_one_line_errors(capsys, tmp_path, demo_tour):
    code = main(["build", str(demo_tour.out), "--out", str(tmp_path / "m"), "--config", str(tmp_path / "nope.yaml")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "nope.yaml" in err
    code = main(["build", "--out", str(tmp_path / "m")])
    assert code == 2 and "TOUR or --demo" in capsys.readouterr().err


def test_lidar_only_real_bag(data_dir, tmp_path, caplog):
    """A stationary sensor, no camera, no odometry: people walking through leave the map."""
    from pathlib import Path

    from semmap.grid.metrics import points_to_mask
    from semmap.io.bag import iter_messages

    bag = data_dir / "leg_tracker" / "positive_3_extracted.bag"
    over = {"topics": {"scan": "/training_scan", "odometry": "none"}, "registration": {"mode": "icp"}}
    res = build(bag, tmp_path / "legs", overrides=over)
    assert res.summary.counts.scans == 175
    assert res.summary.tour.frames.base == "right_laser"
    assert "below range_min" in caplog.text  # the Hokuyo's "nothing seen" codes are pointed out
    _, poses = read_tum(res.out / "trajectory.tum")
    assert np.abs(poses[:, :2]).max() < 0.05  # the sensor did not move
    # with the driver's codes read as "no return", the legs' cells are cleared again
    fixed = build(bag, tmp_path / "legs2", overrides={**over, "paint": {"below_range_min": "no_return"}})
    legs = np.array([(p.position.x, p.position.y) for _, _, m in iter_messages(bag, ["/leg_cluster_positions"])
                     for p in m.poses])

    def left(mapdir: Path) -> float:
        occ = read_map(mapdir / "map.yaml")
        cells = points_to_mask(legs, occ.spec)
        return float((occ.occupied & cells).sum() / cells.sum())

    assert left(fixed.out) < 0.05 < left(res.out)


def test_load_map_reads_back_what_build_wrote(demo_map):
    """semmap.load_map: the map as map_server loads map.yaml, the layers, objects, trajectory, config and
    summary, all equal to what the build wrote."""
    import semmap

    m = semmap.load_map(demo_map.out)
    assert m.summary == demo_map.summary
    seen = read_map(demo_map.out / "map.yaml")
    assert m.spec == seen.spec
    assert np.array_equal(m.occupied, seen.occupied) and np.array_equal(m.unknown, seen.unknown)
    grid = np.load(demo_map.out / "grid.npz")
    assert np.array_equal(m.occupied, grid["occupied"]) and np.array_equal(m.semi_static, grid["semi_static"])
    assert np.array_equal(m.layers.sightings, grid["sightings"]) and m.layers.n_scans == 418
    assert m.semi_static.sum() == m.summary.map.semi_static_cells > 0
    objs = json.loads((demo_map.out / "semi_static_objects.json").read_text())["objects"]
    assert [o.as_dict() for o in m.objects] == objs
    assert m.poses.shape == (418, 3) and m.odometry.shape == (418, 3)
    assert m.config.registration.mode == "fused" and m.class_names[0] == "person"


def test_load_map_reads_a_version_1_folder(demo_map, tmp_path):
    """A map folder written before camera images were renamed (``map_folder_version`` 1, where they
    were "frames"; tests/data/demo_summary_v1.json is the demo's summary from commit 9a59013) reads
    back with version 2's names and the same numbers."""
    import shutil

    import semmap

    folder = tmp_path / "m"
    shutil.copytree(demo_map.out, folder)
    v1 = json.loads((Path(__file__).parent / "data" / "demo_summary_v1.json").read_text())
    assert v1["map_folder_version"] == 1 and "frames" in v1["counts"]
    shutil.copy(Path(__file__).parent / "data" / "demo_summary_v1.json", folder / "summary.json")
    m = semmap.load_map(folder)
    assert m.summary.map_folder_version == 2
    assert m.summary.counts.images == v1["counts"]["frames"] == 140
    assert m.summary.counts.bad_images == v1["counts"]["bad_frames"] == 0
    assert m.summary.tour.topics.image == "/camera/labels" and m.summary.tour.topics.image_kind == "labels"
    # the numbers are the file's (the demo's map has changed since 9a59013 with registration and cleaning)
    assert m.summary.counts.scans == v1["counts"]["scans"] == demo_map.summary.counts.scans
    assert m.summary.map.model_dump(mode="json", exclude_unset=True) == v1["map"]
    assert m.summary.map.grid_bytes is None  # (figures the first folders did not have)
    assert json.loads(demo_map.summary.to_json())["counts"]["images"] == 140  # today's folders say "images"


def test_load_map_refuses_another_layout_and_names_the_file(demo_map, tmp_path):
    import shutil

    import semmap
    from semmap.errors import MapFolderError

    folder = tmp_path / "m"
    shutil.copytree(demo_map.out, folder)
    summary = json.loads((folder / "summary.json").read_text())
    summary["map_folder_version"] = 99
    (folder / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(MapFolderError, match=r"summary.json: map_folder_version 99; this semmap reads versions 1 to 2"):
        semmap.load_map(folder)
    summary["map_folder_version"] = 1
    (folder / "summary.json").write_text(json.dumps(summary))
    (folder / "grid.npz").write_bytes(b"not a zip")
    with pytest.raises(MapFolderError, match=r"grid.npz: not a readable grid"):
        semmap.load_map(folder)
    (folder / "grid.npz").unlink()
    with pytest.raises(MapFolderError, match=r"grid.npz: missing"):
        semmap.load_map(folder)
    assert MapFolderError.exit_code == 7


def test_a_lidar_mounted_upside_down_maps_the_room_as_an_upright_one_does(tmp_path):
    """A LiDAR rolled half a turn (under a bumper) sweeps the other way: its beam at +a in its own frame
    points at -a in the base frame. The transform in /tf_static says so, and the map must follow it: the
    same room as with the LiDAR upright, every wall single. (The simulator cast such beams the upright
    way until stop 53; the build, reading /tf_static right, then scored 71 % agreement.)"""
    from semmap.grid.metrics import _lookup
    from semmap.sim.groundtruth import true_beam_end_points

    over = {"lidar": {"mount": {"xyz": [0.38, 0.23, 0.2], "rpy": [np.pi, 0.0, 0.785398]}}}
    tour = simulate(demo(), tmp_path / "flip", seed=0, config=over)
    # the simulator's own truth: its beams end on its walls
    truth = read_map(tour.out / "ground_truth" / "occupancy.yaml")
    grown = truth.occupied.copy()
    for axis in (0, 1):
        grown |= np.roll(grown, 1, axis) | np.roll(grown, -1, axis)
    ends = true_beam_end_points(tour.out, exclude_dynamic=True)
    assert _lookup(ends, grown, truth.spec).mean() > 0.97
    res = build(tour.out, tmp_path / "map")
    s = score_map(tour.out, res.out)
    assert s["f1"] >= 0.99 and s["standing_left"] == 0.0
    assert res.summary.consistency.endpoints_on_map > 0.95
