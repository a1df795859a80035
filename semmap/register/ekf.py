"""The one filterpy adapter: an SE(2) extended Kalman filter for wheel odometry + ICP poses.

Nothing else in semmap imports :mod:`filterpy`; it is imported lazily when a
:class:`Se2Ekf` is built.

State ``(x, y, yaw, b, k_turn, k_drive)``: the pose of ``base_link`` in the map frame, and the
wheel odometry's systematic errors as they are on real robots: a heading drift ``b`` (rad per
metre driven: unequal wheel diameters), and scale errors of the angle turned (``k_turn``: the
effective wheel base) and of the distance driven (``k_drive``: the wheel radius). Covariance
``P`` (m², rad², ...).

* **Predict** with an odometry increment ``u = (dx, dy, dyaw)`` expressed in the
  previous base frame, corrected by the errors: ``pose ← pose ⊕ ((1 + k_drive)·(dx, dy),
  (1 + k_turn)·dyaw + b·d)`` with ``d = |(dx, dy)|``. The increment's noise grows with the
  distance driven and the angle turned (:class:`~semmap.config.EkfConfig`); the errors drift
  slowly (a random walk per metre and radian).
* **Update** with a pose measurement ``z`` (the ICP result, a (3, 1) array) with
  ``H = [I 0]`` and the yaw residual wrapped to (-π, π]. ICP poses are what make the odometry
  errors observable: after a few metres the filter predicts with the robot's own odometry
  corrected, so the gate below tests ICP against the odometry the robot really has. For the
  first ``learn_after`` metres the errors are only considered, not learnt (a Schmidt update):
  the first local map is a scan or two, its ICP errors are correlated from scan to scan, and
  over a short baseline a few centimetres of them read as a scale error of 20 %.
* **Gate**: :meth:`Se2Ekf.mahalanobis2` gives ``yᵀ S⁻¹ y`` of a candidate
  measurement before it is applied, so the caller can reject outliers.

With the three error priors at 0 (``odom_heading_drift_std``, ``odom_turn_scale_std``,
``odom_drive_scale_std``) the filter is the plain SE(2) EKF.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import EkfConfig
from ..geometry import se2_compose, wrap_angle

__all__ = ["Se2Ekf", "odometry_noise"]

log = logging.getLogger(__name__)

_H = np.hstack([np.eye(3), np.zeros((3, 3))])
_DIM = 6


def odometry_noise(delta: ArrayLike, cfg: EkfConfig) -> NDArray[np.float64]:
    """Covariance (3x3, in the previous base frame) of an odometry increment ``(dx, dy, dyaw)``.

    For a step of length ``d`` (m) turning ``a = |dyaw|`` (rad): a systematic part that
    grows linearly (scale errors, heading drift) plus a random walk whose variance
    grows linearly, on both translation axes and on the heading::

        var_xy  = (odom_trans_noise · d)² + (odom_trans_per_rad · a)² + odom_trans_rw² · d
        var_yaw = (odom_rot_noise · a + odom_rot_per_m · d)² + odom_rot_rw² · (d + a)

    Each std is at least ``odom_min_noise``.
    """
    dx, dy, dyaw = np.asarray(delta, dtype=np.float64).reshape(3)
    d = float(np.hypot(dx, dy))
    a = abs(float(dyaw))
    floor = cfg.odom_min_noise ** 2
    var_t = max((cfg.odom_trans_noise * d) ** 2 + (cfg.odom_trans_per_rad * a) ** 2 + cfg.odom_trans_rw ** 2 * d,
                floor)
    var_r = max((cfg.odom_rot_noise * a + cfg.odom_rot_per_m * d) ** 2 + cfg.odom_rot_rw ** 2 * (d + a), floor)
    return np.diag([var_t, var_t, var_r])


def _corrected(u: NDArray[np.float64], errors: NDArray[np.float64]) -> NDArray[np.float64]:
    """The odometry increment ``u`` with the systematic ``errors`` (b, k_turn, k_drive) taken out."""
    b, k_turn, k_drive = errors
    d = float(np.hypot(u[0], u[1]))
    return np.array([(1.0 + k_drive) * u[0], (1.0 + k_drive) * u[1], (1.0 + k_turn) * u[2] + b * d])


def _residual(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    y = np.subtract(a, b)
    y[2] = wrap_angle(y[2])
    return y


def _make_filter() -> Any:
    from filterpy.kalman import ExtendedKalmanFilter

    class _Se2Filter(ExtendedKalmanFilter):
        """filterpy's EKF with the SE(2) motion model ``x ⊕ u`` as its state transition."""

        x: NDArray[np.float64]

        def predict_x(self, u: Any = 0) -> None:
            x = self.x.reshape(_DIM)
            step = _corrected(np.asarray(u, dtype=np.float64).reshape(3), x[3:])
            self.x = np.concatenate([se2_compose(x[:3], step), x[3:]]).reshape(_DIM, 1)

    return _Se2Filter(dim_x=_DIM, dim_z=3)


class Se2Ekf:
    """SE(2) EKF: odometry increments predict, ICP poses update (see the module docstring)."""

    def __init__(self, cfg: EkfConfig, pose: ArrayLike = (0.0, 0.0, 0.0), cov: ArrayLike | None = None) -> None:
        self.cfg = cfg
        self._f = _make_filter()
        self._f.R = np.diag([cfg.icp_xy_std ** 2, cfg.icp_xy_std ** 2, cfg.icp_yaw_std ** 2])
        #: prior std of (heading drift, turn scale, drive scale)
        self._prior = np.array([cfg.odom_heading_drift_std, cfg.odom_turn_scale_std, cfg.odom_drive_scale_std])
        self._started = False  # the odometry errors are set (to 0, with their prior) by the first reset
        self._driven = 0.0  # m driven since the filter was made (resets do not restart it)
        self.reset(pose, cov)

    # -- state ---------------------------------------------------------------------
    @property
    def pose(self) -> NDArray[np.float64]:
        """The current estimate ``(x, y, yaw)`` (a copy)."""
        return self._f.x.reshape(_DIM)[:3].copy()

    @property
    def cov(self) -> NDArray[np.float64]:
        """The current 3x3 covariance of the pose (a copy)."""
        return np.array(self._f.P[:3, :3], dtype=np.float64)

    @property
    def odometry_errors(self) -> dict[str, float]:
        """The estimated systematic odometry errors: heading drift (rad/m), turn and drive scale errors."""
        b, k_turn, k_drive = self._f.x.reshape(_DIM)[3:]
        return {"heading_drift_rad_per_m": float(b), "turn_scale": float(k_turn), "drive_scale": float(k_drive)}

    @property
    def R(self) -> NDArray[np.float64]:
        """The ICP measurement covariance."""
        return np.array(self._f.R, dtype=np.float64)

    def reset(self, pose: ArrayLike, cov: ArrayLike | None = None) -> None:
        """Set the pose; ``cov`` defaults to ``odom_min_noise²`` on the diagonal. The odometry errors
        learnt so far are kept (the first call sets them to 0 with their prior covariance)."""
        p = np.asarray(pose, dtype=np.float64).reshape(3).copy()
        p[2] = wrap_angle(p[2])
        floor = max(self.cfg.odom_min_noise, 1e-9) ** 2
        pose_cov = np.eye(3) * floor if cov is None else np.asarray(cov, dtype=np.float64).reshape(3, 3).copy()
        if self._started:
            errors, errors_cov = self._f.x.reshape(_DIM)[3:].copy(), np.array(self._f.P[3:, 3:])
        else:
            errors, errors_cov = np.zeros(3), np.diag(self._prior ** 2)
            self._started = True
        self._f.x = np.concatenate([p, errors]).reshape(_DIM, 1)
        P = np.zeros((_DIM, _DIM))
        P[:3, :3] = pose_cov
        P[3:, 3:] = errors_cov
        self._f.P = P

    # -- filter steps ---------------------------------------------------------------
    def predict(self, delta: ArrayLike, noise_scale: ArrayLike = 1.0) -> None:
        """Propagate by the odometry increment ``delta`` (previous base frame); the noise's std is
        multiplied by ``noise_scale`` (a number, or one per axis x, y, yaw)."""
        u = np.asarray(delta, dtype=np.float64).reshape(3)
        x = self._f.x.reshape(_DIM)
        yaw = float(x[2])
        c, s = np.cos(yaw), np.sin(yaw)
        v = _corrected(u, x[3:])  # the step the filter takes
        dx, dy = v[0], v[1]
        d = float(np.hypot(u[0], u[1]))
        # the Jacobian of the motion with respect to the state: the pose, and the odometry errors
        # through the corrected step (∂x'/∂k_drive = R(yaw)·(ux, uy), ∂yaw'/∂b = d, ∂yaw'/∂k_turn = uyaw)
        F = np.eye(_DIM)
        F[0, 2], F[1, 2] = -s * dx - c * dy, c * dx - s * dy
        F[0, 5], F[1, 5] = c * u[0] - s * u[1], s * u[0] + c * u[1]
        F[2, 3], F[2, 4] = d, u[2]
        self._f.F = F
        # the increment's noise is isotropic in x and y, so rotating it into the map frame leaves it as is
        scale = np.broadcast_to(np.asarray(noise_scale, dtype=np.float64), (3,))
        Q = np.zeros((_DIM, _DIM))
        Q[:3, :3] = odometry_noise(u, self.cfg) * np.outer(scale, scale)
        Q[3:, 3:] = np.diag((self.cfg.odom_error_drift * self._prior) ** 2 * (d + abs(float(u[2]))))
        self._f.Q = Q
        self._f.predict(u=u)
        self._driven += d

    def corrected(self, delta: ArrayLike) -> NDArray[np.float64]:
        """The odometry increment ``delta`` with the systematic errors estimated so far taken out."""
        return _corrected(np.asarray(delta, dtype=np.float64).reshape(3), self._f.x.reshape(_DIM)[3:])

    def innovation(self, z: ArrayLike) -> NDArray[np.float64]:
        """``z - x`` with the yaw wrapped, shape (3,)."""
        zz = np.asarray(z, dtype=np.float64).reshape(3, 1)
        return _residual(zz, self._f.x[:3]).reshape(3)

    def mahalanobis2(self, z: ArrayLike, R: ArrayLike | None = None) -> float:
        """Squared Mahalanobis distance ``yᵀ (P + R)⁻¹ y`` of a pose measurement, before applying it
        (``R``: this measurement's covariance; default the configured one)."""
        y = self.innovation(z)
        s = self._f.P[:3, :3] + (self._f.R if R is None else np.asarray(R, dtype=np.float64))
        return float(y @ np.linalg.solve(s, y))

    def update(self, z: ArrayLike, R: ArrayLike | None = None) -> None:
        """Fuse a pose measurement ``z = (x, y, yaw)`` with covariance ``R`` (default: the configured
        one); ungated, gate with :meth:`mahalanobis2`."""
        zz = np.asarray(z, dtype=np.float64).reshape(3, 1)
        rr = None if R is None else np.asarray(R, dtype=np.float64).reshape(3, 3)
        if self._driven < self.cfg.learn_after:
            self._consider_errors(zz, self._f.R if rr is None else rr)
        else:
            self._f.update(zz, HJacobian=lambda _x: _H, Hx=lambda x: x[:3], R=rr, residual=_residual)
        self._f.x[2, 0] = wrap_angle(self._f.x[2, 0])
        # keep P symmetric against round-off
        self._f.P = 0.5 * (self._f.P + self._f.P.T)

    def _consider_errors(self, z: NDArray[np.float64], R: NDArray[np.float64]) -> None:
        """A Schmidt ("consider") update: the pose is corrected with the odometry errors' uncertainty
        accounted for, but the errors themselves are not learnt (their gain rows are 0; Joseph form,
        valid for any gain). Used for the first ``learn_after`` metres."""
        P = np.asarray(self._f.P, dtype=np.float64)
        y = _residual(z, self._f.x[:3])
        S = P[:3, :3] + R
        K = np.linalg.solve(S, P[:3, :]).T  # P Hᵀ S⁻¹ (S symmetric)
        K[3:] = 0.0
        self._f.x = self._f.x + K @ y
        A = np.eye(_DIM) - K @ _H
        self._f.P = A @ P @ A.T + K @ R @ K.T
