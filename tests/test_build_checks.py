"""`semmap build` refuses contradictions, says when the camera labelled almost nothing and why,
finds the calibration in the bag, and writes a config that rebuilds the same map."""

import shutil
from dataclasses import replace

import numpy as np
import pytest
import yaml

from semmap import load_map
from semmap.errors import ConfigError
from semmap.pipeline import build
from semmap.sim.scenarios import demo
from semmap.sim.tour import simulate


@pytest.fixture(scope="module")
def tour(tmp_path_factory):
    return simulate(replace(demo().world, duration_s=8.0), tmp_path_factory.mktemp("tour") / "demo", seed=4)


@pytest.fixture(scope="module")
def with_file(tour, tmp_path_factory):
    """The map built with the tour's calibration file."""
    return build(tour.out, tmp_path_factory.mktemp("maps") / "file", overrides={"workers": False})


def test_calibration_found_in_the_bag(tour, with_file, tmp_path):
    """No calibration file: intrinsics from camera_info, T_cam_lidar from the /tf_static chain."""
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(tour.bag, bare / "demo.bag")
    res = build(bare / "demo.bag", tmp_path / "map", overrides={"workers": False})
    src = res.summary.tour.calibration
    assert "/camera/camera_info" in src and "laser" in src and "camera_optical_frame" in src
    assert res.summary.painting.scans_painted == with_file.summary.painting.scans_painted
    assert res.summary.painting.hits_by_class == with_file.summary.painting.hits_by_class


def test_no_calibration_anywhere_is_a_clear_error(tour, tmp_path):
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(tour.bag, bare / "demo.bag")
    with pytest.raises(ConfigError, match="no calibration file and no sensor_msgs/CameraInfo.*--calibration"):
        build(bare / "demo.bag", tmp_path / "map", overrides={"topics": {"camera_info": "none"}})
    assert not (tmp_path / "map").exists()


def test_odometry_mode_without_odometry_is_an_error(tour, tmp_path):
    with pytest.raises(ConfigError, match="registration.mode is 'odometry' but the tour has no odometry"):
        build(tour.out, tmp_path / "map", overrides={"topics": {"odometry": "none"},
                                                     "registration": {"mode": "odometry"}})
    assert not (tmp_path / "map").exists()


def test_a_tour_without_odometry_does_not_report_fused(tour, tmp_path):
    res = build(tour.out, tmp_path / "map", overrides={"topics": {"odometry": "none"}, "workers": False})
    assert res.summary.registration["mode"] == "icp"
    written = yaml.safe_load((res.out / "config.yaml").read_text())
    assert written["registration"]["mode"] == "icp" and written["topics"]["odometry"] == "none"


def test_scans_without_images_are_explained(tour, tmp_path, caplog):
    res = build(tour.out, tmp_path / "map", overrides={"sync": {"max_image_offset": 0.001}, "workers": False})
    assert res.summary.painting.scans_painted < 0.1 * res.summary.counts.scans
    msg = next(r.getMessage() for r in caplog.records if "paired with an image" in r.getMessage())
    assert "sync.max_image_offset (0.001 s)" in msg and "nearest image was typically" in msg
    assert any("paired with an image" in w for w in res.summary.warnings)


def test_a_calibration_into_the_camera_body_frame_is_explained(tour, tmp_path, caplog):
    """T_cam_lidar into the camera's body frame (x forward, z up), not its optical frame (z forward):
    every LiDAR point is below the camera, so 'behind' it, and none is painted."""
    from semmap.config import OPTICAL_RPY
    from semmap.geometry import se3_from_xyz_rpy, se3_inverse

    calib = yaml.safe_load((tour.out / "calibration.yaml").read_text())
    body = se3_from_xyz_rpy((0.0, 0.0, 0.0), OPTICAL_RPY) @ np.asarray(calib["T_cam_lidar"])
    calib["T_cam_lidar"], calib["T_lidar_cam"] = body.tolist(), se3_inverse(body).tolist()
    path = tmp_path / "body.yaml"
    path.write_text(yaml.safe_dump(calib))
    res = build(tour.out, tmp_path / "map", calibration=path, overrides={"workers": False})
    assert res.summary.painting.scans_painted == 0
    msg = next(r.getMessage() for r in caplog.records if "fell into the camera images" in r.getMessage())
    assert "behind the camera" in msg and "optical frame" in msg and "body.yaml" in msg


def test_config_yaml_rebuilds_the_same_map(tour, with_file, tmp_path):
    written = yaml.safe_load((with_file.out / "config.yaml").read_text())
    assert written["topics"]["scan"] == "/scan" and written["topics"]["labels"] == "/camera/labels"
    assert written["topics"]["odometry"] == "/odom" and written["frames"]["base"] == "base_link"
    assert written["calibration"] == str((tour.out / "calibration.yaml").resolve())
    again = build(tour.bag, tmp_path / "again", config=with_file.out / "config.yaml")
    a, b = load_map(with_file.out), load_map(again.out)
    assert np.array_equal(a.layers.log_odds, b.layers.log_odds) and np.array_equal(a.layers.mobility, b.layers.mobility)
    assert (with_file.out / "map.pgm").read_bytes() == (again.out / "map.pgm").read_bytes()
    assert b.summary.tour.topics.image == "/camera/labels" and b.config == a.config


def test_absurd_grid_memory_is_refused_before_any_work(tour, tmp_path, capsys):
    import time

    from semmap.cli.main import main

    cfg = tmp_path / "fine.yaml"
    cfg.write_text("grid:\n  resolution: 0.0001\n")
    t0 = time.perf_counter()
    assert main(["build", str(tour.out), "--config", str(cfg), "--out", str(tmp_path / "m")]) == 2
    assert time.perf_counter() - t0 < 5
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "grid.resolution 0.0001 m" in err and "needs" in err and "TiB" in err
    assert not (tmp_path / "m").exists() and not list(tmp_path.glob(".m.*"))


def test_verbose_says_what_was_detected_and_hides_other_libraries_debug(tour, tmp_path):
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "semmap", "build", str(tour.out), "--out", str(tmp_path / "m"),
                          "-vv", "-q"], capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr
    err = res.stderr
    assert "scans /scan (frame laser), odometry /odom, label images /camera/labels" in err
    assert "T_base_lidar (base_link -> laser) from the transform chain base_link -> laser" in err
    assert f"calibration {tour.out / 'calibration.yaml'}" in err
    assert "scans were paired with an image" in err
    assert "DEBUG semmap." in err  # -vv: semmap's own debug lines
    assert not [line for line in err.splitlines() if line.startswith("DEBUG") and " semmap." not in line]


def test_report_and_cli_state_how_registration_went(tour, with_file, tmp_path, capsys):
    from semmap.cli.main import main

    report = (with_file.out / "report.md").read_text()
    assert "ICP results used" in report and "rejected by the filter's gate" in report
    assert "the filter restarted" in report
    cfg = tmp_path / "c.yaml"
    cfg.write_text("workers: false\n")
    assert main(["build", str(tour.out), "--config", str(cfg), "--out", str(tmp_path / "m")]) == 0
    out = capsys.readouterr().out
    assert "ICP results used" in out and "rejected by the filter's gate" in out and "filter restarted" in out


def test_a_sweep_whose_middle_comes_after_the_next_scans_is_skipped_not_a_crash(tmp_path):
    """Scans ordered by their stamps are registered at their middle beam's time: a scan whose sweep
    is reported much longer than the others must not put the registration out of order."""
    from semmap.io.bag import BagWriter
    from semmap.records import Scan

    bag = tmp_path / "lidar.bag"
    n = 361
    angles = np.linspace(-np.pi / 2, np.pi / 2, n)
    ranges = np.minimum(3.0 / np.maximum(np.abs(np.cos(angles)), 1e-3), 3.0 / np.maximum(np.abs(np.sin(angles)), 1e-3))
    with BagWriter(bag, "ros1") as w:
        for k in range(60):
            stamp = 1_000_000_000 * 100 + k * 100_000_000
            sweep = 0.9 if k == 20 else 0.05  # scan 20 claims a 0.9 s sweep: its middle is after scan 21's
            w.scan("/scan", stamp, Scan(stamp, "laser", -np.pi / 2, np.pi / (n - 1), ranges.astype(np.float32),
                                        0.05, 10.0, sweep / n, 0.1))
    res = build(bag, tmp_path / "map", overrides={"workers": False, "topics": {"odometry": "none"}})
    assert res.summary.counts.scans_out_of_order >= 1
    assert res.summary.counts.scans + res.summary.counts.scans_out_of_order == 60
