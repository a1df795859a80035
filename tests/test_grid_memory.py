"""Refusing absurd grid memory before the work starts (semmap.grid.fusion.check_grid_memory).

The estimate is checked against what a real SemanticGrid allocates (its layers' nbytes, and the
peak numpy allocations traced while it integrates its first scan and grows once).
"""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

from semmap.config import GridConfig
from semmap.errors import ConfigError
from semmap.grid import SemanticGrid
from semmap.grid.fusion import check_grid_memory, estimate_grid_memory
from semmap.records import PaintedScan

GIB = 2**30
NAMES = ("person", "chair", "table", "bed", "plant")


def ring_scan(radius: float, n: int = 1440) -> PaintedScan:
    """A 360 deg scan with every return at ``radius``, each class seen: the largest first window."""
    a = np.linspace(-math.pi, math.pi, n, endpoint=False)
    pts = radius * np.column_stack([np.cos(a), np.sin(a)])
    return PaintedScan(0, np.zeros(2), pts, np.ones(n, bool), np.full(n, 2), np.arange(n) % len(NAMES), NAMES)


def test_the_estimate_bounds_what_a_grid_allocates_for_its_first_scan_and_one_growth_step():
    """The estimate is an upper bound (the worst alignment of a scan's box on the tiles, every class
    in every tile) and not a loose one; moving on allocates new tiles and copies nothing."""
    cfg = GridConfig(resolution=0.05, tile_margin=10.0, max_range=20.0)
    reach = 12.0
    est = estimate_grid_memory(cfg, reach, len(NAMES))
    grid = SemanticGrid(cfg, NAMES)
    scan = ring_scan(reach)
    tracemalloc.start()  # numpy reports its array buffers to tracemalloc
    try:
        base = tracemalloc.get_traced_memory()[0]
        grid.integrate(np.zeros(3), scan)
        first_peak = tracemalloc.get_traced_memory()[1] - base
        first_bytes, first_tiles = grid.nbytes, grid.n_tiles
        # past a corner of the first tiles: new ones are added, nothing is copied
        tracemalloc.reset_peak()
        step = cfg.tile_margin + 0.5
        grid.integrate(np.array([step, step, 0.0]), scan)
        grow_peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert grid.n_tiles > first_tiles
    assert 0.4 < first_bytes / est.first_window_bytes <= 1.0  # the layers alone
    assert first_peak <= est.first_window_bytes + est.scratch_bytes
    # growing holds the layers and the new tiles, the scratch rasters and the scan's own arrays: nothing
    # near a second copy of the grid (a window grown by copying held both, twice this)
    assert grow_peak - grid.nbytes < 0.25 * grid.nbytes
    assert max(first_peak, grow_peak) <= est.peak_bytes


def test_a_normal_grid_passes_and_returns_its_estimate():
    cfg = GridConfig()  # 5 cm
    need = check_grid_memory(cfg, 30.0, 80, available_bytes=4 * GIB)
    assert need == int(estimate_grid_memory(cfg, 30.0, 80).peak_bytes)
    assert 100 * 2**20 < need < 2 * GIB  # a 30 m LiDAR and 80 COCO classes at 5 cm: under a GiB
    assert check_grid_memory(cfg, 30.0, 80) == need  # and it fits this machine (half its memory)


def test_an_absurd_resolution_is_refused_with_the_estimate_before_any_allocation():
    cfg = GridConfig(resolution=0.0001)
    peak = 0
    with pytest.raises(ConfigError) as err:
        tracemalloc.start()
        try:
            check_grid_memory(cfg, 20.0, 80, available_bytes=16 * GIB)
        finally:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    assert peak < 2**20  # refused from arithmetic, not from a failed allocation
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("grid.resolution 0.0001 m")
    assert "first 60 m x 60 m window needs 78.1 TiB" in msg  # 7 x 7 tiles of 100k cells a side, 174 bytes each
    assert "more than the 16 GiB available" in msg
    assert "coarser grid.resolution (0.05 m is typical)" in msg


def test_by_default_the_limit_is_half_of_this_machines_memory():
    with pytest.raises(ConfigError, match=r"more than the [\d.]+ [GT]iB it may use \(half of this "
                                          r"(machine|container)'s [\d.]+ [GT]iB\)"):
        check_grid_memory(GridConfig(resolution=0.0001), 20.0, 80)


@pytest.mark.parametrize("settings, advice", [
    ({"tile_margin": 1e300}, "smaller grid.tile_margin"),
    ({"resolution": 1e-300}, "coarser grid.resolution"),
    ({"tile_margin": 5000.0}, "smaller grid.tile_margin"),
])
def test_settings_that_overflow_any_machine_are_refused_without_overflowing(settings, advice):
    with pytest.raises(ConfigError, match=advice) as err:
        check_grid_memory(GridConfig(**settings), 20.0, 80)
    assert "\n" not in str(err.value)


def test_a_lidar_without_a_range_limit_counts_the_free_space_range():
    cfg = GridConfig(max_range=10.0)
    assert estimate_grid_memory(cfg, math.inf, 3) == estimate_grid_memory(cfg, 10.0, 3)


def test_a_pose_jump_that_would_grow_the_grid_beyond_memory_is_a_clear_error():
    """One wild pose (odometry jumping a thousand kilometres) must not ask for terabytes: one error naming it."""
    from semmap.errors import SemmapError

    grid = SemanticGrid(GridConfig(), ())
    n = 90
    a = np.linspace(-np.pi, np.pi, n, endpoint=False)
    scan = PaintedScan(0, np.zeros(2), np.column_stack([3 * np.cos(a), 3 * np.sin(a)]), np.ones(n, bool),
                       np.ones(n, np.uint8), np.full(n, -1, np.int16))
    grid.integrate(np.zeros(3), scan)
    with pytest.raises(SemmapError, match=r"m from the area mapped so far would grow the grid.*pose jumped"):
        grid.integrate(np.array([1e6, 0.0, 0.0]), scan)
    assert grid.layers().spec.width < 1000  # the grid is as it was
