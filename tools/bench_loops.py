#!/usr/bin/env python3
"""Benchmark loop closure on a long simulated loop with drifting wheel odometry (issue 22).

It simulates the built-in scenario ``loop`` (a 40 m x 20 m ring corridor driven once round
and 15 m on past the start, about twice ``ward``'s route) with wheel odometry that drifts
more than the simulator's default (``--yaw-drift``, ``--scale-error``; passed to ``semmap
simulate --config``), caches the tour under the temporary folder, and builds it in each
mode with and without loop closure (``registration.loop_closure.enabled``), each build in
its own process. Every map is scored against the ground truth with
:func:`semmap.sim.score.score_map`:

* occupied F1 at 1 cell (the scorer's tolerance: a map cell counts when a truth cell lies in
  its 3 x 3 neighbourhood, and back; recall over the truth cells a true beam reached), with
  its precision and recall: a doubled wall is a second line of occupied cells beyond that
  tolerance, so it costs precision;
* ATE RMSE of the trajectory after SE(2) alignment;
* the build's wall time, and ``summary.json`` → ``registration.loop_closure`` (candidates,
  loops accepted and kept, largest correction).

The reference is the true-pose map (:func:`semmap.sim.score.naive_map`: the recorded scans at
the true poses, no semantics). Targets (issue 22): with loop closure, F1 at 1 cell within 0.01
of the true-pose map; loop closure adds at most 20 % to a build.

    python tools/bench_loops.py                                   # six builds, table
    python tools/bench_loops.py --modes fused --picture /tmp/loops.png --json /tmp/loops.json
    python tools/bench_loops.py --yaw-drift 0.3 --fresh           # another drift (a new tour)
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import statistics
import sys
import tempfile
import time
import traceback
from datetime import date
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from bench_build import run_build
from benchlib import add_set_argument, machine

SCENARIO = "loop"
LOOPS_ON = {"registration": {"loop_closure": {"enabled": True}}}
# (name, mode, loop closure)
RUNS: list[tuple[str, str, bool]] = [
    ("fused", "fused", False), ("fused+lc", "fused", True),
    ("odometry", "odometry", False), ("odometry+lc", "odometry", True),
    ("icp", "icp", False), ("icp+lc", "icp", True),
]


def sim_config(yaw_drift: float, scale_error: float) -> dict[str, Any]:
    """Wheel odometry that drifts: heading bias per metre, and distance and turn scale errors of
    ``scale_error`` to ``scale_error`` + 1 % (the sign is drawn per tour)."""
    scale = [round(scale_error, 4), round(scale_error + 0.01, 4)]
    return {"odometry": {"yaw_drift_deg_per_m": yaw_drift, "scale_error": scale, "yaw_scale_error": scale}}


def tour_key(cfg: dict[str, Any], seed: int) -> str:
    """The simulator's source, its config and the seed: a cached tour of another simulator is not reused."""
    h = hashlib.sha256(json.dumps([cfg, seed], sort_keys=True).encode())
    for f in sorted((REPO / "semmap" / "sim").glob("*.py")) + [REPO / "semmap" / "config.py"]:
        if f.name not in ("score.py", "score_diff.py", "preview.py"):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:10]


def simulate_tour(cache: Path, cfg: dict[str, Any], seed: int, fresh: bool) -> tuple[Path, float | None]:
    """The tour (simulated with ``semmap simulate`` unless cached); returns (folder, seconds or None if cached)."""
    from semmap.cli.main import main as semmap_main
    from semmap.io.yamlio import write_yaml

    out = cache / f"{SCENARIO}-{tour_key(cfg, seed)}"
    if not fresh and (out / "tour.yaml").is_file():
        return out, None
    cache.mkdir(parents=True, exist_ok=True)
    cfg_file = cache / f"{out.name}.sim.yaml"
    write_yaml(cfg_file, cfg)
    t = time.perf_counter()
    code = semmap_main(["simulate", "--scenario", SCENARIO, "--out", str(out), "--config", str(cfg_file),
                        "--seed", str(seed), "--force", "--quiet"])
    if code != 0:
        raise RuntimeError(f"semmap simulate failed with exit code {code}")
    return out, time.perf_counter() - t


# ---------------------------------------------------------------------------------------
# Building and scoring


def run_one(name: str, mode: str, lc: bool, tour: Path, maps: Path, truth: Any,
            extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Build one map (child process), score it, read its loop-closure summary."""
    from semmap.config import merge_overrides
    from semmap.sim.score import score_map

    row: dict[str, Any] = {"run": name, "mode": mode, "loop_closure": lc}
    out = maps / name.replace("+", "_")
    overrides: dict[str, Any] = {"registration": {"mode": mode}}
    if lc:
        overrides["registration"].update(LOOPS_ON["registration"])
    overrides = merge_overrides(overrides, extra or {})
    try:
        t = time.perf_counter()
        res = run_build(tour, out, overrides)
        row["wall_s"] = time.perf_counter() - t
        row["build_s"] = float(res["elapsed_s"])
    except Exception as exc:
        lines = [x for x in str(exc).strip().splitlines() if x.strip()]
        row["error"] = lines[-1] if lines else type(exc).__name__
        print(str(exc)[-3000:], file=sys.stderr)
        return row
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    reg = summary.get("registration", {}) or {}
    row["registration_s"] = reg.get("seconds")
    row["loops"] = reg.get("loop_closure")
    if lc and row["loops"] is None:
        row["note"] = "no registration.loop_closure in summary.json"
    try:
        s = score_map(tour, out, truth=truth)
    except Exception as exc:
        row["error"] = f"scoring: {type(exc).__name__}: {exc}"
        print(traceback.format_exc(), file=sys.stderr)
        return row
    row.update({k: s[k] for k in ("f1", "precision", "recall", "ate_rmse_m", "ghost_rate")})
    row["map"] = str(out)
    return row


def naive_reference(tour: Path, truth: Any) -> dict[str, Any]:
    from semmap.sim.score import naive_map, score_masks

    t = time.perf_counter()
    nm = naive_map(tour)
    s = score_masks(tour, nm.spec, nm.occupied, nm.semi_static, nm.objects, None, truth=truth)
    return {"run": "true poses", "f1": s["f1"], "precision": s["precision"], "recall": s["recall"],
            "ate_rmse_m": 0.0, "wall_s": time.perf_counter() - t}


# ---------------------------------------------------------------------------------------
# Reporting


def _f(v: Any, spec: str, unit: str = "") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    return f"{v:{spec}}{unit}"


def _loops_cell(loops: Any) -> str:
    if not isinstance(loops, dict):
        return "–"
    kept = loops.get("loops")
    kept_n = len(kept) if isinstance(kept, list) else kept
    corr = loops.get("max_correction_m")
    return (f"{loops.get('candidates', '?')} / {loops.get('accepted', '?')} / {kept_n}"
            + (f", ≤ {corr:.2f} m" if isinstance(corr, int | float) else ""))


def table(rows: list[dict[str, Any]], ref: dict[str, Any], overhead: dict[str, Any]) -> list[str]:
    lines = ["| run | F1 (1 cell) | ΔF1 vs true poses | precision | recall | ATE RMSE | build | LC overhead "
             "| loops: candidates / accepted / kept, max correction |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    base = {r["run"]: r for r in rows}
    for r in rows:
        if "error" in r and "f1" not in r:
            lines.append(f"| {r['run']} | failed: {r['error']} | | | | | "
                         f"{_f(r.get('build_s'), '.0f', ' s')} | | |")
            continue
        d = r["f1"] - ref["f1"] if "f1" in r else float("nan")
        ov = ""
        if r["loop_closure"] and r["run"].removesuffix("+lc") in base:
            b = base[r["run"].removesuffix("+lc")]
            if "build_s" in b and "build_s" in r:
                ov = f"{100 * (r['build_s'] / b['build_s'] - 1):+.0f} %"
        note = f" ({r['note']})" if r.get("note") else ""
        lines.append(f"| {r['run']} | {_f(r.get('f1'), '.3f')} | {_f(d, '+.3f')} | {_f(r.get('precision'), '.3f')} | "
                     f"{_f(r.get('recall'), '.3f')} | {_f(r.get('ate_rmse_m'), '.3f', ' m')} | "
                     f"{_f(r.get('build_s'), '.0f', ' s')} | {ov} | {_loops_cell(r.get('loops'))}{note} |")
    lines.append(f"| true poses (naive map) | {ref['f1']:.3f} | 0 | {ref['precision']:.3f} | {ref['recall']:.3f} | "
                 f"0 | | | |")
    if overhead.get("pairs"):
        lines += ["", f"Loop-closure overhead, fused, median of {overhead['pairs']} alternating build pairs: "
                      f"{overhead['without_s']:.1f} s without, {overhead['with_s']:.1f} s with "
                      f"({100 * overhead['ratio'] - 100:+.0f} %)."]
    return lines


def targets(rows: list[dict[str, Any]], ref: dict[str, Any], overhead: dict[str, Any]) -> list[str]:
    lines = ["| target | result |", "|---|---|"]
    by = {r["run"]: r for r in rows}
    for name in ("fused+lc", "odometry+lc", "icp+lc"):
        r = by.get(name)
        if r is None:
            continue
        if "f1" not in r:
            lines.append(f"| {name}: F1 (1 cell) within 0.01 of the true-pose map | FAIL (build failed) |")
            continue
        ok = r["f1"] >= ref["f1"] - 0.01
        lines.append(f"| {name}: F1 (1 cell) within 0.01 of the true-pose map | "
                     f"{'pass' if ok else 'FAIL'} ({r['f1']:.3f} vs {ref['f1']:.3f}) |")
    if overhead.get("pairs"):
        ratio = overhead["ratio"]
    elif "build_s" in by.get("fused", {}) and "build_s" in by.get("fused+lc", {}):
        ratio = by["fused+lc"]["build_s"] / by["fused"]["build_s"]
    else:
        ratio = None
    if ratio is not None:
        lines.append(f"| loop closure adds ≤ 20 % to a (fused) build | {'pass' if ratio <= 1.2 else 'FAIL'} "
                     f"({100 * ratio - 100:+.0f} %) |")
    return lines


def picture(path: Path, tour: Path, rows: list[dict[str, Any]], truth: Any) -> None:
    """The fused map without and with loop closure side by side in the truth frame (their own SE(2)
    alignment), the truth's walls in red beneath; below, the loop's junction enlarged; on the right
    every trajectory over the true path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.transforms import Affine2D

    from semmap.geometry import se2_compose
    from semmap.mapfolder.reader import load_map_folder
    from semmap.register.metrics import ate_errors

    by = {r["run"]: r for r in rows if "map" in r}
    shown = [n for n in ("fused", "fused+lc") if n in by]
    if not shown:
        shown = list(by)[:2]
    if not shown:
        print("no map to draw", file=sys.stderr)
        return
    fig = plt.figure(figsize=(7.5 * len(shown) + 6.0, 11), constrained_layout=True)
    gs = fig.add_gridspec(2, len(shown) + 1, height_ratios=[1.0, 1.0], width_ratios=[1.0] * len(shown) + [0.8])
    ts = truth.spec
    truth_rgba = np.zeros((*truth.occupancy.shape, 4))
    truth_rgba[truth.occupancy] = (0.9, 0.1, 0.1, 0.55)
    truth_extent = (ts.origin_x, ts.origin_x + ts.width * ts.resolution,
                    ts.origin_y, ts.origin_y + ts.height * ts.resolution)
    lo_x, lo_y, hi_x, hi_y = truth_extent[0], truth_extent[2], truth_extent[1], truth_extent[3]
    junction = (-5.0, 21.0, -7.5, 5.0)  # the ring's start and end, the south-west corner and rooms (truth frame)
    aligned: dict[str, Any] = {}
    for name, r in by.items():
        m = load_map_folder(r["map"])
        _, t_gt_map = ate_errors(m.stamps_ns, m.poses, truth.stamps_ns, truth.poses)
        aligned[name] = (m, t_gt_map, se2_compose(t_gt_map, m.poses))
    for col, name in enumerate(shown):
        m, t_gt_map, _ = aligned[name]
        r = by[name]
        img = np.full(m.spec.shape, 0.62)
        img[m.free] = 1.0
        img[m.occupied] = 0.0
        s = m.spec
        extent = (s.origin_x, s.origin_x + s.width * s.resolution, s.origin_y, s.origin_y + s.height * s.resolution)
        tf = Affine2D().rotate(float(t_gt_map[2])).translate(float(t_gt_map[0]), float(t_gt_map[1]))
        for row_i, box in enumerate((None, junction)):
            ax = fig.add_subplot(gs[row_i, col])
            im = ax.imshow(img, cmap="gray", vmin=0, vmax=1, origin="lower", extent=extent, interpolation="nearest")
            im.set_transform(tf + ax.transData)
            ax.imshow(truth_rgba, origin="lower", extent=truth_extent, interpolation="nearest")
            ax.plot(truth.poses[:, 0], truth.poses[:, 1], color="tab:blue", lw=0.6, alpha=0.6)
            if box is None:
                ax.set_xlim(lo_x, hi_x)
                ax.set_ylim(lo_y, hi_y)
                lc = "with loop closure" if r["loop_closure"] else "without loop closure"
                ax.set_title(f"{r['mode']} {lc}: F1 (1 cell) {r['f1']:.3f}, precision {r['precision']:.3f}, "
                             f"ATE {r['ate_rmse_m']:.3f} m")
            else:
                ax.set_xlim(box[0], box[1])
                ax.set_ylim(box[2], box[3])
                ax.set_title("the loop's junction (start and end of the tour)")
            ax.set_aspect("equal")
            ax.set_xlabel("x [m] (truth frame)")
            ax.set_ylabel("y [m]")
    ax = fig.add_subplot(gs[:, len(shown)])
    ax.imshow(truth.occupancy, cmap="Greys", alpha=0.35, origin="lower", extent=truth_extent, interpolation="nearest")
    ax.plot(truth.poses[:, 0], truth.poses[:, 1], color="k", lw=2.0, label="true path")
    colours = {"fused": "tab:orange", "fused+lc": "tab:green", "odometry": "tab:red", "odometry+lc": "tab:pink",
               "icp": "tab:purple", "icp+lc": "tab:cyan"}
    for name, (_, _, p) in aligned.items():
        ate = by[name]["ate_rmse_m"]
        ax.plot(p[:, 0], p[:, 1], lw=1.0, color=colours.get(name), label=f"{name} (ATE {ate:.3f} m)")
    ax.set_xlim(lo_x - 3, hi_x + 3)
    ax.set_ylim(lo_y - 3, hi_y + 3)
    ax.set_aspect("equal")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("trajectories, each aligned to the true path (SE(2))")
    fig.suptitle(f"semmap: loop closure on the simulated '{SCENARIO}' tour ({tour.name}), truth walls in red")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


# ---------------------------------------------------------------------------------------


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="+", default=[r[0] for r in RUNS], choices=[r[0] for r in RUNS],
                    help="which builds (default: all six)")
    ap.add_argument("--yaw-drift", type=float, default=0.3,
                    help="odometry heading drift, deg per m (default 0.3, twice the simulator's 0.15: about 40 deg "
                         "over the tour; the fused map without loop closure doubles walls at the junction)")
    ap.add_argument("--scale-error", type=float, default=0.02,
                    help="odometry scale errors from this to this + 0.01 (default 0.02)")
    ap.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the simulation")
    ap.add_argument("--tours", type=Path, default=Path(tempfile.gettempdir()) / "semmap-loop-tours",
                    help="where simulated tours are cached")
    ap.add_argument("--fresh", action="store_true", help="simulate again even when a cached tour exists")
    ap.add_argument("--maps", type=Path, help="keep the map folders here (default: a temporary folder)")
    ap.add_argument("--timing-pairs", type=int, default=0,
                    help="extra alternating fused builds without and with loop closure for the overhead "
                         "figure (median; a shared machine's speed varies)")
    ap.add_argument("--json", type=Path, help="also write every figure here")
    ap.add_argument("--picture", type=Path, help="write the before/after figure (PNG) here")
    add_set_argument(ap)
    args = ap.parse_args()

    t_start = time.perf_counter()
    cfg = sim_config(args.yaw_drift, args.scale_error)
    tour, sim_s = simulate_tour(args.tours, cfg, args.seed, args.fresh)
    print(f"tour {tour}: " + ("cached" if sim_s is None else f"simulated in {sim_s:.0f} s"), file=sys.stderr)

    from semmap.config import merge_overrides
    from semmap.sim.score import load_truth

    truth = load_truth(tour)
    ref = naive_reference(tour, truth)
    print(f"  true poses   F1 {ref['f1']:.3f}  ({ref['wall_s']:.0f} s)", file=sys.stderr)
    rows: list[dict[str, Any]] = []
    overhead: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="semmap-loop-maps-") as tmp:
        maps = args.maps if args.maps is not None else Path(tmp)
        maps.mkdir(parents=True, exist_ok=True)
        for name, mode, lc in RUNS:
            if name not in args.runs:
                continue
            row = run_one(name, mode, lc, tour, maps, truth, args.set)
            rows.append(row)
            if "f1" in row:
                print(f"  {name:<12} F1 {row['f1']:.3f}  P {row['precision']:.3f}  ATE {row['ate_rmse_m']:.3f} m  "
                      f"build {row['build_s']:.0f} s  loops {_loops_cell(row.get('loops'))}", file=sys.stderr)
            else:
                print(f"  {name:<12} FAILED: {row.get('error')}", file=sys.stderr)
        if args.timing_pairs > 0:
            without: list[float] = []
            with_: list[float] = []
            for _ in range(args.timing_pairs):
                for lc, acc in ((False, without), (True, with_)):
                    ov = {"registration": {"mode": "fused", **({"loop_closure": {"enabled": True}} if lc else {})}}
                    ov = merge_overrides(ov, args.set)
                    try:
                        acc.append(float(run_build(tour, maps / "timing", ov)["elapsed_s"]))
                    except Exception as exc:
                        print(f"timing build failed: {str(exc)[-500:]}", file=sys.stderr)
                    finally:
                        import shutil

                        shutil.rmtree(maps / "timing", ignore_errors=True)
            by = {r["run"]: r for r in rows}
            without += [by["fused"]["build_s"]] if "build_s" in by.get("fused", {}) else []
            with_ += [by["fused+lc"]["build_s"]] if "build_s" in by.get("fused+lc", {}) else []
            if without and with_:
                overhead = {"pairs": min(len(without), len(with_)), "without_s": statistics.median(without),
                            "with_s": statistics.median(with_), "all_without_s": without, "all_with_s": with_}
                overhead["ratio"] = overhead["with_s"] / overhead["without_s"]
        if args.picture:
            try:
                picture(args.picture, tour, rows, truth)
                print(f"picture: {args.picture}", file=sys.stderr)
            except Exception:
                print(traceback.format_exc(), file=sys.stderr)
    wall_s = time.perf_counter() - t_start

    print(f"semmap loop-closure benchmark, {date.today().isoformat()}")
    print(f"machine: {machine()}")
    print(f"tour: scenario {SCENARIO}, seed {args.seed}, odometry {json.dumps(cfg['odometry'])}"
          + (f", simulated in {sim_s:.0f} s" if sim_s is not None else "") + f"; wall time {wall_s / 60:.1f} min\n")
    print("\n".join(table(rows, ref, overhead)))
    print()
    print("\n".join(targets(rows, ref, overhead)))
    if args.json:
        args.json.write_text(json.dumps({"date": date.today().isoformat(), "machine": machine(), "scenario": SCENARIO,
                                         "seed": args.seed, "sim_config": cfg, "simulate_s": sim_s, "tour": str(tour),
                                         "wall_s": wall_s, "true_poses": ref, "runs": rows, "overhead": overhead},
                                        indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
