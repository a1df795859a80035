"""Ground-truth maps of a simulated world at LiDAR height."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..records import GridSpec, Mobility
from .world import Person, World

__all__ = [
    "change_mask",
    "grid_for_world",
    "object_cells",
    "occupancy_layers",
    "people_standing",
    "people_swept",
    "rasterise",
    "standing_stretches",
    "true_beam_end_points",
]

#: a person counts as standing when still for at least this long, s
MIN_STANDING_S = 5.0


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


def standing_stretches(person: Person, duration_s: float, step_s: float = 0.1,
                       min_s: float = MIN_STANDING_S) -> list[tuple[float, float, float, float]]:
    """Where and when a person stood still for ``min_s`` or longer: (t_start, t_end, x, y) each.

    The person's state is sampled every ``step_s`` from 0 to ``duration_s``; a stretch is a run of
    samples with walking speed 0 at one spot, and lasts (samples × ``step_s``), cut at the tour's end.
    """
    t = np.arange(0.0, duration_s + 1e-9, step_s)
    if t.size == 0:
        return []
    st = np.array([person.state(float(x)) for x in t])
    still = st[:, 3] == 0.0
    moved = np.hypot(np.diff(st[:, 0]), np.diff(st[:, 1])) > 1e-3
    # a run breaks where the person walks, or (between two samples) moved to another spot
    brk = np.concatenate([[True], ~still[1:] | ~still[:-1] | moved])
    out = []
    starts = np.nonzero(brk & still)[0]
    for k0 in starts:
        k1 = k0 + 1
        while k1 < len(t) and still[k1] and not brk[k1]:
            k1 += 1
        t0, t1 = float(t[k0]), min(float(t[k0]) + (k1 - k0) * step_s, duration_s)
        if t1 - t0 >= min_s - 1e-9:
            out.append((t0, t1, float(st[k0, 0]), float(st[k0, 1])))
    return out


def people_standing(world: World, spec: GridSpec, duration_s: float, height: float, step_s: float = 0.1,
                    min_s: float = MIN_STANDING_S) -> NDArray[np.bool_]:
    """The cells a person's legs covered at LiDAR ``height`` while standing still for ``min_s`` or longer.

    What a map built from a 2D LiDAR could wrongly keep of a standing person: the legs' cut at the
    scan plane (thin parts mark the cell holding their centre, as for furniture legs), not the
    floor around them.
    """
    polys = []
    for p in world.people:
        seen: set[tuple[float, float]] = set()
        for t0, _, x, y in standing_stretches(p, duration_s, step_s, min_s):
            if (round(x, 4), round(y, 4)) in seen:
                continue
            seen.add((round(x, 4), round(y, 4)))
            polys += [poly for poly, z0, z1, _ in p.body(t0) if z0 <= height <= z1]
    return rasterise(spec, polys) if polys else np.zeros(spec.shape, bool)


def object_cells(world: World, spec: GridSpec, height: float) -> NDArray[np.int64]:
    """How many grid cells each world object's parts cover at ``height`` (0 where none spans it)."""
    out = np.zeros(len(world.objects), np.int64)
    for i, o in enumerate(world.objects):
        polys = [p.polygon for p in o.parts if p.spans(height)]
        if polys:
            out[i] = int(rasterise(spec, polys).sum())
    return out


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
    from .sensors import LidarSim, mount_turn

    tour = Path(tour)
    gt = tour / "ground_truth"
    beams = np.load(gt / "beams.npz")
    cfg = load_model(SimConfig, read_yaml(tour / "config.yaml"), str(tour / "config.yaml"))
    mount = se3_to_se2(se3_from_xyz_rpy(cfg.lidar.mount.xyz, cfg.lidar.mount.rpy))
    turn = mount_turn(cfg.lidar.mount.rpy)  # an upside-down LiDAR's beams turn the other way
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
        local = np.column_stack([r[k, ok] * np.cos(a[ok]), turn * r[k, ok] * np.sin(a[ok])])
        c, s = np.cos(lidar[:, 2]), np.sin(lidar[:, 2])
        out.append(np.column_stack([lidar[:, 0] + c * local[:, 0] - s * local[:, 1],
                                    lidar[:, 1] + s * local[:, 0] + c * local[:, 1]]))
    return np.concatenate(out) if out else np.zeros((0, 2))
