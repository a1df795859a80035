"""``semmap diff``: what changed between two sessions of one building."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._progress import console


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "diff", parents=[common],
        help="compare sessions: what moved, appeared or vanished since the last map",
        description="Align session B's map onto session A's (no initial guess: B's tour may start anywhere, "
                    "facing any way), then report what changed: static obstacles added or removed, movable "
                    "objects moved (with displacement and rotation), appeared or disappeared, and floor "
                    "newly explored or no longer covered. Cells only one session observed are unobserved, "
                    "never changed, and people are never obstacles. Sessions are map folders from "
                    "semmap build, or any map_server map (map.yaml + image, e.g. from slam_toolbox or "
                    "Cartographer), then compared by geometry only.",
    )
    p.add_argument("a", type=Path, metavar="SESSION_A", help="the earlier session: a map folder or a map.yaml")
    p.add_argument("b", type=Path, metavar="SESSION_B", help="the later session")
    p.add_argument("--out", required=True, type=Path, metavar="DIR",
                   help="diff folder to write: changes.json, changes.png/.yaml (mask), overlay.png, report.md")
    p.add_argument("--update", type=Path, metavar="MAP_DIR",
                   help="also write A's map folder with B's changes applied (A's frame and grid, loadable by nav2)")
    p.add_argument("--force", action="store_true", help="replace DIR (and MAP_DIR) if they exist")
    p.add_argument("--tolerance", type=float, default=None, metavar="M",
                   help="obstacles closer than this are the same obstacle (default 0.10 m)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..compare import ChangeSettings, diff
    from ..compare.write import summary_lines
    from ..errors import ConfigError

    st = ChangeSettings()
    if args.tolerance is not None:
        if not args.tolerance >= 0:
            raise ConfigError(f"--tolerance must be 0 or more metres, got {args.tolerance}")
        st = ChangeSettings(tolerance_m=args.tolerance)
    result = diff(args.a, args.b, out=args.out, update=args.update, force=args.force, settings=st)
    if not args.quiet:
        out = console()
        for line in summary_lines(result):
            out.print(line)
        out.print(f"  wrote      {args.out}/ (overlay.png, changes.json, changes.yaml, report.md) in "
                  f"{result.seconds:.1f} s")
        if args.update is not None:
            out.print(f"  updated    {args.update}/: {args.a}'s map with these changes applied")
    return 0
