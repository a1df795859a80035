"""``preview.png``: the exported map for people, with the masks on it, a legend and a scale bar."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch, Polygon
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar
from numpy.typing import NDArray

from ..records import GridSpec
from .layers import Plane

__all__ = ["render_preview"]

_KEEP = (0.85, 0.15, 0.15)
_SLOW = (0.95, 0.55, 0.10)
_SLOW2 = (0.98, 0.85, 0.30)
_FURN = (0.20, 0.45, 0.90)


def _scale_length(width_m: float) -> float:
    for v in (0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500):
        if v >= width_m / 8:
            return float(v)
    return 1000.0


def render_preview(path: Path, spec: GridSpec, plane: Plane, name: str, footprints: list[NDArray[np.float64]],
                   keepout: NDArray[np.bool_] | None, speed: NDArray[np.uint8] | None) -> Path:
    """Draw layer ``plane`` (grey: free white, unknown grey, obstacles black), the keepout and speed
    masks tinted over it, the movable objects' footprints outlined."""
    rgb = np.full((*spec.shape, 3), 0.80, np.float32)
    rgb[plane.free] = 1.0
    rgb[plane.occupied] = 0.0
    legend = [Patch(facecolor="white", edgecolor="0.5", label="free"), Patch(facecolor="0.8", label="unknown"),
              Patch(facecolor="black", label="obstacle")]
    if speed is not None and (speed > 0).any():
        values = np.unique(speed[speed > 0]).tolist()
        for k, v in enumerate(values):  # the slowest zone the strongest tint
            z = speed == v
            colour = _SLOW if k == 0 else _SLOW2
            rgb[z] = 0.6 * rgb[z] + 0.4 * np.array(colour, np.float32)
            legend.append(Patch(facecolor=colour, alpha=0.6, label=f"speed limit {v} % of max"))
    if keepout is not None and keepout.any():
        rgb[keepout] = 0.45 * rgb[keepout] + 0.55 * np.array(_KEEP, np.float32)
        legend.append(Patch(facecolor=_KEEP, alpha=0.7, label="keepout"))
    w_m, h_m = spec.width * spec.resolution, spec.height * spec.resolution
    aspect = h_m / max(w_m, 1e-6)
    fig_w = 9.0
    fig, ax = plt.subplots(figsize=(fig_w, max(3.0, min(12.0, fig_w * aspect)) + 0.8), dpi=110)
    extent = (spec.origin_x, spec.origin_x + w_m, spec.origin_y, spec.origin_y + h_m)
    ax.imshow(rgb, origin="lower", extent=extent, interpolation="nearest")
    for fp in footprints:
        ax.add_patch(Polygon(fp, closed=True, fill=False, edgecolor=_FURN, linewidth=1.0))
    if footprints:
        legend.append(Patch(facecolor="none", edgecolor=_FURN, label="movable object"))
    length = _scale_length(w_m)
    ax.add_artist(AnchoredSizeBar(ax.transData, length, f"{length:g} m", "lower right", pad=0.4, sep=3,
                                  frameon=True, size_vertical=max(spec.resolution, h_m / 200)))
    ax.set_xlabel("x (m, map frame)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"semmap export: {name}, {spec.resolution:g} m cells, {spec.width} x {spec.height}")
    ax.legend(handles=legend, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
