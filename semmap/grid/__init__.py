"""Fusion: a log-odds occupancy grid with class evidence per cell, and its cleaning."""
