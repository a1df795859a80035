"""``semmap simulate``: write a simulated tour as a real bag with ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._progress import console, progress_bar


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    from ..sim.scenarios import SCENARIOS

    p = sub.add_parser(
        "simulate", parents=[common],
        help="simulate an indoor tour and write it as a ROS1/ROS2 bag with ground truth",
        description="Simulate a robot tour (2D LiDAR, RGB camera with label images, wheel odometry, /tf) "
                    "and write it as a real bag plus exact ground truth and preview pictures.",
        epilog=f"built-in scenarios: {', '.join(SCENARIOS)}; random:SEED (e.g. random:7) builds a new random "
               f"world per seed: rooms, furniture, people and sensor rig",
    )
    p.add_argument("--scenario", metavar="NAME|random:SEED|WORLD.yaml",
                   help="a built-in scenario, random:SEED for a procedural world, or a world file "
                        "(e.g. ground_truth/world.yaml of an earlier run)")
    p.add_argument("--out", type=Path, metavar="PATH", help="output folder (must not exist)")
    p.add_argument("--list-scenarios", action="store_true", help="list the built-in scenarios and exit")
    p.add_argument("--format", dest="fmt", default="ros1", choices=["ros1", "mcap", "sqlite3"],
                   help="bag format: ROS1 .bag, or ROS2 with mcap or sqlite3 storage (default: ros1)")
    p.add_argument("--seed", type=int, default=0, help="noise seed; the same seed gives the same bag (default: 0)")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="YAML overriding simulator settings (sensor mounts, rates, noise, topics, frames)")
    p.add_argument("--force", action="store_true", help="replace PATH if it exists")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..errors import ConfigError
    from ..io.bag import bag_info
    from ..sim.scenarios import SCENARIOS
    from ..sim.tour import simulate

    if args.list_scenarios:
        for name, factory in SCENARIOS.items():
            print(f"{name:<10} {factory().world.description}")
        print(f"{'random:N':<10} a procedural world for every whole number N: 3-7 rooms, furniture against the "
              f"walls, people standing, pausing, pacing and guiding, a random sensor rig")
        return 0
    if args.scenario is None or args.out is None:
        raise ConfigError("--scenario and --out are required (or use --list-scenarios)")

    with progress_bar(f"simulating {args.scenario}", enabled=not args.quiet) as progress:
        result = simulate(args.scenario, args.out, fmt=args.fmt, seed=args.seed, config=args.config,
                          force=args.force, progress=progress)
    if args.quiet:
        return 0
    out = console()
    info = bag_info(result.bag)
    out.print(f"[bold]semmap simulate[/bold]: {result.scenario} (seed {result.seed}) → {result.out}")
    out.print(f"  bag        {result.bag}  ({info.storage}, {info.size_bytes / 1e6:.1f} MB, "
              f"{info.duration_s:.1f} s)")
    for t in info.topics:
        rate = f"{t.rate_hz:6.1f} Hz" if t.rate_hz else "       -"
        out.print(f"    {t.name:<24} {t.count:>6} msgs {rate}  {t.msgtype}")
    out.print(f"  truth      {result.out / 'ground_truth'}  (world, maps, trajectory, beams)")
    out.print(f"  calibration {result.out / 'calibration.yaml'}")
    out.print(f"  pictures   {result.out / 'preview' / 'world.png'}, {result.out / 'preview' / 'camera.png'}")
    out.print(f"  took {result.elapsed_s:.1f} s")
    return 0
