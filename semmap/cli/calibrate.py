"""``semmap calibrate``: camera intrinsics, ``T_cam_lidar`` (manual pairs or boards), and a visual check.

Each sub-command calls one function of :mod:`semmap.calib.workflow` / :mod:`semmap.calib.check`;
this module only parses arguments and prints the report.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from ._progress import console, progress_bar

_T_NOTE = "T_cam_lidar maps LiDAR points into the camera (p_cam = T_cam_lidar @ p_lidar); T_lidar_cam is its inverse"


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate the camera and T_cam_lidar (LiDAR→camera), and check a calibration by eye",
        description="Camera intrinsics from board images; T_cam_lidar from hand-picked point/pixel pairs "
                    "(Hong et al.) or automatically from board observations (Zhang & Pless); and a "
                    f"picture of the scan projected into the image. {_T_NOTE}.",
    )
    cs = p.add_subparsers(dest="calib_command", metavar="STEP")
    cs.required = True

    q = cs.add_parser("intrinsics", parents=[common], help="camera matrix and distortion from board images",
                      description="Calibrate a camera (pinhole with OpenCV distortion, or fisheye) from images "
                                  "of a chessboard, ChArUco or ArUco board. Images where the board is not "
                                  "found are reported and skipped.")
    q.add_argument("images", nargs="+", metavar="IMAGE", help="image files or folders of images")
    q.add_argument("--board", required=True, metavar="SPEC",
                   help="chessboard:COLSxROWS:SQUARE (inner corners), charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy] "
                        "(squares) or aruco:COLSxROWS:MARKER:GAP:DICT; metres; DICT e.g. 4X4_50")
    q.add_argument("--model", choices=["pinhole", "fisheye"], default="pinhole", help="camera model (default: pinhole)")
    q.add_argument("--coefficients", type=int, choices=[4, 5, 8], default=5,
                   help="pinhole distortion coefficients: 4 (k1 k2 p1 p2), 5 (+k3, default) or 8 (rational)")
    q.add_argument("--camera-frame", default="camera_optical_frame", help="the camera's optical frame name")
    q.add_argument("--out", type=Path, required=True, metavar="CALIB", help="calibration file to write (YAML)")
    q.add_argument("--force", action="store_true", help="replace CALIB if it exists")
    q.set_defaults(run=run_intrinsics)

    e = cs.add_parser("extrinsics", parents=[common], help="T_cam_lidar from hand-picked LiDAR-point/pixel pairs",
                      description="Hong et al.'s manual method: about 30 pairs of a LiDAR point (x, y in the scan "
                                  "plane) and the pixel where it shows, solved with RANSAC (no initial guess) "
                                  f"and Levenberg-Marquardt. {_T_NOTE}.")
    e.add_argument("--pairs", type=Path, required=True, metavar="FILE",
                   help="Hong's data.txt ('laser_x laser_y u v' per line) or CSV with header x,y,u,v")
    e.add_argument("--intrinsics", type=Path, required=True, metavar="FILE",
                   help="calibration file with the camera (from `calibrate intrinsics`), or ROS camera-info YAML")
    e.add_argument("--undistorted", action="store_true",
                   help="the pixels were picked on an image already undistorted with K (as Hong's tool does)")
    e.add_argument("--ransac-threshold", type=float, default=8.0, metavar="PX",
                   help="RANSAC inlier threshold, pixels (default: 8)")
    e.add_argument("--lidar-frame", default=None, help="the LiDAR's frame name (default: from FILE, else 'laser')")
    e.add_argument("--out", type=Path, required=True, metavar="CALIB", help="calibration file to write (YAML)")
    e.add_argument("--force", action="store_true", help="replace CALIB if it exists")
    e.set_defaults(run=run_extrinsics)

    t = cs.add_parser("target", parents=[common], help="T_cam_lidar automatically from board observations",
                      description="Automatic, target-based calibration: each observation is an image of a board "
                                  "and a scan taken with it. The camera gives the board's plane, the scan the "
                                  "line where it cuts the board (found automatically); line-on-plane constraints "
                                  "(Zhang & Pless 2004), refined jointly with the board poses. Lean the board "
                                  f"forward/back by 20-40 degrees in some views. {_T_NOTE}.")
    t.add_argument("--images", nargs="+", required=True, metavar="IMAGE", help="image files or a folder")
    t.add_argument("--scans", nargs="+", required=True, metavar="SCAN",
                   help="scan files (.pcd, .csv, .npy) or a folder; paired with images by nanosecond names, "
                        "else in sorted order")
    t.add_argument("--board", required=True, metavar="SPEC", help="the board (see `calibrate intrinsics --help`)")
    t.add_argument("--intrinsics", type=Path, required=True, metavar="FILE", help="calibration file with the camera")
    t.add_argument("--prior", type=Path, metavar="CALIB",
                   help="a calibration whose T_cam_lidar decides what the boards cannot (e.g. from the URDF)")
    t.add_argument("--lidar-frame", default=None, help="the LiDAR's frame name (default: from FILE, else 'laser')")
    t.add_argument("--check-dir", type=Path, metavar="DIR", help="also draw each observation's scan on its image here")
    t.add_argument("--out", type=Path, required=True, metavar="CALIB", help="calibration file to write (YAML)")
    t.add_argument("--force", action="store_true", help="replace CALIB if it exists")
    t.set_defaults(run=run_target)

    c = cs.add_parser("check", parents=[common], help="draw the scan projected into the image, coloured by range",
                      description="Judge a calibration by eye: the scan projected through T_cam_lidar onto the "
                                  "camera image, coloured by range. Input: a bag and a time, or an image and a scan.")
    c.add_argument("--calib", type=Path, metavar="CALIB",
                   help="calibration file (default: calibration.yaml of the tour folder given as --bag)")
    c.add_argument("--bag", type=Path, metavar="BAG", help="a bag, ROS2 bag folder or tour folder")
    c.add_argument("--time", type=float, default=None, metavar="S",
                   help="seconds after the bag's start (default: the middle of the bag)")
    c.add_argument("--image-topic", default=None, help="camera topic (default: the one Image/CompressedImage topic)")
    c.add_argument("--scan-topic", default=None, help="scan topic (default: the one LaserScan topic)")
    c.add_argument("--image", type=Path, metavar="IMAGE", help="an image file (with --scan)")
    c.add_argument("--scan", type=Path, metavar="SCAN", help="a scan file: .pcd, .csv (x,y or angle,range) or .npy")
    c.add_argument("--range", nargs=2, type=float, metavar=("MIN", "MAX"), default=None,
                   help="colour scale in metres (default: from the points seen)")
    c.add_argument("--out", type=Path, required=True, metavar="PNG", help="picture to write")
    c.add_argument("--force", action="store_true", help="replace PNG if it exists")
    c.set_defaults(run=run_check)


def _fmt_T(name: str, T: Any) -> list[str]:
    return [f"  {name} ="] + ["    [" + ", ".join(f"{v:9.5f}" for v in row) + "]" for row in T]


def run_intrinsics(args: argparse.Namespace) -> int:
    from ..calib.workflow import calibrate_intrinsics_file

    with progress_bar("detecting the board", enabled=not args.quiet) as progress:
        r = calibrate_intrinsics_file(args.images, args.board, args.out, model=args.model,
                                      distortion_coefficients=args.coefficients, camera_frame=args.camera_frame,
                                      force=args.force, progress=progress)
    if args.quiet:
        return 0
    out = console()
    k = r.intrinsics
    out.print(f"[bold]semmap calibrate intrinsics[/bold]: {len(r.images)} images used, {len(r.skipped)} skipped "
              f"→ {args.out}")
    out.print(f"  model {k.model}, {k.width}x{k.height}, fx {k.fx:.2f} fy {k.fy:.2f} cx {k.cx:.2f} cy {k.cy:.2f}")
    out.print("  D = [" + ", ".join(f"{v:.5f}" for v in k.D) + "]")
    out.print(f"  RMS reprojection error {r.rms_px:.3f} px")
    for im in sorted(r.images, key=lambda x: -x.rms_px):
        out.print(f"    {im.name:<32} {im.points:4d} points  {im.rms_px:6.3f} px")
    for name, why in r.skipped:
        out.print(f"    {name:<32} skipped: {why}")
    return 0


def run_extrinsics(args: argparse.Namespace) -> int:
    from ..calib.workflow import calibrate_extrinsics_file

    r = calibrate_extrinsics_file(args.pairs, args.intrinsics, args.out, undistorted=args.undistorted,
                                  threshold_px=args.ransac_threshold, lidar_frame=args.lidar_frame, force=args.force)
    if args.quiet:
        return 0
    out = console()
    out.print(f"[bold]semmap calibrate extrinsics[/bold]: {len(r.pairs)} pairs, {r.n_inliers} inliers "
              f"(threshold {r.threshold_px:.1f} px) → {args.out}")
    out.print(f"  RMS reprojection error {r.rms_px:.3f} px (inliers); 1-sigma: rotation {r.rotation_std_deg:.3f} deg, "
              f"translation {r.translation_std_m * 100:.2f} cm")
    out.print("  worst pairs:")
    for w in r.worst(5):
        tag = "" if w.inlier else "  OUTLIER"
        out.print(f"    line {w.line:4d}: ({w.lidar_xy[0]:7.3f}, {w.lidar_xy[1]:7.3f}) m → "
                  f"({w.pixel[0]:7.1f}, {w.pixel[1]:7.1f}) px  residual {w.residual_px:7.2f} px{tag}")
    for line in _fmt_T("T_cam_lidar (LiDAR points into the camera)", r.T_cam_lidar):
        out.print(line)
    for line in _fmt_T("T_lidar_cam (camera points into the LiDAR; the research's T_C→L)", r.T_lidar_cam):
        out.print(line)
    return 0


def run_target(args: argparse.Namespace) -> int:
    from ..calib.workflow import calibrate_target_files

    with progress_bar("finding boards", enabled=not args.quiet) as progress:
        r = calibrate_target_files(args.images, args.scans, args.board, args.intrinsics, args.out, prior=args.prior,
                                   lidar_frame=args.lidar_frame, check_dir=args.check_dir, force=args.force,
                                   progress=progress)
    if args.quiet:
        return 0
    out = console()
    out.print(f"[bold]semmap calibrate target[/bold]: {len(r.views)} board observations, "
              f"{len(r.skipped)} skipped → {args.out}")
    out.print(f"  line-to-plane RMS {r.rms_mm:.1f} mm (range noise seen on the boards {r.range_noise_m * 1e3:.1f} mm); "
              f"board normals leave their common plane by {r.normal_spread_deg:.1f} deg")
    for v in r.views:
        out.print(f"    {v.name:<24} {v.n_points:4d} points  RMS {v.rms_mm:6.1f} mm  mean {v.mean_mm:+6.1f} mm  "
                  f"board {v.board_rms_px:.2f} px")
    for name, why in r.skipped:
        out.print(f"    {name:<24} skipped: {why}")
    sr = ", ".join(f"{a} {v:.2f}" for a, v in zip("xyz", r.rotation_std_deg))
    st = ", ".join(f"{a} {v * 100:.1f}" for a, v in zip("xyz", r.translation_std_m))
    out.print(f"  1-sigma about LiDAR axes (deg): {sr}; along LiDAR axes (cm): {st}")
    if r.unobservable:
        out.print("  [yellow]not observable from these boards, held at the prior:[/yellow] "
                  f"{', '.join(r.unobservable)}")
    for line in _fmt_T("T_cam_lidar (LiDAR points into the camera)", r.T_cam_lidar):
        out.print(line)
    for line in _fmt_T("T_lidar_cam (camera points into the LiDAR; the research's T_C→L)", r.T_lidar_cam):
        out.print(line)
    return 0


def run_check(args: argparse.Namespace) -> int:
    from ..calib.check import check_calibration
    from ..errors import ConfigError
    from ..io.calibration import read_calibration

    calib_path = args.calib
    if calib_path is None:
        if args.bag is not None and (args.bag / "calibration.yaml").is_file():
            calib_path = args.bag / "calibration.yaml"
        else:
            raise ConfigError("--calib is required (unless --bag is a tour folder holding calibration.yaml)")
    if args.bag is None and (args.image is None or args.scan is None):
        raise ConfigError("give --bag (and --time), or --image and --scan")
    calib = read_calibration(calib_path)
    if args.bag is not None:
        title = f"{calib_path.name}  t = " + ("middle" if args.time is None else f"{args.time:.2f} s")
    else:
        title = f"{calib_path.name}  {args.image.name}"
    r = check_calibration(calib, image=args.image, scan=args.scan, bag=args.bag, time_s=args.time,
                          image_topic=args.image_topic, scan_topic=args.scan_topic, out=args.out,
                          range_limits=tuple(args.range) if args.range else None, title=title, force=args.force)
    if args.quiet:
        return 0
    out = console()
    dt = r.offset_s
    extra = "" if dt is None or not math.isfinite(dt) else f"; scan {dt * 1e3:+.0f} ms from the image"
    out.print(f"[bold]semmap calibrate check[/bold]: {r.n_in_image} of {r.n_points} scan points in the image"
              f"{extra} → {args.out}")
    return 0
