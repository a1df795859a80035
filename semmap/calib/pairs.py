"""Manual LiDAR-point ↔ image-pixel pairs: reading and writing the pairs file.

Two formats, told apart by the first non-comment line:

* Hong et al.'s ``data.txt`` (`ehong-tl/camera_2d_lidar_calibration`): one pair per line,
  ``laser_x laser_y u v``, separated by spaces; no header.
* CSV with a header naming the columns: ``x,y,u,v`` (also ``laser_x``/``lidar_x``,
  ``laser_y``/``lidar_y``, ``pixel_u``/``pixel_v``). Other columns are ignored.

``x, y`` are metres in the LiDAR frame (the point's z is 0: it lies in the scan plane);
``u, v`` are pixels (column, row) in the camera image. Lines starting with ``#`` are comments.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError

__all__ = ["PointPixelPairs", "read_pairs", "write_pairs"]

_ALIASES = {
    "x": ("x", "laser_x", "lidar_x", "x_m", "lidar_x_m"),
    "y": ("y", "laser_y", "lidar_y", "y_m", "lidar_y_m"),
    "u": ("u", "pixel_u", "u_px", "col"),
    "v": ("v", "pixel_v", "v_px", "row"),
}


@dataclass(frozen=True)
class PointPixelPairs:
    """N pairs of a LiDAR point and the pixel where a person saw it.

    ``lidar_xy`` (N, 2): metres in the LiDAR frame (z = 0). ``pixels`` (N, 2): (u, v) in pixels.
    ``lines`` (N,): the line of each pair in its file (1-based), for reports.
    """

    lidar_xy: NDArray[np.float64]
    pixels: NDArray[np.float64]
    lines: tuple[int, ...] = ()
    source: str = ""

    def __post_init__(self) -> None:
        xy = np.asarray(self.lidar_xy, dtype=np.float64).reshape(-1, 2)
        uv = np.asarray(self.pixels, dtype=np.float64).reshape(-1, 2)
        if xy.shape != uv.shape:
            raise ValueError(f"{xy.shape[0]} LiDAR points but {uv.shape[0]} pixels")
        lines = tuple(self.lines) if self.lines else tuple(range(1, xy.shape[0] + 1))
        for name, a in (("lidar_xy", xy), ("pixels", uv)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "lines", lines)

    def __len__(self) -> int:
        return int(self.lidar_xy.shape[0])

    @property
    def lidar_points(self) -> NDArray[np.float64]:
        """(N, 3) points in the LiDAR frame, z = 0."""
        return np.column_stack([self.lidar_xy, np.zeros(len(self))])


def _parse_float(text: str, source: str, line: int, column: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ConfigError(f"{source}: line {line}: {column} is not a number: {text!r}") from None
    if not math.isfinite(v):
        raise ConfigError(f"{source}: line {line}: {column} is not finite: {text!r}")
    return v


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_pairs(path: str | Path) -> PointPixelPairs:
    """Read a pairs file (Hong's ``data.txt`` or CSV with a header); errors name the file and line."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read pairs file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a text file (expected 'laser_x laser_y u v' lines or CSV)") from None
    src = str(p)
    rows: list[tuple[float, float, float, float]] = []
    lines: list[int] = []
    numbered = [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]
    numbered = [(i, ln) for i, ln in numbered if ln and not ln.startswith("#")]
    if not numbered:
        raise ConfigError(f"{src}: pairs file holds no pairs")
    first = numbered[0][1]
    is_csv = "," in first or p.suffix.lower() == ".csv"
    has_header = not all(_is_number(tok) for tok in first.replace(",", " ").split())
    if is_csv and has_header:
        reader = csv.reader(io.StringIO("\n".join(ln for _, ln in numbered)))
        header = [h.strip().lower() for h in next(reader)]
        cols: dict[str, int] = {}
        for key, names in _ALIASES.items():
            found = [header.index(n) for n in names if n in header]
            if not found:
                raise ConfigError(f"{src}: line {numbered[0][0]}: CSV header has no column {key!r} "
                                  f"(expected x, y, u, v; got {', '.join(header)})")
            cols[key] = found[0]
        for (lineno, _), row in zip(numbered[1:], reader):
            if len(row) <= max(cols.values()):
                raise ConfigError(f"{src}: line {lineno}: expected {len(header)} columns, got {len(row)}")
            rows.append(tuple(_parse_float(row[cols[k]], src, lineno, k) for k in "xyuv"))  # type: ignore[arg-type]
            lines.append(lineno)
    else:
        for lineno, ln in numbered:
            parts = ln.replace(",", " ").split()
            if len(parts) != 4:
                raise ConfigError(f"{src}: line {lineno}: expected 4 numbers 'laser_x laser_y u v', "
                                  f"got {len(parts)}")
            rows.append(tuple(_parse_float(v, src, lineno, k) for v, k in zip(parts, "xyuv")))  # type: ignore[arg-type]
            lines.append(lineno)
    if not rows:
        raise ConfigError(f"{src}: pairs file holds no pairs")
    a = np.array(rows, dtype=np.float64)
    return PointPixelPairs(a[:, :2], a[:, 2:], tuple(lines), src)


def write_pairs(path: str | Path, pairs: PointPixelPairs, fmt: str = "hong") -> Path:
    """Write pairs as Hong's ``data.txt`` (``fmt="hong"``) or CSV with a header (``fmt="csv"``)."""
    p = Path(path)
    if fmt == "csv":
        body = "x,y,u,v\n" + "".join(f"{x:.6f},{y:.6f},{u:.3f},{v:.3f}\n"
                                     for (x, y), (u, v) in zip(pairs.lidar_xy, pairs.pixels))
    elif fmt == "hong":
        body = "".join(f"{x:.6f} {y:.6f} {u:.3f} {v:.3f}\n" for (x, y), (u, v) in zip(pairs.lidar_xy, pairs.pixels))
    else:
        raise ValueError(f"unknown pairs format {fmt!r} (expected 'hong' or 'csv')")
    p.write_text(body, encoding="utf-8")
    return p
