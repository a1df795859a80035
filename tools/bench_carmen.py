#!/usr/bin/env python3
"""semmap's registration on the classic CARMEN logs (Intel, Freiburg 101), scored against their
reference poses as Kümmerle et al. 2009 did.

Each log is imported with ``semmap import carmen`` (honest odometry: the wheels' steps between scans,
never the corrected poses), built with each registration mode, and scored with ``semmap eval-traj``:
relative pose error at steps of 1 and 10 scans (every pair), and the ATE. The reference poses are
themselves SLAM-corrected (GMapping), not ground truth.

Usage::

    python tools/bench_carmen.py                       # ../shared/data/carmen, work in /tmp/semmap-bench-carmen
    python tools/bench_carmen.py --logs intel --modes fused icp
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from datetime import date
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchlib import add_set_argument, machine

from semmap.io.tum import read_tum
from semmap.register.evaluate import trajectory_errors

LOGS = {"intel": "intel-corrected.log.gz", "freiburg101": "freiburg-101-corrected.log.gz"}
#: Kümmerle et al. 2009, Table I: mean translational relative error on Intel (m)
PUBLISHED = {"intel": {"scan matching": 0.220, "RBPF (GMapping)": 0.070, "graph mapping": 0.031}}


def run(data: Path, work: Path, logs: list[str], modes: list[str], extra: dict | None = None) -> list[dict]:
    from semmap.cli.main import main
    from semmap.config import merge_overrides
    from semmap.io.yamlio import write_yaml

    rows = []
    for name in logs:
        src = data / LOGS[name]
        tour = work / name / "tour"
        if not (tour / "import.json").is_file():
            assert main(["import", "carmen", str(src), "--out", str(tour), "--force", "-q"]) == 0
        ref_t, ref_p = read_tum(tour / "reference.tum")
        odo_t, odo_p = read_tum(tour / "odometry.tum")
        e = trajectory_errors(odo_t, odo_p, ref_t, ref_p)
        rows.append({"log": name, "mode": "odometry alone (imported, no build)", "seconds": None, **e.as_dict()})
        for mode in modes:
            cfg = work / name / f"{mode}.yaml"
            write_yaml(cfg, merge_overrides(_config(mode), extra or {}))
            out = work / name / f"map_{mode}"
            t0 = time.perf_counter()
            assert main(["build", str(tour), "--out", str(out), "--config", str(cfg), "--force", "-q"]) == 0
            seconds = time.perf_counter() - t0
            t, p = read_tum(out / "trajectory.tum")
            e = trajectory_errors(t, p, ref_t, ref_p)
            summary = json.loads((out / "summary.json").read_text())
            rows.append({"log": name, "mode": mode, "seconds": round(seconds, 1), **e.as_dict(),
                         "registration": summary.get("registration", {})})
            print(f"  {name} {mode}: RPE1 {e.rpe[1]['trans_mean']:.3f} m, RPE10 {e.rpe[10]['trans_mean']:.3f} m, "
                  f"ATE {e.ate_rmse:.2f} m", flush=True)
    return rows


def _config(mode: str) -> dict:
    """The build config of a mode: ``odometry``, ``icp`` or ``fused``; ``+fit``: ``ekf.fit_margin 0`` (ICP
    beyond the gate taken where the scan fits the map better); ``+loops``: loop closure on."""
    base, *extras = mode.split("+")
    reg: dict = {"mode": base}
    if "fit" in extras:
        reg["ekf"] = {"fit_margin": 0.0}
    if "loops" in extras:
        reg["loop_closure"] = {"enabled": True}
    return {"registration": reg}


def table(rows: list[dict]) -> str:
    lines = ["| log | poses from | RPE δ=1 trans (m) | RPE δ=1 rot (°) | RPE δ=10 trans (m) | RPE δ=10 rot (°) "
             "| ATE RMSE (m) | build (s) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a, b = r["rpe"]["1"], r["rpe"]["10"]
        lines.append(f"| {r['log']} | {r['mode']} | {a['trans_mean']:.3f} ± {a['trans_std']:.3f} | "
                     f"{a['rot_mean_deg']:.2f} ± {a['rot_std_deg']:.2f} | "
                     f"{b['trans_mean']:.3f} ± {b['trans_std']:.3f} | "
                     f"{b['rot_mean_deg']:.2f} ± {b['rot_std_deg']:.2f} | {r['ate_rmse']:.2f} | "
                     f"{r['seconds'] if r['seconds'] is not None else '-'} |")
    for log, figs in PUBLISHED.items():
        for method, v in figs.items():
            lines.append(f"| {log} | published: {method} (Kümmerle et al. 2009) | {v:.3f} | | | | | |")
    return "\n".join(lines)


def picture(work: Path, logs: list[str], modes: list[str], rows: list[dict], path: Path) -> None:
    """The maps of ``modes`` side by side, one row per log, titled with their RPE at step 10 and ATE."""
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(logs), len(modes), figsize=(4.2 * len(modes), 4.2 * len(logs)), squeeze=False)
    for i, name in enumerate(logs):
        for j, mode in enumerate(modes):
            ax = axes[i][j]
            ax.axis("off")
            img = cv2.imread(str(work / name / f"map_{mode}" / "map.pgm"), cv2.IMREAD_GRAYSCALE)
            r = next((x for x in rows if x["log"] == name and x["mode"] == mode), None)
            if img is None or r is None:
                continue
            ax.imshow(img, cmap="gray", vmin=0, vmax=255)
            ax.set_title(f"{name}, {mode}\nRPE δ=10 {r['rpe']['10']['trans_mean']:.3f} m, ATE {r['ate_rmse']:.2f} m",
                         fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "carmen")
    ap.add_argument("--work", type=Path, default=Path("/tmp/semmap-bench-carmen"))
    ap.add_argument("--logs", nargs="+", default=list(LOGS), choices=list(LOGS))
    ap.add_argument("--modes", nargs="+",
                    default=["odometry", "icp", "fused", "odometry+loops", "icp+loops", "fused+loops"],
                    help="registration modes (odometry, icp, fused); +fit: ekf.fit_margin 0; +loops: loop closure")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--picture", type=Path, help="draw the maps of --picture-modes side by side into this PNG")
    ap.add_argument("--picture-modes", nargs="+", default=["fused", "fused+loops"])
    add_set_argument(ap)
    args = ap.parse_args()
    if not args.data.is_dir():
        print(f"{args.data}: no CARMEN logs here", file=sys.stderr)
        return 1
    print(f"*{date.today().isoformat()}, {machine()}*\n")
    rows = run(args.data, args.work, args.logs, args.modes, args.set)
    print()
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    if args.picture:
        picture(args.work, args.logs, [m for m in args.picture_modes if m in args.modes], rows, args.picture)
        print(f"\npicture: {args.picture}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
