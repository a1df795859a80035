#!/usr/bin/env python3
"""semmap's registration modes on the real Hokuyo tours of ``../shared/data/hokuyo_odom_bags``, which have
no ground truth: the truth-free consistency score of every build (``summary.json``, :mod:`semmap.grid.consistency`)
per mode, and one picture per bag with the maps side by side.

Usage::

    python tools/bench_real_bags.py                          # all four bags, modes odometry, icp, fused
    python tools/bench_real_bags.py --modes fused fused+loops --picture docs/images/real_bags.png
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
sys.path.insert(0, str(REPO / "tools"))

from benchlib import add_set_argument, machine

BAGS = ["2018_may9_editted_before1", "2018_may9_editted_after1", "2019_jan17_expt08", "2019_jan17_expt09"]
#: mode name → config overrides
MODES = {
    "odometry": {"registration": {"mode": "odometry"}},
    "icp": {"registration": {"mode": "icp"}},
    "fused": {"registration": {"mode": "fused"}},
    "fused+fit": {"registration": {"mode": "fused", "ekf": {"fit_margin": 0.0}}},
    "fused+loops": {"registration": {"mode": "fused", "loop_closure": {"enabled": True}}},
}


def run(data: Path, work: Path, bags: list[str], modes: list[str], extra: dict | None = None) -> list[dict]:
    from semmap.config import merge_overrides
    from semmap.pipeline import build

    rows = []
    for bag in bags:
        for mode in modes:
            out = work / bag / mode.replace("+", "_")
            t0 = time.perf_counter()
            r = build(data / f"{bag}.bag", out, overrides=merge_overrides(MODES[mode], extra or {}), force=True)
            s = json.loads(r.summary.to_json())
            reg = s["registration"]
            loops = reg.get("loop_closure")
            rows.append({"bag": bag, "mode": mode, "seconds": round(time.perf_counter() - t0, 1),
                         **s["consistency"], "icp_rejected": reg.get("icp_rejected"),
                         "filter_resets": reg.get("filter_resets"), "icp_degenerate": reg.get("icp_degenerate"),
                         "loops": loops.get("accepted") if isinstance(loops, dict) else None,
                         "map": str(out / "map.pgm")})
            print(f"  {bag} {mode}: {100 * s['consistency']['endpoints_on_map']:.1f} % on the map, walls "
                  f"{100 * s['consistency']['wall_thickness_m']:.1f} cm", flush=True)
    return rows


def table(rows: list[dict], modes: list[str]) -> str:
    bags = sorted({r["bag"] for r in rows}, key=lambda b: BAGS.index(b) if b in BAGS else 99)
    head = "| bag | " + " | ".join(modes) + " |"
    lines = [head, "|---|" + "---|" * len(modes)]
    for b in bags:
        cells = []
        for m in modes:
            r = next((x for x in rows if x["bag"] == b and x["mode"] == m), None)
            cells.append("" if r is None else
                         f"{100 * r['endpoints_on_map']:.1f} % · {100 * r['wall_thickness_m']:.1f} cm")
        lines.append(f"| {b} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def picture(rows: list[dict], modes: list[str], path: Path) -> None:
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bags = [b for b in BAGS if any(r["bag"] == b for r in rows)]
    fig, axes = plt.subplots(len(bags), len(modes), figsize=(3.6 * len(modes), 3.2 * len(bags)), squeeze=False)
    for i, b in enumerate(bags):
        for j, m in enumerate(modes):
            ax = axes[i][j]
            ax.axis("off")
            r = next((x for x in rows if x["bag"] == b and x["mode"] == m), None)
            if r is None:
                continue
            ax.imshow(cv2.imread(r["map"], cv2.IMREAD_GRAYSCALE), cmap="gray", vmin=0, vmax=255)
            ax.set_title(f"{b.replace('_editted', '')}\n{m}: {100 * r['endpoints_on_map']:.1f} % on map, walls "
                         f"{100 * r['wall_thickness_m']:.1f} cm", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "hokuyo_odom_bags")
    ap.add_argument("--work", type=Path, default=Path("/tmp/semmap-bench-real-bags"))
    ap.add_argument("--bags", nargs="+", default=BAGS, choices=BAGS)
    ap.add_argument("--modes", nargs="+", default=["odometry", "icp", "fused"], choices=list(MODES))
    ap.add_argument("--picture", type=Path, help="write the maps side by side to this PNG")
    ap.add_argument("--json", type=Path)
    add_set_argument(ap)
    args = ap.parse_args()
    if not args.data.is_dir():
        print(f"no data at {args.data}", file=sys.stderr)
        return 2
    rows = run(args.data, args.work, args.bags, args.modes, args.set)
    print(f"\nConsistency (share of returns within a cell of an occupied cell · mean wall thickness), "
          f"{date.today()}, {machine()}:\n")
    print(table(rows, args.modes))
    if args.picture:
        picture(rows, args.modes, args.picture)
        print(f"\npicture: {args.picture}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
