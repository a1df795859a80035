"""What the benchmark scripts share: a one-line description of the machine they ran on."""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return f"{cpu}, {os.cpu_count()} cores, {mem:.0f} GB RAM, Python {platform.python_version()}"


def host_reference_ms(repeats: int = 5) -> float:
    """How fast the host is right now: the median time (ms) of a fixed workload like a build's.

    Shared and virtual machines slow down by 15-25 % for minutes at a time; timing the same
    work beside each measurement tells a slow spell of the host from a slower program. The
    workload is a scan's worth of raster and array work on two cores' worth of processes'
    memory: a filled polygon, an erosion and float updates over a 400 x 300 window, 200 times.
    """
    import statistics
    import time

    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    grid = rng.standard_normal((1200, 1200)).astype(np.float32)
    angles = np.linspace(-2.3, 2.3, 541)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for k in range(200):
            r0, c0 = (k * 37) % 800, (k * 53) % 800
            lo = grid[r0:r0 + 300, c0:c0 + 400]
            ranges = 100 + 90 * np.abs(np.sin(3 * angles + k))
            verts = np.column_stack([200 + ranges * np.cos(angles), 150 + ranges * np.sin(angles)]).astype(np.int32)
            scratch = np.zeros((300, 400), np.uint8)
            cv2.fillPoly(scratch, [verts], 1)
            scratch = cv2.erode(scratch, np.ones((3, 3), np.uint8))
            cv2.scaleAdd(scratch.astype(np.float32), -0.4, lo, dst=lo)
            cv2.max(lo, -2.0, dst=lo)
        times.append((time.perf_counter() - t0) * 1000)
    return statistics.median(times)


def add_set_argument(ap: argparse.ArgumentParser) -> None:
    """``--set JSON``: config overrides for every build of a benchmark (``args.set``, a dict)."""

    def overrides(text: str) -> dict:
        value = json.loads(text)
        if not isinstance(value, dict):
            raise argparse.ArgumentTypeError("--set takes a JSON object, e.g. '{\"registration\": {...}}'")
        return value

    ap.add_argument("--set", type=overrides, default={}, metavar="JSON",
                    help='config overrides for every build, e.g. \'{"registration": {"refine": {"enabled": true}}}\'')
