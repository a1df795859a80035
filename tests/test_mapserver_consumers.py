"""Every map_server map semmap writes loads in ROS1's map_server and nav2's as semmap meant it.

The loaders' rules are transcribed from their source in ``tests/mapserver_loaders.py``; a map
that passed semmap's own reader once made nav2 load every unknown cell as free.
"""

import json

import numpy as np
import pytest
from mapserver_loaders import RULES, load

from semmap.io.mapserver import FREE_THRESH, OCCUPIED_THRESH, check_trinary_thresholds, read_map, write_map
from semmap.pipeline import build
from semmap.records import GridSpec


@pytest.fixture(scope="module")
def ros1_demo(tmp_path_factory, short_demo_world):
    from semmap.sim.tour import simulate

    return simulate(short_demo_world, tmp_path_factory.mktemp("tour") / "demo", fmt="ros1", seed=5)


@pytest.fixture(scope="module")
def demo_folder(ros1_demo, tmp_path_factory):
    return build(ros1_demo.out, tmp_path_factory.mktemp("maps") / "demo").out


@pytest.mark.parametrize("rule", RULES)
def test_written_map_loads_occupied_free_and_unknown(tmp_path, rule):
    spec = GridSpec(0.05, -1.0, 2.0, 7, 5)
    occupied = np.zeros(spec.shape, bool)
    occupied[1, 2] = occupied[4, 6] = True
    known = np.ones(spec.shape, bool)
    known[0, :] = False
    known[3, 3] = False
    write_map(tmp_path / "m.yaml", spec, occupied, known=known)
    data = load(tmp_path / "m.yaml", rule)
    assert np.array_equal(data == 100, occupied)
    assert np.array_equal(data == 0, known & ~occupied)
    assert np.array_equal(data == -1, ~known)


def test_thresholds_are_map_savers_and_the_old_ones_are_refused():
    check_trinary_thresholds(OCCUPIED_THRESH, FREE_THRESH)
    with pytest.raises(ValueError, match="205 would load as free"):
        check_trinary_thresholds(0.65, 0.25)  # nav2's default: unknown grey becomes free


@pytest.mark.parametrize("rule", RULES)
def test_map_folder_maps_load_as_semmap_meant(demo_folder, rule):
    grid = np.load(demo_folder / "grid.npz")
    summary = json.loads((demo_folder / "summary.json").read_text())["map"]
    cleaned = load(demo_folder / "map.yaml", rule)
    assert np.array_equal(cleaned == 100, grid["occupied"])
    n_free, n_unknown = int((cleaned == 0).sum()), int((cleaned == -1).sum())
    assert n_free == summary["free_cells"]
    assert n_unknown == cleaned.size - summary["occupied_cells"] - summary["free_cells"]
    assert n_unknown > 0.2 * cleaned.size  # the demo's map has unexplored margins all round
    semi = load(demo_folder / "semi_static.yaml", rule)
    assert np.array_equal(semi == 100, grid["semi_static"])
    assert np.array_equal(semi == -1, cleaned == -1)  # the same cells are unknown in both layers
    assert read_map(demo_folder / "map.yaml").unknown.sum() == n_unknown  # semmap's reader agrees


@pytest.mark.parametrize("rule", RULES)
def test_ground_truth_maps_load_as_written(ros1_demo, rule):
    gt = ros1_demo.out / "ground_truth"
    for name in ("occupancy", "static", "semi_static", "people_swept"):
        data = load(gt / f"{name}.yaml", rule)
        assert not (data == -1).any(), name  # the simulator knows every cell
        assert np.array_equal(data == 100, read_map(gt / f"{name}.yaml").occupied), name


def _write_other_tools_map(folder, mode, img, negate=0):
    """A map as another tool's saver may write it: ``img`` (top row first) in ``mode``."""
    import cv2

    name = "m.png"
    assert cv2.imwrite(str(folder / name), img)
    (folder / "m.yaml").write_text(f"image: {name}\nmode: {mode}\nresolution: 0.05\norigin: [-1.0, 2.0, 0.0]\n"
                                   f"negate: {negate}\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return folder / "m.yaml"


@pytest.mark.parametrize("case", ["trinary_alpha", "negate", "scale", "scale_alpha", "raw"])
def test_maps_of_other_tools_read_as_nav2_loads_them(tmp_path, case):
    """``semmap diff`` reads maps from other tools (slam_toolbox, Cartographer, map_saver in any mode):
    semmap's reader calls a cell occupied exactly where nav2 publishes 100 and free where it publishes 0,
    in trinary, scale (in-between values neither) and raw mode (the pixel is the occupancy: 0 free, 100
    occupied, 255 unknown, the rest by the YAML's thresholds), with an alpha channel (not opaque: unknown) and
    with ``negate``."""
    rng = np.random.default_rng(3)
    shape = (9, 13)
    if case == "raw":
        img = rng.choice(np.array([0, 100, 255, 50, 30, 80], np.uint8), size=shape)
        path = _write_other_tools_map(tmp_path, "raw", img)
    else:
        grey = rng.choice(np.array([0, 254, 205, 128, 40, 230], np.uint8), size=shape)
        mode = "scale" if case.startswith("scale") else "trinary"
        if case == "negate":
            grey = 255 - grey
        img = grey
        if case.endswith("alpha"):
            alpha = np.where(rng.random(shape) < 0.3, 0, 255).astype(np.uint8)
            img = np.dstack([grey, grey, grey, alpha])
        path = _write_other_tools_map(tmp_path, mode, img, negate=int(case == "negate"))
    m = read_map(path)
    data = load(path, "nav2")
    if case == "raw":  # nav2 publishes the values as they are: judged by the YAML's thresholds, as trinary
        known = data >= 0
        assert np.array_equal(m.occupied, known & (data / 100 > 0.65))
        assert np.array_equal(m.free, known & (data / 100 < 0.196))
    else:
        assert np.array_equal(m.occupied, data == 100)
        assert np.array_equal(m.free, data == 0)
    assert m.occupied.any() and m.free.any() and m.unknown.any()
    if case == "raw":  # the free floor (0) is no obstacle however black its pixels are
        assert not m.occupied[np.flipud(img) == 0].any()


def test_a_map_in_an_unknown_mode_is_one_error_naming_the_key(tmp_path):
    from semmap.errors import ConfigError

    path = _write_other_tools_map(tmp_path, "ternary", np.zeros((3, 3), np.uint8))
    with pytest.raises(ConfigError, match=r"m\.yaml: mode 'ternary' is not a map_server mode"):
        read_map(path)
