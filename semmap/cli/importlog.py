"""``semmap import carmen``: a CARMEN laser log as a ROS bag that ``semmap build`` reads unchanged."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._progress import console


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser("import", parents=[common], help="convert other recordings into bags semmap reads",
                       description="Convert recordings from other tools into ROS bags that semmap build reads.")
    kinds = p.add_subparsers(dest="kind", metavar="KIND")
    kinds.required = True
    c = kinds.add_parser(
        "carmen", parents=[common], help="a CARMEN laser log (Radish: Intel, Freiburg 101, ...)",
        description="Convert a CARMEN log (FLASER, RLASER, ROBOTLASER1, ODOM; plain or .gz) into a tour folder: "
                    "a ROS bag with /scan, /odom, /tf_static (the laser mount) and, for a corrected log, the "
                    "reference robot poses on /ground_truth/odom and in reference.tum. A corrected log's "
                    "odometry fields hold the reference: the odometry written is the wheel motion between "
                    "scans from its ODOM lines, chained from the origin.")
    c.add_argument("log", type=Path, metavar="LOG", help="the CARMEN log (.log or .log.gz)")
    c.add_argument("--out", required=True, type=Path, metavar="TOUR", help="tour folder to write")
    c.add_argument("--format", dest="fmt", default="ros1", choices=["ros1", "mcap", "sqlite3"],
                   help="bag format (default: ros1)")
    c.add_argument("--force", action="store_true", help="replace TOUR if it holds an earlier import")
    c.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..io.atomic import atomic_dir, check_output
    from ..io.carmen import read_carmen, write_tour

    check_output(args.out, args.force, marker="import.json", inputs=[args.log], what="tour folder")
    log = read_carmen(args.log)
    with atomic_dir(args.out, args.force, marker="import.json", inputs=[args.log], what="tour folder") as tmp:
        s = write_tour(log, Path(tmp), args.fmt)
    if not args.quiet:
        out = console()
        out.print(f"imported {args.log} -> {args.out}/{s['bag']}  ({s['scans']} scans over {s['duration_s']:.0f} s, "
                  f"{s['odom_lines']} ODOM lines)")
        if s["corrected_log"]:
            out.print("  a corrected log: its poses are the reference (/ground_truth/odom, reference.tum); the "
                      "odometry is the wheel motion between scans, not the reference")
        if s["scans_without_odometry_step"]:
            out.print(f"  warning: {s['scans_without_odometry_step']} scans had no ODOM line since the scan before: "
                      f"no odometry message for them")
        out.print(f"  build it:  semmap build {args.out} --out maps/{args.out.name}")
    return 0
