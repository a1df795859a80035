"""Automatic T_cam_lidar from board observations (Zhang & Pless): simulated truth and the real ACFR pairs."""

import math

import numpy as np
import pytest
import yaml

from semmap.calib.boards import BoardDetection, parse_board_spec
from semmap.calib.common import pose_error
from semmap.calib.synth import sim_calibration_truth, sim_intrinsics, simulate_board_views
from semmap.calib.target import (
    TargetObservation,
    board_plane,
    calibrate_target,
    find_board_segments,
)
from semmap.calib.workflow import pair_by_stamp
from semmap.cli.main import main
from semmap.errors import ConfigError
from semmap.io.calibration import read_calibration, write_intrinsics
from semmap.records import CameraIntrinsics

TRUTH = sim_calibration_truth()
INTR = sim_intrinsics()
BOARD = parse_board_spec("chessboard:9x6:0.06")

ACFR_K = [[519.26845842, 0, 331.11197675], [0, 518.89359517, 229.43433605], [0, 0, 1]]
ACFR_D = [0.11418155, 0.19343114, -0.00268067, 0.00371577, -1.09539701]


def _observations(views):
    planes = [board_plane(BoardDetection(v.object_points, v.corners_px), INTR) for v in views]
    segs = find_board_segments([v.scan_xy for v in views], planes, board_width_m=min(BOARD.size_m))
    obs = [TargetObservation(f"v{i}", BoardDetection(v.object_points, v.corners_px), pl, v.scan_xy,
                             None if s is None else s.indices)
           for i, (v, pl, s) in enumerate(zip(views, planes, segs))]
    return obs, segs


def test_simulated_boards_recover_the_truth_within_half_a_degree_and_2cm():
    views = simulate_board_views(TRUTH, INTR, BOARD, n_views=20, tilt_deg=(10, 40), seed=1)
    obs, segs = _observations(views)
    # the board's line is found in every scan, and only board points are taken
    for v, s in zip(views, segs):
        assert s is not None and np.all(v.board_mask[s.indices])
    r = calibrate_target(obs, INTR)
    rot, trans = pose_error(r.T_cam_lidar, TRUTH)
    assert rot <= 0.5 and trans <= 0.02
    assert not r.unobservable
    assert 5 < r.rms_mm < 15  # 1 cm range noise
    assert r.normal_spread_deg > 10


def test_vertical_boards_leave_height_and_tilt_unobservable_and_say_so():
    views = simulate_board_views(TRUTH, INTR, BOARD, n_views=12, tilt_deg=(0, 0), seed=2)
    obs, _ = _observations(views)
    r = calibrate_target(obs, INTR)
    assert set(r.unobservable) == {"rotation about lidar x", "rotation about lidar y", "translation along lidar z"}
    assert r.normal_spread_deg < 1.0
    # what vertical boards do constrain is right: yaw and the LiDAR's position in the scan plane
    T_lidar_cam_est, T_lidar_cam_true = np.linalg.inv(r.T_cam_lidar), np.linalg.inv(TRUTH)
    yaw = lambda T: math.atan2(T[1, 0], T[0, 0])  # noqa: E731
    assert abs(math.degrees(yaw(T_lidar_cam_est) - yaw(T_lidar_cam_true))) < 0.5
    assert np.linalg.norm(T_lidar_cam_est[:2, 3] - T_lidar_cam_true[:2, 3]) < 0.02
    # the height is held at the prior (the linear solution: the scan plane through the camera)
    assert abs(T_lidar_cam_est[2, 3]) < 1e-6
    # a prior (e.g. from the URDF) supplies it instead
    r2 = calibrate_target(obs, INTR, prior_T_cam_lidar=TRUTH)
    assert pose_error(r2.T_cam_lidar, TRUTH)[1] < 0.02


def test_boards_all_facing_one_way_are_refused():
    views = simulate_board_views(TRUTH, INTR, BOARD, n_views=6, seed=3)
    obs, _ = _observations(views)
    same = [TargetObservation(o.name, o.detection, obs[0].plane, o.scan_xy, o.board_indices) for o in obs]
    with pytest.raises(ConfigError, match="every board faces the same way"):
        calibrate_target(same, INTR)


def test_pairing_by_nanosecond_names(tmp_path):
    ims = [tmp_path / f"{t}.png" for t in (1000_000_000, 2000_000_000)]
    scans = [tmp_path / f"{t}.pcd" for t in (2010_000_000, 990_000_000)]
    pairs = pair_by_stamp(ims, scans)
    assert [(a.stem, b.stem) for a, b, _ in pairs] == [("1000000000", "990000000"), ("2000000000", "2010000000")]
    assert pairs[0][2] == pytest.approx(-0.01)


@pytest.fixture(scope="module")
def acfr(data_dir, tmp_path_factory):
    d = data_dir / "acfr_calib" / "examples"
    if not d.is_dir():
        pytest.skip(f"ACFR calibration pairs not found at {d}")
    tmp = tmp_path_factory.mktemp("acfr")
    write_intrinsics(tmp / "camera.yaml", CameraIntrinsics(640, 480, np.array(ACFR_K), np.array(ACFR_D)))
    return d, tmp


def test_acfr_real_pairs_calibrate_automatically(acfr, capsys):
    """Five real image+scan pairs of an 11x8 (inner corners), 20 mm chessboard on a panel, with a
    TurtleBot3's 2D LiDAR (the INTRINSICS.txt note says 7x10: the images and the PDF say 11x8)."""
    d, tmp = acfr
    out = tmp / "calib.yaml"
    code = main(["calibrate", "target", "--images", str(d / "images"), "--scans", str(d / "lasers"),
                 "--board", "chessboard:11x8:0.02", "--intrinsics", str(tmp / "camera.yaml"), "--out", str(out),
                 "--check-dir", str(tmp / "checks")])
    assert code == 0
    rep = yaml.safe_load(out.read_text())["extrinsics"]
    assert rep["views"] == 5 and rep["skipped"] == []
    assert rep["rms_mm"] < 12  # line-to-plane, all boards
    assert all(v["points"] >= 30 and v["rms_mm"] < 15 for v in rep["per_view"])
    # the boards stand vertical: the scan plane's height cannot be seen, and the report says so
    assert "translation along lidar z" in rep["unobservable"]
    T_lidar_cam = read_calibration(out).T_lidar_cam
    # the camera looks along the LiDAR's x axis, a few centimetres from it
    assert T_lidar_cam[:3, 2] @ np.array([1.0, 0, 0]) > 0.99
    assert np.linalg.norm(T_lidar_cam[:3, 3]) < 0.15
    assert len(list((tmp / "checks").glob("check_*.png"))) == 5


def test_acfr_with_the_wrong_board_size_is_one_clear_line(acfr, capsys):
    d, tmp = acfr
    code = main(["calibrate", "target", "--images", str(d / "images"), "--scans", str(d / "lasers"),
                 "--board", "chessboard:7x10:0.02", "--intrinsics", str(tmp / "camera.yaml"),
                 "--out", str(tmp / "c.yaml")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "chessboard:7x10:0.02 found in 0 of 5 images" in err
