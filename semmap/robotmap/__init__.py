"""``semmap export``: maps for the robot from a saved session, without rebuilding.

:func:`export` reads a map folder written by ``semmap build`` (its full-fidelity ``grid.npz``)
and writes, into a new folder::

    OUT/
      cleaned.yaml + .pgm       people dropped, furniture kept as obstacles (the build's map)
      static.yaml + .pgm        static structure only: movable furniture is unknown, not obstacle
      raw.yaml + .pgm           the occupancy before cleaning
      semi_static.yaml + .pgm   the cells flagged movable
      class_NAME.yaml + .pgm    one class's cells (``class:NAME`` layers, on request)
      keepout_mask.yaml + .pgm  nav2 KeepoutFilter mask: the floor under movable furniture
      speed_mask.yaml + .png    nav2 SpeedFilter mask: slower near furniture and where people were
      costmap_filters.yaml      nav2 parameters serving both masks
      objects.geojson           the movable objects' footprints (map frame, metres)
      preview.png               the first layer with the masks, a legend and a scale bar
      export.json               settings, grid, the turn from the build's map frame, cell counts

Each map loads in ROS1 ``map_server`` and nav2's with the cells semmap meant as occupied, free and
unknown, in any ``mode`` (trinary, scale, raw), thresholds and ``negate`` (see
:mod:`semmap.robotmap.encode`). Exposed as ``semmap.export``.
"""

from __future__ import annotations

from pathlib import Path

from .encode import FORMATS, MODES, MapEncoding
from .layers import BASE_LAYERS
from .masks import MaskSettings
from .run import ExportResult, ExportSettings, objects_geojson

__all__ = ["BASE_LAYERS", "FORMATS", "MODES", "ExportResult", "ExportSettings", "MapEncoding", "MaskSettings",
           "export", "objects_geojson"]


def export(session: str | Path, out: str | Path, settings: ExportSettings | None = None, *,
           force: bool = False) -> ExportResult:
    """Export the map folder ``session`` into the new folder ``out`` (whole or not at all); ``force``
    replaces an earlier export there."""
    from ..io.atomic import atomic_dir, check_output
    from ..mapfolder.reader import load_map_folder
    from .run import export_session

    st = settings if settings is not None else ExportSettings()
    check_output(out, force, marker="export.json", inputs=[session], what="export folder")
    m = load_map_folder(session)
    with atomic_dir(out, force, marker="export.json", inputs=[session], what="export folder") as tmp:
        result = export_session(m, Path(tmp), st)
    return result
