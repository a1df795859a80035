#!/usr/bin/env python3
"""Benchmark semmap's cleaned maps against ground truth, beside a naive true-pose mapper.

For each procedurally generated world (``random:SEED``) and each named scenario it simulates
the tour (cached, sensor-noise seed 0), builds the map with ``semmap build`` (default
configuration, in its own process), builds the naive map (:func:`semmap.sim.score.naive_map`:
the recorded scans placed with the true poses, log-odds, no semantics) and scores both with
:func:`semmap.sim.score.score_masks`:

* standing left: share of the cells people stood on (5 s or more) that stay occupied;
* ghost rate: share of the cells people swept that stay occupied;
* occupied F1 at 1-cell tolerance (recall over the truth cells some true beam reached);
* semi-static precision, and recall over the furniture the camera labelled at least once;
* walls flagged: cells flagged movable that lie on walls or pillars (next to no furniture);
* objects: the map's object list against the furniture the camera labelled at least once (count,
  class; an object no camera saw cannot be named).

Then the median and worst case over the random worlds, each named scenario, and the targets.

The scoring worlds (``SCORING_SEEDS``) are held out: develop and tune with ``--dev`` (seeds
0..N-1) or ``--seeds``, and run the scoring seeds only to report.

    python tools/bench_semantic.py                          # the 20 scoring worlds + 4 scenarios
    python tools/bench_semantic.py --dev --worlds 3 --scenarios demo
    python tools/bench_semantic.py --seeds 7 8 --scenarios --json /tmp/sem.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import multiprocessing
import statistics
import sys
import tempfile
import time
import traceback
from concurrent.futures import Future, ProcessPoolExecutor
from datetime import date
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from bench_build import run_build
from benchlib import add_set_argument, machine

# The scoring worlds. These seeds are for scoring only: never look at their worlds or maps,
# and never use them while developing or tuning (use --dev or --seeds); otherwise the scores
# stop telling how semmap does on worlds it was not fitted to.
SCORING_SEEDS = range(1000, 1020)

NAMED_SCENARIOS = ["demo", "ward", "office", "occlusion"]

# (key, label, format, lower is better)
ROWS: list[tuple[str, str, str, bool]] = [
    ("standing_left", "standing left", "pct", True),
    ("ghost_rate", "ghost rate", "pct", True),
    ("f1", "occupied F1", "f3", False),
    ("semi_precision", "semi-static precision", "f3", False),
    ("semi_recall", "semi-static recall (camera-labelled furniture)", "f3", False),
    ("semi_recall_all", "semi-static recall (all furniture)", "f3", False),
    ("walls_flagged", "walls flagged (cells)", "int", True),
    ("objects_count_error", "object count error", "spct", True),
    ("objects_class_right", "object class right", "pct", False),
]


TARGETS = ["standing left ≤ 2 %", "ghost rate ≤ 0.5 %", "F1 ≥ 0.98 and ≥ naive", "semi-static P ≥ 0.90 and R ≥ 0.90",
           "walls flagged = 0", "object count within ±10 %", "class right ≥ 90 %"]


def _target_checks(s: dict, naive: dict) -> dict[str, bool | None]:
    """Pass (True), fail (False) or not measurable (None) for each of ``TARGETS``, one world.

    Semi-static recall is the recall over furniture the camera labelled at least once.
    """

    def ok(value: float, test: Any) -> bool | None:
        return None if value is None or (isinstance(value, float) and math.isnan(value)) else bool(test(value))

    f1 = ok(s["f1"], lambda v: v >= 0.98 and (math.isnan(naive["f1"]) or v >= naive["f1"]))
    p, r = ok(s["semi_precision"], lambda v: v >= 0.90), ok(s["semi_recall"], lambda v: v >= 0.90)
    verdicts = [ok(s["standing_left"], lambda v: v <= 0.02), ok(s["ghost_rate"], lambda v: v <= 0.005), f1,
                None if p is None or r is None else p and r, ok(s["walls_flagged"], lambda v: v == 0),
                ok(s["objects_count_error"], lambda v: abs(v) <= 0.10),
                ok(s["objects_class_right"], lambda v: v >= 0.90)]
    return dict(zip(TARGETS, verdicts))


# ---------------------------------------------------------------------------------------
# Simulating (in a helper process, one tour ahead of the builds)


def simulator_key() -> str:
    """A short hash of the simulator's source: cached tours of another simulator are not reused."""
    h = hashlib.sha256()
    files = sorted((REPO / "semmap" / "sim").glob("*.py")) + [REPO / "semmap" / "config.py"]
    for f in files:
        if f.name not in ("score.py", "preview.py"):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:10]


def simulate_tour(scenario: str, out: str, fresh: bool) -> tuple[str, float]:
    """Simulate ``scenario`` into ``out`` unless a complete tour is there; returns (out, seconds)."""
    from semmap.sim.tour import simulate

    t = time.perf_counter()
    if fresh or not (Path(out) / "tour.yaml").is_file():
        simulate(scenario, out, seed=0, force=True)
    return out, time.perf_counter() - t


def have_generator() -> bool:
    import importlib.util

    return importlib.util.find_spec("semmap.sim.procedural") is not None


# ---------------------------------------------------------------------------------------
# Building and scoring one world


def run_world(name: str, tour: Path, maps: Path, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Build semmap's map (child process) and the naive map, score both."""
    from semmap.sim.score import load_truth, naive_map, score_map, score_masks

    row: dict[str, Any] = {"world": name, "tour": str(tour)}
    t = time.perf_counter()
    out = maps / name.replace(":", "_")
    run_build(tour, out, overrides or {})
    row["build_s"] = time.perf_counter() - t
    truth = load_truth(tour)
    row["truth_objects_from"] = truth.objects_source
    row["semmap"] = score_map(tour, out, truth=truth)
    t = time.perf_counter()
    nm = naive_map(tour)
    row["naive_s"] = time.perf_counter() - t
    row["naive"] = score_masks(tour, nm.spec, nm.occupied, nm.semi_static, nm.objects, None, truth=truth)
    row["naive"]["ate_rmse_m"] = 0.0  # true poses
    return row


# ---------------------------------------------------------------------------------------
# Reporting


def _nan(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def fmt(v: Any, kind: str) -> str:
    if _nan(v):
        return "n/a"
    if kind == "pct":
        return f"{100 * v:.1f} %"
    if kind == "spct":
        return f"{100 * v:+.0f} %"
    if kind == "int":
        return f"{int(v)}"
    if kind == "m":
        return f"{v:.3f} m"
    return f"{v:.3f}"


def world_table(row: dict[str, Any]) -> list[str]:
    if "error" in row:
        return [f"### {row['world']}", "", f"failed: {row['error']}", ""]
    s, n = row["semmap"], row["naive"]
    lines = [f"### {row['world']}", "", "| score | semmap | naive (true poses, no semantics) |", "|---|---:|---:|"]
    for key, label, kind, _ in ROWS:
        lines.append(f"| {label} | {fmt(s[key], kind)} | {fmt(n[key], kind)} |")
    lines.append(f"| objects found / truth | {s['objects_found']} / {s['objects_truth']} | "
                 f"{n['objects_found']} / {n['objects_truth']} |")
    lines.append(f"| objects matched / split / spurious | {s['objects_matched']} / {s['objects_split']} / "
                 f"{s['objects_spurious']} | {n['objects_matched']} / {n['objects_split']} / {n['objects_spurious']} |")
    lines.append(f"| ATE RMSE | {fmt(s['ate_rmse_m'], 'm')} | 0 (true poses) |")
    lines.append(f"| time (build, naive map) | {row['build_s']:.0f} s | {row['naive_s']:.1f} s |")
    return lines + [""]


def _worst(values: list[float], lower_better: bool, key: str) -> float:
    vals = [v for v in values if not _nan(v)]
    if not vals:
        return float("nan")
    if key == "objects_count_error":
        return max(vals, key=abs)
    return max(vals) if lower_better else min(vals)


def summary_table(rows: list[dict[str, Any]]) -> list[str]:
    ok = [r for r in rows if "error" not in r]
    lines = [f"### Over {len(ok)} random worlds" + (f" ({len(rows) - len(ok)} failed)" if len(ok) < len(rows) else ""),
             "", "| score | semmap median | semmap worst | naive median | naive worst |", "|---|---:|---:|---:|---:|"]
    for key, label, kind, lower in ROWS:
        cells = []
        for who in ("semmap", "naive"):
            vals = [r[who][key] for r in ok]
            finite = [v for v in vals if not _nan(v)]
            cells += [fmt(statistics.median(finite) if finite else float("nan"), kind), fmt(_worst(vals, lower, key),
                                                                                          kind)]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + [""]


def targets_table(random_rows: list[dict[str, Any]], named_rows: list[dict[str, Any]]) -> tuple[list[str], bool]:
    cols: list[tuple[str, list[dict[str, Any]]]] = []
    if random_rows:
        cols.append((f"random worlds (all {len(random_rows)})", random_rows))
    cols += [(r["world"], [r]) for r in named_rows]
    lines = ["| target | " + " | ".join(c for c, _ in cols) + " |", "|---|" + "---:|" * len(cols)]
    all_pass = True
    for t in TARGETS:
        cells = []
        for _, rows in cols:
            verdicts = [None if "error" in r else _target_checks(r["semmap"], r["naive"])[t] for r in rows]
            failed = sum(v is False for v in verdicts) + sum("error" in r for r in rows)
            measured = sum(v is not None for v in verdicts)
            if failed:
                all_pass = False
                cells.append(f"FAIL ({failed} of {len(rows)})" if len(rows) > 1 else "FAIL")
            elif measured == 0:
                cells.append("n/a")
            else:
                cells.append("pass" + (f" ({measured} measured)" if measured < len(rows) else ""))
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    return lines + [""], all_pass


# ---------------------------------------------------------------------------------------


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", type=int, default=len(SCORING_SEEDS),
                    help="how many random worlds (the first N scoring seeds, or of the --dev seeds)")
    ap.add_argument("--dev", action="store_true", help="development worlds: seeds 0..N-1, not the scoring seeds")
    ap.add_argument("--seeds", type=int, nargs="+", help="explicit world seeds (development)")
    ap.add_argument("--scenarios", nargs="*", default=NAMED_SCENARIOS, help="named scenarios besides the worlds")
    ap.add_argument("--tours", type=Path, default=Path(tempfile.gettempdir()) / "semmap-semantic-tours",
                    help="where simulated tours are cached (per simulator version)")
    ap.add_argument("--fresh", action="store_true", help="simulate again even when a cached tour exists")
    ap.add_argument("--maps", type=Path, help="keep the map folders here (default: a temporary folder)")
    ap.add_argument("--json", type=Path, help="also write every score here")
    add_set_argument(ap)
    args = ap.parse_args()

    if args.seeds is not None:
        seeds, kind = list(args.seeds), "explicit seeds"
    elif args.dev:
        seeds, kind = list(range(args.worlds)), "development seeds"
    else:
        if args.worlds > len(SCORING_SEEDS):
            ap.error(f"--worlds: there are {len(SCORING_SEEDS)} scoring seeds")
        seeds, kind = list(SCORING_SEEDS[:args.worlds]), "scoring seeds"
    if args.seeds is not None and set(seeds) & set(SCORING_SEEDS) and not args.dev:
        print(f"note: seeds {sorted(set(seeds) & set(SCORING_SEEDS))} are scoring seeds", file=sys.stderr)
    if seeds and not have_generator():
        print("warning: semmap.sim.procedural is not in this tree: the random worlds are skipped", file=sys.stderr)
        seeds = []
    jobs = [(f"random:{s}", True) for s in seeds] + [(sc, False) for sc in args.scenarios]
    if not jobs:
        ap.error("nothing to run (no worlds and no scenarios)")

    t_start = time.perf_counter()
    cache = args.tours / f"sim-{simulator_key()}"
    cache.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="semmap-semantic-maps-") as tmp:
        maps = args.maps if args.maps is not None else Path(tmp)
        maps.mkdir(parents=True, exist_ok=True)
        # the tours are simulated one after another in a helper process, ahead of the builds: the
        # next world simulates while the current one builds and is scored (2 cores, each kept busy)
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
            sims: list[Future] = [pool.submit(simulate_tour, name, str(cache / name.replace(":", "_")), args.fresh)
                                  for name, _ in jobs]
            for (name, is_random), fut in zip(jobs, sims):
                t = time.perf_counter()
                try:
                    tour, sim_s = fut.result()
                    row = run_world(name, Path(tour), maps, args.set)
                    row["simulate_s"] = sim_s
                except Exception as exc:
                    last = (str(exc).strip().splitlines() or [""])[-1]
                    row = {"world": name, "error": f"{type(exc).__name__}: {last}"}
                    print(traceback.format_exc(), file=sys.stderr)
                row["random"] = is_random
                rows.append(row)
                if "error" in row:
                    print(f"  {name:<12} FAILED ({row['error']})", file=sys.stderr)
                else:
                    s, n = row["semmap"], row["naive"]
                    print(f"  {name:<12} standing {fmt(s['standing_left'], 'pct')} (naive "
                          f"{fmt(n['standing_left'], 'pct')})  ghost {fmt(s['ghost_rate'], 'pct')}  F1 "
                          f"{fmt(s['f1'], 'f3')} (naive {fmt(n['f1'], 'f3')})  semi P {fmt(s['semi_precision'], 'f3')}"
                          f" R {fmt(s['semi_recall'], 'f3')}  objects {s['objects_found']}/{s['objects_truth']}  "
                          f"{time.perf_counter() - t:.0f} s", file=sys.stderr)
    wall_s = time.perf_counter() - t_start

    random_rows = [r for r in rows if r["random"]]
    named_rows = [r for r in rows if not r["random"]]
    print(f"semmap semantic benchmark, {date.today().isoformat()}")
    print(f"machine: {machine()}")
    worlds = f"random:{seeds[0]}..{seeds[-1]} ({kind})" if seeds else "none"
    print(f"worlds: {worlds}; scenarios: {', '.join(args.scenarios) or 'none'}; sensor-noise seed 0; "
          f"wall time {wall_s / 60:.1f} min\n")
    for r in rows:
        print("\n".join(world_table(r)))
    if random_rows:
        print("\n".join(summary_table(random_rows)))
    print("### Targets (semmap; random worlds: every world must pass)\n")
    lines, all_pass = targets_table(random_rows, named_rows)
    print("\n".join(lines))
    print("all targets met" if all_pass else "some targets not met")
    if args.json:
        args.json.write_text(json.dumps({"date": date.today().isoformat(), "machine": machine(), "seeds": seeds,
                                         "seed_kind": kind, "scenarios": args.scenarios, "wall_s": wall_s,
                                         "worlds": rows}, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
