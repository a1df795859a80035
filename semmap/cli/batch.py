"""``semmap batch``: every tour of a manifest built, diffed against its previous session, and reported."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ._progress import console


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "batch", parents=[common],
        help="build a fleet's tours from a manifest, diff each against its previous session, report",
        description="Build every tour listed in MANIFEST (sites, tours, configs, calibrations, previous "
                    "sessions) into DIR/<site>/maps/<tour>, diff each against its previous session into "
                    "DIR/<site>/diffs/<tour>, and write DIR/report.md and DIR/report.json. Runs on Ray when it "
                    "is installed (pip install 'semmap[fleet]'): on this machine, or on the cluster given by "
                    "--address; otherwise one tour after another in this process. Run it again with the same "
                    "DIR to resume: maps that are up to date are kept, failed tours are tried again. Exit "
                    "status 1 when a tour failed (its error is in the report).",
    )
    p.add_argument("manifest", type=Path, metavar="MANIFEST", help="the manifest (YAML)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (new, or an earlier "
                                                                          "batch's to resume it)")
    p.add_argument("--address", metavar="ADDR", help="a Ray cluster: 'auto' (the one this machine is in) or "
                                                     "ray://HEAD:10001 (default: start Ray here)")
    p.add_argument("--workers", type=int, metavar="N", help="jobs at once on a local Ray (default: one per core)")
    p.add_argument("--cpus-per-job", type=float, default=1.0, metavar="C",
                   help="cores Ray reserves for each build (default 1; a build runs 2-3 processes)")
    p.add_argument("--gpus-per-job", type=float, default=0.0, metavar="G",
                   help="GPUs Ray reserves for each build, so that builds running a model go to GPU nodes "
                        "(default 0)")
    p.add_argument("--gpus-per-segment", type=float, default=0.0, metavar="G",
                   help="segment each tour whose config runs a model in a Ray task of its own asking for G GPUs, "
                        "then build it from those labels in a task asking for none (default 0: the model runs in "
                        "the build)")
    p.add_argument("--gpus", type=float, metavar="N", dest="local_gpus",
                   help="GPUs the local Ray offers (default: those it detects)")
    p.add_argument("--engine", choices=("auto", "ray", "local"), default="auto",
                   help="ray, local (one tour after another in this process), or auto: ray when installed")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..batch import run_batch

    out = console(stderr=True)
    quiet = args.quiet

    def on_event(kind: str, row: dict[str, Any], done: int, running: int, failed: int, total: int) -> None:
        if quiet:
            return
        res = row.get(kind) or {}
        status = res.get("status", "?")
        secs = res.get("seconds")
        took = f" in {secs:.1f} s" if isinstance(secs, int | float) else ""
        err = f": {res.get('error')}" if res.get("error") else ""
        waiting = total - done - running
        out.print(f"[{done}/{total}] {kind} {row['key']} {status}{took}{err}  ({running} running, "
                  f"{waiting} waiting, {failed} failed)")

    result = run_batch(args.manifest, args.out, address=args.address, workers=args.workers, engine=args.engine,
                       cpus_per_job=args.cpus_per_job, gpus_per_job=args.gpus_per_job,
                       gpus_per_segment=args.gpus_per_segment, local_gpus=args.local_gpus, on_event=on_event)
    if not quiet:
        _print_summary(result)
    if result.failed:
        print(f"semmap batch: {len(result.failed)} of {len(result.rows)} tours failed: "
              f"{', '.join(result.failed)} (see {result.report_md})", file=sys.stderr)
        return 1
    return 0


def _print_summary(result: Any) -> None:
    out = console()
    from ..batch.runner import ray_available

    if result.engine == "ray":
        how = "Ray" + (f" at {result.address}" if result.address else " on this machine")
    else:
        how = "one process" + ("" if ray_available() else " (Ray is not installed)")
    built = sum(1 for r in result.rows if r["build"].get("status") == "built")
    kept = sum(1 for r in result.rows if r["build"].get("status") == "up to date")
    diffs = sum(1 for r in result.rows if (r.get("diff") or {}).get("status") == "done")
    out.print(f"[bold]semmap batch[/bold]: {len(result.rows)} tours in {result.seconds:.1f} s with {how}: "
              f"{built} built, {kept} up to date, {len(result.failed)} failed; {diffs} diffs")
    out.print(f"  report     {result.report_md}")
