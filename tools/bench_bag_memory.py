#!/usr/bin/env python3
"""Benchmark what reading a bag costs: memory held by open readers, open time, streaming throughput.

For each bag (a ``.bag`` file, a ROS2 bag folder or a tour folder), in a fresh process each:

* **open**: the time of the first ``open_bag`` in the process and of the next ones (a build opens
  its bag about 8 times: ``open_tour`` 6, the scan stream, the label images);
* **readers**: anonymous RSS (``RssAnon`` in /proc) held by one and by two readers open at once,
  as a build holds them (scans and odometry; label images), over the process before opening;
* **stream**: the time to stream the scans, and the scans and odometry, through ``iter_messages``
  (deserialised, as a build reads them), best of ``--repeats``; and the anonymous RSS and the
  tracemalloc peak while the scans stream (a separate pass).

Runs against whichever ``semmap`` is importable (set PYTHONPATH to compare two trees). Prints a Markdown
table and writes JSON with ``--json``.

    python tools/bench_bag_memory.py /tmp/semmap-long-tours/ward-5min /tmp/semmap-long-tours/ward-30min
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import gc, json, sys, time, tracemalloc
from contextlib import ExitStack
from pathlib import Path
import semmap.io.bag as B

def anon_kb():
    for line in open("/proc/self/status"):
        if line.startswith("RssAnon:"):
            return int(line.split()[1])
    return 0

bag, scan, odom, repeats = B.resolve_bag_path(sys.argv[1]), sys.argv[2], sys.argv[3], int(sys.argv[4])
out = {"bag": str(bag), "semmap": B.__file__}
import rosbags.highlevel, rosbags.rosbag1, rosbags.rosbag2  # noqa: E401 - imported before the baseline
gc.collect()
t = time.perf_counter()
with B.open_bag(bag) as r:
    out["messages"] = sum(max(c.msgcount, 0) for c in r.connections)
    out["scans"] = B.message_count(bag, scan, r)
out["open_first_s"] = time.perf_counter() - t
times = []
for _ in range(5):
    t = time.perf_counter()
    with B.open_bag(bag):
        pass
    times.append(time.perf_counter() - t)
out["open_next_s"] = sorted(times)[len(times) // 2]
gc.collect()
base = anon_kb()
with ExitStack() as stack:
    stack.enter_context(B.open_bag(bag))
    gc.collect()
    out["one_reader_mb"] = (anon_kb() - base) / 1024
    stack.enter_context(B.open_bag(bag))
    gc.collect()
    out["two_readers_mb"] = (anon_kb() - base) / 1024
for name, topics in (("scans", [scan]), ("scans_odom", [scan, odom])):
    best = None
    for _ in range(repeats):
        t = time.perf_counter()
        with B.open_bag(bag) as r:
            n = sum(1 for _ in B.iter_messages(bag, topics, reader=r))
        dt = time.perf_counter() - t
        best = dt if best is None else min(best, dt)
    out[f"stream_{name}_s"], out[f"stream_{name}_n"] = best, n
gc.collect()
base = anon_kb()
high = 0
tracemalloc.start()
with B.open_bag(bag) as r:
    for i, _ in enumerate(B.iter_messages(bag, [scan], reader=r)):
        if i % 500 == 0:
            high = max(high, anon_kb() - base)
    out["stream_tracemalloc_peak_mb"] = tracemalloc.get_traced_memory()[1] / 2**20
tracemalloc.stop()
out["stream_anon_high_mb"] = high / 1024
print(json.dumps(out))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bags", nargs="+", type=Path)
    ap.add_argument("--scan", default="/scan")
    ap.add_argument("--odom", default="/odom")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    rows = []
    for bag in args.bags:
        res = subprocess.run([sys.executable, "-c", CHILD, str(bag), args.scan, args.odom, str(args.repeats)],
                             capture_output=True, text=True, check=False)
        if res.returncode != 0:
            print(res.stderr[-3000:], file=sys.stderr)
            return 1
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
        print(f"  {bag}: done", file=sys.stderr, flush=True)
    print(f"semmap: {rows[0]['semmap']}\n")
    print("| bag | messages | scans | open, first (s) | open, next (s) | one reader (MB) | two readers (MB) | "
          "scans streamed (s) | scans/s | scans + odometry (s) | msgs/s | anon RSS while streaming (MB) | "
          "tracemalloc peak (MB) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {Path(r['bag']).name} | {r['messages']} | {r['scans']} | {r['open_first_s']:.3f} | "
              f"{r['open_next_s']:.3f} | {r['one_reader_mb']:.1f} | {r['two_readers_mb']:.1f} | "
              f"{r['stream_scans_s']:.2f} | {r['stream_scans_n'] / r['stream_scans_s']:.0f} | "
              f"{r['stream_scans_odom_s']:.2f} | {r['stream_scans_odom_n'] / r['stream_scans_odom_s']:.0f} | "
              f"{r['stream_anon_high_mb']:.1f} | {r['stream_tracemalloc_peak_mb']:.2f} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
