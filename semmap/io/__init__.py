"""Reading and writing what crosses the file system: bags, maps, calibration."""
