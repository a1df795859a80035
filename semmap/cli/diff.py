"""``semmap diff``: what changed between two sessions of one building."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ._progress import console

if TYPE_CHECKING:
    from ..compare import ChangeSettings


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
    p.add_argument("sessions", type=Path, nargs="+", metavar="SESSION",
                   help="two sessions, earlier first (map folders or map.yaml); with more, a change history: "
                        "each aligned to the first and compared with the one before")
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
    if len(args.sessions) < 2:
        raise ConfigError("give two sessions (A B), or more for a change history")
    if len(args.sessions) > 2:
        return _history(args, st)
    args.a, args.b = args.sessions
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


def _history(args: argparse.Namespace, st: ChangeSettings) -> int:
    from ..compare.history import diff_history, write_history
    from ..compare.write import TYPE_LABELS
    from ..errors import ConfigError
    from ..io.atomic import atomic_dir, check_output

    if args.update is not None:
        raise ConfigError("--update takes two sessions; with more, diff the last two with --update")
    check_output(args.out, args.force, marker="history.json", inputs=args.sessions, what="diff folder")
    h = diff_history(list(args.sessions), settings=st)
    with atomic_dir(args.out, args.force, marker="history.json", inputs=args.sessions, what="diff folder") as tmp:
        write_history(h, tmp)
    if not args.quiet:
        out = console()
        names = h.names
        out.print(f"change history of {len(names)} sessions, in {names[0]}'s map frame:")
        for k, d in enumerate(h.steps):
            shown = [f"{n} {TYPE_LABELS[t]}" for t, n in d.counts().items() if n]
            out.print(f"  {names[k]} -> {names[k + 1]}: " + (", ".join(shown) if shown else "no change"))
        again = [p for p in h.places if len({k for k, _ in p.events}) > 1]
        out.print(f"  {len(h.places)} places changed, {len(again)} of them in more than one session")
        out.print(f"  wrote      {args.out}/ (history.md, history.json, steps/) in {h.seconds:.1f} s")
    return 0
