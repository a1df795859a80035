"""``semmap eval-traj``: a trajectory's relative and absolute errors against reference poses (evo)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ._progress import console


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "eval-traj", parents=[common], help="trajectory errors against reference poses (RPE, ATE; with evo)",
        description="The relative pose error between scans 1 and 10 apart (Kümmerle et al. 2009: mean and "
                    "standard deviation, translation and rotation) and the ATE after a rigid alignment, of a "
                    "trajectory against reference poses, always beside the same errors of the dead-reckoned "
                    "odometry. Computed with evo.")
    p.add_argument("traj", type=Path, metavar="TRAJ",
                   help="a map folder from semmap build (its trajectory.tum and odometry.tum) or a TUM file")
    p.add_argument("--ref", required=True, type=Path, metavar="REF",
                   help="reference poses: a TUM file, or a tour folder (reference.tum from semmap import, "
                        "ground_truth/trajectory.tum from semmap simulate)")
    p.add_argument("--odometry", type=Path, metavar="TUM", help="the odometry to compare with (default: the map "
                                                                "folder's odometry.tum)")
    p.add_argument("--delta", type=int, action="append", metavar="N", help="RPE step in scans (default 1 and 10)")
    p.add_argument("--max-diff", type=float, default=0.01, metavar="S", help="pair poses by stamp within S seconds")
    p.add_argument("--json", action="store_true", help="print the figures as JSON")
    p.set_defaults(run=run)


def _tum_of(path: Path, kinds: tuple[str, ...], what: str) -> Path:
    from ..errors import ConfigError

    if path.is_file():
        return path
    for k in kinds:
        if (path / k).is_file():
            return path / k
    raise ConfigError(f"{path}: no {what} ({' or '.join(kinds)}) there")


def run(args: argparse.Namespace) -> int:
    from ..errors import ConfigError
    from ..io.tum import read_tum
    from ..register.evaluate import trajectory_errors

    deltas = tuple(args.delta) if args.delta else (1, 10)
    if any(d < 1 for d in deltas):
        raise ConfigError("--delta must be a whole number of scans, 1 or more")
    est_path = _tum_of(args.traj, ("trajectory.tum",), "trajectory")
    ref_path = _tum_of(args.ref, ("reference.tum", "ground_truth/trajectory.tum"), "reference poses")
    odom_path = args.odometry
    if odom_path is None and args.traj.is_dir() and (args.traj / "odometry.tum").is_file():
        odom_path = args.traj / "odometry.tum"
    ref_t, ref_p = read_tum(ref_path)
    rows = {}
    for name, path in (("trajectory", est_path), ("odometry", odom_path)):
        if path is None:
            continue
        t, poses = read_tum(path)
        rows[name] = trajectory_errors(t, poses, ref_t, ref_p, deltas, args.max_diff)
    if args.json:
        print(json.dumps({"reference": str(ref_path), **{k: v.as_dict() for k, v in rows.items()}}, indent=2))
        return 0
    if args.quiet:
        return 0
    out = console()
    out.print(f"{est_path} against {ref_path}")
    head = "".join(f"  RPE δ={d:<3} trans (m)    rot (°)     " for d in deltas)
    out.print(f"{'':12}{head}  ATE RMSE (m)")
    for name, e in rows.items():
        cells = ""
        for d in deltas:
            r = e.rpe.get(d)
            cells += (f"  {r['trans_mean']:.3f} ± {r['trans_std']:.3f}  {r['rot_mean_deg']:5.2f} ± "
                      f"{r['rot_std_deg']:5.2f}  " if r else f"  {'-':>27}  ")
        out.print(f"{name:<12}{cells}  {e.ate_rmse:.3f}   ({e.poses} poses)")
    return 0
