"""Memory of a large building (issue 24): an L-shaped floor 150 m x 150 m at 5 cm, built with the defaults.

Usage::

    python tools/bench_large.py                      # simulate (cached) and build; print the figures
    python tools/bench_large.py --json out.json --picture docs/images/large_floor.png

The world is made here: two wings 150 m long and 30 m wide at right angles (an L, so its bounding
box is 150 m x 150 m, 9 million cells at 5 cm, of which about 3.2 million are floor), each wing
three 10 m halls side by side with doorways between them, furniture along the walls (chairs, tables,
beds, couches, cabinets), a few people standing. The robot drives every hall once, about 850 m at
up to 1.5 m/s; a 10 Hz LiDAR, a 2 Hz 320 x 240 camera (JPEG, mono8 labels) keep the bag small.

Figures: each process's peak RSS and the peak of their sum at the same moment (sampled from /proc,
as ``tools/bench_long_tour.py`` does), the grid's bytes (its layers at the end: the window's cells
times the bytes per cell), and bytes per observed cell (cells with any hit or free evidence).
Targets (issue 24): at most 1 GB in all, at most 40 bytes per observed cell in the grid.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_long_tour import build_tour
from benchlib import machine

WING_LEN = 150.0
WING_W = 30.0
HALL = 10.0


def make_world(seed: int = 0):
    """The L-shaped floor (see the module's documentation)."""
    from semmap.sim import world as W

    rng = np.random.default_rng(seed)
    objs = []
    oid = iter(range(1, 100000))

    def wall(x0, y0, x1, y1):
        objs.append(W.wall(next(oid), x0, y0, x1, y1))

    L, B = WING_LEN, WING_W
    # the outline of the L
    for a, b in zip([(0, 0), (L, 0), (L, B), (B, B), (B, L), (0, L)], [(L, 0), (L, B), (B, B), (B, L), (0, L), (0, 0)]):
        wall(*a, *b)

    def hall_wall(fixed, lo, hi, gaps, along_x):
        """A wall from lo to hi at x or y = fixed, with 2.4 m doorways centred at gaps."""
        cuts = sorted(gaps)
        start = lo
        for g in cuts:
            if g - 1.2 > start:
                wall(*( (start, fixed, g - 1.2, fixed) if along_x else (fixed, start, fixed, g - 1.2)))
            start = g + 1.2
        if hi > start:
            wall(*((start, fixed, hi, fixed) if along_x else (fixed, start, fixed, hi)))

    doors = [45.0, 75.0, 105.0, 135.0]
    hall_wall(HALL, B, L, [145.0] + doors[:-1], along_x=True)          # wing A: walls along x at y = 10, 20
    hall_wall(2 * HALL, B, L, [35.0] + doors[1:], along_x=True)
    hall_wall(2 * HALL, B, L, [145.0] + doors[:-1], along_x=False)     # wing B: walls along y at x = 20, 10
    hall_wall(HALL, B, L, [35.0] + doors[1:], along_x=False)
    # pillars in the lobby
    for x, y in ((10, 10), (20, 10), (10, 20), (20, 20)):
        objs.append(W.pillar(next(oid), x, y))

    makers = [W.chair, W.table, W.bed, W.couch, W.cabinet]

    def furnish(x0, x1, y_wall, inward, along_x):
        """Furniture against a wall every 6-9 m, clear of the doorways."""
        x = x0 + rng.uniform(2, 5)
        while x < x1 - 3:
            if all(abs(x - d) > 3 for d in [35.0, 145.0, *doors]):
                make = makers[int(rng.integers(len(makers)))]
                depth = 0.5 if make is W.chair else 1.0
                off = y_wall + inward * (0.15 + depth / 2 + 0.1)
                yaw = 0.0 if along_x else math.pi / 2
                pose = (x, off, yaw) if along_x else (off, x, yaw)
                objs.append(make(next(oid), pose))
            x += rng.uniform(6, 9)

    for k in range(3):  # three halls per wing, furniture on both long walls
        lo, hi = k * HALL, (k + 1) * HALL
        furnish(B, L, lo, +1, along_x=True)
        furnish(B, L, hi, -1, along_x=True)
        furnish(B, L, lo, +1, along_x=False)
        furnish(B, L, hi, -1, along_x=False)
    people = []
    for i, (x, y) in enumerate([(60.0, 8.5), (120.0, 12.0), (8.5, 90.0), (12.0, 60.0)]):
        people.append(W.Person(id=next(oid), name=f"standing{i}", waypoints=np.array([[x, y]]), loop=False))
    h = HALL / 2
    route = np.array([
        (25.0, h), (145.0, h), (145.0, 3 * h), (35.0, 3 * h), (35.0, 5 * h), (145.0, 5 * h), (25.0, 5 * h),
        (5 * h, 35.0), (5 * h, 145.0), (3 * h, 145.0), (3 * h, 35.0), (h, 35.0), (h, 145.0)])
    return W.World(name="large_floor", objects=tuple(objs), people=tuple(people), route=route, start_yaw=0.0,
                   description="an L-shaped floor, two 150 m x 30 m wings (tools/bench_large.py)")


SIM_CONFIG = {
    "robot": {"max_speed": 1.5},
    "lidar": {"rate_hz": 10.0},
    "camera": {"rate_hz": 2.0, "width": 320, "height": 240,
               "K": [[300.9, 0.0, 164.1], [0.0, 300.1, 120.2], [0.0, 0.0, 1.0]],
               "image_format": "jpeg", "label_encoding": "mono8"},
}


def simulate(work: Path) -> Path:
    from semmap.sim.tour import simulate as sim

    tour = work / "large_floor"
    if not (tour / "tour.yaml").is_file():
        t0 = time.perf_counter()
        sim(make_world(), tour, seed=0, config=SIM_CONFIG, force=True)
        print(f"simulated in {time.perf_counter() - t0:.0f} s", flush=True)
    return tour


def grid_figures(map_dir: Path) -> dict:
    with np.load(map_dir / "grid.npz") as z:
        hits, free = z["hits"], z["free"]
        n_cls = z["class_counts"].shape[0]
        h, w = hits.shape
        observed = int(np.count_nonzero((hits > 0) | (free > 0)))
    per_cell = 2 + 2 + 2 + 2 * 4 + 2 * n_cls  # log-odds, hits, free, 4 mobility counts, a count per class seen
    grid_bytes = h * w * per_cell
    return {"window_cells": h * w, "window_m": [round(w * 0.05, 1), round(h * 0.05, 1)], "class_layers": n_cls,
            "observed_cells": observed, "grid_bytes": grid_bytes,
            "bytes_per_observed_cell": round(grid_bytes / max(observed, 1), 1)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "semmap-bench-large")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--picture", type=Path, help="the map's semantic.png, copied here")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    tour = simulate(args.work)
    out = args.work / "map"
    if (out / "summary.json").is_file():  # an earlier run's map: built again
        import shutil

        shutil.rmtree(out)
    _, summary, sampler, _ = build_tour(tour, out, 0.1)
    procs = {rec["cmd"].split()[0] if rec.get("cmd") else str(pid): round(rec["hwm_kb"] / 1024, 1)
             for pid, rec in sampler.procs.items()}
    g = grid_figures(out)
    m = summary["map"]  # the tiles the fusing grid held (what a dense window would hold: grid_figures)
    g |= {"tiles": m["grid_tiles"], "tile_bytes": m["grid_bytes"], "observed_cells": m["observed_cells"],
          "bytes_per_observed_cell": m["grid_bytes_per_observed_cell"],
          "window_bytes_per_observed_cell": round(g["grid_bytes"] / max(m["observed_cells"], 1), 1)}
    fig = {"date": time.strftime("%Y-%m-%d"), "machine": machine(), "scans": summary["counts"]["scans"],
           "tour_s": summary["tour"]["duration_s"], "build_s": summary["timings_s"]["total"],
           "peak_rss_mb": summary["peak_rss_mb"], "peak_rss_mb_workers": summary["peak_rss_mb_workers"],
           "peak_rss_mb_all_at_once": round(sampler.total_peak_kb / 1024, 1), "processes": procs, **g}
    print(json.dumps(fig, indent=1))
    ok_total = fig["peak_rss_mb_all_at_once"] <= 1024
    ok_cell = g["bytes_per_observed_cell"] <= 40
    print(f"\n| measure | figure | target |\n|---|---|---|\n"
          f"| peak RSS of all processes at once | {fig['peak_rss_mb_all_at_once']:.0f} MB | ≤ 1024 MB "
          f"({'met' if ok_total else 'missed'}) |\n"
          f"| peak RSS per process | main {fig['peak_rss_mb']:.0f} MB, "
          + ", ".join(f"{k} {v:.0f} MB" for k, v in fig["peak_rss_mb_workers"].items()) + " | |\n"
          f"| grid while fusing: {g['tiles']} tiles of 10 m; the map's window {g['window_m'][0]} m × "
          f"{g['window_m'][1]} m, {g['class_layers']} class layers | {g['tile_bytes'] / 2**20:.0f} MB (a window: "
          f"{g['grid_bytes'] / 2**20:.0f} MB) | |\n"
          f"| grid bytes per observed cell ({g['observed_cells']} cells) | {g['bytes_per_observed_cell']} (a window: "
          f"{g['window_bytes_per_observed_cell']}) | ≤ 40 ({'met' if ok_cell else 'missed'}) |")
    if args.picture:
        args.picture.write_bytes((out / "semantic.png").read_bytes())
    if args.json:
        args.json.write_text(json.dumps(fig, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
