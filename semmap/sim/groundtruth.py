"""Ground-truth maps of a simulated world at LiDAR height."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..records import GridSpec, Mobility
from .world import World

__all__ = ["grid_for_world", "rasterise", "occupancy_layers", "people_swept", "change_mask", "true_beam_end_points"]


def grid_for_world(world: World, resolution: float, margin: float) -> GridSpec:
    return GridSpec.covering(*world.bounds(margin), resolution)


def rasterise(spec: GridSpec, polygons: Iterable[NDArray[np.float64]]) -> NDArray[np.bool_]:
    """Cells (grid order) covered by polygons; thin parts still mark the cell they stand in."""
    img = np.zeros(spec.shape, np.uint8)
    pts = [np.round(((p - [spec.origin_x, spec.origin_y]) / spec.resolution - 0.5) * 16).astype(np.int32)
           for p in polygons]
    if pts:
        cv2.fillPoly(img, pts, 1, lineType=cv2.LINE_8, shift=4)
        # a part thinner than a cell must still occupy the cell holding its centre
        for p in polygons:
            c = p.mean(axis=0)
            r, k = spec.world_to_cell(c)
            if 0 <= r < spec.height and 0 <= k < spec.width:
                img[r, k] = 1
    return img.astype(bool)


def occupancy_layers(world: World, spec: GridSpec, height: float) -> dict[str, NDArray[np.bool_]]:
    """Static and semi-static occupancy of the plane at ``height`` (what a 2D LiDAR can hit)."""
    layers = {}
    for name, mob in (("static", Mobility.STATIC), ("semi_static", Mobility.SEMI_STATIC)):
        polys = [p.polygon for o in world.objects if o.mobility == mob for p in o.parts if p.spans(height)]
        layers[name] = rasterise(spec, polys)
    layers["occupancy"] = layers["static"] | layers["semi_static"]
    return layers


def people_swept(world: World, spec: GridSpec, duration_s: float, radius: float,
                 step_s: float = 0.1) -> NDArray[np.bool_]:
    """Every cell a person's body disc covered at some time during the tour."""
    swept = np.zeros(spec.shape, np.uint8)
    for t in np.arange(0.0, duration_s + 1e-9, step_s):
        polys = [p.footprint(float(t), radius) for p in world.people]
        if polys:
            swept |= rasterise(spec, polys).astype(np.uint8)
    return swept.astype(bool)


def change_mask(before: NDArray[np.bool_], after: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """0 none, 1 added (occupied only after), 2 removed (occupied only before)."""
    out = np.zeros(before.shape, np.uint8)
    out[after & ~before] = 1
    out[before & ~after] = 2
    return out


def true_beam_end_points(tour: str | Path, exclude_dynamic: bool = True) -> NDArray[np.float64]:
    """World-frame points where the true LiDAR beams of a simulated tour ended (M, 2).

    Each beam is placed with the true pose at its own firing time (the scan sweeps while the
    robot moves). People's returns are left out by default: what is left is the structure a
    map could have seen, the denominator of an honest recall.
    """
    from ..config import SimConfig, load_model
    from ..geometry import se2_compose, se3_from_xyz_rpy, se3_to_se2
    from ..io.tum import read_tum
    from ..io.yamlio import read_yaml
    from .sensors import LidarSim

    tour = Path(tour)
    gt = tour / "ground_truth"
    beams = np.load(gt / "beams.npz")
    cfg = load_model(SimConfig, read_yaml(tour / "config.yaml"), str(tour / "config.yaml"))
    mount = se3_to_se2(se3_from_xyz_rpy(cfg.lidar.mount.xyz, cfg.lidar.mount.rpy))
    offsets = beams["time_offset_s"] if "time_offset_s" in beams.files else LidarSim(cfg.lidar).beam_dt
    t_ref, p_ref = read_tum(gt / "trajectory.tum")
    tr = (t_ref - t_ref[0]) * 1e-9
    yaw = np.unwrap(p_ref[:, 2])
    r, a, mob = beams["range"], beams["angles"], beams["mobility"]
    out = []
    for k in range(r.shape[0]):
        ok = np.isfinite(r[k])
        if exclude_dynamic:
            ok &= mob[k] != 3
        t = (beams["stamp_ns"][k] - t_ref[0]) * 1e-9 + offsets[ok]
        poses = np.column_stack([np.interp(t, tr, p_ref[:, 0]), np.interp(t, tr, p_ref[:, 1]),
                                 np.interp(t, tr, yaw)])
        lidar = se2_compose(poses, mount)
        local = np.column_stack([r[k, ok] * np.cos(a[ok]), r[k, ok] * np.sin(a[ok])])
        c, s = np.cos(lidar[:, 2]), np.sin(lidar[:, 2])
        out.append(np.column_stack([lidar[:, 0] + c * local[:, 0] - s * local[:, 1],
                                    lidar[:, 1] + s * local[:, 0] + c * local[:, 1]]))
    return np.concatenate(out) if out else np.zeros((0, 2))
