"""Camera intrinsics from board images: chessboard and ChArUco (4x4 ArUco), pinhole and fisheye.

No photos of ArUco boards come with the project, so the images are rendered: the board's
texture seen through a known camera, lens distortion included, blurred and noisy.
"""

import cv2
import numpy as np
import pytest
import yaml

from semmap.calib.boards import BoardSpec, detect_board, parse_board_spec
from semmap.calib.intrinsics import calibrate_intrinsics
from semmap.calib.synth import board_poses_in_view, render_board_image
from semmap.cli.main import main
from semmap.errors import ConfigError
from semmap.io.calibration import read_intrinsics
from semmap.records import CameraIntrinsics

PINHOLE = CameraIntrinsics(640, 480, np.array([[600.0, 0, 322.0], [0, 602.0, 236.0], [0, 0, 1]]),
                           np.array([-0.28, 0.09, 0.001, -0.0005, 0.0]))
FISHEYE = CameraIntrinsics(480, 360, np.array([[220.0, 0, 242.0], [0, 220.0, 178.0], [0, 0, 1]]),
                           np.array([0.05, -0.01, 0.002, -0.001]), "fisheye")


@pytest.fixture(scope="module")
def chessboard_images():
    board = parse_board_spec("chessboard:9x6:0.03")
    poses = board_poses_in_view(board, PINHOLE, 8, (0.45, 0.9), seed=0)
    return board, [render_board_image(board, PINHOLE, T, seed=i) for i, T in enumerate(poses)]


def test_pinhole_chessboard_recovers_the_camera(chessboard_images):
    board, images = chessboard_images
    blank = np.full((480, 640), 120, np.uint8)
    r = calibrate_intrinsics([*images, blank], board)
    k = r.intrinsics
    assert abs(k.fx / 600.0 - 1) < 0.01 and abs(k.fy / 602.0 - 1) < 0.01
    assert abs(k.cx - 322.0) < 3 and abs(k.cy - 236.0) < 3
    assert abs(k.D[0] + 0.28) < 0.03
    assert r.rms_px < 0.3 and len(r.images) == 8
    assert all(im.rms_px < 0.5 for im in r.images)
    assert r.skipped == (("image 8", "board chessboard:9x6:0.03 not found"),)


def test_fisheye_charuco_4x4_recovers_the_camera():
    board = parse_board_spec("charuco:7x5:0.05:0.0375:4X4_50")
    poses = board_poses_in_view(board, FISHEYE, 7, (0.22, 0.4), max_angle_deg=30, seed=1)
    images = [render_board_image(board, FISHEYE, T, seed=i) for i, T in enumerate(poses)]
    r = calibrate_intrinsics(images, board, model="fisheye")
    k = r.intrinsics
    assert k.model == "fisheye" and k.D.size == 4
    assert abs(k.fx / 220.0 - 1) < 0.01 and abs(k.cx - 242.0) < 3 and abs(k.cy - 178.0) < 3
    assert r.rms_px < 0.4


def test_aruco_grid_board_is_detected():
    board = parse_board_spec("aruco:4x3:0.04:0.01:DICT_4X4_50")
    T = board_poses_in_view(board, PINHOLE, 1, (0.35, 0.45), seed=2)[0]
    det = detect_board(render_board_image(board, PINHOLE, T), board)
    assert det is not None and len(det) == 4 * 12  # every marker's four corners


@pytest.mark.parametrize("spec, parsed", [
    ("chessboard:11x8:0.02", BoardSpec("chessboard", 11, 8, 0.02)),
    ("checkerboard:7X10:0.025", BoardSpec("chessboard", 7, 10, 0.025)),
    ("charuco:5x7:0.04:0.03:DICT_4X4_50", BoardSpec("charuco", 5, 7, 0.04, 0.03, "4X4_50")),
    ("charuco:5x7:0.04:0.03:4x4_100:legacy", BoardSpec("charuco", 5, 7, 0.04, 0.03, "4X4_100", legacy=True)),
    ("aruco:5x7:0.04:0.01:4X4_250", BoardSpec("aruco", 5, 7, 0.04, 0.01, "4X4_250")),
])
def test_board_spec_syntax(spec, parsed):
    assert parse_board_spec(spec) == parsed
    assert parse_board_spec(str(parsed)) == parsed


@pytest.mark.parametrize("spec, match", [
    ("chessboard:11:0.02", "expected chessboard:COLSxROWS:SQUARE"),
    ("chessboard:11x8:big", "square size missing or not a number"),
    ("charuco:5x7:0.04:0.05:4X4_50", "the marker must be smaller than the square"),
    ("charuco:5x7:0.04:0.03:4X4_51", "unknown ArUco dictionary '4X4_51'"),
    ("circles:4x11:0.02", "expected chessboard"),
])
def test_bad_board_specs_say_what_is_wrong(spec, match):
    with pytest.raises(ConfigError, match=match):
        parse_board_spec(spec)


def test_cli_writes_k_d_rms_and_each_image_error(tmp_path, chessboard_images, capsys):
    board, images = chessboard_images
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i, im in enumerate(images[:6]):
        cv2.imwrite(str(folder / f"view{i}.png"), im)
    cv2.imwrite(str(folder / "blank.png"), np.full((480, 640), 90, np.uint8))
    out = tmp_path / "camera.yaml"
    code = main(["calibrate", "intrinsics", str(folder), "--board", str(board), "--out", str(out)])
    assert code == 0
    assert "blank.png" in capsys.readouterr().out
    data = yaml.safe_load(out.read_text())
    intr = data["intrinsics"]
    assert intr["model"] == "pinhole" and (intr["width"], intr["height"]) == (640, 480)
    assert len(intr["D"]) == 5 and intr["rms_px"] < 0.3
    assert sorted(i["file"] for i in intr["images"]) == [f"view{i}.png" for i in range(6)]
    assert intr["skipped"] == [{"file": "blank.png", "reason": "board chessboard:9x6:0.03 not found"}]
    assert abs(read_intrinsics(out).fx / 600.0 - 1) < 0.01


def test_cli_too_few_boards_is_one_line(tmp_path, capsys):
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"b{i}.png"), np.full((48, 64), 90, np.uint8))
    code = main(["calibrate", "intrinsics", str(tmp_path), "--board", "chessboard:9x6:0.03",
                 "--out", str(tmp_path / "c.yaml")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "found in 0 of 3 images" in err
