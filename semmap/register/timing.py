"""The offset between the odometry's clock and the LiDAR's, estimated from the tour itself.

Drivers stamp late or early: on the Hokuyo bags of ``../shared/data`` the wheel odometry is
stamped 0.15 s before the scans it goes with, so every turn's odometry increment is off by what
the robot turned in 0.15 s, and fusion fights it. ICP alone gives the turn rate on the scans'
clock; the odometry gives it on its own. The offset is the shift of the odometry's stamps that
makes the two turn-rate series agree best (least squares over a grid, refined by a parabola).
Turning is what makes it observable: without enough of it the estimate is not used.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..config import LoopClosureConfig, RegistrationConfig
from ..records import Mobility, PaintedScan

__all__ = ["OffsetEstimate", "estimate_odometry_offset"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OffsetEstimate:
    """``offset_s``: add to the odometry's stamps (0 when not ``used``); the RMS difference of the turn
    rates per scan step (rad) with no shift and with the best; ``turned_rad``: what ICP saw the robot turn."""

    offset_s: float
    used: bool
    rms_at_zero: float
    rms_at_best: float
    turned_rad: float
    scans: int
    reason: str


def estimate_odometry_offset(stamps_ns: NDArray[np.int64], points: Sequence[NDArray[np.float64]],
                             odom_stamps_ns: NDArray[np.int64], odom_yaw: NDArray[np.float64],
                             reg_cfg: RegistrationConfig, max_offset_s: float = 0.5, min_turn_rad: float = 3.0,
                             min_gain: float = 0.2, min_offset_s: float = 0.02) -> OffsetEstimate:
    """Estimate the odometry's clock offset from scans (their stamps and base-frame points (N, 2)) and
    the odometry's headings at its own stamps.

    Used only when the scans turned at least ``min_turn_rad`` in all, the best shift lowers the RMS by
    ``min_gain`` of its value with no shift, and it is at least ``min_offset_s``.
    """
    from .registrar import Registrar

    t = np.asarray(stamps_ns, np.int64)
    n = t.size
    ot = np.asarray(odom_stamps_ns, np.int64)
    if n < 20 or ot.size < 10:
        return OffsetEstimate(0.0, False, float("nan"), float("nan"), 0.0, n, "too few scans or odometry messages")
    # scan matching's turn rates only: loop closure would search these scans for loops to no use
    reg = Registrar(reg_cfg.model_copy(update={"mode": "icp", "loop_closure": LoopClosureConfig()}))
    yaw = np.empty(n)
    for i in range(n):
        pts = np.asarray(points[i], np.float64).reshape(-1, 2)
        m = pts.shape[0]
        scan = PaintedScan(stamp_ns=int(t[i]), origin=np.zeros(2), points=pts, hit=np.ones(m, bool),
                           mobility=np.full(m, int(Mobility.STATIC), np.uint8), class_id=np.full(m, -1, np.int16))
        yaw[i] = reg.register(scan, None)[2]
    d_icp = np.diff(np.unwrap(yaw))
    turned = float(np.abs(d_icp).sum())
    oyaw = np.unwrap(np.asarray(odom_yaw, np.float64))
    ok_o = np.isfinite(oyaw)
    ot, oyaw = ot[ok_o], oyaw[ok_o]
    rel = (t - ot[0]) * 1e-9
    orel = (ot - ot[0]) * 1e-9
    shifts = np.arange(-max_offset_s, max_offset_s + 1e-9, 0.01)
    rms = np.full(shifts.size, np.inf)
    # a turn between two scans of more than this is an ICP failure, not a turn
    sane = np.abs(d_icp) < 0.5
    for k, s in enumerate(shifts):
        q = rel - s  # the odometry's time of each scan if its stamps were shifted by s
        inside = (q >= orel[0]) & (q <= orel[-1])
        yo = np.interp(q, orel, oyaw)
        both = sane & inside[1:] & inside[:-1]
        if both.sum() >= max(10, n // 4):
            rms[k] = float(np.sqrt(np.mean((np.diff(yo)[both] - d_icp[both]) ** 2)))
    k0 = int(np.argmin(np.abs(shifts)))
    if not np.isfinite(rms).any() or not np.isfinite(rms[k0]):
        return OffsetEstimate(0.0, False, float("nan"), float("nan"), turned, n,
                              "the odometry does not cover the scans")
    kb = int(np.nanargmin(rms))
    best = float(shifts[kb])
    if 0 < kb < shifts.size - 1 and np.all(np.isfinite(rms[kb - 1:kb + 2])):
        a, b, c = rms[kb - 1], rms[kb], rms[kb + 1]
        den = a - 2 * b + c
        if den > 0:
            best += 0.01 * 0.5 * (a - c) / den
    def result(offset: float, reason: str) -> OffsetEstimate:
        return OffsetEstimate(offset, not reason, float(rms[k0]), float(rms[kb]), turned, n, reason)

    if turned < min_turn_rad:
        return result(0.0, f"the robot turned only {turned:.1f} rad in the scans looked at")
    if rms[kb] > (1.0 - min_gain) * rms[k0] or abs(best) < min_offset_s:
        return result(0.0, "no shift fits clearly better than none")
    if kb in (0, shifts.size - 1):
        return result(0.0, f"the best shift is at the search limit ({max_offset_s} s)")
    # a turn seen by ICP at scan time t is in the odometry at its time t - s: its stamps need + s
    return result(float(best), "")
