"""semmap export: every mode, threshold, negate and transform, read back as map_server reads it.

The exported maps are read with ``tests/mapserver_loaders.py`` (ROS1 map_server, nav2 since 2025 and
nav2 before it, each transcribed from its source), never with semmap's own reader.
"""

import json
import math
import signal

import cv2
import numpy as np
import pytest
import yaml
from mapserver_loaders import RULES, load
from scipy.spatial import cKDTree

import semmap
from semmap.cli.main import main
from semmap.errors import ConfigError
from semmap.geometry import se2_apply, se2_inverse
from semmap.records import GridSpec
from semmap.robotmap import ExportSettings, MapEncoding, MaskSettings
from semmap.robotmap.geometry import dominant_direction
from semmap.robotmap.layers import layer_plane


@pytest.fixture(scope="module")
def folder(demo_map):
    return demo_map.out


@pytest.fixture(scope="module")
def session(folder):
    return semmap.load_map(folder)


def _export(folder, tmp_path, name, **kw):
    out = tmp_path / name
    enc = kw.pop("encoding", MapEncoding())
    r = semmap.export(folder, out, ExportSettings(encoding=enc, **kw))
    return out, r


ENCODINGS = [
    MapEncoding(),
    MapEncoding(negate=True),
    MapEncoding(image_format="png"),
    MapEncoding(occupied_thresh=0.5, free_thresh=0.3),
    MapEncoding(occupied_thresh=0.9, free_thresh=0.05, negate=True, image_format="png"),
    MapEncoding(mode="scale", image_format="png"),
    MapEncoding(mode="scale", image_format="png", negate=True, occupied_thresh=0.8, free_thresh=0.1),
    MapEncoding(mode="raw"),
    MapEncoding(mode="raw", image_format="png"),
]


@pytest.mark.parametrize("enc", ENCODINGS, ids=lambda e: f"{e.mode}-{e.image_format}-n{int(e.negate)}-"
                                                        f"{e.occupied_thresh}-{e.free_thresh}")
def test_every_mode_loads_occupied_free_and_unknown_as_meant(folder, session, tmp_path, enc):
    out, _ = _export(folder, tmp_path, "e", encoding=enc, masks=False)
    for name in ("cleaned", "static", "raw", "semi_static"):
        plane, _ = layer_plane(session, name)
        observed = np.isfinite(plane.prob)
        undecided = plane.unknown & observed
        for rule in RULES:
            data = load(out / f"{name}.yaml", rule)
            assert np.array_equal(data == 100, plane.occupied), (name, rule)
            assert np.array_equal(data == 0, plane.free), (name, rule)
            if enc.mode == "trinary":
                assert np.array_equal(data == -1, plane.unknown), (name, rule)
            else:  # scale and raw keep the probability of observed cells left undecided
                assert np.array_equal(data == -1, plane.unknown & ~observed), (name, rule)
                v = data[undecided].astype(int)
                assert ((v >= 1) & (v <= 99)).all(), (name, rule, np.unique(v))
    # the cleaned layer is the build's map: the same cells as map.yaml, in every loader
    for rule in RULES:
        built = load(folder / "map.yaml", rule)
        data = load(out / "cleaned.yaml", rule)
        assert np.array_equal(built == 100, data == 100) and np.array_equal(built == 0, data == 0)


def test_scale_mode_keeps_the_probability_of_undecided_cells(folder, session, tmp_path):
    out, _ = _export(folder, tmp_path, "s", encoding=MapEncoding(mode="scale", image_format="png"), masks=False,
                     layers=("raw",))
    plane, _ = layer_plane(session, "raw")
    und = plane.unknown & np.isfinite(plane.prob)
    assert und.sum() >= 5  # the demo has a few cells the evidence left undecided
    data = load(out / "raw.yaml", "nav2").astype(float)
    # nav2's value is 100 (p - free) / (occ - free): the probability comes back within one grey level
    p_back = 0.196 + data[und] / 100.0 * (0.65 - 0.196)
    p = np.clip(plane.prob[und], 0.2, 0.645)
    assert np.abs(p_back - p).max() < 0.01
    # the image itself is RGBA with never-observed cells transparent, as nav2's saver writes them
    img = cv2.imread(str(out / "raw.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape[2] == 4
    assert np.array_equal(np.flipud(img[..., 3]) == 0, plane.unknown & ~np.isfinite(plane.prob))


def test_raw_mode_writes_percent_and_unknown_255(folder, session, tmp_path):
    out, _ = _export(folder, tmp_path, "r", encoding=MapEncoding(mode="raw"), masks=False, layers=("cleaned",))
    img = np.flipud(cv2.imread(str(out / "cleaned.pgm"), cv2.IMREAD_UNCHANGED))
    plane, _ = layer_plane(session, "cleaned")
    assert (img[plane.occupied] == 100).all() and (img[plane.free] == 0).all()
    assert (img[plane.unknown & ~np.isfinite(plane.prob)] == 255).all()


@pytest.mark.parametrize("kw, message", [
    (dict(occupied_thresh=0.3, free_thresh=0.5), "free_thresh < occupied_thresh"),
    (dict(occupied_thresh=0.501, free_thresh=0.5), "no grey level loads as unknown"),
    (dict(occupied_thresh=1.0, free_thresh=0.2), "no grey level loads as occupied"),
    (dict(mode="scale"), "needs PNG"),
    (dict(mode="raw", negate=True), "negate does not apply to mode raw"),
    (dict(mode="bitmap"), "mode must be one of"),
])
def test_settings_no_map_server_could_load_alike_are_refused(kw, message):
    with pytest.raises(ConfigError, match=message):
        MapEncoding(**kw)


def _occupied_centres(yaml_path, rule="nav2"):
    """World (x, y) of every occupied cell of a map, from its YAML as map_server reads it."""
    doc = yaml.safe_load(yaml_path.read_text())
    data = load(yaml_path, rule)
    res, (ox, oy, yaw) = float(doc["resolution"]), doc["origin"]
    assert yaw == 0.0
    spec = GridSpec(res, float(ox), float(oy), data.shape[1], data.shape[0])
    r, c = np.nonzero(data == 100)
    return spec, data, np.stack([ox + (c + 0.5) * res, oy + (r + 0.5) * res], axis=1)


@pytest.mark.parametrize("kw", [
    dict(resolution=0.10), dict(resolution=0.025), dict(resolution=0.07), dict(crop_margin=0.3),
    dict(rotate_deg=30.0), dict(rotate_deg=-63.5, crop_margin=0.2, resolution=0.08), dict(straighten=True),
], ids=lambda kw: ",".join(f"{k}={v}" for k, v in kw.items()))
def test_obstacles_keep_their_world_coordinates_through_every_transform(folder, tmp_path, kw):
    out, r = _export(folder, tmp_path, "g", layers=("cleaned",), **kw)
    src_spec, src, src_xy = _occupied_centres(folder / "map.yaml")
    spec, data, xy = _occupied_centres(out / "cleaned.yaml")
    T = np.asarray(json.loads((out / "export.json").read_text())["T_export_build"])
    assert np.allclose(T, r.T_export_build)
    # every obstacle of the build's map is an obstacle at its place in the export
    moved = se2_apply(T, src_xy)
    rc = spec.world_to_cell(moved)
    inside = (rc[:, 0] >= 0) & (rc[:, 0] < spec.height) & (rc[:, 1] >= 0) & (rc[:, 1] < spec.width)
    assert inside.all()
    assert (data[rc[:, 0], rc[:, 1]] == 100).all()
    # and every obstacle of the export was one in the build's map, within a cell of either grid
    back = se2_apply(se2_inverse(T), xy)
    d, _ = cKDTree(src_xy).query(back)
    assert d.max() <= (spec.resolution + src_spec.resolution) * math.sqrt(0.5) + 1e-6
    # free floor in the export is free floor in the build's map under its centre
    fr, fc = np.nonzero(data == 0)
    centres = np.stack([spec.origin_x + (fc + 0.5) * spec.resolution, spec.origin_y + (fr + 0.5) * spec.resolution],
                       axis=1)
    sr, sc = np.nonzero(src == 0)
    src_free = np.stack([src_spec.origin_x + (sc + 0.5) * src_spec.resolution,
                         src_spec.origin_y + (sr + 0.5) * src_spec.resolution], axis=1)
    d, _ = cKDTree(src_free).query(se2_apply(se2_inverse(T), centres))
    assert d.max() <= src_spec.resolution * math.sqrt(0.5) + 1e-6  # the source cell under it (a tie: one of them)
    if kw.get("crop_margin") is not None and "rotate_deg" not in kw:
        known = np.argwhere(data != -1)
        m = int(math.ceil(kw["crop_margin"] / spec.resolution))
        assert known[:, 0].min() == m and known[:, 1].min() == m  # the margin, in whole cells
    if kw.get("straighten"):
        assert float(T[2]) == 0.0  # the demo's walls already run along the axes: no turn, no resampling


@pytest.mark.parametrize("turn_deg", [17.0, -38.0, 4.0])
def test_straighten_finds_the_walls_direction(turn_deg):
    spec = GridSpec(0.05, -10.0, -10.0, 400, 400)
    img = np.zeros(spec.shape, np.uint8)
    a = math.radians(turn_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    for poly in ([(-6, -4), (6, -4), (6, 4), (-6, 4)], [(0, -4), (0, 1)], [(-6, 0), (-2, 0)]):
        pts = (np.array(poly, float) @ rot.T - [spec.origin_x, spec.origin_y]) / spec.resolution
        cv2.polylines(img, [np.round(pts).astype(np.int32)], len(poly) > 2, 1, 1)
    got = math.degrees(dominant_direction(img > 0, spec))
    assert abs(got + turn_deg) < 0.3 or abs(abs(got + turn_deg) - 90) < 0.3


def test_masks_for_nav2(folder, session, tmp_path):
    out, _ = _export(folder, tmp_path, "m", layers=("cleaned",),
                     mask_settings=MaskSettings(speed_near_furniture=50, speed_near_people=30))
    keep = load(out / "keepout_mask.yaml", "nav2")
    assert set(np.unique(keep).tolist()) == {0, 100}
    spec = session.cleaned.spec
    for o in session.cleaned.objects:  # the floor under every movable object is kept out
        r_, c_ = spec.world_to_cell(np.asarray([o.centroid]))[0]
        assert keep[r_, c_] == 100, o.class_name
    assert (keep[session.cleaned.static & ~session.cleaned.semi_static] == 0).mean() > 0.9  # walls are not keepout
    speed = load(out / "speed_mask.yaml", "nav2")
    assert set(np.unique(speed).tolist()) <= {0, 30, 50}
    people = session.cleaned.dynamic_removed
    assert people.any() and (speed[people] == 30).all()  # where people were seen: 30 % of max speed
    semi = session.cleaned.semi_static
    assert (speed[semi & ~people] > 0).all()
    params = yaml.safe_load((out / "costmap_filters.yaml").read_text())
    info = params["speed_costmap_filter_info_server"]["ros__parameters"]
    assert (info["type"], info["base"], info["multiplier"]) == (1, 0.0, 1.0)  # the value is the per cent
    assert params["keepout_costmap_filter_info_server"]["ros__parameters"]["type"] == 0
    assert params["keepout_filter_mask_server"]["ros__parameters"]["yaml_filename"] == "keepout_mask.yaml"
    costmap = params["global_costmap"]["global_costmap"]["ros__parameters"]
    assert costmap["filters"] == ["keepout_filter", "speed_filter"]
    assert costmap["speed_filter"]["plugin"] == "nav2_costmap_2d::SpeedFilter"


def test_objects_geojson(folder, session, tmp_path):
    out, _ = _export(folder, tmp_path, "j", layers=("cleaned",), rotate_deg=90.0)
    doc = json.loads((out / "objects.geojson").read_text())
    assert doc["type"] == "FeatureCollection" and doc["frame_id"] == "map"
    objs = session.cleaned.objects
    assert len(doc["features"]) == len(objs) > 0
    for f, o in zip(doc["features"], objs, strict=True):
        ring = np.asarray(f["geometry"]["coordinates"][0])
        assert f["geometry"]["type"] == "Polygon" and np.array_equal(ring[0], ring[-1])
        x, y = ring[:-1, 0], ring[:-1, 1]
        assert np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y) > 0  # counter-clockwise (RFC 7946)
        assert f["properties"]["class"] == o.class_name
        # turned by 90 degrees with the map: (x, y) -> (-y, x)
        assert np.allclose(f["properties"]["centroid"], [-o.centroid[1], o.centroid[0]], atol=2e-3)


def test_class_layer(folder, session, tmp_path):
    names = session.layers.class_names
    seen = [names[k] for k in session.layers.class_ids if names[k] not in ("person", "wall")]
    cls = seen[0]
    out, r = _export(folder, tmp_path, "c", layers=(f"class:{cls}",), masks=False)
    data = load(out / f"class_{cls.replace(' ', '_')}.yaml", "ros1")
    assert (data == 100).sum() == r.counts[f"class:{cls}"]["occupied"] > 0
    assert ((data == 100) <= session.layers.observed).all()
    with pytest.raises(ConfigError, match="no class 'unicorn'"):
        _export(folder, tmp_path, "c2", layers=("class:unicorn",))
    assert not (tmp_path / "c2").exists()


def test_cli_export(folder, tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["export", str(folder), "--out", str(out), "--crop", "--straighten"]) == 0
    text = capsys.readouterr().out
    assert "exported" in text and "cleaned" in text and "keepout_mask" in text
    assert (out / "preview.png").is_file() and (out / "export.json").is_file()
    assert main(["export", str(folder), "--out", str(out)]) != 0  # exists: no --force
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(out) in err


@pytest.mark.parametrize("args, message", [
    (["--mode", "scale", "--format", "pgm"], "needs PNG"),
    (["--mode", "raw", "--negate"], "negate does not apply"),
    (["--layer", "walls"], "unknown layer"),
    (["--free-thresh", "0.7"], "free_thresh < occupied_thresh"),
    (["--resolution", "0"], "--resolution"),
    (["--straighten", "--rotate", "10"], "give one"),
    (["--speed-near-people", "120"], "per cent"),
])
def test_cli_bad_settings_one_line_no_folder(folder, tmp_path, capsys, args, message):
    out = tmp_path / "bad"
    assert main(["export", str(folder), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob(".bad*"))


def test_cli_not_a_map_folder(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["export", str(tmp_path / "empty"), "--out", str(tmp_path / "o")]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "summary.json" in err
    assert not (tmp_path / "o").exists()


def test_interrupted_export_leaves_no_folder(folder, tmp_path, monkeypatch):
    import semmap.robotmap.run as run_mod

    calls = []
    real = run_mod.write_layer

    def interrupted(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            signal.raise_signal(signal.SIGINT)
        return real(*a, **k)

    monkeypatch.setattr(run_mod, "write_layer", interrupted)
    # Ctrl-C as Python maps it by default; a runner started in the background (`cmd &` in a script)
    # inherits SIGINT ignored, and then no signal would arrive
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            semmap.export(folder, tmp_path / "x")
    finally:
        signal.signal(signal.SIGINT, old)
    assert not (tmp_path / "x").exists() and not list(tmp_path.iterdir())


def _big_session(demo_folder, path, tiles=6):
    """The demo's map folder tiled ``tiles`` x ``tiles`` times: a floor of ~3.5 M cells whose export takes
    seconds, for the signal tests."""
    import shutil

    shutil.copytree(demo_folder, path)
    with np.load(path / "grid.npz", allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    shape = data["occupied"].shape
    for k, v in data.items():
        if v.ndim == 2 and v.shape == shape:
            data[k] = np.tile(v, (tiles, tiles))
        elif v.ndim == 3 and v.shape[1:] == shape:
            data[k] = np.tile(v, (1, tiles, tiles))
    data["sightings"] = np.zeros((0, 4), np.int32)
    np.savez_compressed(path / "grid.npz", **data)
    img = cv2.imread(str(path / "map.pgm"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path / "map.pgm"), np.tile(img, (tiles, tiles)))


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_during_a_long_export_leaves_a_whole_folder_or_none(folder, tmp_path, sig):
    """SIGTERM or Ctrl-C while a big session is exported: the command ends promptly with the signal's
    exit code and one line, or (had it finished) exit 0 and a whole folder; never a partial folder,
    and no process left."""
    import contextlib
    import os
    import subprocess
    import sys
    import time

    from conftest import wait_until_catches

    big = tmp_path / "big"
    _big_session(folder, big)
    out = tmp_path / "exp"
    proc = subprocess.Popen([sys.executable, "-m", "semmap", "export", str(big), "--out", str(out), "--straighten",
                             "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    wait_until_catches(proc.pid, signal.SIGTERM)  # semmap's main() running: the imports are done
    time.sleep(1.5)  # reading the session, then the layers
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail("semmap export did not end within 30 s of the signal")
    assert not list(tmp_path.glob(".*partial*")), "a hidden partial folder was left"
    if proc.returncode == 0:
        assert (out / "export.json").is_file() and (out / "preview.png").is_file()
    else:
        assert proc.returncode == 128 + int(sig) and not out.exists(), err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and ("terminated" in lines[0] or "interrupted" in lines[0])
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, 0)
        pytest.fail("a process of the export is still running")


@pytest.mark.parametrize("kw", [dict(resolution=0.08), dict(crop_margin=0.3), dict(rotate_deg=30.0),
                                dict(straighten=True, crop_margin=0.2, resolution=0.1)],
                         ids=lambda kw: ",".join(f"{k}={v}" for k, v in kw.items()))
def test_every_mode_gives_the_same_cells_after_a_transform(folder, tmp_path, kw):
    """Scale and raw maps carry the same obstacles and floor as the trinary map through every transform."""
    got = {}
    for enc in (MapEncoding(), MapEncoding(mode="scale", image_format="png"), MapEncoding(mode="raw"),
                MapEncoding(negate=True, image_format="png")):
        out, _ = _export(folder, tmp_path, f"{enc.mode}{int(enc.negate)}", encoding=enc, masks=False,
                         layers=("cleaned", "static"), **kw)
        for rule in RULES:
            for name in ("cleaned", "static"):
                data = load(out / f"{name}.yaml", rule)
                got.setdefault((rule, name), []).append((data == 100, data == 0))
    for (rule, name), runs in got.items():
        occ0, free0 = runs[0]
        assert occ0.any() and free0.any()
        for occ, free in runs[1:]:
            assert np.array_equal(occ, occ0) and np.array_equal(free, free0), (rule, name)
