#!/usr/bin/env python3
"""Before and after: what a naive LiDAR map keeps where people stood and furniture stands, and what
semmap's cleaned map keeps.

For a simulated tour and the map ``semmap build`` made of it, the figure shows close-ups around
the person who stood longest and around a bed or couch against a wall (the two cases the
cleaning used to get wrong), each twice: the naive map (the recorded scans placed with the true
poses, log-odds, no semantics: :func:`semmap.sim.score.naive_map`) and semmap's map, both in the
ground-truth frame. Colours: black occupied, blue flagged semi-static, red dropped as a person,
magenta where a person stood (truth), light green the furniture (truth).

    python tools/figure_cleaning.py TOUR MAP_DIR --out docs/images/cleaning_before_after.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _crop_centres(tour: Path, truth) -> list[tuple[str, np.ndarray]]:  # type: ignore[no-untyped-def]
    """(title, world xy) of the longest-standing person and of a bed or couch against a wall."""
    from semmap.sim.world import load_world

    gt = tour / "ground_truth"
    world = load_world(gt / "world.yaml")
    info = json.loads((gt / "objects.json").read_text(encoding="utf-8")) if (gt / "objects.json").is_file() else {}
    out: list[tuple[str, np.ndarray]] = []
    people = sorted(info.get("people", []), key=lambda p: -float(p.get("standing_s", 0.0)))
    by_id = {p.id: p for p in world.people}
    for rec in people:
        p = by_id.get(int(rec["id"]))
        if p is not None and rec.get("lidar_hits", 0) > 0 and rec.get("standing_s", 0) >= 5:
            role = rec.get("role") or "standing"
            seen = "seen by the camera" if rec.get("camera_images", 0) else "never seen by the camera"
            out.append((f"{p.name} ({role}, {seen})", np.asarray(p.state(1e9 if p.waypoints.shape[0] == 1
                                                                          else 0.0)[:2])))
            break
    walls = [o for o in world.objects if o.cls == "wall"]
    objs = {int(o["id"]): o for o in info.get("objects", [])}
    best = None
    for o in world.objects:
        if o.cls not in ("bed", "couch") or objs.get(o.id, {}).get("painted_hits", 1) <= 0:
            continue
        pts = np.concatenate([p.polygon for p in o.parts])
        gap = min(float(np.min(np.abs(_box_distances(pts, w)))) for w in walls) if walls else np.inf
        key = (gap > 0.05, -objs.get(o.id, {}).get("painted_hits", 0))
        if best is None or key < best[0]:
            best = (key, o)
    if best is not None:
        o = best[1]
        out.append((f"{o.name} against a wall", o.centroid()))
    return out


def _box_distances(pts: np.ndarray, wall) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Distance (m) of points to the bounding box of a wall's parts (0 inside)."""
    poly = np.concatenate([p.polygon for p in wall.parts])
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    d = np.maximum(np.maximum(lo - pts, pts - hi), 0.0)
    return np.hypot(d[:, 0], d[:, 1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("tour", type=Path, help="a simulated tour folder (semmap simulate)")
    ap.add_argument("map", type=Path, help="the map folder semmap build wrote from it")
    ap.add_argument("--out", type=Path, required=True, help="PNG to write")
    ap.add_argument("--half", type=float, default=1.6, help="half the side of each close-up, m")
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from semmap import load_map
    from semmap.grid.metrics import transfer
    from semmap.register.metrics import ate_errors
    from semmap.sim.score import load_truth, naive_map

    truth = load_truth(args.tour)
    spec = truth.spec
    m = load_map(args.map)
    _, t_gt_map = ate_errors(m.stamps_ns, m.poses, truth.stamps_ns, truth.poses)
    after = {"occupied": transfer(m.occupied, m.spec, spec, t_gt_map),
             "semi": transfer(m.semi_static & m.occupied, m.spec, spec, t_gt_map),
             "dropped": transfer(m.cleaned.dynamic_removed, m.spec, spec, t_gt_map)}
    naive = naive_map(args.tour)
    before = {"occupied": transfer(naive.occupied, naive.spec, spec), "semi": np.zeros(spec.shape, bool),
              "dropped": np.zeros(spec.shape, bool)}
    crops = _crop_centres(args.tour, truth)
    if not crops:
        print(f"{args.tour}: no standing person and no bed or couch to show", file=sys.stderr)
        return 1

    def render(layers: dict[str, np.ndarray]) -> np.ndarray:
        img = np.full((*spec.shape, 3), 255, np.uint8)
        img[truth.semi_static] = (205, 240, 205)
        if truth.standing is not None:
            img[truth.standing] = (245, 170, 245)
        img[layers["occupied"]] = (0, 0, 0)
        img[layers["semi"]] = (30, 110, 235)
        img[layers["dropped"]] = (225, 30, 30)
        return img

    imgs = {"naive map (true poses, no semantics)": render(before), "semmap": render(after)}
    fig, axes = plt.subplots(len(crops), 2, figsize=(7.5, 3.7 * len(crops)), squeeze=False)
    res = spec.resolution
    for row, (title, xy) in enumerate(crops):
        r, c = spec.world_to_cell(np.asarray(xy, float))
        h = int(args.half / res)
        r0, r1 = max(r - h, 0), min(r + h, spec.height)
        c0, c1 = max(c - h, 0), min(c + h, spec.width)
        for col, (name, img) in enumerate(imgs.items()):
            ax = axes[row, col]
            x0, y0 = spec.origin_x + c0 * res, spec.origin_y + r0 * res
            ax.imshow(img[r0:r1, c0:c1], origin="lower", interpolation="nearest",
                      extent=(x0, x0 + (c1 - c0) * res, y0, y0 + (r1 - r0) * res))
            ax.set_title(f"{name}\n{title}", fontsize=8)
            ax.tick_params(labelsize=7)
    fig.suptitle(f"{truth.tour.name if truth.tour else ''}: black occupied, blue semi-static, red dropped as a "
                 "person;\nmagenta where a person stood, green furniture (truth)", fontsize=8)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
