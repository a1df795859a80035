#!/usr/bin/env python3
"""Instructions executed by `semmap build`, per process, under valgrind's callgrind: a speed
comparison that the host's noise cannot blur.

Wall-clock A/B runs on a shared 2-core VM swing by ±30 % pair to pair, which hides a 5 % change.
Instruction counts are deterministic: this script builds one tour with this tree (and, with
``--baseline``, with another source tree), under ``valgrind --tool=callgrind --trace-children=yes``,
and prints the instructions of each process (the main process and each worker), split into
importing modules (before the build's clock starts) and the rest.

    python tools/bench_instructions.py TOUR                       # this tree
    python tools/bench_instructions.py TOUR --baseline /tmp/base  # and another tree, side by side

A build under callgrind runs about 50 times slower: use a short tour (``semmap simulate
--scenario demo``, 418 scans, takes about 4 minutes). Needs valgrind (``apt install valgrind``).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _inclusive(path: Path, pattern: str) -> int:
    """The largest inclusive cost of a function matching ``pattern`` (its outermost call)."""
    out = subprocess.run(["callgrind_annotate", "--inclusive=yes", str(path)], capture_output=True, text=True,
                         check=True).stdout
    best = 0
    for line in out.splitlines():
        if re.search(pattern, line):
            m = re.match(r"\s*([\d,]+)", line)
            if m:
                best = max(best, int(m.group(1).replace(",", "")))
    return best


def measure(tree: Path, tour: Path) -> dict[str, dict[str, int]]:
    """Instructions per process of one build with the semmap in ``tree``."""
    with tempfile.TemporaryDirectory() as d:
        out = Path(d)
        cmd = ["valgrind", "--tool=callgrind", "--trace-children=yes", f"--callgrind-out-file={out}/cg.%p",
               sys.executable, "-m", "semmap", "build", str(tour), "--out", str(out / "map"), "-q"]
        res = subprocess.run(cmd, cwd=tree, env=dict(os.environ, PYTHONPATH=str(tree)), capture_output=True,
                             text=True, check=False)
        if res.returncode != 0:
            raise SystemExit(f"build with {tree} failed under callgrind:\n{res.stderr[-2000:]}")
        procs: dict[str, dict[str, int]] = {}
        for f in sorted(out.glob("cg.*")):
            text = f.read_text(errors="replace")
            total = re.search(r"^(?:summary|totals): (\d+)", text, re.M)
            cmd_line = re.search(r"^cmd: (.*)$", text, re.M)
            if total is None or cmd_line is None:
                continue  # the resource tracker's fork without a profile
            c = cmd_line.group(1)
            if "resource_tracker" in c:
                name = "resource tracker"
            elif "spawn_main" in c:
                name = f"worker {sum(1 for k in procs if k.startswith('worker')) + 1}"
            else:
                name = "main"
            imports = _inclusive(f, r"import\.c:PyImport_ImportModuleLevelObject \[")
            procs[name] = {"total": int(total.group(1)), "imports": imports}
        return procs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tour", type=Path, help="a tour folder or bag (short: a build runs ~50x slower)")
    ap.add_argument("--baseline", type=Path, help="another semmap source tree to compare with")
    args = ap.parse_args()
    if shutil.which("valgrind") is None:
        ap.error("valgrind is not installed (apt install valgrind)")
    trees = {"this tree": REPO}
    if args.baseline is not None:
        trees["baseline"] = args.baseline.resolve()
    results = {k: measure(t, args.tour.resolve()) for k, t in trees.items()}
    names = sorted({n for r in results.values() for n in r}, key=lambda n: (n != "main", n))
    print(f"Instructions (millions) of `semmap build {args.tour}`, per process; imports happen before the clock\n")
    head = "| process | " + " | ".join(f"{k}: total | {k}: without imports" for k in trees)
    if args.baseline is not None:
        head += " | ratio without imports"
    print(head + " |")
    print("|---" * (1 + 2 * len(trees) + (args.baseline is not None)) + "|")
    sums = dict.fromkeys(trees, 0)
    for n in names:
        row = [n]
        work = {}
        for k in trees:
            p = results[k].get(n, {"total": 0, "imports": 0})
            work[k] = p["total"] - p["imports"]
            sums[k] += work[k]
            row += [f"{p['total'] / 1e6:,.0f}", f"{work[k] / 1e6:,.0f}"]
        if args.baseline is not None:
            row.append(f"{work['this tree'] / work['baseline']:.3f}" if work["baseline"] else "-")
        print("| " + " | ".join(row) + " |")
    if args.baseline is not None and sums["baseline"]:
        print(f"\nAll processes, without imports: {sums['this tree'] / 1e6:,.0f} M against "
              f"{sums['baseline'] / 1e6:,.0f} M (ratio {sums['this tree'] / sums['baseline']:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
