"""Fusion: a log-odds occupancy grid with class evidence per cell, and its cleaning.

* :class:`SemanticGrid` fuses painted scans (``integrate(pose, scan)``) into
  :class:`GridLayers`: log-odds, hit/free counts, mobility and class evidence.
* :func:`clean` turns the layers into a :class:`CleanedMap`: people dropped, furniture
  flagged semi-static and listed as :class:`SemiStaticObject`.
* :mod:`semmap.grid.metrics` scores maps against ground truth.
"""

from .clean import CleanedMap, SemiStaticObject, clean, evidence_occupancy, group_cells
from .fusion import N_MOBILITY, GridLayers, SemanticGrid

__all__ = ["N_MOBILITY", "CleanedMap", "GridLayers", "SemanticGrid", "SemiStaticObject", "clean", "evidence_occupancy",
           "group_cells"]
