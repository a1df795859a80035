"""The calibration workflow on files: what each ``semmap calibrate`` command does, importable.

* :func:`calibrate_intrinsics_file`: board images → a camera-only calibration file.
* :func:`calibrate_extrinsics_file`: a pairs file + a camera → a full calibration file.
* :func:`calibrate_target_files`: board images + scans + a camera → a full calibration file.
* :func:`semmap.calib.check.check_calibration`: the scan drawn on the image, to judge by eye.

Every file written names its transforms: ``T_cam_lidar`` maps LiDAR points into the camera,
``T_lidar_cam`` is its inverse.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError, OutputExistsError
from ..io.calibration import (
    read_calibration,
    read_intrinsics,
    read_intrinsics_report,
    write_calibration,
    write_intrinsics,
)
from ..io.yamlio import read_yaml
from ..records import Calibration, CameraIntrinsics
from .boards import BoardSpec, detect_board, parse_board_spec
from .extrinsics import PairsCalibration, calibrate_from_pairs
from .intrinsics import IntrinsicsCalibration, Model, calibrate_intrinsics
from .pairs import read_pairs
from .scans import read_scan_points
from .target import (
    TargetCalibration,
    TargetObservation,
    board_plane,
    calibrate_target,
    find_board_segments,
)

__all__ = [
    "IMAGE_SUFFIXES",
    "SCAN_SUFFIXES",
    "calibrate_extrinsics_file",
    "calibrate_intrinsics_file",
    "calibrate_target_files",
    "expand_files",
    "pair_by_stamp",
    "target_observations",
]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
SCAN_SUFFIXES = (".pcd", ".csv", ".npy")


def _guard(out: str | Path, force: bool) -> Path:
    p = Path(out)
    if p.exists() and not force:
        raise OutputExistsError(f"{p}: exists; use --force to replace it")
    if not p.parent.is_dir():
        raise ConfigError(f"{p}: folder {p.parent} does not exist")
    return p


def expand_files(items: Sequence[str | Path], suffixes: Sequence[str], what: str) -> list[Path]:
    """Files as given, folders expanded to their files with ``suffixes`` (sorted)."""
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.suffix.lower() in suffixes)
            if not found:
                raise ConfigError(f"{p}: folder holds no {what} ({', '.join(suffixes)})")
            out.extend(found)
        elif p.is_file():
            out.append(p)
        else:
            raise ConfigError(f"{p}: no such {what} file or folder")
    return out


def pair_by_stamp(images: Sequence[Path], scans: Sequence[Path]) -> list[tuple[Path, Path, float | None]]:
    """Pair images with scans: by nearest time when every name is an integer (nanoseconds, as
    the ACFR data and rosbag extraction tools write), otherwise in sorted order.

    Returns ``(image, scan, offset_s)`` with ``offset_s = scan time - image time`` (None if unknown).
    """
    if all(p.stem.isdigit() for p in [*images, *scans]) and images and scans:
        st = np.array([int(s.stem) for s in scans], dtype=np.int64)
        pairs: list[tuple[Path, Path, float | None]] = []
        for im in images:
            k = int(np.argmin(np.abs(st - int(im.stem))))
            pairs.append((im, scans[k], (int(st[k]) - int(im.stem)) * 1e-9))
        used = [s for _, s, _ in pairs]
        if len(set(used)) != len(used):
            raise ConfigError("two images pair with the same scan by time; give one scan per image")
        return pairs
    if len(images) != len(scans):
        raise ConfigError(f"{len(images)} images but {len(scans)} scans; give one scan per image "
                          "(or name both by nanosecond timestamps)")
    return [(im, sc, None) for im, sc in zip(sorted(images), sorted(scans))]


def calibrate_intrinsics_file(
    images: Sequence[str | Path],
    board: BoardSpec | str,
    out: str | Path,
    *,
    model: Model = "pinhole",
    distortion_coefficients: int = 5,
    camera_frame: str = "camera_optical_frame",
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> IntrinsicsCalibration:
    """Calibrate a camera from board images (files or folders) and write a camera-only calibration file."""
    out_p = _guard(out, force)
    files = expand_files(images, IMAGE_SUFFIXES, "image")
    result = calibrate_intrinsics(files, board, model=model, distortion_coefficients=distortion_coefficients,
                                  progress=progress)
    write_intrinsics(out_p, result.intrinsics, result.report(), camera_frame=camera_frame)
    return result


def _frames(path: str | Path) -> tuple[str, str]:
    """The camera and LiDAR frame names a calibration file gives (defaults otherwise)."""
    data = read_yaml(path, "calibration")
    if isinstance(data, dict) and "intrinsics" in data:
        return str(data.get("camera_frame", "camera_optical_frame")), str(data.get("lidar_frame", "laser"))
    return "camera_optical_frame", "laser"


def calibrate_extrinsics_file(
    pairs: str | Path,
    intrinsics: str | Path,
    out: str | Path,
    *,
    undistorted: bool = False,
    threshold_px: float = 8.0,
    camera_frame: str | None = None,
    lidar_frame: str | None = None,
    force: bool = False,
    seed: int = 0,
) -> PairsCalibration:
    """Hong's manual method: solve ``T_cam_lidar`` from a pairs file and write the calibration file.

    ``intrinsics``: any calibration file (from ``semmap calibrate intrinsics``, a full one, or
    ROS camera-info YAML). The output keeps its camera and its intrinsics report.
    """
    out_p = _guard(out, force)
    intr = read_intrinsics(intrinsics)
    cam_f, lid_f = _frames(intrinsics)
    result = calibrate_from_pairs(read_pairs(pairs), intr, undistorted=undistorted, threshold_px=threshold_px,
                                  seed=seed)
    calib = Calibration(intr, result.T_cam_lidar, camera_frame or cam_f, lidar_frame or lid_f)
    write_calibration(out_p, calib, {"extrinsics": result.report()}, read_intrinsics_report(intrinsics))
    return result


def target_observations(
    images: Sequence[str | Path],
    scans: Sequence[str | Path],
    board: BoardSpec | str,
    intrinsics: CameraIntrinsics,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[list[TargetObservation], list[tuple[str, str]]]:
    """Load image/scan pairs, find the board in each image and its line in each scan.

    Returns the observations (``board_indices`` set where the board was found in the scan)
    and the pairs skipped, with the reason.
    """
    spec = parse_board_spec(board)
    img_files = expand_files(images, IMAGE_SUFFIXES, "image")
    scan_files = expand_files(scans, SCAN_SUFFIXES, "scan")
    pairs = pair_by_stamp(img_files, scan_files)
    skipped: list[tuple[str, str]] = []
    dets, planes, pts, names = [], [], [], []
    import cv2

    for k, (im, sc, dt) in enumerate(pairs):
        if progress:
            progress(k + 1, len(pairs))
        if dt is not None and abs(dt) > 0.2:
            log.warning("%s: the nearest scan %s is %.3f s away", im.name, sc.name, dt)
        img = cv2.imread(str(im), cv2.IMREAD_GRAYSCALE)
        if img is None:
            skipped.append((im.name, "not an image OpenCV can read"))
            continue
        if (img.shape[1], img.shape[0]) != (intrinsics.width, intrinsics.height):
            raise ConfigError(f"{im}: image is {img.shape[1]}x{img.shape[0]}, the camera is "
                              f"{intrinsics.width}x{intrinsics.height}")
        det = detect_board(img, spec)
        if det is None:
            skipped.append((im.name, f"board {spec} not found in the image"))
            log.info("%s: board %s not found; skipped", im.name, spec)  # counted in the result
            continue
        dets.append(det)
        planes.append(board_plane(det, intrinsics))
        pts.append(read_scan_points(sc)[:, :2])
        names.append(im.stem)
    if len(dets) < 3:
        raise ConfigError(f"board {spec} found in {len(dets)} of {len(pairs)} images; need at least 3")
    segs = find_board_segments(pts, planes, board_width_m=min(spec.size_m))
    obs = []
    for name, det, pl, xy, seg in zip(names, dets, planes, pts, segs):
        if seg is None:
            skipped.append((name, "board not found in the scan"))
        obs.append(TargetObservation(name, det, pl, xy, None if seg is None else seg.indices))
    return obs, skipped


def calibrate_target_files(
    images: Sequence[str | Path],
    scans: Sequence[str | Path],
    board: BoardSpec | str,
    intrinsics: str | Path,
    out: str | Path,
    *,
    prior: str | Path | None = None,
    camera_frame: str | None = None,
    lidar_frame: str | None = None,
    check_dir: str | Path | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> TargetCalibration:
    """Board-based automatic calibration on files; writes the calibration file.

    ``prior``: a calibration file whose ``T_cam_lidar`` decides the directions the boards leave
    unobservable (e.g. from the robot's URDF). ``check_dir``: also draw each observation's scan
    on its image there (``check_<name>.png``).
    """
    out_p = _guard(out, force)
    intr = read_intrinsics(intrinsics)
    cam_f, lid_f = _frames(intrinsics)
    prior_T: NDArray[np.float64] | None = None
    if prior is not None:
        prior_T = read_calibration(prior).T_cam_lidar
    obs, skipped = target_observations(images, scans, board, intr, progress=progress)
    result = calibrate_target(obs, intr, prior_T_cam_lidar=prior_T)
    result = _with_skipped(result, skipped)
    calib = Calibration(intr, result.T_cam_lidar, camera_frame or cam_f, lidar_frame or lid_f)
    report = result.report()
    report["board"] = str(parse_board_spec(board))
    if prior is not None:
        report["prior"] = str(prior)
    write_calibration(out_p, calib, {"extrinsics": report}, read_intrinsics_report(intrinsics))
    if check_dir is not None:
        from .check import draw_scan_on_image, read_image

        d = Path(check_dir)
        d.mkdir(parents=True, exist_ok=True)
        img_files = {p.stem: p for p in expand_files(images, IMAGE_SUFFIXES, "image")}
        import cv2

        for o in obs:
            pic, _ = draw_scan_on_image(read_image(img_files[o.name]), o.scan_xy, calib, title=o.name)
            cv2.imwrite(str(d / f"check_{o.name}.png"), pic)
    return result


def _with_skipped(result: TargetCalibration, skipped: list[tuple[str, str]]) -> TargetCalibration:
    from dataclasses import replace

    merged = list(dict.fromkeys([*result.skipped, *skipped]))
    return replace(result, skipped=tuple(merged))
