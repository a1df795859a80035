"""Registration: KISS-ICP scan-to-map odometry fused with wheel odometry in an SE(2) EKF.

* :class:`Registrar` (``registrar.py``): one pose per painted scan, in the map frame;
  modes ``fused`` (default), ``icp`` and ``odometry``.
* ``kiss.py``: the one KISS-ICP adapter (imported lazily).
* ``ekf.py``: the one filterpy adapter, the SE(2) EKF (imported lazily).
* :func:`ate_rmse` (``metrics.py``): absolute trajectory error after SE(2) alignment.
"""

from __future__ import annotations

from .metrics import align_se2, associate, ate_errors, ate_rmse, interpolate_poses
from .registrar import Registrar

__all__ = ["Registrar", "align_se2", "associate", "ate_errors", "ate_rmse", "interpolate_poses"]
