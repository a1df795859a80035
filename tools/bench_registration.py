#!/usr/bin/env python3
"""Benchmark scan registration: ATE RMSE and throughput of the three modes on simulated tours.

For each scenario: simulate it (ROS1, ``--seed``, default 0) into a temporary folder (or reuse
``--tours DIR/<scenario>``), turn its ``/scan`` messages into PaintedScans with
ground-truth mobility (see :func:`load_tour`), run ``odometry``, ``icp`` and
``fused``, and compare each trajectory with ``ground_truth/trajectory.tum``
(ATE RMSE after SE(2) alignment). Prints a Markdown table.

    python tools/bench_registration.py                         # ward and office
    python tools/bench_registration.py --scenarios demo --tours /tmp/reg

:func:`load_tour` is also what ``tests/test_register.py`` uses to build its input.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import dataclass
from datetime import date
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from semmap.config import RegistrationConfig
from semmap.geometry import se2_apply, se2_between, se2_compose, se3_from_xyz_rpy, se3_to_se2
from semmap.io.bag import open_bag
from semmap.io.tum import read_tum
from semmap.io.yamlio import read_yaml
from semmap.records import PaintedScan
from semmap.register import Registrar, ate_rmse, interpolate_poses

MODES = ("odometry", "icp", "fused")


@dataclass
class TourData:
    """What registration needs from a simulated tour, one entry per ``/scan`` message."""

    stamps: NDArray[np.int64]  # (S,) scan header stamps (first beam), ns
    scans: list[PaintedScan]
    odom: NDArray[np.float64]  # (S, 3) wheel odometry at the stamps (NaN rows outside odometry's span)
    gt_stamps: NDArray[np.int64]
    gt_poses: NDArray[np.float64]  # true base poses, world frame (50 Hz)



sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import machine


def load_tour(tour: str | Path, deskew: bool = True, limit: int | None = None) -> TourData:
    """Read a simulated tour folder into PaintedScans.

    Ranges are the real noisy ``/scan`` messages; the LiDAR mount (T_base_laser) is
    ``lidar.mount`` of ``config.yaml``; mobility and class come from
    ``ground_truth/beams.npz``; odometry is ``ground_truth/odometry.tum``
    interpolated at each scan stamp. With ``deskew``, beam i (fired at
    ``stamp + i·time_increment``) is moved into the base frame at the scan stamp with
    the interpolated odometry, as PaintedScan promises; otherwise the sweep is ignored.
    """
    tour = Path(tour)
    cfg = read_yaml(tour / "config.yaml", "simulator configuration")
    mount = cfg["lidar"]["mount"]
    t_base_laser = se3_to_se2(se3_from_xyz_rpy(mount["xyz"], mount["rpy"]))
    topic = cfg["lidar"]["topic"]
    base_frame = cfg["robot"]["base_frame"]
    beams = np.load(tour / "ground_truth" / "beams.npz")
    odom_t, odom_p = read_tum(tour / "ground_truth" / "odometry.tum")
    gt_t, gt_p = read_tum(tour / "ground_truth" / "trajectory.tum")
    bag = next(p for p in tour.iterdir() if p.suffix == ".bag" or (p / "metadata.yaml").is_file())

    scans: list[PaintedScan] = []
    stamps: list[int] = []
    with open_bag(bag) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for k, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
            if limit is not None and k >= limit:
                break
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
            r = np.asarray(msg.ranges, dtype=np.float64)
            n = r.size
            ang = msg.angle_min + msg.angle_increment * np.arange(n)
            hit = np.isfinite(r) & (r >= msg.range_min) & (r <= msg.range_max)
            rr = np.where(hit, r, msg.range_max)
            p_laser = np.column_stack([rr * np.cos(ang), rr * np.sin(ang)])
            pts = se2_apply(t_base_laser, p_laser)
            if deskew and msg.time_increment > 0:
                beam_t = stamp + np.round(np.arange(n) * msg.time_increment * 1e9).astype(np.int64)
                o = interpolate_poses(odom_t, odom_p, np.concatenate([[stamp], beam_t]))
                if np.all(np.isfinite(o)):
                    rel = se2_between(o[0], o[1:])  # base at beam time, in base at scan stamp
                    pts = se2_compose(rel, np.column_stack([pts, np.zeros(n)]))[:, :2]
            if k < beams["stamp_ns"].size and int(beams["stamp_ns"][k]) != stamp:
                raise ValueError(f"{tour}: scan {k} stamp {stamp} differs from beams.npz")
            scans.append(PaintedScan(
                stamp_ns=stamp, origin=t_base_laser[:2], points=pts, hit=hit,
                mobility=beams["mobility"][k], class_id=beams["class_index"][k],
                class_names=tuple(str(s) for s in beams["class_names"]), frame_id=base_frame))
            stamps.append(stamp)
    st = np.asarray(stamps, dtype=np.int64)
    return TourData(st, scans, interpolate_poses(odom_t, odom_p, st), gt_t, gt_p)


def run(data: TourData, cfg: RegistrationConfig) -> tuple[NDArray[np.float64], float, dict]:
    """Register every scan; returns poses (S, 3), wall seconds and the registrar's stats."""
    reg = Registrar(cfg)
    poses = np.empty((len(data.scans), 3))
    t = time.perf_counter()
    for i, scan in enumerate(data.scans):
        o = data.odom[i]
        poses[i] = reg.register(scan, o if np.all(np.isfinite(o)) else None)
    return poses, time.perf_counter() - t, reg.stats


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["ward", "office"])
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    ap.add_argument("--seed", type=int, default=0, help="simulator noise seed")
    ap.add_argument("--tours", type=Path, help="reuse simulated tours in DIR/<scenario> (simulated if absent)")
    ap.add_argument("--no-deskew", action="store_true", help="ignore the LiDAR sweep when building scans")
    ap.add_argument("--config", type=Path, help="YAML with RegistrationConfig overrides")
    ap.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = ap.parse_args()

    from semmap.config import load_model, load_yaml

    base = load_model(RegistrationConfig, load_yaml(args.config) if args.config else {}, str(args.config))
    rows = []
    with tempfile.TemporaryDirectory(prefix="semmap-bench-reg-") as tmp:
        for name in args.scenarios:
            tour = (args.tours / name) if args.tours else Path(tmp) / name
            if not tour.is_dir():
                from semmap.sim.tour import simulate

                simulate(name, tour, fmt="ros1", seed=args.seed)
            t = time.perf_counter()
            data = load_tour(tour, deskew=not args.no_deskew)
            load_s = time.perf_counter() - t
            for mode in args.modes:
                poses, wall, stats = run(data, base.model_copy(update={"mode": mode}))
                ate = ate_rmse(data.stamps, poses, data.gt_stamps, data.gt_poses)
                rows.append({"scenario": name, "mode": mode, "scans": len(data.scans), "ate_m": ate,
                             "wall_s": wall, "scans_per_s": len(data.scans) / wall, "load_s": load_s,
                             "stats": stats})
                print(f"{name:8s} {mode:8s} ATE {ate:.4f} m  {len(data.scans) / wall:7.1f} scans/s  "
                      f"{json.dumps({k: v for k, v in stats.items() if k.startswith(('icp', 'odom'))})}",
                      file=sys.stderr)
    print(f"semmap registration benchmark, {date.today().isoformat()}, seed {args.seed}, "
          f"deskew {'off' if args.no_deskew else 'on'}")
    print(f"machine: {machine()}\n")
    print("| scenario | mode | scans | ATE RMSE (m) | scans/s | ICP accepted | rejected | failed |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        s = r["stats"]
        print(f"| {r['scenario']} | {r['mode']} | {r['scans']} | {r['ate_m']:.3f} | {r['scans_per_s']:.0f} | "
              f"{s['icp_accepted']} | {s['icp_rejected']} | {s['icp_failed']} |")
    if args.json:
        args.json.write_text(json.dumps({"date": date.today().isoformat(), "machine": machine(), "rows": rows},
                                        indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
