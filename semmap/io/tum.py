"""Trajectories in TUM format: ``t x y z qx qy qz qw`` per line, t in seconds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..geometry import quaternion_to_yaw, yaw_to_quaternion

__all__ = ["read_tum", "write_tum"]


def write_tum(path: str | Path, stamps_ns: NDArray[np.int64], poses: NDArray[np.float64]) -> Path:
    """Write SE(2) poses (N, 3) with integer-nanosecond stamps as a TUM file (z = 0)."""
    p = Path(path)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if stamps.shape[0] != poses.shape[0]:
        raise ValueError("one stamp per pose")
    q = yaw_to_quaternion(poses[:, 2])
    with p.open("w", encoding="utf-8") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for t, (x, y, _), (qx, qy, qz, qw) in zip(stamps, poses, q):
            sec, ns = divmod(int(t), 1_000_000_000)
            f.write(f"{sec}.{ns:09d} {x:.6f} {y:.6f} 0.000000 {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}\n")
    return p


def read_tum(path: str | Path) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Read a TUM file: integer-nanosecond stamps and SE(2) poses (x, y, yaw)."""
    p = Path(path)
    stamps: list[int] = []
    rows: list[list[float]] = []
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read trajectory ({exc.strerror})") from None
    for i, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8:
            raise ConfigError(f"{p}:{i}: expected 8 values 't x y z qx qy qz qw', got {len(parts)}")
        sec, _, frac = parts[0].partition(".")
        try:
            stamps.append(int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]))
            rows.append([float(v) for v in parts[1:]])
        except ValueError:
            raise ConfigError(f"{p}:{i}: not a number") from None
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    yaw = quaternion_to_yaw(a[:, 3:7])
    return np.asarray(stamps, dtype=np.int64), np.column_stack([a[:, 0], a[:, 1], yaw])
