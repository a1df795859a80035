"""Throughput of ``semmap batch``: a manifest of 8 simulated tours, built in one process and on a local
Ray with 1 and 2 workers (issue 24).

Usage::

    python tools/bench_batch.py                       # 8 demo tours (seeds 0-7), local / ray 1 / ray 2
    python tools/bench_batch.py --scenario office --tours 4 --json out.json

Each run starts from an empty output folder (nothing is up to date), so every tour is built. The
tours are simulated once into ``--work`` and reused. Figures: wall time of the batch, tours per hour,
scans per second over the whole batch, and the speed-up over one Ray worker. A build is itself 2-3
processes (decode and paint, register, fuse), so on a machine with few cores more workers buy little:
the batch is meant for many cores or a cluster (``--address``), where each worker has its own.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import machine


def _simulate(work: Path, scenario: str, n: int) -> list[Path]:
    from semmap.sim.tour import simulate

    tours = []
    for seed in range(n):
        out = work / "tours" / f"{scenario}-{seed}"
        if not (out / "tour.yaml").is_file():
            shutil.rmtree(out, ignore_errors=True)
            simulate(scenario, out, seed=seed)
        tours.append(out)
    return tours


def _run(manifest: Path, out: Path, engine: str, workers: int | None) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "semmap", "batch", str(manifest), "--out", str(out), "--engine", engine, "-q"]
    if workers:
        cmd += ["--workers", str(workers)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.strip()}")
    report = json.loads((out / "report.json").read_text())
    rows = report["tours"]
    scans = sum(r["build"]["scores"]["scans"] for r in rows)
    tour_s = sum(r["build"]["scores"]["duration_s"] for r in rows)
    builds = [r["build"]["seconds"] for r in rows]
    return {"engine": engine, "workers": workers, "wall_s": round(wall, 2), "tours": len(rows),
            "tours_per_h": round(3600 * len(rows) / wall, 1), "scans_per_s": round(scans / wall, 1),
            "real_time_factor": round(tour_s / wall, 1), "build_s_mean": round(sum(builds) / len(builds), 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="demo")
    ap.add_argument("--tours", type=int, default=8)
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "semmap-bench-batch")
    ap.add_argument("--runs", nargs="+", default=["local", "ray:1", "ray:2"],
                    help="local, or ray:N for a local Ray with N workers")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    t0 = time.perf_counter()
    tours = _simulate(args.work, args.scenario, args.tours)
    sim_s = time.perf_counter() - t0
    manifest = args.work / "manifest.yaml"
    lines = ["sites:"]
    for i, tour in enumerate(tours):
        lines += [f"  - name: site{i}", f"    tours: [{tour}]"]
    manifest.write_text("\n".join(lines) + "\n")
    results = []
    for run in args.runs:
        engine, _, n = run.partition(":")
        r = _run(manifest, args.work / f"out-{run.replace(':', '-')}", engine, int(n) if n else None)
        results.append(r)
        print(f"  {run:8s} {r['wall_s']:7.1f} s  {r['tours_per_h']:7.1f} tours/h  {r['scans_per_s']:7.1f} scans/s"
              f"  build {r['build_s_mean']:.1f} s each", flush=True)
    base = next((r for r in results if r["engine"] == "ray" and r["workers"] == 1), results[0])
    for r in results:
        r["speedup_vs_ray_1"] = round(base["wall_s"] / r["wall_s"], 2)
    date = time.strftime("%Y-%m-%d")
    print(f"\n{args.tours} `{args.scenario}` tours ({tours[0].name} ...; simulated in {sim_s:.0f} s), {date}, "
          f"{machine()}:\n")
    print("| run | wall | tours per hour | scans/s | × tour length | mean build | speed-up vs Ray, 1 worker |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in results:
        name = "one process" if r["engine"] == "local" else f"Ray, {r['workers']} worker{'s' * (r['workers'] > 1)}"
        print(f"| {name} | {r['wall_s']:.1f} s | {r['tours_per_h']:.0f} | {r['scans_per_s']:.0f} "
              f"| {r['real_time_factor']:.1f} | {r['build_s_mean']:.1f} s | {r['speedup_vs_ray_1']:.2f} |")
    if args.json:
        args.json.write_text(json.dumps({"date": date, "machine": machine(), "scenario": args.scenario,
                                         "runs": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
