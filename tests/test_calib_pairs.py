"""Hong et al.'s manual method: LiDAR-point ↔ pixel pairs → T_cam_lidar, robust and guess-free."""

import numpy as np
import pytest

from semmap.calib.common import pose_error
from semmap.calib.extrinsics import calibrate_from_pairs
from semmap.calib.pairs import PointPixelPairs, read_pairs, write_pairs
from semmap.calib.synth import sim_calibration_truth, sim_intrinsics, simulate_pairs
from semmap.cli.main import main
from semmap.errors import ConfigError
from semmap.geometry import se3_from_xyz_rpy, se3_inverse
from semmap.io.calibration import read_calibration, write_intrinsics
from semmap.records import CameraIntrinsics

TRUTH = sim_calibration_truth()
INTR = sim_intrinsics()


@pytest.mark.parametrize("seed", range(5))
def test_30_clean_pairs_with_1px_noise_meet_the_targets(seed):
    pairs, _ = simulate_pairs(TRUTH, INTR, n=30, noise_px=1.0, seed=seed)
    r = calibrate_from_pairs(pairs, INTR, seed=seed)
    rot, trans = pose_error(r.T_cam_lidar, TRUTH)
    assert rot <= 0.3 and trans <= 0.01
    assert r.n_inliers == 30
    assert 1.0 < r.rms_px < 1.8  # 1 px per axis → about 1.4 px RMS


@pytest.mark.parametrize("seed", range(5))
def test_20_percent_gross_outliers_are_found_and_do_not_hurt(seed):
    pairs, truly_inlier = simulate_pairs(TRUTH, INTR, n=30, noise_px=1.0, outlier_fraction=0.2, seed=seed)
    r = calibrate_from_pairs(pairs, INTR, seed=seed)
    rot, trans = pose_error(r.T_cam_lidar, TRUTH)
    assert rot <= 0.6 and trans <= 0.02
    assert np.array_equal(r.inliers, truly_inlier)
    worst = r.worst(6)
    assert {w.index for w in worst} == set(np.flatnonzero(~truly_inlier))
    assert all(not w.inlier for w in worst)


def test_no_initial_guess_needed_for_an_upside_down_lidar_behind_the_camera():
    T_base_lidar = se3_from_xyz_rpy([-0.2, 0.1, 0.6], [np.pi, 0.0, 2.5])  # flipped, facing backwards-ish
    T_base_cam = se3_from_xyz_rpy([0.3, 0.0, 0.3], [-np.pi / 2, 0.0, -np.pi / 2])
    truth = se3_inverse(T_base_cam) @ T_base_lidar
    pairs, _ = simulate_pairs(truth, INTR, n=30, noise_px=1.0, outlier_fraction=0.2, seed=7)
    r = calibrate_from_pairs(pairs, INTR)
    rot, trans = pose_error(r.T_cam_lidar, truth)
    assert rot < 0.6 and trans < 0.02


def test_pixels_picked_on_an_undistorted_image():
    distorted = CameraIntrinsics(640, 480, INTR.K, np.array([-0.3, 0.1, 0.0, 0.0, 0.0]))
    # Hong's tool: the person picks on an image undistorted with the same K
    pairs, _ = simulate_pairs(TRUTH, INTR, n=30, noise_px=1.0, seed=3)
    ok = calibrate_from_pairs(pairs, distorted, undistorted=True)
    wrong = calibrate_from_pairs(pairs, distorted, undistorted=False)
    assert pose_error(ok.T_cam_lidar, TRUTH)[0] < 0.3 and ok.rms_px < 1.8
    assert wrong.rms_px > 2 * ok.rms_px  # the option matters, and the RMS shows it


def test_hong_data_txt_and_csv_read_the_same(tmp_path):
    pairs, _ = simulate_pairs(TRUTH, INTR, n=12, seed=1)
    a = read_pairs(write_pairs(tmp_path / "data.txt", pairs, "hong"))
    b = read_pairs(write_pairs(tmp_path / "pairs.csv", pairs, "csv"))
    assert np.allclose(a.lidar_xy, pairs.lidar_xy, atol=1e-6) and np.allclose(a.pixels, pairs.pixels, atol=1e-3)
    assert np.allclose(a.lidar_xy, b.lidar_xy) and np.allclose(a.pixels, b.pixels)
    # CSV with other column names and order, comments and blank lines
    (tmp_path / "c.csv").write_text("# picked by hand\nu,v,laser_x,laser_y\n\n1404,1542,-1.719532,0.319881\n")
    c = read_pairs(tmp_path / "c.csv")
    assert c.lidar_xy.tolist() == [[-1.719532, 0.319881]] and c.pixels.tolist() == [[1404.0, 1542.0]]
    assert c.lines == (4,)


@pytest.mark.parametrize("text, match", [
    ("1 2 3 4\n1 2 3\n", r"data.txt: line 2: expected 4 numbers"),
    ("1 2 3 4\n1 2 x 4\n", r"data.txt: line 2: u is not a number"),
    ("", r"data.txt: pairs file holds no pairs"),
])
def test_bad_pairs_files_name_the_file_and_line(tmp_path, text, match):
    p = tmp_path / "data.txt"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match):
        read_pairs(p)


def test_csv_without_a_pixel_column(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("x,y,u\n1,2,3\n")
    with pytest.raises(ConfigError, match=r"p.csv: line 1: CSV header has no column 'v'"):
        read_pairs(p)


def test_too_few_or_collinear_pairs_are_refused():
    few = PointPixelPairs(np.ones((4, 2)), np.ones((4, 2)), source="data.txt")
    with pytest.raises(ConfigError, match="data.txt: 4 pairs; need at least 6"):
        calibrate_from_pairs(few, INTR)
    x = np.linspace(1, 3, 10)
    line = PointPixelPairs(np.column_stack([x, 0.5 * x]), np.ones((10, 2)), source="data.txt")
    with pytest.raises(ConfigError, match="data.txt: the LiDAR points lie on one line"):
        calibrate_from_pairs(line, INTR)


def test_cli_writes_both_transforms_and_the_report(tmp_path, capsys):
    pairs, truly_inlier = simulate_pairs(TRUTH, INTR, n=30, outlier_fraction=0.2, seed=2)
    write_pairs(tmp_path / "data.txt", pairs)
    write_intrinsics(tmp_path / "camera.yaml", INTR, {"rms_px": 0.2})
    out = tmp_path / "calib.yaml"
    code = main(["calibrate", "extrinsics", "--pairs", str(tmp_path / "data.txt"), "--intrinsics",
                 str(tmp_path / "camera.yaml"), "--out", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "OUTLIER" in text and "T_cam_lidar (LiDAR points into the camera)" in text
    calib = read_calibration(out)
    assert pose_error(calib.T_cam_lidar, TRUTH)[0] < 0.6
    import yaml

    data = yaml.safe_load(out.read_text())
    rep = data["extrinsics"]
    assert rep["pairs"] == 30 and rep["inliers"] == 24 and len(rep["residuals_px"]) == 30
    assert sorted(rep["outlier_lines"]) == sorted((np.flatnonzero(~truly_inlier) + 1).tolist())
    assert data["intrinsics"]["rms_px"] == 0.2  # the camera's report is kept
    # once written, it is not overwritten without --force
    code = main(["calibrate", "extrinsics", "--pairs", str(tmp_path / "data.txt"), "--intrinsics",
                 str(tmp_path / "camera.yaml"), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 4 and len(err.splitlines()) == 1 and "calib.yaml" in err and "--force" in err


def test_cli_missing_pairs_file_is_one_line(tmp_path, capsys):
    write_intrinsics(tmp_path / "camera.yaml", INTR)
    code = main(["calibrate", "extrinsics", "--pairs", str(tmp_path / "nope.txt"), "--intrinsics",
                 str(tmp_path / "camera.yaml"), "--out", str(tmp_path / "c.yaml")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "nope.txt: cannot read pairs file" in err
