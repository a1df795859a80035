"""`semmap calibrate check`: the scan drawn on the image, coloured by range, from files or a bag."""

import cv2
import numpy as np
import pytest

from semmap.calib.check import check_calibration
from semmap.calib.scans import read_scan_points
from semmap.calib.synth import sim_calibration_truth, sim_intrinsics
from semmap.cli.main import main
from semmap.errors import ConfigError
from semmap.geometry import project_points, se3_apply, se3_from_xyz_rpy, se3_inverse
from semmap.records import Calibration, CameraIntrinsics

CALIB = Calibration(sim_intrinsics(), sim_calibration_truth())


def _wall_scan():
    """A slanted wall 2 to 3.5 m ahead of the robot, in the LiDAR frame (corner LiDAR yawed 45°)."""
    y = np.linspace(-0.6, 0.6, 60)
    x = np.linspace(2.0, 3.5, 60)
    pts_base = np.column_stack([x, y, np.full(60, 0.2)])
    T_lidar_base = se3_inverse(se3_from_xyz_rpy([0.38, 0.23, 0.2], [0, 0, np.pi / 4]))
    return se3_apply(T_lidar_base, pts_base)


def test_points_land_in_the_image_coloured_near_blue_far_red(tmp_path):
    img = np.full((480, 640, 3), 128, np.uint8)
    pts = _wall_scan()
    r = check_calibration(CALIB, image=img, scan=pts, out=tmp_path / "check.png", range_limits=(1.0, 5.0))
    assert r.n_points == 60 and r.n_in_image == 60
    assert r.image.shape[0] > 480 and r.image.shape[1] == 640  # the image plus a colour bar
    assert cv2.imread(str(tmp_path / "check.png")).shape == r.image.shape
    k = CALIB.intrinsics
    uv, _ = project_points(k.K, k.D, se3_apply(CALIB.T_cam_lidar, pts), 640, 480)
    rng = np.linalg.norm(pts, axis=1)
    near, far = int(np.argmin(rng)), int(np.argmax(rng))
    c_near = r.image[int(round(uv[near, 1])), int(round(uv[near, 0]))].astype(int)
    c_far = r.image[int(round(uv[far, 1])), int(round(uv[far, 0]))].astype(int)
    assert c_near[0] > c_near[2]  # BGR: blue-ish
    assert c_far[2] > c_far[0]  # red-ish


def test_an_inverted_transform_shows_at_a_glance(caplog):
    wrong = Calibration(CALIB.intrinsics, CALIB.T_lidar_cam)  # T_C→L given where T_cam_lidar belongs
    img = np.zeros((480, 640, 3), np.uint8)
    assert check_calibration(wrong, image=img, scan=_wall_scan()).n_in_image < 30
    behind = _wall_scan() * np.array([-1.0, -1.0, 1.0])  # the wall behind the robot
    r = check_calibration(CALIB, image=img, scan=behind)
    assert r.n_in_image == 0 and "is T_cam_lidar inverted" in caplog.text


def test_scan_files_pcd_csv_npy(tmp_path):
    pts = _wall_scan()
    (tmp_path / "s.pcd").write_text(
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {len(pts) + 1}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts) + 1}\nDATA ascii\n"
        + "".join(f"{x} {y} 0 0\n" for x, y, _ in pts) + "0 0 0 0\n")
    np.savetxt(tmp_path / "s.csv", pts[:, :2], delimiter=",", header="x,y", comments="")
    r = np.linalg.norm(pts[:, :2], axis=1)
    a = np.arctan2(pts[:, 1], pts[:, 0])
    np.savetxt(tmp_path / "p.csv", np.column_stack([a, r]), delimiter=",", header="angle,range", comments="")
    np.save(tmp_path / "s.npy", pts[:, :2])
    for name in ("s.pcd", "s.csv", "p.csv", "s.npy"):
        got = read_scan_points(tmp_path / name)
        assert got.shape == (60, 3), name  # the (0, 0) "no return" point is dropped
        assert np.allclose(got[:, :2], pts[:, :2], atol=1e-6), name
    np.save(tmp_path / "r.npy", r)
    with pytest.raises(ConfigError, match="r.npy: holds ranges only"):
        read_scan_points(tmp_path / "r.npy")


@pytest.mark.parametrize("short_tour", ["ros1"], indirect=True)
def test_check_from_a_simulated_tour(short_tour, tmp_path, capsys):
    out = tmp_path / "check.png"
    assert main(["calibrate", "check", "--bag", str(short_tour.out), "--time", "4.0", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "scan points in the image" in text and "ms from the image" in text
    img = cv2.imread(str(out))
    assert img is not None and img.shape[1] == 640
    r = check_calibration(CALIB, bag=short_tour.bag, time_s=4.0)
    assert r.n_in_image > 50
    assert abs(r.offset_s) < 0.05  # the nearest scan (15 Hz) to the image


@pytest.mark.parametrize("short_tour", ["ros1"], indirect=True)
def test_check_bad_topic_or_time_is_one_line(short_tour, tmp_path, capsys):
    code = main(["calibrate", "check", "--bag", str(short_tour.out), "--time", "400", "--out", str(tmp_path / "c.png")])
    err = capsys.readouterr().err.strip()
    assert code == 3 and len(err.splitlines()) == 1 and "outside the bag" in err
    code = main(["calibrate", "check", "--bag", str(short_tour.out), "--scan-topic", "/nope", "--out",
                 str(tmp_path / "c.png")])
    err = capsys.readouterr().err.strip()
    assert code == 3 and "topic /nope (scan) is not in the bag" in err


def test_check_on_the_acfr_pair(data_dir, tmp_path):
    d = data_dir / "acfr_calib" / "examples"
    if not d.is_dir():
        pytest.skip(f"ACFR calibration pairs not found at {d}")
    intr = CameraIntrinsics(640, 480, np.array([[519.27, 0, 331.11], [0, 518.89, 229.43], [0, 0, 1]]),
                            np.array([0.11418155, 0.19343114, -0.00268067, 0.00371577, -1.09539701]))
    # the camera looks along the LiDAR's x axis (optical z = LiDAR x, optical x = −LiDAR y)
    T = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1.0]])
    r = check_calibration(Calibration(intr, T), image=sorted((d / "images").glob("*.png"))[0],
                          scan=sorted((d / "lasers").glob("*.pcd"))[0], out=tmp_path / "c.png")
    assert r.n_points > 300 and 60 < r.n_in_image < r.n_points


@pytest.mark.parametrize("short_tour", ["ros1", "mcap"], indirect=True)
def test_check_on_a_damaged_bag_is_one_line(short_tour, tmp_path, capsys):
    """A bag cut short (a robot's battery died): one line naming the bag, exit 3, no picture."""
    import shutil

    src = short_tour.bag
    if src.is_dir():
        bag = tmp_path / "cut"
        shutil.copytree(src, bag)
        data_file = next(f for f in bag.iterdir() if f.suffix in (".mcap", ".db3"))
    else:
        bag = data_file = tmp_path / "cut.bag"
        shutil.copy(src, bag)
    data = data_file.read_bytes()
    data_file.write_bytes(data[: len(data) // 2])
    shutil.copy(short_tour.out / "calibration.yaml", tmp_path / "calibration.yaml")
    code = main(["calibrate", "check", "--bag", str(bag), "--calib", str(tmp_path / "calibration.yaml"),
                 "--out", str(tmp_path / "c.png")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3, err
    assert len(err) == 1 and str(bag) in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "c.png").exists()
