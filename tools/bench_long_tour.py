#!/usr/bin/env python3
"""Benchmark `semmap build` on long tours: does memory stay flat as the tour gets longer?

For each tour length (default 5, 15 and 30 minutes) it simulates the `ward` scenario driven for
as many laps as fit (``World.laps``; the robot waits between laps until the people are out of its
way, and the tour is cut at the length asked for), builds it with `semmap build`'s default
settings (workers on) in a child process, and reports:

* the tour: duration, scans, bag size;
* the map: cells and m² of the map folder's grid (cropped to what was seen), and the observed
  (free or occupied) area;
* memory: the peak RSS of the main process and of each worker as `summary.json` gives them
  (``peak_rss_mb``, ``peak_rss_mb_workers``: each process's ``ru_maxrss``), their sum, and RSS
  per map cell; and, sampled from /proc every 0.1 s, the peak of the processes' RSS *at the same
  time* and each process's own high-water mark (``VmHWM``), split into anonymous and file-backed
  pages, with how fast each process's RSS grows while the scans stream (bytes per scan);
* the build time (the build's own clock, end to end) and scans per second.

The verdict fits the summed peak RSS against the tour length (and the map's cells, where the maps
differ in size): memory is flat when the tour-length term over the lengths measured stays under
``--flat-mb`` (25 MB) or ``--flat-fraction`` (5 %) of the shortest tour's figure, whichever is larger.

Bags: camera 640x480 at 5 Hz as JPEG (`camera.image_format: jpeg`), label images `mono8` (the
topic `semmap build` reads by default), LiDAR at its default 15 Hz, odometry and ground truth at
50 Hz; ROS1 format. The 30-minute bag is about 3.3 GB.

    python tools/bench_long_tour.py                                   # 5, 15, 30 min; tours deleted after
    python tools/bench_long_tour.py --minutes 5 --out /tmp/lt          # one tour
    python tools/bench_long_tour.py --tours /tmp/lt-tours --keep       # simulate once, reuse next time
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
from benchlib import host_reference_ms, machine

#: simulator settings of the benchmark's tours (everything else: the defaults)
SIM_CONFIG = {"camera": {"image_format": "jpeg", "label_encoding": "mono8"}}

SIM_CHILD = r"""
import json, resource, sys, time
from dataclasses import replace
from semmap.sim.robot import plan_tour
from semmap.sim.scenarios import get_scenario
from semmap.sim.tour import effective_config, simulate
name, out, fmt, seed, duration, cfg = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), float(sys.argv[5]), \
    json.loads(sys.argv[6])
sc = get_scenario(name)
one = plan_tour(sc.world, effective_config(sc, cfg).robot)
laps = int(duration // one.duration) + 2  # enough laps, with the waits between them; the tour is cut at duration
t = time.perf_counter()
r = simulate(replace(sc.world, laps=laps, duration_s=duration), out, fmt=fmt, seed=seed, config=cfg)
print(json.dumps({"wall_s": time.perf_counter() - t, "tour_s": r.duration_s, "laps_planned": laps,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

#: put on PYTHONPATH for the build: every Python process of it (the build and its spawned workers) writes its
#: own peak RSS (VmHWM, exact, read from /proc as it exits) into $SEMMAP_BENCH_EXIT_DIR
EXIT_HOOK = r"""
import atexit, json, os, resource, sys


def _semmap_bench_dump():
    try:
        fields = {}
        for line in open("/proc/self/status"):
            key, _, value = line.partition(":")
            if key in ("VmHWM", "VmRSS", "RssAnon", "RssFile"):
                fields[key] = int(value.split()[0])
        with open(os.path.join(os.environ["SEMMAP_BENCH_EXIT_DIR"], f"{os.getpid()}.json"), "w") as f:
            json.dump({"pid": os.getpid(), "ppid": os.getppid(), "argv": sys.argv, "status_kb": fields,
                       "ru_maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}, f)
    except Exception:
        pass


if os.environ.get("SEMMAP_BENCH_EXIT_DIR"):
    atexit.register(_semmap_bench_dump)
"""

BUILD_CHILD = r"""
import json, sys
from semmap.pipeline import build
r = build(sys.argv[1], sys.argv[2])
print(json.dumps({"summary_path": str(r.out / "summary.json"), "elapsed_s": r.elapsed_s}))
"""


# ---------------------------------------------------------------------------------------------
# memory of a process tree, sampled from /proc


def _status(pid: int) -> dict[str, int] | None:
    """VmRSS, VmHWM, RssAnon, RssFile, RssShmem of a process, kB (None once it has gone)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    out = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM", "RssAnon", "RssFile", "RssShmem"):
            out[key] = int(value.split()[0])
    return out if "VmRSS" in out else None


def _children(root: int) -> list[int]:
    """Every descendant of ``root`` (from each process's parent id in /proc/*/stat)."""
    parent: dict[int, int] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                stat = Path(f"/proc/{d}/stat").read_text()
            except OSError:
                continue
            parent[int(d)] = int(stat[stat.rindex(")") + 2:].split()[1])
    found, todo = [], [root]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        found += kids
        todo += kids
    return found


def _comm(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


class TreeSampler(threading.Thread):
    """Samples the RSS of a process and its descendants every ``interval`` seconds."""

    def __init__(self, root: int, interval: float = 0.1, rescan: float = 0.5) -> None:
        super().__init__(daemon=True)
        self.root, self.interval, self.rescan = root, interval, rescan
        self.procs: dict[int, dict] = {}  # pid -> {"cmd", "first", "last", "hwm_kb", "series": [(t, rss, anon, file)]}
        self.total_peak_kb = 0
        self.total_peak_t = 0.0
        self._halt = threading.Event()
        self.t0 = time.perf_counter()

    def stop(self) -> None:
        self._halt.set()
        self.join()

    def run(self) -> None:
        pids = [self.root]
        last_scan = -1e9
        while not self._halt.is_set():
            now = time.perf_counter() - self.t0
            if now - last_scan > self.rescan:
                pids = [self.root] + _children(self.root)
                last_scan = now
            total = 0
            for pid in pids:
                st = _status(pid)
                if st is None:
                    continue
                rec = self.procs.get(pid)
                if rec is None:
                    rec = self.procs[pid] = {"cmd": _cmdline(pid), "first": now, "series": [], "hwm_kb": 0}
                rec["last"] = now
                if now - last_scan < 1e-9 or "comm" not in rec:  # workers name themselves after they start
                    rec["comm"] = _comm(pid)
                rec["hwm_kb"] = max(rec["hwm_kb"], st.get("VmHWM", 0))
                rec["series"].append((now, st["VmRSS"], st.get("RssAnon", 0), st.get("RssFile", 0)))
                total += st["VmRSS"]
            if total > self.total_peak_kb:
                self.total_peak_kb, self.total_peak_t = total, now
            self._halt.wait(self.interval)

    def named(self) -> dict[str, dict]:
        """The processes by role: main (the build), its workers by the name they give themselves
        (``semmap-register``, ``semmap-fusion``, ``semmap-images`` in /proc/PID/comm), else in the order
        they started, and multiprocessing's resource tracker."""
        roles = {"semmap-register": "registration", "semmap-fusion": "fusion", "semmap-images": "images"}
        out: dict[str, dict] = {}
        unnamed = []
        for pid, rec in sorted(self.procs.items(), key=lambda kv: (kv[1]["first"], kv[0])):
            if pid == self.root:
                out["main"] = rec
            elif rec.get("comm") in roles:
                out[roles[rec["comm"]]] = rec
            elif "resource_tracker" in rec["cmd"]:
                out[f"resource_tracker_{pid}"] = rec
            elif "spawn_main" in rec["cmd"] or "multiprocessing" in rec["cmd"]:
                unnamed.append(rec)
            else:
                out[f"other_{pid}"] = rec
        free = [n for n in ["registration", "fusion", "images"] if n not in out] + [f"worker{i}" for i in range(3, 20)]
        for name, rec in zip(free, unnamed):
            out[name] = rec
        return out


def _at(series: list[tuple], t: float, column: int) -> float | None:
    """The sampled value (MB) of ``column`` at the first sample at or after ``t``."""
    for row in series:
        if row[0] >= t:
            return round(row[column] / 1024, 1)
    return None


def _growth_bytes_per_s(series: list[tuple], t_from: float, t_to: float, column: int = 1) -> float | None:
    """Least-squares slope (bytes/s) of RSS (kB, ``column`` of the series) between two times."""
    pts = [(s[0], s[column]) for s in series if t_from <= s[0] <= t_to]
    if len(pts) < 5:
        return None
    n = len(pts)
    mt = sum(p[0] for p in pts) / n
    mv = sum(p[1] for p in pts) / n
    var = sum((p[0] - mt) ** 2 for p in pts)
    if var <= 0:
        return None
    return 1024.0 * sum((p[0] - mt) * (p[1] - mv) for p in pts) / var


# ---------------------------------------------------------------------------------------------
# tours


def _size_bytes(path: Path) -> int:
    return path.stat().st_size if path.is_file() else sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def _tour_matches(tour: Path, scenario: str, seed: int, fmt: str, duration: float) -> bool:
    """A cached tour is reused only when it was simulated with this benchmark's settings."""
    import yaml

    from semmap.sim.scenarios import get_scenario
    from semmap.sim.tour import effective_config

    try:
        manifest = yaml.safe_load((tour / "tour.yaml").read_text())
        cfg = yaml.safe_load((tour / "config.yaml").read_text())
        world = yaml.safe_load((tour / "ground_truth" / "world.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return False
    want = effective_config(get_scenario(scenario), SIM_CONFIG).model_dump(mode="json")
    return (manifest.get("scenario") == scenario and manifest.get("seed") == seed and manifest.get("format") == fmt
            and abs(float(manifest.get("duration_s", 0.0)) - duration) < 0.5 and cfg == want
            and world.get("laps", 1) > 1 and (tour / manifest["bag"]).exists())


def _lap_length_m(scenario: str) -> float:
    """The length of one lap of the scenario's route (m)."""
    from semmap.sim.robot import plan_tour
    from semmap.sim.scenarios import get_scenario
    from semmap.sim.tour import effective_config

    sc = get_scenario(scenario)
    return plan_tour(sc.world, effective_config(sc, SIM_CONFIG).robot).length()


def simulate_tour(tour: Path, scenario: str, seed: int, fmt: str, duration: float) -> dict:
    res = subprocess.run([sys.executable, "-c", SIM_CHILD, scenario, str(tour), fmt, str(seed), str(duration),
                          json.dumps(SIM_CONFIG), ], capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"simulating {tour} failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def build_tour(tour: Path, out: Path, interval: float) -> tuple[dict, dict, TreeSampler, dict[int, dict]]:
    """Build in a child process with the defaults, sampling the memory of its process tree; also each
    process's exact peak RSS as it exited (by pid)."""
    with tempfile.TemporaryDirectory(prefix="semmap-bench-hook-") as hook:
        (Path(hook) / "sitecustomize.py").write_text(EXIT_HOOK)
        dumps = Path(hook) / "exits"
        dumps.mkdir()
        env = dict(os.environ, SEMMAP_BENCH_EXIT_DIR=str(dumps),
                   PYTHONPATH=os.pathsep.join(p for p in (hook, os.environ.get("PYTHONPATH")) if p))
        proc = subprocess.Popen([sys.executable, "-c", BUILD_CHILD, str(tour), str(out)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=env)
        sampler = TreeSampler(proc.pid, interval)
        sampler.start()
        stdout, stderr = proc.communicate()
        sampler.stop()
        exits = {}
        for f in dumps.glob("*.json"):
            d = json.loads(f.read_text())
            exits[int(d["pid"])] = d
    if proc.returncode != 0:
        raise RuntimeError(f"build of {tour} failed:\n{stderr[-3000:]}")
    res = json.loads(stdout.strip().splitlines()[-1])
    return res, json.loads(Path(res["summary_path"]).read_text()), sampler, exits


def measure(minutes: float, args: argparse.Namespace, tours: Path, maps: Path, delete_tours: bool) -> dict:
    duration = 60.0 * minutes
    tour = tours / f"{args.scenario}-{minutes:g}min"
    sim = None
    if _tour_matches(tour, args.scenario, args.seed, args.format, duration):
        print(f"  {tour.name}: reusing the cached tour", file=sys.stderr)
    else:
        print(f"  {tour.name}: simulating {duration:.0f} s", file=sys.stderr, flush=True)
        if tour.exists():
            shutil.rmtree(tour)
        sim = simulate_tour(tour, args.scenario, args.seed, args.format, duration)
        print(f"  {tour.name}: simulated in {sim['wall_s']:.0f} s", file=sys.stderr, flush=True)
    import yaml

    manifest = yaml.safe_load((tour / "tour.yaml").read_text())
    world = yaml.safe_load((tour / "ground_truth" / "world.yaml").read_text())
    bag_bytes = _size_bytes(tour / manifest["bag"])
    mapdir = maps / tour.name
    if mapdir.exists():
        shutil.rmtree(mapdir)
    host_ms = host_reference_ms(3)
    print(f"  {tour.name}: building (host reference {host_ms:.1f} ms)", file=sys.stderr, flush=True)
    res, summary, sampler, exits = build_tour(tour, mapdir, args.sample_interval)
    import numpy as np

    with np.load(mapdir / "grid.npz", allow_pickle=False) as grid:  # the file's arrays, as written
        grid_bytes = int(sum(grid[k].nbytes for k in grid.files))
    w, h = summary["map"]["size_cells"]
    res_m = summary["map"]["resolution"]
    cells = int(w * h)
    observed = int(summary["map"]["occupied_cells"] + summary["map"]["free_cells"])
    workers = dict(summary.get("peak_rss_mb_workers", {}))
    total = summary["peak_rss_mb"] + sum(workers.values())
    scans = summary["counts"]["scans"]
    loop_s = summary["timings_s"]["loop"]
    # the streaming phase, as the sampler saw it: while the workers lived, less the first and last fifth
    named = sampler.named()
    procs = {}
    worker_recs = [r for k, r in named.items() if k in ("registration", "fusion", "images")]
    t_a = max((r["first"] for r in worker_recs), default=0.0)
    t_b = min((r["last"] for r in worker_recs), default=0.0)
    span = t_b - t_a
    pid_of = {id(rec): pid for pid, rec in sampler.procs.items()}
    for name, rec in named.items():
        series = rec["series"]
        ex = exits.get(pid_of[id(rec)])
        peak = max(series, key=lambda s: s[1]) if series else (0, 0, 0, 0)
        slope = _growth_bytes_per_s(series, t_a + 0.2 * span, t_b - 0.2 * span) if span > 2 else None
        slope_anon = _growth_bytes_per_s(series, t_a + 0.2 * span, t_b - 0.2 * span, 2) if span > 2 else None
        procs[name] = {
            "pid": pid_of[id(rec)],
            # exact, as the process exited; else the last value sampled (which can miss a peak in its last 0.1 s)
            "vm_hwm_mb": round((ex["status_kb"]["VmHWM"] if ex else rec["hwm_kb"]) / 1024, 1),
            "vm_hwm_source": "exit" if ex else "sampled",
            "ru_maxrss_mb": round(ex["ru_maxrss_kb"] / 1024, 1) if ex else None,
            "sampled_peak_rss_mb": round(peak[1] / 1024, 1),
            "anon_mb_at_peak": round(peak[2] / 1024, 1), "file_mb_at_peak": round(peak[3] / 1024, 1),
            "growth_bytes_per_scan": None if slope is None else round(slope * loop_s / scans, 1),
            "anon_growth_bytes_per_scan": None if slope_anon is None else round(slope_anon * loop_s / scans, 1),
            "samples": len(series),
            # RSS early in the streaming phase: what the process holds before the scans add anything
            "anon_mb_streaming_start": _at(series, t_a + 0.2 * span, 2),
            "rss_mb_streaming_start": _at(series, t_a + 0.2 * span, 1),
        }
    row = {
        "minutes": minutes,
        "tour_s": summary["tour"]["duration_s"],
        "laps_planned": world.get("laps"),
        "laps_driven": round(manifest["path_length_m"] / _lap_length_m(args.scenario), 2),
        "path_length_m": manifest["path_length_m"],
        "scans": scans,
        "bag_bytes": bag_bytes,
        "bag_messages": int(sum(manifest["message_counts"].values())),
        "map_cells": cells,
        "map_m2": round(cells * res_m * res_m, 1),
        "observed_m2": round(observed * res_m * res_m, 1),
        "map_size_cells": [w, h],
        "grid_npz_mb": round(grid_bytes / 2**20, 2),
        "peak_rss_mb_main": summary["peak_rss_mb"],
        "peak_rss_mb_workers": workers,
        "peak_rss_mb_sum": round(total, 1),
        "sampled_peak_rss_mb_all_at_once": round(sampler.total_peak_kb / 1024, 1),
        # each process's own high-water mark from /proc (ru_maxrss of a spawned worker can start at its
        # parent's RSS, and a worker's figure in summary.json is taken before it sends its results)
        "vm_hwm_mb_sum": round(sum(p["vm_hwm_mb"] for n, p in procs.items() if not n.startswith("resource_tracker")),
                               1),
        "summary_minus_own_mb": {
            n: round((summary["peak_rss_mb"] if n == "main" else workers[n]) - procs[n]["vm_hwm_mb"], 1)
            for n in ["main", *workers] if n in procs},
        "processes": procs,
        "rss_bytes_per_cell": None,  # below: the processes' own peaks over the map's cells
        "build_s": round(res["elapsed_s"], 2),
        "loop_s": loop_s,
        "scans_per_s": summary["throughput"]["scans_per_s"],
        "host_reference_ms": round(host_ms, 1),
        "simulation": sim,
    }
    row["rss_bytes_per_cell"] = round(row["vm_hwm_mb_sum"] * 2**20 / cells, 1)
    if delete_tours:
        shutil.rmtree(tour)
    return row


# ---------------------------------------------------------------------------------------------
# verdict


def _git_state() -> dict:
    """The commit and the uncommitted changes the benchmark ran on (others may be editing the tree)."""
    import hashlib

    def git(*a: str) -> str:
        return subprocess.run(["git", "-C", str(REPO), *a], capture_output=True, text=True, check=False).stdout

    return {"git_head": git("rev-parse", "HEAD").strip(),
            "git_modified": [ln[3:] for ln in git("status", "--porcelain").splitlines()],
            "git_diff_sha1": hashlib.sha1(git("diff", "HEAD").encode()).hexdigest()}


def _worker_names(rows: list[dict]) -> list[str]:
    order = ["registration", "fusion", "images"]
    names = {k for r in rows for k in r["peak_rss_mb_workers"]}
    return [n for n in order if n in names] + sorted(names - set(order))


def _lstsq(x_cols: list[list[float]], y: list[float]) -> list[float]:
    import numpy as np

    a = np.column_stack([np.ones(len(y))] + [np.asarray(c, float) for c in x_cols])
    coef, *_ = np.linalg.lstsq(a, np.asarray(y, float), rcond=None)
    return [float(c) for c in coef]


def verdict(rows: list[dict], flat_mb: float, flat_fraction: float, map_copies: float) -> dict:
    """Fit each peak-RSS figure against the tour length: peak = a + b * minutes (least squares).

    The tour-length term, b * (longest - shortest minutes), is what the longest tour costs over the
    shortest. The map's share of it is bounded by ``map_copies`` times the change of the map's own bytes
    (the grid layers as grid.npz holds them): the fusion worker's grid and its snapshot, the pickled
    hand-over, the main process's copy, its cleaning and cropping. A figure is flat when its term, less
    the map's share, stays under the larger of ``flat_mb`` and ``flat_fraction`` of the shortest tour's
    figure. Memory is flat when the sum of the processes' own peaks, the peak of all processes at the same
    moment, and each process's own peak are all flat. summary.json's figures (ru_maxrss) are judged
    the same way and reported, but not used: a spawned worker's ru_maxrss starts at its parent's RSS
    at the spawn, and the workers read theirs before sending their results.
    """
    if len(rows) < 2:
        return {"flat": None, "reason": "one tour: nothing to compare"}
    rows = sorted(rows, key=lambda r: r["minutes"])
    mins = [r["minutes"] for r in rows]
    span = mins[-1] - mins[0]
    ds = rows[-1]["scans"] - rows[0]["scans"]
    map_share = max(0.0, map_copies * (rows[-1]["grid_npz_mb"] - rows[0]["grid_npz_mb"]))

    def fit(y: list[float]) -> dict:
        a, b = _lstsq([mins], y)
        term = b * span
        limit = max(flat_mb, flat_fraction * y[0])
        beyond = term - map_share
        return {"mb_per_minute": round(b, 3), "intercept_mb": round(a, 1), "tour_length_term_mb": round(term, 1),
                "bytes_per_scan": round(term * 2**20 / ds, 1) if ds > 0 else None, "values_mb": y,
                "beyond_map_mb": round(beyond, 1), "limit_mb": round(limit, 1), "flat": abs(beyond) <= limit}

    tests = {"sum of own peaks": fit([r["vm_hwm_mb_sum"] for r in rows]),
             "all processes at the same moment (sampled)": fit([r["sampled_peak_rss_mb_all_at_once"] for r in rows])}
    for n in ["main"] + _worker_names(rows):
        hwm = [r["processes"].get(n, {}).get("vm_hwm_mb") for r in rows]
        if all(v is not None for v in hwm):
            tests[f"{n}, own peak"] = fit(hwm)
    reported = {"sum, summary.json": fit([r["peak_rss_mb_sum"] for r in rows])}
    for n in ["main"] + _worker_names(rows):
        summ = [r["peak_rss_mb_main"] if n == "main" else r["peak_rss_mb_workers"].get(n) for r in rows]
        if all(v is not None for v in summ):
            reported[f"{n}, summary.json"] = fit(summ)
    flat = all(t["flat"] for t in tests.values())
    grown = [f"{k} {t['beyond_map_mb']:+.1f} MB (limit {t['limit_mb']:.1f})" for k, t in tests.items() if not t["flat"]]
    reason = (f"from {mins[0]:g} to {mins[-1]:g} min the map's growth explains at most {map_share:.1f} MB "
              f"({map_copies:g} copies of its layers); beyond that, " +
              (", ".join(grown) + " grow more than the limit" if grown else
               "every figure stays within its limit (the larger of "
               f"{flat_mb:g} MB and {100 * flat_fraction:g} % of the shortest tour's figure)"))
    return {"model": "peak RSS = a + b * minutes", "map_copies": map_copies, "map_share_mb": round(map_share, 1),
            "tests": tests, "summary_json": reported, "flat": flat, "reason": reason}


# ---------------------------------------------------------------------------------------------


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", nargs="+", type=float, default=[5.0, 15.0, 30.0])
    ap.add_argument("--scenario", default="ward", help="a built-in scenario whose route closes into laps "
                                                         "(ward; office's way back to its start hits a pillar)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--format", default="ros1", choices=["ros1", "mcap", "sqlite3"])
    ap.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "semmap-long-tour",
                    help="results (long_tour.json, long_tour.md) and the map folders")
    ap.add_argument("--tours", type=Path, help="cache of simulated tours: reused when their settings match, and "
                                                 "kept (default: OUT/tours, deleted after each build)")
    ap.add_argument("--keep", action="store_true", help="keep the simulated tours (a few GB)")
    ap.add_argument("--sample-interval", type=float, default=0.1, help="seconds between RSS samples")
    ap.add_argument("--flat-mb", type=float, default=25.0)
    ap.add_argument("--flat-fraction", type=float, default=0.05)
    ap.add_argument("--map-copies", type=float, default=8.0,
                    help="copies of the map's layers the build may hold at its peak (the map's allowance)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    tours = args.tours if args.tours is not None else args.out / "tours"
    tours.mkdir(parents=True, exist_ok=True)
    maps = args.out / "maps"
    maps.mkdir(exist_ok=True)
    delete = args.tours is None and not args.keep
    free_gb = shutil.disk_usage(tours).free / 1e9
    need_gb = 1.9e-3 * max(args.minutes) * 60 if delete else 1.9e-3 * sum(args.minutes) * 60
    if free_gb < need_gb + 1:
        ap.error(f"{tours}: {free_gb:.1f} GB free, the tours need about {need_gb:.1f} GB")

    started = datetime.now(timezone.utc).astimezone()
    rows = []
    for m in sorted(args.minutes):
        rows.append(measure(m, args, tours, maps, delete))
        r = rows[-1]
        print(f"  {m:g} min: {r['scans']} scans, peak RSS {r['peak_rss_mb_sum']:.0f} MB (sum), "
              f"{r['sampled_peak_rss_mb_all_at_once']:.0f} MB (sampled, all at once), build {r['build_s']:.1f} s",
              file=sys.stderr, flush=True)
    v = verdict(rows, args.flat_mb, args.flat_fraction, args.map_copies)
    mach = machine()
    names = _worker_names(rows)
    procs = ["main", *names]
    lines = [f"`semmap build` on long tours ({args.scenario}, seed {args.seed}, {args.format}; build defaults, "
             f"workers on), {started.strftime('%Y-%m-%d %H:%M %Z')}",
             f"machine: {mach}", "",
             "| tour | laps driven | scans | bag (GB) | bag messages | map (cells) | map (m²) | observed (m²) | "
             "build (s) | scans/s | host reference (ms) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        w, h = r["map_size_cells"]
        lines.append(f"| {r['minutes']:g} min ({r['tour_s']:.0f} s) | {r['laps_driven']:.1f} | {r['scans']} | "
                     f"{r['bag_bytes'] / 1e9:.2f} | {r['bag_messages']} | {r['map_cells']} ({w}×{h}) | "
                     f"{r['map_m2']:.0f} | "
                     f"{r['observed_m2']:.0f} | {r['build_s']:.1f} | {r['scans_per_s']:.0f} | "
                     f"{r['host_reference_ms']:.1f} |")
    lines += ["", "Peak RSS (MB): as summary.json gives it (each process's ru_maxrss), and each process's own "
                  "high-water mark (VmHWM, read as it exits); the peak of all processes at the same moment (sampled "
                  "every 0.1 s); the own peaks per map cell:", "",
              "| tour | " + " | ".join(f"{n} (summary)" for n in procs) + " | sum (summary) | "
              + " | ".join(f"{n} (own)" for n in procs) + " | sum (own) | all at once (sampled) | "
              "bytes per map cell (own) |",
              "|---|" + "---:|" * (2 * len(procs) + 4)]
    for r in rows:
        summ = [r["peak_rss_mb_main"]] + [r["peak_rss_mb_workers"].get(n, float("nan")) for n in names]
        own = [r["processes"].get(n, {}).get("vm_hwm_mb", float("nan")) for n in procs]
        lines.append(f"| {r['minutes']:g} min | " + " | ".join(f"{x:.1f}" for x in summ)
                     + f" | {r['peak_rss_mb_sum']:.1f} | " + " | ".join(f"{x:.1f}" for x in own)
                     + f" | {r['vm_hwm_mb_sum']:.1f} | {r['sampled_peak_rss_mb_all_at_once']:.1f} | "
                       f"{r['rss_bytes_per_cell']:.0f} |")
    lines += ["", "Per process (sampled from /proc every 0.1 s): anonymous and file-backed pages at its sampled "
                  "peak; growth: least-squares slope of its RSS while the scans stream (the middle 60 % of the "
                  "time the workers live), per scan:", "",
              "| tour | process | own peak (MB) | anon at peak (MB) | file at peak (MB) | "
              "anon early in streaming (MB) | RSS growth (B/scan) | anon growth (B/scan) |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        for n, p in r["processes"].items():
            if n.startswith("resource_tracker"):
                continue
            g = "" if p["growth_bytes_per_scan"] is None else f"{p['growth_bytes_per_scan']:+.0f}"
            ga = "" if p["anon_growth_bytes_per_scan"] is None else f"{p['anon_growth_bytes_per_scan']:+.0f}"
            early = "" if p["anon_mb_streaming_start"] is None else f"{p['anon_mb_streaming_start']:.1f}"
            lines.append(f"| {r['minutes']:g} min | {n} | {p['vm_hwm_mb']:.1f} | {p['anon_mb_at_peak']:.1f} | "
                         f"{p['file_mb_at_peak']:.1f} | {early} | {g} | {ga} |")
    if v.get("flat") is not None:
        lines += ["", f"Fit of each figure against the tour length ({v['model']}); the term is what the longest tour "
                      "costs over the shortest:", "",
                  "| figure | values (MB) | MB per minute of tour | tour-length term (MB) | bytes per scan | "
                  "beyond the map (MB) | limit (MB) | flat |",
                  "|---|---|---:|---:|---:|---:|---:|---|"]
        figs = list(v["tests"].items()) + list(v["summary_json"].items())
        for n, f in figs:
            bps = f.get("bytes_per_scan")
            vals = " / ".join(f"{x:.1f}" for x in f["values_mb"])
            lines.append(f"| {n} | {vals} | {f['mb_per_minute']:+.3f} | {f['tour_length_term_mb']:+.1f} | "
                         f"{'' if bps is None else f'{bps:+.0f}'} | {f['beyond_map_mb']:+.1f} | {f['limit_mb']:.1f} | "
                         f"{'yes' if f['flat'] else '**no**'} |")
        lines += ["", "(summary.json's figures are shown but not judged: they are each process's own VmHWM since "
                      "2026-11-23; before, a spawned worker's ru_maxrss started at its parent's RSS at the spawn.)", "",
                  f"Verdict: memory is {'FLAT' if v['flat'] else 'NOT flat'} apart from the map: {v['reason']}."]
    text = "\n".join(lines)
    print(text)
    (args.out / "long_tour.md").write_text(text + "\n")
    (args.out / "long_tour.json").write_text(json.dumps({
        "date": started.isoformat(timespec="seconds"), "machine": mach, "scenario": args.scenario,
        "seed": args.seed, "format": args.format, "sim_config": SIM_CONFIG, "build_config": "defaults",
        **_git_state(),
        "tours": rows, "verdict": v}, indent=2))
    print(f"\nwritten: {args.out / 'long_tour.md'}, {args.out / 'long_tour.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
