"""Wheel odometry as a time series: interpolated poses for deskewing and synchronisation."""

from __future__ import annotations

import bisect
import math

import numpy as np
from numpy.typing import NDArray

from ..geometry import wrap_angle

__all__ = ["OdomTrack"]


class OdomTrack:
    """A sliding window of odometry poses ``(x, y, yaw)`` of base_link in the odom frame.

    Poses are interpolated linearly in position and along the shortest arc in yaw.
    Old samples are dropped with :meth:`trim`, so memory stays bounded on long tours.
    """

    def __init__(self, max_gap_s: float = 0.5) -> None:
        self.max_gap_ns = int(max_gap_s * 1e9)
        self._t: list[int] = []
        self._f: list[tuple[float, float, float]] = []  # poses as plain floats (the few-stamps path needs no arrays)
        self._arrays: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None  # cache for interpolate
        self.out_of_order = 0

    def __len__(self) -> int:
        return len(self._t)

    @property
    def last_ns(self) -> int | None:
        return self._t[-1] if self._t else None

    def add(self, stamp_ns: int, pose: NDArray[np.float64]) -> None:
        if self._t and stamp_ns <= self._t[-1]:
            self.out_of_order += 1  # repeated or backwards stamps are dropped, and counted
            return
        self._t.append(int(stamp_ns))
        x, y, yaw = np.asarray(pose, dtype=np.float64)[:3].tolist()
        self._f.append((x, y, yaw))
        self._arrays = None

    def trim(self, before_ns: int) -> None:
        """Forget samples older than ``before_ns`` (keeping one before it for interpolation)."""
        k = bisect.bisect_left(self._t, before_ns) - 1
        if k > 0:
            del self._t[:k]
            del self._f[:k]
            self._arrays = None

    def covers(self, t_ns: int) -> bool:
        return bool(self._t) and self._t[0] <= t_ns <= self._t[-1]

    def interpolate(self, t_ns: NDArray[np.int64] | int) -> NDArray[np.float64] | None:
        """Poses at ``t_ns`` (scalar → (3,), array → (N, 3)); None if any time is not covered
        or falls in a gap longer than ``max_gap_s`` between samples."""
        if len(self._t) < 2:
            return None
        if np.ndim(t_ns) == 0 or len(t_ns) <= 4:  # the painter asks for 1-3 stamps a scan: no arrays needed
            return self._few(t_ns)
        tt = np.atleast_1d(np.asarray(t_ns, dtype=np.int64))
        if self._arrays is None:
            self._arrays = (np.asarray(self._t, dtype=np.int64), np.asarray(self._f, dtype=np.float64))
        t, p = self._arrays
        if tt.min() < t[0] or tt.max() > t[-1]:
            return None
        k = np.clip(np.searchsorted(t, tt, side="right") - 1, 0, len(t) - 2)
        gap = t[k + 1] - t[k]
        if np.any(gap > self.max_gap_ns):
            return None
        f = ((tt - t[k]) / np.maximum(gap, 1)).astype(np.float64)[:, None]
        a, b = p[k], p[k + 1]
        out = a + f * (b - a)
        d = b[:, 2] - a[:, 2]
        d = (d + np.pi) % (2 * np.pi) - np.pi  # shortest arc (the ±π tie does not matter here)
        yaw = a[:, 2] + f[:, 0] * d
        out[:, 2] = np.pi - (np.pi - yaw) % (2 * np.pi)  # wrap to (-π, π]
        return out[0] if np.ndim(t_ns) == 0 else out

    def _few(self, t_ns: NDArray[np.int64] | int) -> NDArray[np.float64] | None:
        """:meth:`interpolate` for a handful of stamps, in plain floats (same arithmetic)."""
        scalar = np.ndim(t_ns) == 0
        stamps = [int(t_ns)] if scalar else [int(v) for v in t_ns]
        t, f = self._t, self._f
        out = np.empty((len(stamps), 3))
        for i, tq in enumerate(stamps):
            if tq < t[0] or tq > t[-1]:
                return None
            k = min(max(bisect.bisect_right(t, tq) - 1, 0), len(t) - 2)
            gap = t[k + 1] - t[k]
            if gap > self.max_gap_ns:
                return None
            w = (tq - t[k]) / max(gap, 1)
            (ax, ay, ayaw), (bx, by, byaw) = f[k], f[k + 1]
            d = (byaw - ayaw + math.pi) % (2 * math.pi) - math.pi
            yaw = ayaw + w * d
            out[i] = (ax + w * (bx - ax), ay + w * (by - ay), wrap_angle(yaw))
        return out[0] if scalar else out
