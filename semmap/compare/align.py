# TEMPORARY placeholder until the diff-align branch lands (not to be committed)
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..records import GridSpec


@dataclass(frozen=True)
class AlignInput:
    spec: GridSpec
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]

@dataclass(frozen=True)
class Alignment:
    T_a_b: NDArray[np.float64]
    residual_m: float = 0.0
    inlier_fraction: float = 1.0
    overlap: float = 1.0
    ambiguity: float = 0.0
    seconds: float = 0.0
    def as_dict(self) -> dict[str, Any]:
        t = self.T_a_b
        return {"T_a_b": [float(t[0]), float(t[1]), float(t[2])], "yaw_deg": float(np.degrees(t[2])),
                "residual_m": self.residual_m, "inlier_fraction": self.inlier_fraction, "overlap": self.overlap,
                "ambiguity": self.ambiguity, "seconds": self.seconds}

def align_maps(a: AlignInput, b: AlignInput, **kw: Any) -> Alignment:
    raise NotImplementedError
