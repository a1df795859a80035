"""Pictures of a simulated tour: the world from above, and one camera image."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch
from numpy.typing import NDArray

from ..geometry import project_points, se2_compose, se3_apply
from ..palette import MOBILITY_COLORS, class_color, rgb01
from ..records import Calibration, GridSpec, Mobility
from .robot import OdometryTrace, Trajectory
from .world import World

__all__ = ["camera_preview", "world_preview"]


def world_preview(path: Path, world: World, spec: GridSpec, layers: dict[str, NDArray[np.bool_]],
                  traj: Trajectory, odom: OdometryTrace, swept: NDArray[np.bool_]) -> None:
    img = np.full(spec.shape + (3,), 255, np.uint8)
    img[swept] = (255, 215, 215)
    img[layers["static"]] = (40, 40, 40)
    from .groundtruth import rasterise

    h_cls: dict[str, None] = {}
    for o in world.objects:
        if o.cls in ("wall", "pillar", "cabinet"):
            continue
        # the full footprint in a light tint, what the LiDAR sees (legs) in full colour
        col = np.array(class_color(o.cls))
        foot = rasterise(spec, [p.polygon for p in o.parts])
        img[foot & ~layers["static"]] = (0.35 * col + 0.65 * 255).astype(np.uint8)
        img[foot & layers["semi_static"]] = col
        h_cls[o.cls] = None
    for o in world.objects:
        if o.cls == "cabinet":
            img[rasterise(spec, [p.polygon for p in o.parts])] = class_color("cabinet")
    extent = (spec.origin_x, spec.origin_x + spec.width * spec.resolution,
              spec.origin_y, spec.origin_y + spec.height * spec.resolution)
    w_in = 10.0
    h_in = max(4.0, w_in * (extent[3] - extent[2]) / (extent[1] - extent[0]) + 1.2)
    fig, ax = plt.subplots(figsize=(w_in, min(h_in, 14.0)), dpi=120)
    ax.imshow(img, origin="lower", extent=extent, interpolation="nearest")
    for p in world.people:
        wp = p.waypoints
        if len(wp) > 1:
            loop = np.vstack([wp, wp[:1]]) if p.loop else wp
            ax.plot(loop[:, 0], loop[:, 1], "--", color="#e6194b", lw=0.8, alpha=0.8)
        ax.plot(wp[0, 0], wp[0, 1], "o", color="#e6194b", ms=4)
    ax.plot(traj.x, traj.y, "-", color="#1f5fbf", lw=1.6, label="robot (ground truth)")
    start = np.array([traj.x[0], traj.y[0], traj.yaw[0]])
    odo_world = se2_compose(start, odom.pose)
    ax.plot(odo_world[:, 0], odo_world[:, 1], "-", color="#f58231", lw=1.0, alpha=0.9,
            label="wheel odometry (aligned at start)")
    ax.annotate("", xy=(start[0] + 0.8 * np.cos(start[2]), start[1] + 0.8 * np.sin(start[2])),
                xytext=(start[0], start[1]), arrowprops=dict(arrowstyle="->", color="#1f5fbf", lw=2))
    ax.plot(start[0], start[1], "s", color="#1f5fbf", ms=6, label="start")
    handles, _ = ax.get_legend_handles_labels()
    handles += [Patch(color=rgb01(class_color(c)), label=c) for c in h_cls]
    handles += [Patch(color=(0.16, 0.16, 0.16), label="wall / pillar"),
                Patch(color=(1.0, 0.84, 0.84), label="swept by people"),
                plt.Line2D([], [], ls="--", color="#e6194b", label="people's paths")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{world.name}: {traj.length():.0f} m in {traj.duration:.0f} s "
                 f"(full footprints tinted, LiDAR-height parts solid)", fontsize=10)
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def camera_preview(path: Path, rgb: NDArray[np.uint8], label: NDArray[np.uint16], names: Sequence[str],
                   calib: Calibration, angles: NDArray[np.floating[Any]], ranges: NDArray[np.float64],
                   rows: NDArray[np.int32], row_mobility: NDArray[np.uint8], title: str = "") -> None:
    """RGB | label overlay | the true scan projected with T_cam_lidar, coloured by mobility."""
    overlay = rgb.astype(np.float32).copy()
    present = [int(v) for v in np.unique(label) if v > 0]
    for v in present:
        m = label == v
        overlay[m] = 0.45 * overlay[m] + 0.55 * np.array(class_color(names[v - 1]))
    ok = np.isfinite(ranges)
    pts = np.column_stack([ranges[ok] * np.cos(angles[ok]), ranges[ok] * np.sin(angles[ok]), np.zeros(ok.sum())])
    intr = calib.intrinsics
    uv, inside = project_points(intr.K, intr.D, se3_apply(calib.T_cam_lidar, pts), intr.width, intr.height,
                                intr.model)
    mob = np.where(rows[ok] >= 0, row_mobility[np.maximum(rows[ok], 0)], 0)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3), dpi=90)
    axes[0].imshow(rgb)
    axes[0].set_title("RGB")
    axes[1].imshow(overlay.astype(np.uint8))
    axes[1].set_title("ground-truth labels")
    axes[1].legend(handles=[Patch(color=rgb01(class_color(names[v - 1])), label=names[v - 1])
                            for v in present], loc="lower right", fontsize=7)
    axes[2].imshow(rgb)
    for m in (Mobility.STATIC, Mobility.SEMI_STATIC, Mobility.DYNAMIC):
        sel = inside & (mob == m)
        axes[2].scatter(uv[sel, 0], uv[sel, 1], s=5, color=np.array(MOBILITY_COLORS[m]) / 255, label=m.label)
    axes[2].set_title("scan projected with T_cam_lidar (true mobility)")
    axes[2].legend(loc="lower right", fontsize=7)
    for ax in axes:
        ax.set_xlim(0, intr.width)
        ax.set_ylim(intr.height, 0)
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
