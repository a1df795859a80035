#!/usr/bin/env python3
"""Benchmark the frame selection (``segmentation.select``): model calls against map quality.

For each procedurally generated world (``random:SEED``) and named scenario it simulates the tour
(cached, as ``tools/bench_semantic.py`` does), builds the map once per selection in its own process,
and scores each map against the simulator's truth (:func:`semmap.sim.score.score_map`, issue 12's
scores): standing people left, ghost rate, occupied F1, semi-static precision and recall (recall over
furniture the camera labelled at least once). The selections:

* ``all``: every camera frame (the reference);
* ``motion``: a frame per 0.3 m or 10° of motion, or per second;
* ``need``: a frame when the returns in view lack camera evidence;
* ``need@1fps``: ``need`` with a budget of one frame per second of tour (``max_rate: 1``);
* ``need-eager``: ``need`` looking again sooner (``need_cells: 1`` instead of 2);
* ``all@14fps``: every frame up to 14 a second (``max_rate: 14``): on a 15 Hz camera, one frame in
  fifteen skipped, the rest as ``all``: how far a map's scores move when the model merely runs on
  slightly other frames (the scores' noise floor, against which the tolerances of 0.01 are judged);
* ``all@3fps``: frames evenly spread at 3 a second (a fifth of a 15 Hz camera, ``need``'s budget).

It reports per world and in all: model calls (frames segmented) as a share of ``all``'s, and each score's
difference from ``all``'s (worst over the worlds), with the targets of issue 23: ``need`` at most a fifth
of the calls with every score within 0.01 (ghosts and standing people within 0.5 percentage points), the
budget within 0.02. The label images come from the bag, so no model runs here: model time is
``tools/bench_segment.py``'s per-frame time times the calls.

The scoring worlds (seeds 1000-1019) are held out: develop with ``--seeds`` (e.g. 0-7), report with the
default.

    python tools/bench_select.py                        # the 20 scoring worlds + ward and office
    python tools/bench_select.py --seeds 0 1 2 3 --scenarios --modes all need
    python tools/bench_select.py --camera-hz 15 --onnx yolo11n-seg.onnx --modes all need   # build speed
    python tools/bench_select.py --seeds 1 --scenarios --camera-hz 15 --model sam3 --modes need --project-sam3

``--model BACKEND[:PATH]`` runs a model instead of reading the bag's label images: ``onnx:MODEL``,
``mediapipe-selfie:MODEL`` or ``sam3[:FOLDER]`` (without a folder: a random-weight SAM 3 of the
``small`` preset, ``tests/sam3_helpers.py``, prompted with ``--prompts``). It reports build speed
against the tour's length, not map scores (random weights label nothing a scorer could use), and runs
only the selections asked for (``--score`` scores the maps too: with a real model such as the
MediaPipe person model, people and ghosts mean something). ``--project-sam3`` adds the full SAM 3's
model time, projected from the measured time per frame by torch's FLOP counts of both models
(embedding plus one decoder pass per prompt): what the selection would cost with the real model on
this CPU if time followed FLOPs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from datetime import date
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from bench_build import run_build
from bench_semantic import SCORING_SEEDS, simulate_tour, simulator_key
from benchlib import add_set_argument, machine

MODES: dict[str, dict[str, Any]] = {
    "all": {"select": "all"},
    "motion": {"select": "motion"},
    "need": {"select": "need"},
    "need@1fps": {"select": "need", "max_rate": 1.0},
    "need-eager": {"select": "need", "need_cells": 1.0},
    # the scores' noise floor: every frame but one in fifteen (a 15 Hz camera at 14 a second), so nearly all
    # the information of `all`, on slightly other frames
    "all@14fps": {"select": "all", "max_rate": 14.0},
    # evenly spread frames at need's budget (a fifth of a 15 Hz camera): what choosing the frames buys
    "all@3fps": {"select": "all", "max_rate": 3.0},
}

# (key, label, format, tolerance against `all`, lower is better)
SCORES: list[tuple[str, str, str, float, bool]] = [
    ("standing_left", "standing left", "pct", 0.005, True),
    ("ghost_rate", "ghost rate", "pct", 0.005, True),
    ("f1", "occupied F1", "f3", 0.01, False),
    ("semi_precision", "semi-static P", "f3", 0.01, False),
    ("semi_recall", "semi-static R", "f3", 0.01, False),
]
BUDGET_TOLERANCE = 0.02  # the budget's scores within this of `all`'s (ghosts and standing people too)


def fmt(v: Any, kind: str) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{100 * v:.2f} %" if kind == "pct" else f"{v:.3f}"


def build_and_score(name: str, tour: Path, out: Path, mode: str, extra: dict[str, Any],
                    score: bool = True) -> dict[str, Any]:
    from semmap.sim.score import score_map

    seg = dict(MODES[mode])
    overrides = {**extra, "segmentation": {**extra.get("segmentation", {}), **seg}}
    t = time.perf_counter()
    run_build(tour, out, overrides)
    wall = time.perf_counter() - t
    summary = json.loads((out / "summary.json").read_text())
    s = score_map(tour, out) if score else {}
    fs = summary["painting"].get("frame_selection") or {}
    timings = summary.get("timings_s") or {}
    return {"world": name, "mode": mode, "build_s": round(wall, 2), "frames": fs.get("frames_segmented"),
            "frames_skipped": fs.get("frames_skipped"), "scans_from_memory": fs.get("scans_from_memory"),
            "duration_s": summary["tour"]["duration_s"], "model_s": timings.get("segmentation_busy"),
            "wait_model_s": timings.get("wait_images"), "loop_s": timings.get("loop"),
            **{k: s.get(k) for k, *_ in SCORES}}


def model_settings(spec: str, prompts: list[str]) -> tuple[dict[str, Any], str]:
    """The ``segmentation`` settings of ``--model BACKEND[:PATH]``, and a label for the table."""
    backend, _, path = spec.partition(":")
    if backend == "sam3":
        if not path:
            sys.path.insert(0, str(REPO / "tests"))
            import atexit
            import shutil

            from sam3_helpers import save_random_model

            tmp = Path(tempfile.mkdtemp(prefix="semmap-sam3-"))
            atexit.register(shutil.rmtree, tmp, True)
            folder = save_random_model(tmp / "small", "small", vocabulary=tuple(prompts))
            label = f"SAM 3, `small` preset, random weights, {len(prompts)} prompt{'s' if len(prompts) != 1 else ''}"
        else:
            folder, label = Path(path), f"SAM 3 ({Path(path).name}), {len(prompts)} prompts"
        return {"backend": "sam3", "model": str(Path(folder).resolve()), "prompts": list(prompts)}, label
    if backend in ("onnx", "mediapipe-selfie") and path:
        return {"backend": backend, "model": str(Path(path).resolve())}, f"{backend} ({Path(path).name})"
    raise SystemExit(f"bench_select.py: --model {spec!r}: expected onnx:MODEL, mediapipe-selfie:MODEL or "
                     f"sam3[:FOLDER]")


def sam3_factor(prompts: int) -> float:
    """How many times the `small` preset's FLOPs per frame (504 px) the full SAM 3's are (1008 px), with
    ``prompts`` decoder passes each: torch's counts (``tests/sam3_helpers.flop_split``)."""
    sys.path.insert(0, str(REPO / "tests"))
    from sam3_helpers import flop_split, random_config

    full, small = flop_split(), flop_split(random_config("small"))
    return (full["vision"] + prompts * full["decoder"]) / (small["vision"] + prompts * small["decoder"])


def speed_table(rows: list[dict[str, Any]], modes: list[str], label: str, hz: float | None,
                factor: float | None = None, scored: bool = False) -> None:
    """Build time against the tour's length, per selection, with a model backend (``--model``)."""
    note = "map scores below" if scored else "map scores are not reported: the weights may be random"
    print(f"Builds with {label} on {hz:g} Hz camera tours: faster than real time when the tour's length over "
          f"the build's wall time is above 1 ({note})\n" if hz else f"Builds with {label}\n")
    head = ("| mode | frames segmented (share of all frames) | model busy (s) | model per frame (ms) | build wall "
            "time (s) | tour (s) | tour / build | waiting for the model |")
    if factor is not None:
        head += " full SAM 3, projected: model time (s) | tour / model time |"
    print(head)
    print("|---|---|---|---|---|---|---|---|" + ("---|---|" if factor is not None else ""))
    for mode in modes:
        rs = [r for r in rows if r["mode"] == mode]
        frames = sum(r["frames"] or 0 for r in rs)
        total = sum((r["frames"] or 0) + (r["frames_skipped"] or 0) for r in rs)
        busy = sum(r["model_s"] or 0.0 for r in rs)
        wall = sum(r["build_s"] for r in rs)
        dur = sum(r["duration_s"] for r in rs)
        loop = sum(r["loop_s"] or 0.0 for r in rs)
        wait = sum(r["wait_model_s"] or 0.0 for r in rs)
        line = (f"| {mode} | {frames} ({100 * frames / max(total, 1):.0f} %) | {busy:.1f} | "
                f"{1000 * busy / max(frames, 1):.0f} | {wall:.1f} | {dur:.1f} | **{dur / wall:.2f}** | "
                f"{100 * wait / loop if loop else 0:.0f} % |")
        if factor is not None:
            projected = busy * factor
            line += f" {projected:.0f} | {dur / projected if projected else float('nan'):.3f} |"
        print(line)
    if factor is not None:
        print(f"\n(the full SAM 3 at 1008 px costs {factor:.1f}× the `small` preset's FLOPs per frame with these "
              f"prompts; projected time = model busy × that, if time followed FLOPs)")


def deltas(row: dict[str, Any], ref: dict[str, Any]) -> dict[str, float]:
    """Each score's change against `all`, signed so that negative is worse."""
    out = {}
    for key, _, _, _, lower in SCORES:
        a, b = ref.get(key), row.get(key)
        if any(v is None or (isinstance(v, float) and math.isnan(v)) for v in (a, b)):
            continue
        out[key] = (a - b) if lower else (b - a)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="*", default=list(SCORING_SEEDS),
                    help="world seeds (default: the 20 scoring seeds; develop on others)")
    ap.add_argument("--scenarios", nargs="*", default=["ward", "office"], help="named scenarios besides the worlds")
    ap.add_argument("--modes", nargs="+", default=["all", "motion", "need", "need@1fps"], choices=list(MODES))
    ap.add_argument("--tours", type=Path, default=Path(tempfile.gettempdir()) / "semmap-semantic-tours",
                    help="where simulated tours are cached (shared with bench_semantic.py)")
    ap.add_argument("--maps", type=Path, help="keep the map folders here (default: a temporary folder)")
    ap.add_argument("--json", type=Path, help="also write every row here")
    ap.add_argument("--camera-hz", type=float,
                    help="simulate every tour with a camera of this rate instead of the world's own (2-5 Hz in the "
                         "random worlds; 15-30 Hz on real robots)")
    ap.add_argument("--same-poses", action="store_true",
                    help="registration.exclude_dynamic: false in every build, so that every selection gets the same "
                         "trajectory and the scores differ by the labels alone (by default the registration leaves "
                         "out returns painted as people, so labels move the poses by a few millimetres, and thin "
                         "legs flip in and out of the map)")
    ap.add_argument("--model", metavar="BACKEND[:PATH]",
                    help="segment with a model instead of the bag's label images: onnx:MODEL, "
                         "mediapipe-selfie:MODEL or sam3[:FOLDER] (default folder: a random-weight SAM 3 of the "
                         "small preset); reports build speed against the tour's length instead of map scores")
    ap.add_argument("--prompts", default="person,chair,couch,bed,dining table,potted plant",
                    help="with --model sam3: the text prompts, comma-separated (default: the simulator's classes)")
    ap.add_argument("--project-sam3", action="store_true",
                    help="with --model sam3: also project the full SAM 3's model time from torch's FLOP counts")
    ap.add_argument("--score", action="store_true",
                    help="with --model: score the maps too (a real model's, e.g. the MediaPipe person model: people "
                         "and ghosts mean something, furniture does not); needs the 'all' mode as the reference")
    ap.add_argument("--onnx", type=Path, metavar="MODEL",
                    help="segment with this ONNX model (e.g. YOLO11n-seg) instead of the bag's label images, and "
                         "report build speed against the tour's length instead of map scores")
    add_set_argument(ap)
    args = ap.parse_args()
    if args.onnx is not None:
        if args.model is not None:
            ap.error("--onnx MODEL is --model onnx:MODEL: give one of them")
        args.model = f"onnx:{args.onnx}"
    label = ""
    if args.model is not None:
        seg, label = model_settings(args.model, [p.strip() for p in args.prompts.split(",") if p.strip()])
        args.set = {**args.set, "segmentation": {**args.set.get("segmentation", {}), **seg}}
    if args.project_sam3 and not (args.model or "").startswith("sam3"):
        ap.error("--project-sam3 needs --model sam3")
    if args.same_poses:
        args.set = {**args.set, "registration": {**args.set.get("registration", {}), "exclude_dynamic": False}}
    score = args.model is None or args.score
    if "all" not in args.modes and score:  # the reference of the map scores
        args.modes.insert(0, "all")
    worlds = [f"random:{s}" for s in args.seeds] + list(args.scenarios)
    if not worlds:
        ap.error("no worlds and no scenarios")

    cache = args.tours / (f"sim-{simulator_key()}" + (f"-camera-{args.camera_hz:g}hz" if args.camera_hz else ""))
    cache.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="semmap-select-") as tmp:
        maps = args.maps or Path(tmp)
        for name in worlds:
            tour = str(cache / name.replace(":", "_"))
            if args.camera_hz is None:
                simulate_tour(name, tour, False)
            elif not (Path(tour) / "tour.yaml").is_file():
                from semmap.sim.tour import simulate

                simulate(name, tour, seed=0, config={"camera": {"rate_hz": args.camera_hz}}, force=True)
            for mode in args.modes:
                out = maps / f"{name.replace(':', '_')}_{mode.replace('@', '_')}"
                if out.exists():
                    import shutil

                    shutil.rmtree(out)
                row = build_and_score(name, Path(tour), out, mode, args.set, score=score)
                rows.append(row)
                if not score:
                    print(f"  {name:<12} {mode:<10} frames {row['frames']:>4}  build {row['build_s']:.1f} s for a "
                          f"{row['duration_s']:.1f} s tour", file=sys.stderr)
                    continue
                print(f"  {name:<12} {mode:<10} frames {row['frames']:>4}  standing {fmt(row['standing_left'], 'pct')}"
                      f"  ghost {fmt(row['ghost_rate'], 'pct')}  F1 {fmt(row['f1'], 'f3')}  semi P "
                      f"{fmt(row['semi_precision'], 'f3')} R {fmt(row['semi_recall'], 'f3')}  {row['build_s']:.0f} s",
                      file=sys.stderr)
    wall = time.perf_counter() - t0

    by = {(r["world"], r["mode"]): r for r in rows}
    print(f"semmap frame-selection benchmark, {date.today().isoformat()}")
    print(f"machine: {machine()}")
    print(f"worlds: {', '.join(worlds)}; wall time {wall / 60:.1f} min"
          + (f"; camera at {args.camera_hz:g} Hz" if args.camera_hz else "; each world's own camera rate")
          + ("; the same poses for every selection (registration.exclude_dynamic: false)" if args.same_poses else "")
          + "\n")
    if args.model is not None:
        factor = sam3_factor(len(args.set["segmentation"]["prompts"])) if args.project_sam3 else None
        speed_table(rows, args.modes, label, args.camera_hz, factor, scored=score)
        if not score:
            if args.json:
                args.json.write_text(json.dumps({"date": date.today().isoformat(), "machine": machine(),
                                                 "worlds": worlds, "rows": rows}, indent=2, default=float))
            return 0
        print()
    # per score, the worst world's change and the mean over the worlds (the tolerance applies to each world)
    print("| mode | model calls (share of all) | " + " | ".join(f"{lab}: worst / mean change" for _, lab, *_ in SCORES)
          + " | worlds within tolerance |")
    print("|---|---|" + "---|" * len(SCORES) + "---|")
    verdicts = {}
    for mode in args.modes:
        calls = sum(by[(w, mode)]["frames"] or 0 for w in worlds)
        calls_all = sum(by[(w, "all")]["frames"] or 0 for w in worlds)
        worst: dict[str, float] = {}
        changes: dict[str, list[float]] = {}
        ok_worlds = 0
        for w in worlds:
            d = deltas(by[(w, mode)], by[(w, "all")])
            tol_ok = True
            for key, _, _, tol, _ in SCORES:
                if key in d:
                    worst[key] = min(worst.get(key, 0.0), d[key])
                    changes.setdefault(key, []).append(d[key])
                    limit = max(tol, BUDGET_TOLERANCE) if mode.startswith("need@") else tol
                    tol_ok &= d[key] >= -limit - 1e-12
            ok_worlds += tol_ok
        cells = []
        mean = {key: sum(v) / len(v) for key, v in changes.items()}
        for key, _, kind, _, _ in SCORES:
            v, m = worst.get(key, 0.0), mean.get(key, 0.0)
            cells.append(f"{100 * v:+.2f} / {100 * m:+.2f} pp" if kind == "pct" else f"{v:+.3f} / {m:+.3f}")
        share = calls / calls_all if calls_all else float("nan")
        print(f"| {mode} | {calls} ({100 * share:.0f} %) | " + " | ".join(cells) + f" | {ok_worlds} of {len(worlds)} |")
        verdicts[mode] = {"calls": calls, "share": share, "worst": worst, "mean": mean, "worlds_ok": ok_worlds}
    print("\nPer world (frames segmented; each score's change against all, negative is worse):\n")
    print("| world | mode | frames | " + " | ".join(lab for _, lab, *_ in SCORES) + " |")
    print("|---|---|---|" + "---|" * len(SCORES))
    for w in worlds:
        for mode in args.modes:
            r = by[(w, mode)]
            if mode == "all":
                cells = [fmt(r[k], kind) for k, _, kind, _, _ in SCORES]
            else:
                d = deltas(r, by[(w, "all")])
                cells = [(f"{100 * d[k]:+.2f} pp" if kind == "pct" else f"{d[k]:+.3f}") if k in d else "-"
                         for k, _, kind, _, _ in SCORES]
            print(f"| {w} | {mode} | {r['frames']} | " + " | ".join(cells) + " |")
    if args.json:
        args.json.write_text(json.dumps({"date": date.today().isoformat(), "machine": machine(), "worlds": worlds,
                                         "rows": rows, "verdicts": verdicts}, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
