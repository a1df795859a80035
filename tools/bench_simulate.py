#!/usr/bin/env python3
"""Benchmark `semmap simulate`: wall time, real-time factor, bag size and peak memory per scenario.

Each scenario runs in its own process (so peak RSS is its own), writing into a
temporary folder that is deleted afterwards. Prints a Markdown table for
docs/benchmarks.md and, with --json, the raw figures.

    python tools/bench_simulate.py                       # ward (the 60 s target) and demo
    python tools/bench_simulate.py --scenarios ward office occlusion --format mcap
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from semmap.sim.tour import simulate
from semmap.io.bag import bag_info
t = time.perf_counter()
r = simulate(sys.argv[1], sys.argv[2], fmt=sys.argv[3], seed=0)
wall = time.perf_counter() - t
info = bag_info(r.bag)
print(json.dumps({"wall_s": wall, "tour_s": r.duration_s, "bag_mb": info.size_bytes / 1e6,
                  "messages": info.message_count,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""



sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import machine


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["ward", "demo"])
    ap.add_argument("--format", default="ros1", choices=["ros1", "mcap", "sqlite3"])
    ap.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="semmap-bench-") as tmp:
        for name in args.scenarios:
            out = Path(tmp) / name
            t = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", CHILD, name, str(out), args.format],
                                 capture_output=True, text=True, check=False)
            if res.returncode != 0:
                print(res.stderr, file=sys.stderr)
                return 1
            fig = json.loads(res.stdout.strip().splitlines()[-1])
            fig["process_s"] = time.perf_counter() - t
            fig["scenario"] = name
            rows.append(fig)
    print(f"semmap simulate benchmark, {date.today().isoformat()}, format {args.format}")
    print(f"machine: {machine()}\n")
    print("| scenario | tour length (s) | generation (s) | real-time factor | bag (MB) | messages | peak RSS (MB) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['scenario']} | {r['tour_s']:.1f} | {r['wall_s']:.1f} | {r['tour_s'] / r['wall_s']:.1f}x | "
              f"{r['bag_mb']:.0f} | {r['messages']} | {r['peak_rss_mb']:.0f} |")
    if args.json:
        args.json.write_text(json.dumps({"date": date.today().isoformat(), "machine": machine(),
                                         "format": args.format, "results": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
