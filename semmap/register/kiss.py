"""The one KISS-ICP adapter: scan-to-local-map ICP for planar scans, with a caller-chosen initial guess.

Nothing else in semmap imports :mod:`kiss_icp`; it is imported lazily when a
:class:`KissMatcher` is built. Upstream ``KissICP.register_frame`` always
predicts with its own constant-velocity model and inserts its own ICP result
into the local map. semmap needs the wheel-odometry guess and the EKF-fused pose
instead, so this module assembles the same components (voxel down-sampling, the
voxel hash map, the adaptive threshold and the registration) and exposes the
three steps separately: :meth:`KissMatcher.align`,
:meth:`KissMatcher.update_threshold` and :meth:`KissMatcher.update_map`.

Poses cross this boundary as SE(2) ``(x, y, yaw)`` of ``base_link`` in the map
frame; points as (N, 2) base-frame coordinates. Internally KISS-ICP works in 3D:
points become (N, 3) float64 with z = 0 and poses 4x4 matrices. Deskewing is off:
:class:`~semmap.records.PaintedScan` points arrive already motion-compensated.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..config import RegistrationConfig
from ..geometry import se2_to_se3, se3_inverse, se3_to_se2

__all__ = ["KissMatcher", "PreparedScan", "sweep_information"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PreparedScan:
    """One scan down-sampled the way KISS-ICP does it, as (N, 3) float64 base-frame points (z = 0).

    ``map_points`` (voxel/2 grid) go into the local map; ``source`` (1.5·voxel grid)
    is what ICP aligns.
    """

    map_points: NDArray[np.float64]
    source: NDArray[np.float64]
    #: the point-to-line Hessian of the match (3x3, base frame, per unit residual variance): see
    #: :func:`sweep_information`
    information: NDArray[np.float64] = field(default_factory=lambda: np.zeros((3, 3)))


def sweep_information(points: NDArray[np.float64], radius: float, spacing: float, step: int = 2,
                      max_flatness: float = 0.2) -> NDArray[np.float64]:
    """The Hessian ``Σ wᵢ Jᵢᵀ Jᵢ`` of a point-to-line match of a scan's returns, given in sweep order
    (N, 2), in their own frame.

    A point on a line moves the residual ``n · (δt + δθ · p⊥)`` for a small motion ``(δt, δθ)`` of
    the scan, so ``J = (nx, ny, n · p⊥)`` with ``p⊥ = (-py, px)``. The Hessian is what ICP's solution
    is sure of: its inverse times the residual variance is the pose covariance, and a corridor, whose
    lines all run one way, gives a Hessian with a (near-)zero eigenvalue along it. The base frame does
    not depend on the pose, so this is computed once per scan, beside the down-sampling.

    Each return's line is the chord between the returns ``step`` beams before and after it, when both
    lie within ``radius`` of it and it lies within ``max_flatness`` of the chord's half-length from it
    (else: a corner, an edge, clutter, left out). Each return counts by the length of surface it
    stands for (the chord over ``2 · step`` beams, in units of ``spacing``), so near walls, which a
    LiDAR samples densely, do not outweigh far ones, as voxel down-sampling has it.
    """
    p = np.asarray(points, np.float64).reshape(-1, 2)
    n = p.shape[0]
    if n < 2 * step + 1:
        return np.zeros((3, 3))
    mid, before, after = p[step:n - step], p[:n - 2 * step], p[2 * step:]
    chord = after - before
    length = np.hypot(chord[:, 0], chord[:, 1])
    near = (np.hypot(*(before - mid).T) < radius) & (np.hypot(*(after - mid).T) < radius) & (length > 1e-6)
    off = np.abs(chord[:, 0] * (mid[:, 1] - before[:, 1]) - chord[:, 1] * (mid[:, 0] - before[:, 0]))
    ok = near & (off <= max_flatness * 0.5 * length * np.maximum(length, 1e-12))
    if not np.any(ok):
        return np.zeros((3, 3))
    c, q, ln = chord[ok], mid[ok], length[ok]
    nrm = np.column_stack([-c[:, 1], c[:, 0]]) / ln[:, None]
    j = np.column_stack([nrm[:, 0], nrm[:, 1], -nrm[:, 0] * q[:, 1] + nrm[:, 1] * q[:, 0]])
    w = ln / (2.0 * step) / spacing
    return (j * w[:, None]).T @ j


class KissMatcher:
    """KISS-ICP's local map, adaptive threshold and registration, driven step by step.

    ``cfg`` supplies ``voxel_size``, ``max_range`` (also the radius of the local map
    around the robot), ``max_points_per_voxel``, ``initial_threshold``,
    ``min_motion``, ``max_iterations``, ``convergence`` and ``max_threads``.
    """

    def __init__(self, cfg: RegistrationConfig) -> None:
        from kiss_icp.config import KISSConfig
        from kiss_icp.mapping import get_voxel_hash_map
        from kiss_icp.registration import get_registration
        from kiss_icp.threshold import get_threshold_estimator
        from kiss_icp.voxelization import voxel_down_sample

        # KISSConfig is a pydantic BaseSettings (reads KISS_ICP_* environment variables):
        # every field that matters is set explicitly.
        self._kcfg = KISSConfig(
            data={"max_range": cfg.max_range, "min_range": cfg.min_range, "deskew": False},
            mapping={"voxel_size": cfg.voxel_size, "max_points_per_voxel": cfg.max_points_per_voxel},
            registration={"max_num_iterations": cfg.max_iterations,
                          "convergence_criterion": cfg.convergence,
                          "max_num_threads": cfg.max_threads},
            adaptive_threshold={"fixed_threshold": None, "initial_threshold": cfg.initial_threshold,
                                "min_motion_th": cfg.min_motion},
        )
        self._voxel = float(cfg.voxel_size)
        self._max_source = int(cfg.max_source_points)
        self._down: Any = voxel_down_sample
        self._new_map: Any = get_voxel_hash_map
        self._map: Any = get_voxel_hash_map(self._kcfg)
        self._reg: Any = get_registration(self._kcfg)
        self._threshold: Any = get_threshold_estimator(self._kcfg)

    # -- steps -------------------------------------------------------------------------
    def prepare(self, points_xy: NDArray[np.float64]) -> PreparedScan:
        """Down-sample (N, 2) base-frame points as upstream ``KissICP.voxelize`` does."""
        pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        p3 = np.zeros((pts.shape[0], 3), dtype=np.float64)
        p3[:, :2] = pts
        if p3.shape[0] == 0:
            return PreparedScan(p3, p3)
        map_points = self._down(p3, self._voxel * 0.5)
        source = self._down(map_points, self._voxel * 1.5)
        if self._max_source and source.shape[0] > self._max_source:
            # open spaces give many more points than three degrees of freedom need: thin the
            # ICP source (not the map) with a coarser grid, keeping the cost per scan bounded; a
            # scan plane's points lie along lines, so their number falls linearly with the grid
            scale = float(source.shape[0] / self._max_source)
            source = self._down(map_points, self._voxel * 1.5 * scale)
        source = np.ascontiguousarray(source, dtype=np.float64)
        return PreparedScan(np.ascontiguousarray(map_points, dtype=np.float64), source,
                            sweep_information(pts, 2.0 * self._voxel, self._voxel))

    @property
    def map_empty(self) -> bool:
        """True until points have been inserted into the local map."""
        return bool(self._map.empty())

    @property
    def sigma(self) -> float:
        """The current adaptive threshold (m); ICP matches within 3σ with a Geman-McClure kernel of σ."""
        return float(self._threshold.get_threshold())

    def new_map(self) -> Any:
        """An empty map with this matcher's settings, for :meth:`align` and :meth:`update_map` to use instead of
        the local map (a caller that keeps several)."""
        return self._new_map(self._kcfg)

    def align(self, scan: PreparedScan, guess: NDArray[np.float64], voxel_map: Any = None) -> NDArray[np.float64]:
        """ICP of ``scan.source`` against the local map (or ``voxel_map``, from :meth:`new_map`) from the SE(2)
        ``guess``; returns the SE(2) pose.

        The 6-DoF result is projected onto the floor (z, roll and pitch dropped).
        """
        sigma = self.sigma
        t = self._reg.align_points_to_map(
            points=scan.source,
            voxel_map=self._map if voxel_map is None else voxel_map,
            initial_guess=se2_to_se3(guess),
            max_correspondance_distance=3.0 * sigma,
            kernel=sigma,
        )
        return se3_to_se2(np.asarray(t, dtype=np.float64))

    def update_threshold(self, guess: NDArray[np.float64], result: NDArray[np.float64]) -> None:
        """Feed the prediction error ``guess⁻¹ · result`` to the adaptive threshold, as upstream does."""
        dev = se3_inverse(se2_to_se3(guess)) @ se2_to_se3(result)
        self._threshold.update_model_deviation(dev)

    def update_map(self, scan: PreparedScan, pose: NDArray[np.float64], voxel_map: Any = None) -> None:
        """Insert the scan at the SE(2) ``pose`` into the local map (or ``voxel_map``) and drop map points beyond
        ``max_range`` from it."""
        if scan.map_points.shape[0] == 0:
            return
        (self._map if voxel_map is None else voxel_map).update(scan.map_points, se2_to_se3(pose))

    def map_points(self) -> NDArray[np.float64]:
        """The local map as (M, 2) points in the map frame (for inspection and plots)."""
        pc = np.asarray(self._map.point_cloud(), dtype=np.float64).reshape(-1, 3)
        return pc[:, :2].copy()
