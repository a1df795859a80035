#!/usr/bin/env python3
"""Benchmark the background-line occlusion filter against per-beam ground truth.

The LiDAR sits at a front corner of the robot, the camera at the front centre, so LiDAR
points behind a foreground object can project onto its mask (a wall behind a person gets
painted dynamic). For each simulated scenario (default: occlusion, ward) and each lateral
offset of the LiDAR from the camera (default: 0.0, 0.2, 0.4 m) this simulates the tour
(cached), paints every scan with and without the filter (:func:`semmap.paint.export.iter_painted`)
and scores every beam against ``ground_truth/beams.npz`` (matched by scan stamp and beam):

* **wrong**: painted dynamic or semi-static without the filter, but truly something else.
  Reported: the share of them the filter removed (made ``unknown``); target >= 90 %.
* **correct**: painted (not ``unknown``) without the filter, and equal to the truth.
  Reported: the share the filter kept unchanged; target >= 98 %.
* points relabelled per painted scan (mean, max); the wrong points by kind (true → painted);
  and, for the wrong points left and the correct points lost, whether another LiDAR point lies
  nearer on the same camera ray (a wrong point left without one sits behind something the
  LiDAR plane does not cut: a bed's side, a chair's seat, a table top).

Then it builds the map with the filter off and on (each build in its own process) and
scores it as ``tools/bench_build.py`` does: occupied F1, ghost rate (people left in the
cleaned map), semi-static precision and recall.

LiDAR mounts: x = 0.38 m and height 0.2 m as the default corner mount, y = the offset
(the camera is at y = 0). Offsets > 0 keep the default yaw (pi/4, the corner mount);
the centred LiDAR (offset 0) looks straight ahead (yaw 0). The yaw does not change where
points land, only which bearings the 270 deg sweep covers; both cover the camera's view.
At 0.4 m the LiDAR sits 0.1 m outside the 0.6 m wide footprint (the simulator does not
mind).

    python tools/bench_occlusion.py                                   # about 5 min on 2 cores
    python tools/bench_occlusion.py --scenarios occlusion --offsets 0.2 --no-map
    python tools/bench_occlusion.py --pictures /tmp/occ-pics --json occ.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import replace
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from bench_build import run_build, score_simulated
from benchlib import machine

LIDAR_X, LIDAR_Z, CORNER_YAW = 0.38, 0.2, math.pi / 4
CAMERA_XY = np.array([0.42, 0.0])  # the simulator's default camera mount (not changed here)
RAY_WIDTH_DEG, RAY_MARGIN = 1.0, 0.3  # "a nearer point on the camera ray", for the breakdown only

UNKNOWN, STATIC, SEMI, DYNAMIC = 0, 1, 2, 3
_NAMES = {UNKNOWN: "unknown", STATIC: "static", SEMI: "semi-static", DYNAMIC: "dynamic"}


def mount(offset: float) -> dict:
    yaw = 0.0 if abs(offset) < 1e-9 else CORNER_YAW
    return {"xyz": [LIDAR_X, float(offset), LIDAR_Z], "rpy": [0.0, 0.0, yaw]}


def tour_for(tours: Path, scenario: str, offset: float, duration: float | None, seed: int) -> Path:
    """The simulated tour for this scenario and LiDAR offset, simulated once and cached."""
    from semmap.sim.scenarios import Scenario, get_scenario
    from semmap.sim.tour import simulate

    name = f"{scenario}_y{offset:.2f}_seed{seed}" + (f"_{duration:g}s" if duration else "")
    out = tours / name
    if (out / "tour.yaml").is_file() and (out / "ground_truth" / "beams.npz").is_file():
        return out
    sc = get_scenario(scenario)
    if duration:
        sc = Scenario(replace(sc.world, duration_s=float(duration)), sc.overrides, sc.base)
    t = time.perf_counter()
    simulate(sc, out, seed=seed, config={"lidar": {"mount": mount(offset)}}, force=True)
    print(f"  simulated {name} in {time.perf_counter() - t:.0f} s", file=sys.stderr)
    return out


def nearer_on_ray(pair, which: np.ndarray, width: float = math.radians(RAY_WIDTH_DEG),
                  margin: float = RAY_MARGIN) -> np.ndarray:
    """Per beam (for ``which``): does another in-view LiDAR point lie on its camera ray, ``margin`` nearer?

    The camera ray is taken in the floor plane from the camera centre: bearings within
    ``width``. A wrong point without one has nothing at LiDAR height in front of it: what the
    mask shows there overhangs the LiDAR plane (a bed's side, a chair's seat, a table top),
    or was never hit. A correct point with one is a candidate for true occlusion.
    """
    out = np.zeros(which.size, bool)
    view = pair.view
    beams = view.beams
    rel = pair.raw.points[beams] - CAMERA_XY
    d = np.hypot(rel[:, 0], rel[:, 1])
    az = np.arctan2(rel[:, 1], rel[:, 0])
    for j in np.nonzero(which[beams])[0]:
        near = (np.abs(az - az[j]) <= width) & (d < d[j] - margin)
        out[beams[j]] = bool(near.any())
    return out


class Tally:
    """Per-beam counts over a tour."""

    def __init__(self) -> None:
        self.scans = self.painted_scans = self.beams_matched = 0
        self.wrong = self.wrong_removed = self.correct = self.correct_kept = 0
        self.relabelled: list[int] = []
        self.wrong_kinds: dict[str, list[int]] = {}  # "true → painted": [wrong, removed]
        self.lost_kinds: dict[str, int] = {}  # correct points the filter made unknown, by mobility
        self.survivors_blocked = 0  # surviving wrong points with a nearer LiDAR point on their camera ray
        self.lost_blocked = 0  # correct points lost that had one
        self.survivor_ranges: list[float] = []
        self.best_wrong_left: tuple[int, Any] = (0, None)  # (wrong points left, pair)

    def add(self, pair, truth_mob: np.ndarray) -> None:
        raw = pair.raw.mobility
        filt = pair.filtered.mobility
        self.scans += 1
        self.beams_matched += raw.size
        if pair.view is None:
            return
        self.painted_scans += 1
        self.relabelled.append(pair.relabelled)
        wrong = (raw >= SEMI) & (raw != truth_mob)
        removed = wrong & (filt == UNKNOWN)
        correct = (raw != UNKNOWN) & (raw == truth_mob)
        kept = correct & (filt == raw)
        self.wrong += int(wrong.sum())
        self.wrong_removed += int(removed.sum())
        self.correct += int(correct.sum())
        self.correct_kept += int(kept.sum())
        for i in np.nonzero(wrong)[0]:
            k = f"{_NAMES[int(truth_mob[i])]} → {_NAMES[int(raw[i])]}"
            entry = self.wrong_kinds.setdefault(k, [0, 0])
            entry[0] += 1
            entry[1] += int(removed[i])
        for i in np.nonzero(correct & ~kept)[0]:
            k = _NAMES[int(raw[i])]
            self.lost_kinds[k] = self.lost_kinds.get(k, 0) + 1
        left = wrong & ~removed
        lost = correct & ~kept
        if left.any() or lost.any():
            blocked = nearer_on_ray(pair, left | lost)
            self.survivors_blocked += int((blocked & left).sum())
            self.lost_blocked += int((blocked & lost).sum())
            self.survivor_ranges += [float(r) for r in pair.scan.ranges[left]]
        n_left = int(left.sum())
        if n_left > self.best_wrong_left[0]:
            self.best_wrong_left = (n_left, pair)

    def as_dict(self) -> dict:
        rel = np.asarray(self.relabelled or [0])
        rng = np.asarray(self.survivor_ranges or [np.nan])
        return {
            "scans": self.scans, "painted_scans": self.painted_scans, "beams": self.beams_matched,
            "wrong": self.wrong, "wrong_removed": self.wrong_removed,
            "wrong_removed_share": self.wrong_removed / self.wrong if self.wrong else float("nan"),
            "correct": self.correct, "correct_kept": self.correct_kept,
            "correct_kept_share": self.correct_kept / self.correct if self.correct else float("nan"),
            # of the correct points no nearer LiDAR point hides from the camera: a label on a point the camera
            # could not see is right by chance (a wall behind a wall), and losing it is the filter's job
            "correct_kept_share_unhidden": (self.correct_kept / (self.correct - self.lost_blocked)
                                            if self.correct > self.lost_blocked else float("nan")),
            "relabelled_per_scan_mean": float(rel.mean()), "relabelled_per_scan_max": int(rel.max()),
            "wrong_kinds": {k: {"wrong": v[0], "removed": v[1]} for k, v in sorted(self.wrong_kinds.items())},
            "correct_lost_by_mobility": dict(sorted(self.lost_kinds.items())),
            "survivors": self.wrong - self.wrong_removed,
            "survivors_with_nearer_point_on_ray": self.survivors_blocked,
            "correct_lost": self.correct - self.correct_kept,
            "correct_lost_with_nearer_point_on_ray": self.lost_blocked,
            "survivor_range_median_m": float(np.nanmedian(rng)),
        }


def score_tour(tour: Path, pictures: Path | None, tag: str) -> dict:
    """Paint the tour with and without the filter and score every beam against the truth."""
    from semmap.paint.export import iter_painted
    from semmap.paint.figure import ImagePicker, camera_image, paint_picture

    gt = np.load(tour / "ground_truth" / "beams.npz")
    row_of = {int(s): i for i, s in enumerate(gt["stamp_ns"])}
    truth = gt["mobility"]
    tally = Tally()
    most = ImagePicker()
    unmatched = 0
    t = time.perf_counter()
    for pair in iter_painted(tour):
        i = row_of.get(pair.scan.stamp_ns)
        if i is None or truth.shape[1] != pair.raw.mobility.size:
            unmatched += 1
            continue
        tally.add(pair, truth[i])
        most.offer(pair)
    res = tally.as_dict() | {"unmatched_scans": unmatched, "paint_s": time.perf_counter() - t}
    if pictures is not None:
        pictures.mkdir(parents=True, exist_ok=True)
        picks = [("most-relabelled", most.best)]
        if tally.best_wrong_left[1] is not None:
            picks.append(("most-wrong-left", tally.best_wrong_left[1]))
        for what, pair in picks:
            if pair is None or pair.view is None:
                continue
            img = camera_image(tour, pair.view.stamp_ns)
            out = pictures / f"{tag}-{what}.png"
            paint_picture(pair, out, img, truth=truth[row_of[pair.scan.stamp_ns]],
                          title=f"{tag}, {what.replace('-', ' ')}: scan at {pair.scan.stamp_ns / 1e9:.3f} s")
            res.setdefault("pictures", []).append(str(out))
    return res


def score_maps(tour: Path, tmp: Path, tag: str) -> dict:
    out = {}
    for on in (False, True):
        mapdir = tmp / f"{tag}-{'on' if on else 'off'}"
        t = time.perf_counter()
        run_build(tour, mapdir, {"paint": {"occlusion": {"filter": on}}})
        s = score_simulated(tour, mapdir)
        out["on" if on else "off"] = {k: s[k] for k in ("f1", "recall", "ghost_rate", "semi_precision",
                                                          "semi_recall", "ate_rmse_m")}
        out["on" if on else "off"]["build_s"] = time.perf_counter() - t
    return out


def _pct(x: float) -> str:
    return "-" if x != x else f"{100 * x:.1f} %"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["occlusion", "ward"])
    ap.add_argument("--offsets", nargs="+", type=float, default=[0.0, 0.2, 0.4],
                    help="lateral offsets of the LiDAR from the camera, m")
    ap.add_argument("--duration", type=float, default=None,
                    help="cut every tour to this many seconds (default: the whole route: occlusion 52 s, ward 116 s)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tours", type=Path, default=Path(tempfile.gettempdir()) / "semmap-bench-occlusion",
                    help="where simulated tours are cached")
    ap.add_argument("--no-map", action="store_true", help="skip building the maps (per-beam scores only)")
    ap.add_argument("--pictures", type=Path, metavar="DIR",
                    help="draw Fig. 6 (with the truth) of the scan with the most relabelled points and of the "
                         "one with the most wrong points left, per scenario and offset")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()

    t_all = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="semmap-bench-occ-maps-") as tmp:
        for sc in args.scenarios:
            for off in args.offsets:
                tag = f"{sc}-y{off:.2f}"
                tour = tour_for(args.tours, sc, off, args.duration, args.seed)
                row = {"scenario": sc, "offset_m": off, "lidar_mount": mount(off), "tour": str(tour),
                       **score_tour(tour, args.pictures, tag)}
                if not args.no_map:
                    row["map"] = score_maps(tour, Path(tmp), tag)
                rows.append(row)
                print(f"  {tag}: wrong {row['wrong']}, removed {_pct(row['wrong_removed_share'])}; correct "
                      f"{row['correct']}, kept {_pct(row['correct_kept_share'])}", file=sys.stderr)
    total_s = time.perf_counter() - t_all

    print(f"semmap occlusion filter benchmark, {date.today().isoformat()}")
    print(f"machine: {machine()}\n")
    print("Per beam, against the simulator's truth (wrong: painted dynamic or semi-static without the filter "
          "but truly something else; correct: painted and equal to the truth):\n")
    print("| scenario | LiDAR y (m) | painted scans | wrong | removed by the filter (≥ 90 %) | correct | "
          "kept by the filter (≥ 98 %) | kept, of those no nearer point hides | relabelled per scan, mean | max |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['scenario']} | {r['offset_m']:.1f} | {r['painted_scans']} | {r['wrong']} | "
              f"{_pct(r['wrong_removed_share'])} | {r['correct']} | {_pct(r['correct_kept_share'])} | "
              f"{_pct(r['correct_kept_share_unhidden'])} | "
              f"{r['relabelled_per_scan_mean']:.2f} | {r['relabelled_per_scan_max']} |")
    print("\nWrong points by kind (true → painted without the filter: removed / wrong), and what survives:\n")
    print(f"| scenario | LiDAR y (m) | kinds | wrong left | of them with a nearer point on the camera ray "
          f"(±{RAY_WIDTH_DEG:g}°, {RAY_MARGIN:g} m) | median range of those left (m) | correct lost, by mobility | "
          f"of them with a nearer point on the ray |")
    print("|---|---:|---|---:|---:|---:|---|---:|")
    for r in rows:
        kinds = "; ".join(f"{k}: {v['removed']}/{v['wrong']}" for k, v in r["wrong_kinds"].items()) or "-"
        lost = ", ".join(f"{k} {v}" for k, v in r["correct_lost_by_mobility"].items()) or "-"
        print(f"| {r['scenario']} | {r['offset_m']:.1f} | {kinds} | {r['survivors']} | "
              f"{r['survivors_with_nearer_point_on_ray']} | {r['survivor_range_median_m']:.2f} | {lost} | "
              f"{r['correct_lost_with_nearer_point_on_ray']} |")
    if not args.no_map:
        print("\nThe cleaned map, filter off → on (`paint.occlusion.filter`; EKF fusion; scored as in "
              "tools/bench_build.py):\n")
        print("| scenario | LiDAR y (m) | occupied F1 | occupied recall | ghost rate | semi-static precision | "
              "semi-static recall |")
        print("|---|---:|---:|---:|---:|---:|---:|")
        for r in rows:
            a, b = r["map"]["off"], r["map"]["on"]
            print(f"| {r['scenario']} | {r['offset_m']:.1f} | {a['f1']:.3f} → {b['f1']:.3f} | "
                  f"{a['recall']:.3f} → {b['recall']:.3f} | {100 * a['ghost_rate']:.2f} → "
                  f"{100 * b['ghost_rate']:.2f} % | {a['semi_precision']:.3f} → {b['semi_precision']:.3f} | "
                  f"{a['semi_recall']:.3f} → {b['semi_recall']:.3f} |")
    print(f"\nLiDAR mounts: x {LIDAR_X} m, height {LIDAR_Z} m, y = the offset; yaw pi/4 (corner) for offsets > 0, "
          f"0 for the centred one. Tours: seed {args.seed}, "
          f"{'whole routes' if not args.duration else f'{args.duration:g} s'}. Took {total_s:.0f} s.")
    if args.json:
        args.json.write_text(json.dumps({"date": date.today().isoformat(), "machine": machine(),
                                         "duration_s": args.duration, "seed": args.seed, "rows": rows,
                                         "total_s": total_s}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
