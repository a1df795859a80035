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
        self._f: list[tuple[float, float, float]] = []  # poses as plain floats (interpolate needs no arrays)
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

    def trim(self, before_ns: int) -> None:
        """Forget samples older than ``before_ns`` (keeping one before it for interpolation)."""
        k = bisect.bisect_left(self._t, before_ns) - 1
        if k > 0:
            del self._t[:k]
            del self._f[:k]

    def covers(self, t_ns: int) -> bool:
        return bool(self._t) and self._t[0] <= t_ns <= self._t[-1]

    def interpolate(self, t_ns: NDArray[np.int64] | int) -> NDArray[np.float64] | None:
        """Poses at ``t_ns`` (scalar → (3,), array → (N, 3)); None if any time is not covered
        or falls in a gap longer than ``max_gap_s`` between samples (a time with a sample of its own
        takes that sample, whatever the gaps beside it).

        Callers ask for a handful of stamps per scan (the painter: 1-3), so this works in plain
        floats rather than building arrays of the whole window."""
        if len(self._t) < 2:
            return None
        scalar = np.ndim(t_ns) == 0
        stamps = [int(t_ns)] if scalar else [int(v) for v in np.asarray(t_ns).reshape(-1)]
        t, f = self._t, self._f
        out = np.empty((len(stamps), 3))
        for i, tq in enumerate(stamps):
            if tq < t[0] or tq > t[-1]:
                return None
            k = min(max(bisect.bisect_right(t, tq) - 1, 0), len(t) - 2)
            gap = t[k + 1] - t[k]
            if tq in (t[k], t[k + 1]):  # a sample at the very stamp needs no interpolation, however far the next
                out[i] = f[k] if tq == t[k] else f[k + 1]
                continue
            if gap > self.max_gap_ns:
                return None
            w = (tq - t[k]) / max(gap, 1)
            (ax, ay, ayaw), (bx, by, byaw) = f[k], f[k + 1]
            d = (byaw - ayaw + math.pi) % (2 * math.pi) - math.pi
            yaw = ayaw + w * d
            out[i] = (ax + w * (bx - ax), ay + w * (by - ay), wrap_angle(yaw))
        return out[0] if scalar else out
