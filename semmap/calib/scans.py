"""Reading one 2D scan from a file: PCD (as the ACFR calibration data), CSV or NPY.

* ``.pcd``: ASCII or binary PCD with fields ``x y [z]`` (metres, LiDAR frame).
* ``.csv``: a header naming ``x,y[,z]`` (points) or ``angle,range`` (radians, metres), or a
  single ``range`` column (then ``angle_min`` and ``angle_increment`` are needed).
* ``.npy``: an (N, 2) or (N, 3) array of points, or an (N,) array of ranges (then
  ``angle_min`` and ``angle_increment`` are needed).

Points with a non-finite coordinate or at the origin (what some drivers write for "no
return") are dropped. The result is (N, 3) points in the LiDAR frame.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError

__all__ = ["ranges_to_points", "read_scan_points"]


def ranges_to_points(ranges: NDArray[np.floating], angle_min: float, angle_increment: float,
                     range_min: float = 0.0, range_max: float = np.inf) -> NDArray[np.float64]:
    """``sensor_msgs/LaserScan`` ranges → (N, 3) points (z = 0); invalid beams dropped."""
    r = np.asarray(ranges, dtype=np.float64).ravel()
    a = angle_min + angle_increment * np.arange(r.size)
    ok = np.isfinite(r) & (r >= max(range_min, 1e-6)) & (r <= range_max)
    return np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok]), np.zeros(ok.sum())])


def _clean(p: NDArray[np.float64]) -> NDArray[np.float64]:
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    ok = np.all(np.isfinite(p), axis=1) & (np.linalg.norm(p, axis=1) > 1e-6)
    return p[ok]


def _read_pcd(p: Path) -> NDArray[np.float64]:
    data = p.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise ConfigError(f"{p}: PCD header ends without a DATA line")
        line = data[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    fields = header.get("FIELDS", [])
    if "x" not in fields or "y" not in fields:
        raise ConfigError(f"{p}: PCD has no x/y fields (FIELDS {' '.join(fields)})")
    n = int(header.get("POINTS", header.get("WIDTH", ["0"]))[0])
    kind = header["DATA"][0].lower()
    cols = [fields.index(c) for c in ("x", "y", "z") if c in fields]
    if kind == "ascii":
        try:
            arr = np.loadtxt(io.BytesIO(data[pos:]), ndmin=2)
        except ValueError as exc:
            raise ConfigError(f"{p}: malformed PCD data ({exc})") from None
        if arr.shape[1] < len(fields):
            raise ConfigError(f"{p}: PCD rows have {arr.shape[1]} values, FIELDS names {len(fields)}")
        return _clean(arr[:, cols].astype(np.float64))
    if kind == "binary":
        sizes = [int(s) for s in header.get("SIZE", [])]
        types = header.get("TYPE", [])
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
        names = [f"f{i}" for i in range(len(fields))]
        fmt = [(nm, f"<{t.lower()}{s}", (c,) if c > 1 else ()) for nm, t, s, c in zip(names, types, sizes, counts)]
        try:
            rec = np.frombuffer(data[pos:], dtype=np.dtype(fmt), count=n)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{p}: malformed binary PCD ({exc})") from None
        return _clean(np.column_stack([rec[names[c]].astype(np.float64) for c in cols]))
    raise ConfigError(f"{p}: PCD 'DATA {kind}' is not supported (use ascii or binary)")


def read_scan_points(path: str | Path, angle_min: float | None = None,
                     angle_increment: float | None = None) -> NDArray[np.float64]:
    """Read a scan file (PCD, CSV or NPY) → (N, 3) points in the LiDAR frame (m)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such scan file")
    suffix = p.suffix.lower()

    def polar(r: NDArray[np.float64]) -> NDArray[np.float64]:
        if angle_min is None or angle_increment is None:
            raise ConfigError(f"{p}: holds ranges only; give the scan's angle_min and angle_increment")
        return ranges_to_points(r, angle_min, angle_increment)

    try:
        if suffix == ".pcd":
            return _read_pcd(p)
        if suffix == ".npy":
            try:
                a = np.load(p, allow_pickle=False)
            except ValueError as exc:
                raise ConfigError(f"{p}: not a plain NumPy array file ({exc})") from None
            if a.ndim == 1:
                return polar(a.astype(np.float64))
            if a.ndim == 2 and a.shape[1] in (2, 3):
                return _clean(a.astype(np.float64))
            raise ConfigError(f"{p}: expected (N, 2)/(N, 3) points or (N,) ranges, got shape {a.shape}")
        if suffix in (".csv", ".txt"):
            text = p.read_text(encoding="utf-8")
            rows = [r for r in csv.reader(io.StringIO(text)) if r and not r[0].lstrip().startswith("#")]
            if not rows:
                raise ConfigError(f"{p}: empty scan file")
            header = [h.strip().lower() for h in rows[0]]
            try:
                vals = np.array([[float(v) for v in r] for r in rows[1:]], dtype=np.float64).reshape(len(rows) - 1, -1)
            except ValueError as exc:
                raise ConfigError(f"{p}: a value is not a number ({exc})") from None
            if "x" in header and "y" in header:
                cols = [header.index(c) for c in ("x", "y", "z") if c in header]
                return _clean(vals[:, cols])
            if "angle" in header and "range" in header:
                a, r = vals[:, header.index("angle")], vals[:, header.index("range")]
                ok = np.isfinite(r) & (r > 0)
                return np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok]), np.zeros(ok.sum())])
            if "range" in header or "ranges" in header:
                return polar(vals[:, header.index("range" if "range" in header else "ranges")])
            raise ConfigError(f"{p}: CSV header must name x,y[,z] or angle,range or range (got {', '.join(header)})")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read scan ({exc.strerror})") from None
    raise ConfigError(f"{p}: unknown scan file type {suffix!r} (expected .pcd, .csv or .npy)")
