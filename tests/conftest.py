"""Shared fixtures: short simulated tours in every bag format, and the real data folder."""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data() -> Path:
    return Path(os.environ.get("SEMMAP_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def data_dir() -> Path:
    d = shared_data()
    if not d.is_dir():
        pytest.skip(f"real data not found at {d} (set SEMMAP_DATA to ../shared/data)")
    return d


@pytest.fixture(scope="session")
def short_demo_world():
    from semmap.sim.scenarios import demo

    return replace(demo().world, duration_s=8.0)


@pytest.fixture(scope="session", params=["ros1", "mcap", "sqlite3"])
def short_tour(request, tmp_path_factory, short_demo_world):
    """An 8 s demo tour in each bag format."""
    from semmap.sim.tour import simulate

    out = tmp_path_factory.mktemp(f"tour_{request.param}") / "demo"
    return simulate(short_demo_world, out, fmt=request.param, seed=3)


@pytest.fixture(scope="session")
def demo_tour(tmp_path_factory):
    """The full 28 s demo tour (a standing person, a walking one, furniture)."""
    from semmap.sim.tour import simulate

    return simulate("demo", tmp_path_factory.mktemp("tour") / "demo", seed=0)


@pytest.fixture(scope="session")
def demo_map(demo_tour, tmp_path_factory):
    """The demo tour's map folder, built with the default configuration (read it, do not change it)."""
    from semmap.pipeline import build

    return build(demo_tour.out, tmp_path_factory.mktemp("maps") / "demo")


def wait_until_catches(pid: int, sig: int, timeout: float = 30.0) -> None:
    """Wait until process ``pid`` catches ``sig`` (Linux: SigCgt in /proc/PID/status), so a signal sent
    then tests semmap's handling, not how fast a loaded machine starts Python."""
    status = Path(f"/proc/{pid}/status")
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            caught = next(int(line.split()[1], 16) for line in status.read_text().splitlines()
                          if line.startswith("SigCgt:"))
        except (OSError, StopIteration):
            return  # not Linux, or already gone: the plain sleep of the caller stands
        if caught >> (int(sig) - 1) & 1:
            return
        time.sleep(0.05)
