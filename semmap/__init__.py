"""semmap: semantic, cleaned 2D occupancy maps from recorded robot tours.

The public API::

    import semmap
    result = semmap.simulate("demo", "tours/demo", fmt="mcap", seed=0)
    info = semmap.bag_info(result.bag)
    m = semmap.load_map("maps/demo")          # a map folder written by semmap build
    d = semmap.diff("maps/week1", "maps/week2", out="diffs/week2")  # what changed
    r = semmap.run_batch("fleet.yaml", "maps/2026-11-27")           # a fleet's tours, on Ray if installed
    e = semmap.export("maps/demo", "robot/demo", semmap.ExportSettings(crop_margin=0.5))  # maps for a robot

Heavy modules load on first use, so ``import semmap`` stays fast.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from .version import __version__

_LAZY = {
    "build": "semmap.pipeline",
    "load_map": "semmap.mapfolder.reader",
    "diff": "semmap.compare",
    "diff_history": "semmap.compare.history",
    "run_batch": "semmap.batch",
    "BatchResult": "semmap.batch",
    "DiffResult": "semmap.compare",
    "export": "semmap.robotmap",
    "ExportSettings": "semmap.robotmap",
    "ExportResult": "semmap.robotmap",
    "MapEncoding": "semmap.robotmap",
    "MapFolder": "semmap.mapfolder.reader",
    "BuildSummary": "semmap.mapfolder.summary",
    "ScanStream": "semmap.paint.stream",
    "BuildResult": "semmap.pipeline",
    "BuildConfig": "semmap.config",
    "simulate": "semmap.sim.tour",
    "SimulationResult": "semmap.sim.tour",
    "bag_info": "semmap.io.bag",
    "BagInfo": "semmap.io.bag",
    "load_world": "semmap.sim.world",
    "World": "semmap.sim.world",
    "SCENARIOS": "semmap.sim.scenarios",
    "SimConfig": "semmap.config",
    "read_calibration": "semmap.io.calibration",
    "write_calibration": "semmap.io.calibration",
    "read_map": "semmap.io.mapserver",
    "Mobility": "semmap.records",
    "Calibration": "semmap.records",
    "CameraIntrinsics": "semmap.records",
    "SemmapError": "semmap.errors",
}

_RENAMED = {"load_map": "load_map_folder"}

__all__ = ["__version__", *_LAZY]  # noqa: PLE0604 - the lazy names are strings

if TYPE_CHECKING:  # pragma: no cover
    # ruff: noqa: F401
    from .batch import BatchResult, run_batch
    from .compare import DiffResult, diff
    from .compare.history import diff_history
    from .config import BuildConfig, SimConfig
    from .errors import SemmapError
    from .io.bag import BagInfo, bag_info
    from .io.calibration import read_calibration, write_calibration
    from .io.mapserver import read_map
    from .mapfolder.reader import MapFolder
    from .mapfolder.reader import load_map_folder as load_map
    from .mapfolder.summary import BuildSummary
    from .paint.stream import ScanStream
    from .pipeline import BuildResult, build
    from .records import Calibration, CameraIntrinsics, Mobility
    from .robotmap import ExportResult, ExportSettings, MapEncoding, export
    from .sim.scenarios import SCENARIOS
    from .sim.tour import SimulationResult, simulate
    from .sim.world import World, load_world


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'semmap' has no attribute {name!r}")
    value = getattr(import_module(module), _RENAMED.get(name, name))
    globals()[name] = value
    return value
