"""Painting: project scans into the camera, look up labels, map classes to mobility."""
