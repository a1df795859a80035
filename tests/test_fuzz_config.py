"""Mutated build configs and calibration files: a clear one-line error or a valid object, never a traceback.

Valid files (docs/build.md's build config, the calibration.yaml ``semmap simulate`` writes) are
mutated at the YAML level (keys dropped, values replaced by NaN, inf, huge, negative or zero
numbers, strings, wrong-length lists, unknown keys, extra nesting) and at the byte level (bytes
flipped, inserted, deleted, the file truncated). Every case must end in a valid object or a
:class:`~semmap.errors.SemmapError` whose message is one line naming the file. A few fixed cases
run through ``semmap build`` in-process: exit codes 0-5 (never 70, an internal error), one
stderr line, and no map folder when it fails.
"""

from __future__ import annotations

import copy
import math
import signal
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from semmap.config import BuildConfig
from semmap.errors import ConfigError, SemmapError
from semmap.grid.fusion import check_grid_memory
from semmap.io.calibration import read_calibration
from semmap.io.tour import load_build_config
from semmap.records import Calibration

# docs/build.md's example (section "Configuration"), with workers off
README_CONFIG = """\
topics:
  scan: /front/scan              # null: detect
  labels: /camera/labels         # label images (mono8/mono16) for the 'topic' backend
  odometry: /wheel/odom          # 'none': build without odometry
frames:
  base: base_link                # default: the odometry's child frame
  base_T_lidar: {xyz: [0.38, 0.23, 0.2], rpy: [0, 0, 0.785]}   # only if the bag has no /tf_static
calibration: calibration.yaml    # relative to this file
segmentation:
  backend: topic                 # label images recorded in the bag
  class_list: coco               # the names of the label values (config/classes.yaml)
sync:
  max_image_offset: 0.1          # s: pair each scan with the nearest image within this
  motion_compensation: true      # move the scan to the image time through odometry
  deskew: true                   # undo the motion during the sweep
registration:
  mode: fused                    # fused | icp | odometry
  voxel_size: 0.15
  max_range: 20.0
grid:
  resolution: 0.05
cleaning:
  dynamic_fraction: 0.3          # drop a cell when this share of its labelled hits was dynamic
  semi_static_fraction: 0.5
workers: false                   # everything in one process
"""


def fuzz(n: int):
    return settings(deadline=None, derandomize=True, max_examples=n, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                           HealthCheck.data_too_large])


@pytest.fixture(scope="module")
def tour(tmp_path_factory, short_demo_world):
    """A 3 s simulated tour (ROS1 bag) and the calibration.yaml the simulator writes beside it."""
    from semmap.sim.tour import simulate

    out = tmp_path_factory.mktemp("fuzz_tour") / "demo"
    return simulate(replace(short_demo_world, duration_s=3.0), out, fmt="ros1", seed=3).out


@pytest.fixture(scope="module")
def calibration_text(tour) -> str:
    return (tour / "calibration.yaml").read_text(encoding="utf-8")


@contextmanager
def time_limit(seconds: int):
    """Fail instead of hanging."""
    def alarm(signum, frame):
        raise TimeoutError(f"no answer within {seconds} s")
    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def outcome(fn, path: Path) -> Any:
    """``fn(path)``, or None when it raised a SemmapError with a one-line message naming the file.
    Any other exception fails the test."""
    with time_limit(20):
        try:
            return fn(path)
        except SemmapError as exc:
            msg = str(exc)
            assert "\n" not in msg.strip(), f"a multi-line error: {msg!r}"
            assert str(path) in msg, f"the error does not name the file: {msg!r}"
            assert "Traceback" not in msg
            return None


# ---------------------------------------------------------------------------------------
# mutations


NASTY = st.sampled_from([
    math.nan, math.inf, -math.inf, -1, -1.0, 0, 0.0, 1e-300, 1e300, -1e300, 10**30, 2**64, 1, 7, 0.5,
    True, False, None, "", "abc", "1.5", "nan", ".inf", "~/nowhere", "\x00", [], {}, [1, 2, 3], [[1, 2], [3]],
    {"a": 1}, [math.nan] * 5, [0.0] * 4, [0.0] * 9,
])


def nodes(tree: Any, path: tuple = ()) -> list[tuple]:
    """Every path into a tree of dicts and lists (the root is ``()``)."""
    out = [path]
    if isinstance(tree, dict):
        for k, v in tree.items():
            out += nodes(v, path + (k,))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out += nodes(v, path + (i,))
    return out


def get(tree: Any, path: tuple) -> Any:
    for k in path:
        tree = tree[k]
    return tree


@st.composite
def yaml_mutations(draw, text: str) -> str:
    """1-3 structural mutations of a YAML mapping, dumped back to YAML."""
    tree = yaml.safe_load(text)  # a fresh tree: mutations work in place
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in nodes(tree) if p]
        path = draw(st.sampled_from(paths))
        parent, key = get(tree, path[:-1]), path[-1]
        op = draw(st.sampled_from(["drop", "replace", "replace", "replace", "unknown", "nest", "wrap", "grow",
                                   "shrink", "stringify", "scale"]))
        value = parent[key]
        if op == "drop":
            del parent[key]
        elif op == "replace":
            parent[key] = copy.deepcopy(draw(NASTY))
        elif op == "unknown":
            target = value if isinstance(value, dict) else parent if isinstance(parent, dict) else tree
            target[draw(st.sampled_from(["extra", "resolutoin", "K2", "0", "intrinsics"]))] = copy.deepcopy(draw(NASTY))
        elif op == "nest":
            parent[key] = {"value": value}
        elif op == "wrap":
            parent[key] = [value]
        elif op == "grow":
            parent[key] = (value + [value[-1] if value else 0.0]) if isinstance(value, list) else [value, value]
        elif op == "shrink":
            parent[key] = value[:-1] if isinstance(value, list) else []
        elif op == "stringify":
            parent[key] = str(value)
        elif op == "scale":  # a number off by a unit: mm for m, deg for rad, ns for s
            factor = draw(st.sampled_from([1e-9, 1e-3, -1.0, 57.3, 1e3, 1e9]))
            parent[key] = value * factor if isinstance(value, int | float) and not isinstance(value, bool) else value
    return yaml.safe_dump(tree, sort_keys=False)


@st.composite
def byte_mutations(draw, text: str) -> bytes:
    """1-4 byte-level edits: flips, insertions, deletions, a truncation."""
    data = bytearray(text.encode("utf-8"))
    for _ in range(draw(st.integers(1, 4))):
        if not data:
            break
        i = draw(st.integers(0, len(data) - 1))
        op = draw(st.sampled_from(["flip", "flip", "insert", "delete", "truncate", "duplicate_line"]))
        if op == "flip":
            data[i] ^= draw(st.integers(1, 255))
        elif op == "insert":
            data[i:i] = draw(st.sampled_from([b":", b"-", b"[", b"]", b"{", b"\t", b" ", b"\n", b"#", b"'", b"\"",
                                              b"&a", b"*a", b"!!python/object", b"1e999", b".nan", b"\x00"]))
        elif op == "delete":
            del data[i:i + draw(st.integers(1, 40))]
        elif op == "truncate":
            del data[i:]
        else:
            start = data.rfind(b"\n", 0, i) + 1
            end = data.find(b"\n", i)
            end = len(data) if end < 0 else end + 1
            data[end:end] = data[start:end]
    return bytes(data)


def valid_calibration(calib: Calibration) -> None:
    intr = calib.intrinsics
    assert intr.width > 0 and intr.height > 0
    assert np.isfinite(intr.K).all() and np.isfinite(intr.D).all() and np.isfinite(calib.T_cam_lidar).all()
    assert np.linalg.norm(calib.T_cam_lidar[:3, 3]) <= 10.0


def finite_numbers(tree: Any) -> bool:
    if isinstance(tree, dict):
        return all(finite_numbers(v) for v in tree.values())
    if isinstance(tree, list | tuple):
        return all(finite_numbers(v) for v in tree)
    return not isinstance(tree, float) or math.isfinite(tree)


def valid_config(result: tuple[BuildConfig, Path]) -> None:
    cfg, base = result
    assert isinstance(cfg, BuildConfig) and isinstance(base, Path)
    assert finite_numbers(cfg.model_dump())
    g = cfg.grid
    assert g.resolution > 0 and g.l_min < 0 < g.l_max and g.l_max - g.l_min <= 65.535
    # the grid the config asks for is either affordable or refused with the estimate, never a crash
    try:
        check_grid_memory(g, cfg.registration.max_range, 80)
    except ConfigError as exc:
        assert "\n" not in str(exc) and "grid." in str(exc)


# ---------------------------------------------------------------------------------------
# loading


@fuzz(150)
@given(data=st.data())
def test_mutated_calibration_files_load_or_fail_with_one_line(tmp_path, calibration_text, data):
    path = tmp_path / "calibration.yaml"
    path.write_text(data.draw(yaml_mutations(calibration_text)), encoding="utf-8")
    calib = outcome(read_calibration, path)
    if calib is not None:
        valid_calibration(calib)


@fuzz(150)
@given(data=st.data())
def test_corrupted_calibration_files_load_or_fail_with_one_line(tmp_path, calibration_text, data):
    path = tmp_path / "calibration.yaml"
    path.write_bytes(data.draw(byte_mutations(calibration_text)))
    calib = outcome(read_calibration, path)
    if calib is not None:
        valid_calibration(calib)


@fuzz(150)
@given(data=st.data())
def test_mutated_build_configs_load_or_fail_with_one_line(tmp_path, data):
    path = tmp_path / "site.yaml"
    path.write_text(data.draw(yaml_mutations(README_CONFIG)), encoding="utf-8")
    result = outcome(load_build_config, path)
    if result is not None:
        valid_config(result)


@fuzz(150)
@given(data=st.data())
def test_corrupted_build_configs_load_or_fail_with_one_line(tmp_path, data):
    raw = data.draw(byte_mutations(README_CONFIG))
    path = tmp_path / "site.yaml"
    path.write_bytes(raw)
    result = outcome(load_build_config, path)
    if result is not None:
        valid_config(result)


@pytest.mark.parametrize("content", [b"grid:\n  resolution: 0.05\xff\n", b"a: " + b"[" * 5000 + b"]" * 5000 + b"\n"],
                         ids=["not-utf8", "nested-too-deep"])
def test_a_config_that_is_not_yaml_text_is_a_config_error(tmp_path, content):
    path = tmp_path / "site.yaml"
    path.write_bytes(content)
    assert outcome(load_build_config, path) is None


@pytest.mark.parametrize("content", [b"intrinsics:\n  width: 640\xff\n", b"a: " + b"[" * 5000 + b"]" * 5000 + b"\n"],
                         ids=["not-utf8", "nested-too-deep"])
def test_a_calibration_that_is_not_yaml_text_is_a_config_error(tmp_path, content):
    path = tmp_path / "calibration.yaml"
    path.write_bytes(content)
    assert outcome(read_calibration, path) is None


@pytest.mark.parametrize("d", [".nan", ".inf", "-.inf"])
def test_nan_or_inf_in_the_distortion_coefficients_is_refused(tmp_path, calibration_text, d):
    """As K and T_cam_lidar are: NaN in D used to load, and the build painted nothing without a word."""
    data = yaml.safe_load(calibration_text)
    data["intrinsics"]["D"] = [0.0, 0.0, 0.0, 0.0, "X"]
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(data).replace("X", d), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"intrinsics: D contains NaN or inf") as err:
        read_calibration(path)
    assert str(err.value).startswith(str(path))


def test_nan_in_a_ros_camera_info_file_is_refused(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_text("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [600, 0, 320, 0, "
                    "600, 240, 0, 0, 1]}\ndistortion_model: plumb_bob\ndistortion_coefficients: {rows: 1, cols: 5, "
                    "data: [0.1, .nan, 0, 0, 0]}\n", encoding="utf-8")
    from semmap.io.calibration import read_intrinsics

    with pytest.raises(ConfigError, match="D contains NaN or inf"):
        read_intrinsics(path)


# ---------------------------------------------------------------------------------------
# end to end, a few fixed cases


def tour_config(tmp_path: Path, **changes: Any) -> Path:
    """The docs/build.md config pointed at the simulated tour's topics, with ``changes`` ({"grid.resolution": x})."""
    cfg = yaml.safe_load(README_CONFIG)
    cfg["topics"] = {"scan": "/scan", "labels": "/camera/labels", "odometry": "/odom"}
    del cfg["frames"]["base_T_lidar"]
    del cfg["calibration"]
    for key, value in changes.items():
        *parents, leaf = key.split(".")
        node = cfg
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    path = tmp_path / "site.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    return path


def calibration_with(tmp_path: Path, text: str, **changes: Any) -> Path:
    data = yaml.safe_load(text)
    for key, value in changes.items():
        node = data
        *parents, leaf = key.split(".")
        for p in parents:
            node = node[p]
        node[leaf] = value
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


E2E = {
    "valid": ({}, {}, 0, None),
    "nan-distortion": ({}, {"intrinsics.D": [0.0, math.nan, 0.0, 0.0, 0.0]}, 2, "calibration.yaml: intrinsics: D"),
    "inf-resolution": ({"grid.resolution": math.inf}, {}, 2, "site.yaml: grid.resolution"),
    "huge-image-offset": ({"sync.max_image_offset": 1e300}, {}, 2, "site.yaml: sync.max_image_offset"),
    "clamps-overflow-storage": ({"grid.l_max": 100.0}, {}, 2, "site.yaml: grid: "),
}


@pytest.mark.parametrize("case", list(E2E))
def test_semmap_build_ends_in_a_map_or_one_line(tmp_path, tour, calibration_text, capsys, case):
    from semmap.cli.main import main

    cfg_changes, calib_changes, code, message = E2E[case]
    cfg = tour_config(tmp_path, **cfg_changes)
    calib = calibration_with(tmp_path, calibration_text, **calib_changes)
    out = tmp_path / "map"
    with time_limit(120):
        rc = main(["build", str(tour), "--out", str(out), "--config", str(cfg), "--calibration", str(calib), "-q"])
    err = capsys.readouterr().err
    assert rc == code and 0 <= rc <= 5, err
    assert "Traceback" not in err
    if rc == 0:
        assert (out / "map.yaml").is_file()
    else:  # log records (WARNING name: ...) may precede it; the error itself is one line
        lines = [line for line in err.splitlines() if line.strip() and not line.startswith(("WARNING ", "INFO "))]
        assert len(lines) == 1 and lines[0].startswith("semmap build: error: "), err
        assert message in lines[0]
        assert not out.exists()
