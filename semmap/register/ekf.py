"""The one filterpy adapter: an SE(2) extended Kalman filter for wheel odometry + ICP poses.

Nothing else in semmap imports :mod:`filterpy`; it is imported lazily when a
:class:`Se2Ekf` is built.

State ``x = (x, y, yaw)``: the pose of ``base_link`` in the map frame, with
covariance ``P`` (m², rad²).

* **Predict** with an odometry increment ``u = (dx, dy, dyaw)`` expressed in the
  previous base frame: ``x ← x ⊕ u``. The increment's noise grows with the
  distance driven and the angle turned (:class:`~semmap.config.EkfConfig`).
* **Update** with a pose measurement ``z`` (the ICP result, a (3, 1) array) with
  ``H = I`` and the yaw residual wrapped to (-π, π].
* **Gate**: :meth:`Se2Ekf.mahalanobis2` gives ``yᵀ S⁻¹ y`` of a candidate
  measurement before it is applied, so the caller can reject outliers.
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

_H = np.eye(3)


def odometry_noise(delta: ArrayLike, cfg: EkfConfig) -> NDArray[np.float64]:
    """Covariance (3x3, in the previous base frame) of an odometry increment ``(dx, dy, dyaw)``.

    For a step of length ``d`` (m) turning ``a = |dyaw|`` (rad): a systematic part that
    grows linearly (scale errors, heading drift) plus a random walk whose variance
    grows linearly, on both translation axes and on the heading::

        var_xy  = (odom_trans_noise · d)² + odom_trans_rw² · d
        var_yaw = (odom_rot_noise · a + odom_rot_per_m · d)² + odom_rot_rw² · (d + a)

    Each std is at least ``odom_min_noise``.
    """
    dx, dy, dyaw = np.asarray(delta, dtype=np.float64).reshape(3)
    d = float(np.hypot(dx, dy))
    a = abs(float(dyaw))
    floor = cfg.odom_min_noise ** 2
    var_t = max((cfg.odom_trans_noise * d) ** 2 + cfg.odom_trans_rw ** 2 * d, floor)
    var_r = max((cfg.odom_rot_noise * a + cfg.odom_rot_per_m * d) ** 2 + cfg.odom_rot_rw ** 2 * (d + a), floor)
    return np.diag([var_t, var_t, var_r])


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
            self.x = se2_compose(self.x.reshape(3), np.asarray(u, dtype=np.float64).reshape(3)).reshape(3, 1)

    return _Se2Filter(dim_x=3, dim_z=3)


class Se2Ekf:
    """SE(2) EKF: odometry increments predict, ICP poses update (see the module docstring)."""

    def __init__(self, cfg: EkfConfig, pose: ArrayLike = (0.0, 0.0, 0.0), cov: ArrayLike | None = None) -> None:
        self.cfg = cfg
        self._f = _make_filter()
        self._f.R = np.diag([cfg.icp_xy_std ** 2, cfg.icp_xy_std ** 2, cfg.icp_yaw_std ** 2])
        self.reset(pose, cov)

    # -- state ---------------------------------------------------------------------
    @property
    def pose(self) -> NDArray[np.float64]:
        """The current estimate ``(x, y, yaw)`` (a copy)."""
        return self._f.x.reshape(3).copy()

    @property
    def cov(self) -> NDArray[np.float64]:
        """The current 3x3 covariance (a copy)."""
        return np.array(self._f.P, dtype=np.float64)

    @property
    def R(self) -> NDArray[np.float64]:
        """The ICP measurement covariance."""
        return np.array(self._f.R, dtype=np.float64)

    def reset(self, pose: ArrayLike, cov: ArrayLike | None = None) -> None:
        """Set the state; ``cov`` defaults to ``odom_min_noise²`` on the diagonal."""
        p = np.asarray(pose, dtype=np.float64).reshape(3).copy()
        p[2] = wrap_angle(p[2])
        self._f.x = p.reshape(3, 1)
        floor = max(self.cfg.odom_min_noise, 1e-9) ** 2
        self._f.P = np.eye(3) * floor if cov is None else np.asarray(cov, dtype=np.float64).reshape(3, 3).copy()

    # -- filter steps ---------------------------------------------------------------
    def predict(self, delta: ArrayLike, noise_scale: float = 1.0) -> None:
        """Propagate by the odometry increment ``delta`` (previous base frame); noise × ``noise_scale``²."""
        u = np.asarray(delta, dtype=np.float64).reshape(3)
        yaw = float(self._f.x[2, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        dx, dy = u[0], u[1]
        # Jacobians of x ⊕ u with respect to the state (F) and to the increment (G).
        self._f.F = np.array([[1.0, 0.0, -s * dx - c * dy],
                              [0.0, 1.0, c * dx - s * dy],
                              [0.0, 0.0, 1.0]])
        # the increment's noise is isotropic in x and y, so rotating it into the map frame leaves it as is
        self._f.Q = (noise_scale ** 2) * odometry_noise(u, self.cfg)
        self._f.predict(u=u)

    def innovation(self, z: ArrayLike) -> NDArray[np.float64]:
        """``z - x`` with the yaw wrapped, shape (3,)."""
        zz = np.asarray(z, dtype=np.float64).reshape(3, 1)
        return _residual(zz, self._f.x).reshape(3)

    def mahalanobis2(self, z: ArrayLike) -> float:
        """Squared Mahalanobis distance ``yᵀ (P + R)⁻¹ y`` of a pose measurement, before applying it."""
        y = self.innovation(z)
        s = self._f.P + self._f.R
        return float(y @ np.linalg.solve(s, y))

    def update(self, z: ArrayLike) -> None:
        """Fuse a pose measurement ``z = (x, y, yaw)`` (ungated; gate with :meth:`mahalanobis2`)."""
        zz = np.asarray(z, dtype=np.float64).reshape(3, 1)
        self._f.update(zz, HJacobian=lambda _x: _H, Hx=lambda x: x, residual=_residual)
        self._f.x[2, 0] = wrap_angle(self._f.x[2, 0])
        # keep P symmetric against round-off
        self._f.P = 0.5 * (self._f.P + self._f.P.T)
