"""Scan registration: the base pose of every scan in the map frame.

:class:`Registrar` takes :class:`~semmap.records.PaintedScan` records one at a time,
in time order, with the wheel-odometry pose at each scan's stamp, and returns the
pose ``(x, y, yaw)`` of ``base_link`` in the map frame. The map frame is the base
pose of the first scan (so the first pose is the identity).

Modes (:class:`~semmap.config.RegistrationConfig` ``mode``):

``odometry``
    Wheel odometry alone: ``T_map_base = T_odom_base(first)⁻¹ · T_odom_base``.
``icp``
    KISS-ICP alone, as upstream does it: scan-to-local-map ICP from a
    constant-velocity guess; the ICP result goes into the local map.
``fused`` (default)
    An EKF predicts with the odometry increment between consecutive scans, corrected
    by the odometry's systematic errors it has learnt (:mod:`~semmap.register.ekf`), with
    a noise scaled to the odometry's disagreement with ICP over recent stretches
    (``ekf.adapt_window``); ICP starts from that prediction; its result is a pose
    measurement (covariance: :meth:`Registrar._icp_covariance`; a degenerate match
    leaves the direction it cannot see to odometry, and over the first metre driven,
    ``ekf.first_view``, so does a weak one), gated by its Mahalanobis distance
    (chi-square, ``ekf.gate_chi2``). With ``ekf.fit_margin``
    below 1, a result beyond the gate is still taken (the filter restarts from it)
    when the scan lies on the local map better at ICP's pose than at the prediction:
    real wheel odometry drifts in heading and scale more than any noise model
    allows, and then the gate rejects good matches (off by default: see
    docs/registration.md). Rejected or failed ICP leaves the prediction. The fused
    pose goes into the local map and is the base of the next guess; a scan whose ICP
    result was rejected is not inserted (it contradicts the prediction, so one of them
    is wrong). After
    ``ekf.reset_after`` rejections in a row ICP is trusted again: the filter
    restarts from the ICP pose (wheel slip, a kidnapped robot). Without odometry
    at this scan or the previous one, the step runs as in ``icp`` mode and the
    filter restarts from the ICP pose.

With ``loop_closure.enabled``, every registered scan also goes to a
:class:`~semmap.register.loops.LoopCloser`; :meth:`Registrar.close_loops` solves its pose graph
at the end of the tour. The loop closer needs nothing back until then, so it may run elsewhere
(``Registrar(cfg, close_loops_here=False)``: each scan's keyframe record, made here by a
:class:`~semmap.register.loops.KeyframeSelector` (keyframe selection, down-sampling, normals,
descriptor and the step edge's re-match), is left in :attr:`Registrar.loop_record` for
:meth:`~semmap.register.loops.LoopCloser.add_record`; the build runs the loop search in the fusion
worker, off the registration's critical path, and this process has the time for the rest).

With ``exclude_dynamic``, points painted :attr:`~semmap.records.Mobility.DYNAMIC`
are neither matched nor inserted into the local map. Only beams with ``hit`` set
and a range (from ``scan.origin``) within ``[min_range, max_range]`` are used.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import RegistrationConfig
from ..geometry import se2_apply, se2_between, se2_compose, se2_inverse, wrap_angle
from ..records import Mobility, PaintedScan
from .ekf import Se2Ekf, odometry_noise
from .kiss import KissMatcher
from .refine import LineRefiner

__all__ = ["Registrar"]

log = logging.getLogger(__name__)

_ZERO = np.zeros(3)
#: m², ICP's variance along the direction a degenerate match cannot see (with ekf.icp_point_std 0)
_DEGENERATE_VAR = 1.0


@dataclass(frozen=True)
class _Prepared:
    """A scan ready for ICP (see :meth:`Registrar.prepare`)."""

    scan: Any  # kiss.PreparedScan
    points_used: int
    points_dynamic_excluded: int


def _as_pose(p: ArrayLike | None, what: str) -> NDArray[np.float64] | None:
    if p is None:
        return None
    a = np.asarray(p, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{what} must be (x, y, yaw), got shape {np.shape(p)}")
    if not np.all(np.isfinite(a)):
        return None
    a = a.copy()
    a[2] = wrap_angle(a[2])
    return a


def registration_speed(scans: int, seconds: float) -> dict[str, Any]:
    """``seconds`` and ``scans_per_s`` of the build summary's ``registration``."""
    return {"seconds": round(seconds, 3), "scans_per_s": round(scans / seconds, 1) if seconds > 0 else None}


def loop_config(cfg: RegistrationConfig) -> Any:
    """The :class:`~semmap.register.loops.LoopConfig` of ``cfg.loop_closure``."""
    from .loops import LoopConfig

    lc = cfg.loop_closure
    return LoopConfig(
        keyframe_distance=lc.keyframe_distance, keyframe_angle=lc.keyframe_angle,
        min_separation=lc.min_separation, search_radius=lc.search_radius, drift_per_m=lc.drift_per_m,
        descriptor=lc.descriptor, min_inliers=lc.min_inliers, inlier_distance=lc.inlier_distance,
        rematch=lc.rematch)


def loop_closer(cfg: RegistrationConfig) -> Any:
    """The :class:`~semmap.register.loops.LoopCloser` ``cfg.loop_closure`` asks for (None: off). It takes each
    registered scan's pose and down-sampled points, or their :class:`~semmap.register.loops.ScanRecord`, and
    needs nothing back until the end of the tour, so it may run in another process than the registration (the
    build's fusion worker, idle while loop closure defers fusion to the end)."""
    if not cfg.loop_closure.enabled:
        return None
    from .loops import LoopCloser

    return LoopCloser(loop_config(cfg), cfg)


def solve_loops(closer: Any) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Solve a :func:`loop_closer`'s pose graph: the corrected poses (N, 3), one per scan added, and its
    counters for the build summary (``registration.loop_closure``)."""
    result = closer.optimise()
    stats = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in result.stats.items()}
    stats["loops"] = [list(map(int, ab)) for ab in result.loops]
    return np.asarray(result.poses, np.float64).reshape(-1, 3), stats


class Registrar:
    """Registers painted scans one after another; see the module docstring for the modes.

    >>> reg = Registrar(RegistrationConfig(mode="fused"))      # doctest: +SKIP
    >>> for scan, odom in zip(scans, odom_poses):              # doctest: +SKIP
    ...     pose = reg.register(scan, odom)                    # (x, y, yaw) in the map frame
    >>> reg.stats["icp_rejected"]                              # doctest: +SKIP
    """

    def __init__(self, cfg: RegistrationConfig, close_loops_here: bool = True) -> None:
        self.cfg = cfg
        self._matcher: KissMatcher | None = None if cfg.mode == "odometry" else KissMatcher(cfg)
        # loop closure keeps keyframes' points: in odometry mode a matcher down-samples them and does no more
        self._sampler: KissMatcher | None = self._matcher if self._matcher is not None or not \
            cfg.loop_closure.enabled else KissMatcher(cfg)
        self._closer: Any = loop_closer(cfg) if close_loops_here else None
        self._loop_stats: dict[str, Any] | None = None
        #: with loop closure run elsewhere (``close_loops_here=False``): the last registered scan's
        #: :class:`~semmap.register.loops.ScanRecord`, for that :class:`~semmap.register.loops.LoopCloser`'s
        #: ``add_record``
        self.loop_record: Any = None
        self._selector: Any = None
        if not close_loops_here and cfg.loop_closure.enabled:
            from .loops import KeyframeSelector

            self._selector = KeyframeSelector(loop_config(cfg), cfg)
        self._ekf: Se2Ekf | None = Se2Ekf(cfg.ekf) if cfg.mode == "fused" else None
        rf = cfg.refine
        self._refiner: LineRefiner | None = LineRefiner(neighbours=rf.neighbours) \
            if rf.enabled and self._matcher is not None else None
        self._refined_since = np.inf  # m driven + rad turned since the refiner's map was taken
        self._pose: NDArray[np.float64] | None = None  # last returned pose (map frame)
        self._velocity = _ZERO.copy()  # last increment, for the constant-velocity guess
        self._last_odom: NDArray[np.float64] | None = None  # odometry pose at the previous scan
        self._map_from_odom: NDArray[np.float64] | None = None  # T_map_odom (odometry mode)
        self._last_stamp: int | None = None
        self._counts: dict[str, int] = {
            "scans": 0,  # scans registered
            "icp_accepted": 0,  # ICP results used (icp mode: every successful ICP)
            "icp_over_odometry": 0,  # fused: of the results used, those beyond the gate (ekf.fit_margin < 1)
            "icp_rejected": 0,  # ICP results gated out by the EKF (fused)
            "icp_failed": 0,  # ICP not run or unusable: too few points, empty map, non-finite result
            "filter_resets": 0,  # fused: the EKF restarted from ICP after ekf.reset_after rejections in a row
            "icp_degenerate": 0,  # ICP results whose match leaves a direction unconstrained (a corridor)
            "icp_refined": 0,  # ICP results refined point-to-line (refine.enabled)
            "odom_missing": 0,  # scans without odometry (fused: ran as icp; odometry: extrapolated)
            "points_used": 0,  # hit points passed to the down-sampler
            "points_dynamic_excluded": 0,  # hit points dropped because painted dynamic
        }
        self._rejected_run = 0  # ICP results gated out in a row
        self._driven = 0.0  # m driven since the first scan
        # the odometry noise's scale (std; x, y and yaw), learnt from its disagreement with ICP
        window = cfg.ekf.adapt_window
        self._noise_scale = np.ones(3)
        self._excess_t: deque[float] = deque(maxlen=max(window, 1))
        self._excess_r: deque[float] = deque(maxlen=max(window, 1))
        self._max_scale = np.ones(2)
        self._anchor: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # ICP pose and covariance
        self._stretch_odom = _ZERO.copy()  # corrected odometry motion since the anchor, in its frame
        self._stretch_q = np.zeros(2)  # its configured noise: std of translation (per axis) and heading
        self._stretch_path = 0.0  # m driven + rad turned since the anchor
        self._max_d2 = 0.0
        self._seconds = 0.0

    # -- public ------------------------------------------------------------------------
    @property
    def stats(self) -> dict[str, Any]:
        """Counters for the build summary, plus ``mode``, ``seconds`` and ``scans_per_s``."""
        out: dict[str, Any] = {"mode": self.cfg.mode, **self._counts}
        out["max_mahalanobis2_accepted"] = round(self._max_d2, 3)
        if self._ekf is not None:
            out["odometry_noise_scale_max"] = {"translation": round(float(self._max_scale[0]), 2),
                                               "rotation": round(float(self._max_scale[1]), 2)}
        if self._loop_stats is not None:
            out["loop_closure"] = self._loop_stats
        out.update(registration_speed(self._counts["scans"], self._seconds))
        return out

    @property
    def pose(self) -> NDArray[np.float64] | None:
        """The last pose returned by :meth:`register` (None before the first scan)."""
        return None if self._pose is None else self._pose.copy()

    def local_map(self) -> NDArray[np.float64]:
        """KISS-ICP's local map as (M, 2) map-frame points ((0, 2) in ``odometry`` mode)."""
        return np.zeros((0, 2)) if self._matcher is None else self._matcher.map_points()

    def prepare(self, scan: PaintedScan) -> Any:
        """The stateless first step of :meth:`register`: select and down-sample the scan's points.

        It may run in another process (the build pipeline does it beside the painter) and its
        result be passed to :meth:`register` as ``prepared``. None in ``odometry`` mode without
        loop closure.
        """
        if self._sampler is None:
            return None
        pts, used, dynamic = self._select(scan)
        return _Prepared(self._sampler.prepare(pts), used, dynamic)

    def register(self, scan: PaintedScan, odom_pose: ArrayLike | None, prepared: Any = None) -> NDArray[np.float64]:
        """Return the base_link pose (x, y, yaw) in the map frame for this scan.

        ``odom_pose``: the wheel-odometry pose (x, y, yaw) of base_link in the odom
        frame at ``scan.stamp_ns``, or None. The map frame is the first scan's base
        pose (identity). Scans must come in time order. ``prepared``: this scan's
        :meth:`prepare` result, if already computed.
        """
        t0 = time.perf_counter()
        if self._last_stamp is not None and scan.stamp_ns < self._last_stamp:
            raise ValueError(f"scans must be registered in time order ({scan.stamp_ns} < {self._last_stamp})")
        odom = _as_pose(odom_pose, "odom_pose")
        if odom is None:
            self._counts["odom_missing"] += 1
        prep = prepared if prepared is not None else self.prepare(scan)
        pose = self._odometry_step(odom) if self.cfg.mode == "odometry" else self._scan_step(scan, odom, prep)
        self.loop_record = None  # (never the scan before's)
        if self.cfg.loop_closure.enabled and prep is not None:
            if self._closer is not None:
                self._closer.add(self._counts["scans"], pose, prep.scan.map_points[:, :2])
            else:
                self.loop_record = self._selector.make(self._counts["scans"], pose, prep.scan.map_points[:, :2])
        if self._pose is not None:
            self._velocity = se2_between(self._pose, pose)
            self._driven += float(np.hypot(self._velocity[0], self._velocity[1]))
        self._pose = pose
        self._last_odom = odom
        self._last_stamp = scan.stamp_ns
        self._counts["scans"] += 1
        self._seconds += time.perf_counter() - t0
        return pose.copy()

    def close_loops(self) -> NDArray[np.float64] | None:
        """With ``loop_closure.enabled``: solve the pose graph of every scan registered so far and return
        the corrected poses (N, 3), one per :meth:`register` call; its counters join :attr:`stats`
        (``loop_closure``). None without loop closure."""
        if self._closer is None:
            return None
        t0 = time.perf_counter()
        poses, self._loop_stats = solve_loops(self._closer)
        self._seconds += time.perf_counter() - t0
        return poses

    # -- modes ---------------------------------------------------------------------------
    def _odometry_step(self, odom: NDArray[np.float64] | None) -> NDArray[np.float64]:
        if odom is None:  # no odometry: keep moving as before
            return _ZERO.copy() if self._pose is None else se2_compose(self._pose, self._velocity)
        if self._map_from_odom is None:  # anchor: this scan's pose is what we have so far
            here = _ZERO if self._pose is None else self._pose
            self._map_from_odom = se2_compose(here, se2_inverse(odom))
        return se2_compose(self._map_from_odom, odom)

    def _scan_step(self, scan: PaintedScan, odom: NDArray[np.float64] | None, prep: _Prepared) -> NDArray[np.float64]:
        assert self._matcher is not None
        self._counts["points_used"] += prep.points_used
        self._counts["points_dynamic_excluded"] += prep.points_dynamic_excluded
        prepared = prep.scan
        if self._pose is None:  # first scan: defines the map frame
            if self._ekf is not None:
                self._ekf.reset(_ZERO)
            self._matcher.update_map(prepared, _ZERO)
            return _ZERO.copy()

        use_odom = self._ekf is not None and odom is not None and self._last_odom is not None
        delta = _ZERO
        if use_odom:
            assert self._ekf is not None and self._last_odom is not None and odom is not None
            delta = se2_between(self._last_odom, odom)
            self._ekf.predict(delta, self._noise_scale)
            guess = self._ekf.pose
        else:
            guess = se2_compose(self._pose, self._velocity)

        result = self._icp(prepared, guess)
        R: NDArray[np.float64] | None = None
        degenerate = False
        if result is not None:
            R, degenerate = self._icp_covariance(prepared, result)
            self._counts["icp_degenerate"] += int(degenerate)
        if self._ekf is not None:
            self._learn_odometry_noise(delta if use_odom else None, result, R, degenerate)
        if use_odom:
            assert self._ekf is not None
            if result is not None:
                assert R is not None
                d2 = self._ekf.mahalanobis2(result, R)
                if d2 <= self.cfg.ekf.gate_chi2:
                    self._ekf.update(result, R)
                    self._counts["icp_accepted"] += 1
                    self._max_d2 = max(self._max_d2, d2)
                    self._matcher.update_threshold(guess, result)
                    self._rejected_run = 0
                elif self._fits_better(prepared, result, self._ekf.pose):
                    # odometry and ICP disagree, and ICP's pose explains the scan better than the prediction
                    # does (by more than ekf.fit_margin): the odometry is off (a heading drift, a slip), not ICP
                    self._ekf.reset(result, R)
                    self._counts["icp_accepted"] += 1
                    self._counts["icp_over_odometry"] += 1
                    self._matcher.update_threshold(guess, result)
                    self._rejected_run = 0
                else:
                    self._counts["icp_rejected"] += 1
                    self._rejected_run += 1
                    log.debug("scan %d: ICP rejected, Mahalanobis² %.1f > %.1f (correction %s)",
                              scan.stamp_ns, d2, self.cfg.ekf.gate_chi2, np.round(self._ekf.innovation(result), 4))
                    if 0 < self.cfg.ekf.reset_after <= self._rejected_run:
                        # ICP has disagreed with odometry for a while: odometry is the suspect
                        log.info("scan %d: %d ICP results gated out in a row; restarting the filter from ICP",
                                 scan.stamp_ns, self._rejected_run)
                        self._ekf.reset(result, R)
                        self._counts["filter_resets"] += 1
                        self._rejected_run = 0
                    else:
                        # keep the local map clean: a scan that contradicts the prediction is not inserted
                        return self._ekf.pose
            pose = self._ekf.pose
        else:
            if result is not None:
                self._counts["icp_accepted"] += 1
                self._matcher.update_threshold(guess, result)
            pose = guess if result is None else result
            if self._ekf is not None:  # fused without odometry: restart the filter from here
                self._ekf.reset(pose, R if R is not None else self._ekf.cov)
                self._rejected_run = 0
        self._matcher.update_map(prepared, pose)
        return pose

    # -- helpers -------------------------------------------------------------------------
    def _icp_covariance(self, prepared: Any, pose: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
        """ICP's pose covariance in the map frame, and whether the match is degenerate.

        ``H`` is the match's point-to-line Hessian in the base frame
        (:func:`~semmap.register.kiss.sweep_information`). Degenerate: the weaker direction of
        translation carries under ``degenerate_ratio`` of the stronger's information (a corridor,
        one wall). With ``icp_point_std`` 0 (the default) the covariance is the fixed ``icp_xy_std`` /
        ``icp_yaw_std``, plus 1 m² along the direction a degenerate match cannot see, so odometry
        holds it. Otherwise ``icp_point_std² · (H + prior)⁻¹`` with a broad prior (1 m, 1 rad) that
        keeps a direction no line constrains finite, rotated into the map frame, the fixed ones
        its floor. (Measured: the fixed one is better on the simulated tours and on Intel, the
        Hessian's with 5 cm on the Hokuyo bags; docs/registration.md.)
        """
        e = self.cfg.ekf
        floor = np.diag([e.icp_xy_std ** 2, e.icp_xy_std ** 2, e.icp_yaw_std ** 2])
        H = np.asarray(getattr(prepared, "information", np.zeros((3, 3))), np.float64)
        lam, vec = np.linalg.eigh(H[:2, :2])
        # until the robot has moved, the local map is one view, whose beam pattern holds a weak match to where
        # the robot stood (stop 53: a tour starting in a corridor): the wheels keep a weak direction then
        first_m, first_ratio = e.first_view
        ratio = e.degenerate_ratio if self._driven >= first_m else max(e.degenerate_ratio, first_ratio)
        degenerate = bool(lam[1] <= 0 or lam[0] < ratio * lam[1])
        c, s = np.cos(pose[2]), np.sin(pose[2])
        G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        if e.icp_point_std <= 0:
            # the fixed covariance, but a direction the match cannot see is left to odometry
            cov_base = np.zeros((3, 3))
            if degenerate:
                cov_base[:2, :2] = np.outer(vec[:, 0], vec[:, 0]) * _DEGENERATE_VAR
            cov = G @ cov_base @ G.T + floor
            return 0.5 * (cov + cov.T), degenerate
        sp2 = e.icp_point_std ** 2
        cov = G @ (sp2 * np.linalg.inv(H + sp2 * np.eye(3))) @ G.T + floor
        return 0.5 * (cov + cov.T), degenerate

    def _learn_odometry_noise(self, delta: NDArray[np.float64] | None, result: NDArray[np.float64] | None,
                              R: NDArray[np.float64] | None, degenerate: bool) -> None:
        """Scale the odometry noise to its disagreement with ICP (``ekf.adapt_window``, ``adapt_baseline``).

        The wheels' motion (with the filter's systematic errors taken out) is compared with ICP's
        over stretches of ``adapt_baseline`` (m driven + rad turned) between two well-constrained ICP
        results: over a stretch the odometry's error grows while ICP's stays that of its two ends,
        so ICP's noise does not swamp it (per scan, at walking speed, it would). Per stretch, the
        share of the squared disagreement that the two ICP covariances do not explain, over the
        configured odometry noise of the stretch; the scale is the square root of its median over
        the last ``adapt_window`` stretches over the median of chi-square (1 dof for the heading, 2
        for the position), at least 1. A median, so a wrong ICP match now and then does not move
        it. ICP results are measured against the map, not integrated, so this does not feed back
        on itself.
        """
        e = self.cfg.ekf
        if e.adapt_window <= 0 or self._ekf is None:
            return
        if delta is not None:
            q = odometry_noise(delta, e)
            self._stretch_odom = se2_compose(self._stretch_odom, self._ekf.corrected(delta))
            # stds add up: the odometry's errors over a stretch are mostly systematic (a scale, a drift),
            # not independent from step to step
            self._stretch_q += np.sqrt(np.array([q[0, 0], q[2, 2]]))
            self._stretch_path += float(np.hypot(delta[0], delta[1]) + abs(delta[2]))
        if result is None or R is None or degenerate:
            return
        if delta is None or self._anchor is None:  # (re)start a stretch here
            self._anchor = (result.copy(), R.copy())
            self._stretch_odom, self._stretch_q, self._stretch_path = _ZERO.copy(), np.zeros(2), 0.0
            return
        if self._stretch_path < e.adapt_baseline:
            return
        icp0, R0 = self._anchor
        err = se2_between(self._stretch_odom, se2_between(icp0, result))
        length = float(np.hypot(self._stretch_odom[0], self._stretch_odom[1]))
        ends_r = R0[2, 2] + R[2, 2]
        ends_t = np.trace(R0[:2, :2]) + np.trace(R[:2, :2]) + length ** 2 * R0[2, 2]
        var_t, var_r = self._stretch_q ** 2
        self._excess_r.append(max(err[2] ** 2 - ends_r, 0.0) / var_r)
        self._excess_t.append(max(err[0] ** 2 + err[1] ** 2 - ends_t, 0.0) / (2.0 * var_t))
        cap = e.adapt_max_scale
        need = min(3, e.adapt_window)
        if len(self._excess_t) >= need:
            self._noise_scale[:2] = float(np.sqrt(np.clip(np.median(self._excess_t) / 0.693, 1.0, cap ** 2)))
        if len(self._excess_r) >= need:
            self._noise_scale[2] = float(np.sqrt(np.clip(np.median(self._excess_r) / 0.455, 1.0, cap ** 2)))
        self._max_scale = np.maximum(self._max_scale, self._noise_scale[1:])
        self._anchor = (result.copy(), R.copy())
        self._stretch_odom, self._stretch_q, self._stretch_path = _ZERO.copy(), np.zeros(2), 0.0

    def _select(self, scan: PaintedScan) -> tuple[NDArray[np.float64], int, int]:
        """Hit points within range, without dynamic ones if configured: (M, 2) base frame,
        and the counts of points used and of dynamic points left out."""
        keep = scan.hit.copy()
        r = np.hypot(scan.points[:, 0] - scan.origin[0], scan.points[:, 1] - scan.origin[1])
        keep &= (r >= self.cfg.min_range) & (r <= self.cfg.max_range) & np.isfinite(r)
        dynamic = 0
        if self.cfg.exclude_dynamic:
            dyn = keep & (scan.mobility == int(Mobility.DYNAMIC))
            dynamic = int(dyn.sum())
            keep &= ~dyn
        return scan.points[keep], int(keep.sum()), dynamic

    def _fits_better(self, prepared: Any, icp: NDArray[np.float64], prediction: NDArray[np.float64]) -> bool:
        """True when the scan, placed at the ICP pose, lies on the local map better than at the
        predicted pose: its mean squared distance to the map (each capped at 3σ of the adaptive
        threshold, at least a voxel) is below ``1 - ekf.fit_margin`` of the prediction's. A wrong ICP
        match, or one that slid along a corridor, fits no better than the prediction and is gated out."""
        assert self._matcher is not None
        margin = self.cfg.ekf.fit_margin
        if margin >= 1.0:
            return False
        from scipy.spatial import cKDTree

        cloud = self._matcher.map_points()
        pts = np.asarray(prepared.source, np.float64)[:, :2]
        if cloud.shape[0] < 3 or pts.shape[0] < 3:
            return False
        tree = cKDTree(cloud)
        cap = max(3.0 * self._matcher.sigma, self.cfg.voxel_size)

        def cost(pose: NDArray[np.float64]) -> float:
            d, _ = tree.query(se2_apply(pose, pts), distance_upper_bound=cap)
            return float(np.mean(np.minimum(d, cap) ** 2))

        return cost(icp) < (1.0 - margin) * cost(prediction)

    def _icp(self, prepared: Any, guess: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Run ICP from ``guess``; None (counted as failed) when it cannot give a usable pose."""
        assert self._matcher is not None
        n = prepared.source.shape[0]
        if n < self.cfg.min_points or self._matcher.map_empty:
            self._counts["icp_failed"] += 1
            log.debug("ICP skipped: %d points (min %d), map empty: %s", n, self.cfg.min_points,
                      self._matcher.map_empty)
            return None
        result = self._matcher.align(prepared, guess)
        if not np.all(np.isfinite(result)):
            self._counts["icp_failed"] += 1
            log.debug("ICP returned a non-finite pose")
            return None
        return self._refine(prepared, result)

    def _refine(self, prepared: Any, result: NDArray[np.float64]) -> NDArray[np.float64]:
        """KISS-ICP's result refined point-to-line against the local map (``refine``); the result as it
        is when there are too few lines to match."""
        if self._refiner is None:
            return result
        rf = self.cfg.refine
        if self._pose is not None and self._refined_since < np.inf:
            step = se2_between(self._pose, result)
            self._refined_since += float(np.hypot(step[0], step[1]) + abs(step[2]))
        if self._refined_since >= rf.rebuild_distance or not self._refiner.has_map:
            assert self._matcher is not None
            self._refiner.set_map(self._matcher.map_points())
            self._refined_since = 0.0
        out = self._refiner.refine(prepared.map_points[:, :2], result, rf.kernel, rf.max_distance)
        if out is None:
            return result
        self._counts["icp_refined"] += 1
        return out.pose
