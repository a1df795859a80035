"""``semmap info``: topics, types, counts, rates and time span of a bag."""

from __future__ import annotations

import argparse
import json
from datetime import datetime, timezone
from pathlib import Path

from ._progress import console


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "info", parents=[common], help="summarise a bag: topics, message types, counts, rates, time span",
        description="Summarise a ROS1 .bag or ROS2 (sqlite3/mcap) bag, or the bag inside a tour folder.",
    )
    p.add_argument("bag", type=Path, metavar="BAG", help="a .bag file, a ROS2 bag folder, or a tour folder")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    p.set_defaults(run=run)


def _time(ns: int | None) -> str:
    if ns is None:
        return "-"
    iso = datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]
    return f"{iso} UTC ({ns / 1e9:.3f})"


def run(args: argparse.Namespace) -> int:
    from ..io.bag import bag_info

    info = bag_info(args.bag)
    if args.json:
        print(json.dumps(info.as_dict(), indent=2))
        return 0
    out = console()
    out.print(f"path:      {info.path}")
    out.print(f"storage:   {info.storage}")
    out.print(f"size:      {info.size_bytes / 1e6:.1f} MB")
    out.print(f"duration:  {info.duration_s:.3f} s")
    out.print(f"start:     {_time(info.start_ns)}")
    out.print(f"end:       {_time(info.end_ns)}")
    out.print(f"messages:  {info.message_count}")
    if info.index_note:
        out.print(f"index:     {info.index_note}", markup=False)
    out.print("topics:")
    width = max((len(t.name) for t in info.topics), default=10)
    for t in info.topics:
        rate = f"{t.rate_hz:8.2f} Hz" if t.rate_hz else "         - "
        out.print(f"  {t.name:<{width}}  {t.count:>7} msgs {rate}  {t.msgtype}")
    return 0
