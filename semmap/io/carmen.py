"""CARMEN laser logs (the Radish datasets: Intel, Freiburg 101, ...) as ROS bags ``semmap build`` reads.

A CARMEN log is text, one message a line::

    FLASER n r1 ... rn x y theta odom_x odom_y odom_theta timestamp [hostname] logger_timestamp
    RLASER (the same, for the rear laser)
    ROBOTLASER1 type start fov resolution max_range accuracy remission_mode n r1 ... rn
                m v1 ... vm laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety side_safety turn_axis timestamp [hostname] logger_timestamp
    ODOM x y theta tv rv accel timestamp [hostname] logger_timestamp
    PARAM name value [hostname] [timestamp]

``x y theta`` of a laser line is the laser's pose; in a *corrected* log (``*-corrected.log``) it
is the pose a SLAM system estimated (a reference, not ground truth).

**The odometry trap.** In the corrected logs the laser lines' ``odom_*`` fields are copies of the
corrected pose, and the ODOM stream restarts at the corrected pose after every scan (the ODOM
line stamped 0 right after each scan). Taking either as odometry hands a mapper the answer. The
honest odometry is the wheel motion between two scans: the inverse of the previous scan's
corrected robot pose times the last ODOM line before the next scan. :func:`honest_odometry`
chains those steps from the origin. A log whose laser odometry fields differ from its poses is a
raw log: there the fields are the odometry.

:func:`write_tour` writes the bag: ``/scan`` (and ``/rear_scan``) ``sensor_msgs/LaserScan``,
``/odom`` ``nav_msgs/Odometry`` (``odom`` -> ``base_link``), ``/ground_truth/odom`` with the
reference robot poses (corrected logs), and ``/tf_static`` with the lasers' mounts from the log's
``robot_frontlaser_offset`` / ``robot_rearlaser_offset``.
"""

from __future__ import annotations

import contextlib
import gzip
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..geometry import se2_compose, se2_inverse, se2_to_se3, wrap_angle
from ..records import Scan

__all__ = ["CarmenLog", "CarmenScan", "honest_odometry", "read_carmen", "write_tour"]

#: readings at or beyond this are "no return" when the log names no laser maximum (SICK LMS: 81.83)
DEFAULT_MAX_RANGE = 80.0
#: at most this share of consecutive scans may share a stamp, or the log cannot be paired in time
MAX_EQUAL_STAMPS = 0.01


@dataclass(frozen=True)
class CarmenScan:
    """One laser line: which laser, its readings, the laser pose and odometry fields, its stamp."""

    laser: str  # "front" or "rear"
    ranges: NDArray[np.float32]
    angle_min: float
    angle_increment: float
    max_range: float | None
    pose: NDArray[np.float64]  # the laser's pose (x, y, theta) as logged
    odom: NDArray[np.float64]  # the odometry fields (the robot's, or the laser's for FLASER)
    stamp: float
    line: int
    #: index into the log's ODOM lines of the last ODOM line before this scan (-1: none)
    last_odom: int = -1


@dataclass
class CarmenLog:
    """A parsed CARMEN log."""

    path: Path
    scans: list[CarmenScan] = field(default_factory=list)
    odom: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # ODOM poses, file order
    odom_stamps: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    params: dict[str, str] = field(default_factory=dict)

    @property
    def front(self) -> list[CarmenScan]:
        return [s for s in self.scans if s.laser == "front"]

    @property
    def corrected(self) -> bool:
        """The laser lines' odometry fields copy their poses: a corrected log, whose poses are a reference."""
        f = self.front
        return bool(f) and all(np.allclose(s.pose, s.odom, atol=1e-6) for s in f)

    def mount(self, laser: str) -> NDArray[np.float64]:
        """The laser's pose on the robot (x, y, yaw) from the log's PARAM lines (rear: turned half way)."""
        key = "robot_frontlaser_offset" if laser == "front" else "robot_rearlaser_offset"
        try:
            off = float(self.params.get(key, "0") or 0.0)
        except ValueError:
            raise ConfigError(f"{self.path}: PARAM {key} is not a number: {self.params[key]!r}") from None
        return np.array([off, 0.0, 0.0]) if laser == "front" else np.array([-off, 0.0, math.pi])


def _open_text(p: Path) -> list[str]:
    try:
        raw = p.read_bytes()
        if raw[:2] == b"\x1f\x8b":
            raw = gzip.decompress(raw)
        return raw.decode("utf-8", errors="strict").splitlines()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the log ({exc.strerror or exc})") from None
    except (EOFError, gzip.BadGzipFile) as exc:
        raise ConfigError(f"{p}: not a readable gzip file ({exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a text CARMEN log") from None


def _floats(tokens: list[str], p: Path, no: int, what: str) -> NDArray[np.float64]:
    try:
        return np.asarray([float(t) for t in tokens], np.float64)
    except ValueError:
        raise ConfigError(f"{p}:{no}: {what}: a field is not a number") from None


def _tail_stamp(rest: list[str], p: Path, no: int, tag: str) -> float:
    """The ``timestamp [hostname] logger_timestamp`` tail: the first stamp."""
    if len(rest) not in (2, 3):
        raise ConfigError(f"{p}:{no}: {tag}: expected 'timestamp [hostname] logger_timestamp' at the end, "
                          f"found {len(rest)} fields")
    return float(_floats(rest[:1], p, no, tag)[0])


def _laser_angles(n: int, fov: float = math.pi) -> tuple[float, float]:
    """CARMEN's FLASER/RLASER: n beams over 180°; an odd count includes both ends (181, 361),
    an even count does not (180 beams 1° apart from -90°, as GMapping's CARMEN reader has it)."""
    inc = fov / (n - 1) if n % 2 == 1 else fov / n
    return -fov / 2.0, inc


def read_carmen(path: str | Path) -> CarmenLog:
    """Parse a CARMEN log (plain or gzip). Every malformed line is one :class:`ConfigError` naming
    the file and line."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such log file")
    log = CarmenLog(p)
    odom: list[NDArray[np.float64]] = []
    stamps: list[float] = []
    for no, line in enumerate(_open_text(p), start=1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        tag = tok[0]
        try:
            if tag in ("FLASER", "RLASER"):
                n = int(tok[1])
                if n < 2 or len(tok) < 2 + n + 6 + 2:
                    raise ConfigError(f"{p}:{no}: {tag}: {n} readings, 6 pose fields and 'timestamp [hostname] "
                                      f"logger_timestamp' expected, {len(tok) - 2} fields follow")
                ranges = _floats(tok[2:2 + n], p, no, tag)
                nums = _floats(tok[2 + n:2 + n + 6], p, no, tag)
                stamp = _tail_stamp(tok[2 + n + 6:], p, no, tag)
                a0, inc = _laser_angles(n)
                log.scans.append(CarmenScan("front" if tag == "FLASER" else "rear", ranges.astype(np.float32), a0,
                                            inc, None, nums[:3], nums[3:6], stamp, no, len(odom) - 1))
            elif tag == "ROBOTLASER1":
                head = _floats(tok[1:8], p, no, tag)
                n = int(tok[8])
                ranges = _floats(tok[9:9 + n], p, no, tag)
                m = int(tok[9 + n])
                k = 10 + n + m
                nums = _floats(tok[k:k + 6], p, no, tag)
                stamp = _tail_stamp(tok[k + 11:], p, no, tag)
                log.scans.append(CarmenScan("front", ranges.astype(np.float32), float(head[1]), float(head[3]),
                                            float(head[4]), nums[:3], nums[3:6], stamp, no, len(odom) - 1))
            elif tag == "ODOM":
                nums = _floats(tok[1:7], p, no, tag)
                odom.append(nums[:3])
                stamps.append(_tail_stamp(tok[7:], p, no, tag))
            elif tag == "PARAM" and len(tok) >= 3:
                log.params[tok[1]] = tok[2]
        except (IndexError, ValueError):
            raise ConfigError(f"{p}:{no}: {tag}: malformed line") from None
    if not log.front:
        raise ConfigError(f"{p}: no FLASER or ROBOTLASER1 line: not a CARMEN laser log")
    log.odom = np.asarray(odom, np.float64).reshape(-1, 3)
    log.odom_stamps = np.asarray(stamps, np.float64)
    return log


def _check_stamps(log: CarmenLog) -> None:
    t = np.array([s.stamp for s in log.front])
    same = int(np.count_nonzero(np.diff(t) <= 0))
    if t.size > 1 and same > MAX_EQUAL_STAMPS * (t.size - 1):
        raise ConfigError(f"{log.path}: {same} of {t.size - 1} consecutive scans have a stamp no later than the one "
                          f"before (stamps too coarse to pair scans with odometry in time)")


def _robot_pose(laser_pose: NDArray[np.float64], mount: NDArray[np.float64]) -> NDArray[np.float64]:
    return se2_compose(laser_pose, se2_inverse(mount))


def honest_odometry(log: CarmenLog) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64],
                                             NDArray[np.float64]]:
    """The robot's odometry, chained from the origin: its pose at each front scan (N, 3), which scans
    had a step of their own (False: no ODOM line since the scan before, so no motion is known), and
    the wheel path between scans: stamps (M,) and poses (M, 3) of the ODOM lines in the odometry frame.

    Corrected logs: an ODOM line j after scan k-1 is at ``odom[k-1] * inverse(corrected robot pose of
    scan k-1) * ODOM[j]``, and scan k's pose is that of the last ODOM line before it. The restart lines
    (the corrected pose itself, stamped 0) carry no motion and are left out. Raw logs: the laser lines'
    odometry fields, and the ODOM lines as they are."""
    front = log.front
    n = len(front)
    out = np.zeros((n, 3))
    ok = np.ones(n, bool)
    if not log.corrected:
        out[:] = [s.odom for s in front]
        keep = log.odom_stamps > 0
        return out, ok, log.odom_stamps[keep], log.odom[keep]
    mount = log.mount("front")
    path_t: list[float] = []
    path_p: list[NDArray[np.float64]] = []
    for k in range(1, n):
        j0, j = front[k - 1].last_odom, front[k].last_odom
        while j > j0 and log.odom_stamps[j] <= 0:  # a restart line carries no wheel motion
            j -= 1
        if j < 0 or j <= j0:  # no wheel ODOM line between the two scans: the step is unknown
            out[k] = out[k - 1]
            ok[k] = False
            continue
        base = se2_compose(out[k - 1], se2_inverse(_robot_pose(front[k - 1].pose, mount)))
        for i in range(j0 + 1, j + 1):
            if log.odom_stamps[i] > 0:
                p = se2_compose(base, log.odom[i])
                p[2] = float(wrap_angle(p[2]))
                path_t.append(float(log.odom_stamps[i]))
                path_p.append(p)
        out[k] = se2_compose(base, log.odom[j])
        out[k, 2] = float(wrap_angle(out[k, 2]))
    return out, ok, np.asarray(path_t, np.float64), np.asarray(path_p, np.float64).reshape(-1, 3)


def write_tour(log: CarmenLog, out: Path, fmt: str = "ros1", name: str | None = None) -> dict[str, Any]:
    """Write the log into the (existing, empty) folder ``out``: the bag, ``reference.tum`` (corrected
    logs: the reference robot poses), ``odometry.tum`` and ``import.json``. Returns the summary."""
    from .bag import BagWriter, bag_suffix
    from .tum import write_tum

    _check_stamps(log)
    front = log.front
    stamps = np.array([s.stamp for s in front])
    t0 = max(0.0, 1.0 - float(stamps.min()))  # bag times must be positive: a log from 0 s starts at 1 s

    def ns(t: float) -> int:
        return int(round((t + t0) * 1e9))

    odo, ok, path_t, path_p = honest_odometry(log)
    max_range = DEFAULT_MAX_RANGE
    with contextlib.suppress(KeyError, ValueError):
        max_range = float(log.params["robot_front_laser_max"])
    mount_f, mount_r = log.mount("front"), log.mount("rear")
    corrected = log.corrected
    stem = name or log.path.name.split(".")[0]
    bag = out / (stem + bag_suffix(fmt))  # type: ignore[arg-type]
    stamps_ns = np.array([ns(t) for t in stamps], np.int64)
    with BagWriter(bag, fmt) as w:  # type: ignore[arg-type]
        tf = [(stamps_ns[0], "base_link", "laser", se2_to_se3(mount_f))]
        if any(s.laser == "rear" for s in log.scans):
            tf.append((stamps_ns[0], "base_link", "rear_laser", se2_to_se3(mount_r)))
        w.transforms("/tf_static", int(stamps_ns[0]), tf, static=True)
        # the wheel path between scans, in time order (a stamp no later than the last written is skipped)
        events: list[tuple[float, int, Any]] = [(float(t), 0, p) for t, p in zip(path_t, path_p, strict=True)]
        events += [(float(s.stamp), 1, s) for s in log.scans]
        events.sort(key=lambda e: (e[0], e[1]))
        last_odom_ns = -1
        k = 0
        for stamp, kind, item in events:
            if kind == 0:
                t = ns(stamp)
                if t > last_odom_ns:
                    w.odometry("/odom", t, t, "odom", "base_link", item, (0.0, 0.0, 0.0))
                    last_odom_ns = t
                continue
            s = item
            t = ns(s.stamp)
            rng = s.ranges.astype(np.float32)
            rmax = float(s.max_range) if s.max_range else max_range
            frame = "laser" if s.laser == "front" else "rear_laser"
            topic = "/scan" if s.laser == "front" else "/rear_scan"
            w.scan(topic, t, Scan(t, frame, float(s.angle_min), float(s.angle_increment), rng, 0.0,
                                  float(np.nextafter(np.float32(rmax), np.float32(0)))))
            if s.laser != "front":
                continue
            if ok[k] and t > last_odom_ns:
                w.odometry("/odom", t, t, "odom", "base_link", odo[k], (0.0, 0.0, 0.0))
                last_odom_ns = t
            if corrected:
                w.odometry("/ground_truth/odom", t, t, "map", "base_link", _robot_pose(s.pose, mount_f),
                           (0.0, 0.0, 0.0))
            k += 1
    ref = np.array([_robot_pose(s.pose, mount_f) for s in front]) if corrected else None
    if ref is not None:
        write_tum(out / "reference.tum", stamps_ns, ref)
    write_tum(out / "odometry.tum", stamps_ns[ok], odo[ok])
    summary: dict[str, Any] = {
        "source": str(log.path), "bag": bag.name, "format": fmt, "scans": len(front),
        "rear_scans": sum(1 for s in log.scans if s.laser == "rear"), "odom_lines": int(log.odom.shape[0]),
        "corrected_log": corrected,
        "odometry": ("per-scan wheel steps from the ODOM lines (the reference is not used)" if corrected
                     else "the laser lines' odometry fields"),
        "scans_without_odometry_step": int((~ok[1:]).sum()) if len(ok) > 1 else 0,
        "reference": "reference.tum and /ground_truth/odom (the log's corrected poses)" if corrected else None,
        "laser_mount_front": [round(float(v), 4) for v in mount_f], "max_range_m": max_range,
        "time_offset_s": t0, "duration_s": round(float(stamps.max() - stamps.min()), 3),
    }
    (out / "import.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    return summary

