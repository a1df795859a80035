"""`semmap diff` from the command line on real map folders: the diff folder, the change mask as
nav2's map_server loads it (mode raw), the updated map, a plain map_server map, and bad input."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
import yaml
from conftest import wait_until_catches

import semmap
from semmap.cli.main import main
from semmap.errors import AlignmentError, MapFolderError
from semmap.io.mapserver import read_map


def nav2_raw(yaml_path):
    """A mode-raw map as nav2's map_io loads it: shade = grey / 255, value = round(shade * 255) when
    0 <= value <= 100 else -1 (unknown); image row 0 is the grid's top row."""
    meta = yaml.safe_load(yaml_path.read_text())
    assert meta["mode"] == "raw"
    img = cv2.imread(str(yaml_path.parent / meta["image"]), cv2.IMREAD_UNCHANGED).astype(np.float64)
    value = np.round(img / 255.0 * 255.0)
    grid = np.where((value >= 0) & (value <= 100), value, -1).astype(np.int8)
    return meta, np.flipud(grid)


@pytest.fixture(scope="module")
def changed(demo_map, tmp_path_factory):
    """The demo map as a plain map_server map with a new 60 cm x 40 cm obstacle on free floor."""
    d = tmp_path_factory.mktemp("changed")
    m = read_map(demo_map.out / "map.yaml")
    occ = m.occupied.copy()
    free = m.free.copy()
    dist = cv2.distanceTransform((~occ & free).astype(np.uint8), cv2.DIST_L2, 5)
    r, c = np.unravel_index(int(np.argmax(dist)), dist.shape)  # the most open spot
    occ[r - 4:r + 4, c - 6:c + 6] = True
    from semmap.io.mapserver import write_map

    write_map(d / "map.yaml", m.spec, occ, known=occ | free)
    xy = (m.spec.origin_x + (c + 0.5) * m.spec.resolution, m.spec.origin_y + (r + 0.5) * m.spec.resolution)
    return d / "map.yaml", xy


def test_diff_against_a_plain_map_finds_the_new_obstacle_and_writes_every_file(demo_map, changed, tmp_path, capsys):
    b_yaml, where = changed
    out, upd = tmp_path / "diff", tmp_path / "updated"
    assert main(["diff", str(demo_map.out), str(b_yaml), "--out", str(out), "--update", str(upd)]) == 0
    text = capsys.readouterr().out
    assert "geometric diff only" in text and "1 new static obstacle" in text
    assert {p.name for p in out.iterdir()} == {"changes.json", "changes.png", "changes.yaml", "overlay.png",
                                             "report.md"}
    data = json.loads((out / "changes.json").read_text())
    assert data["semantic"] is False and data["counts"]["static_added"] == 1
    assert sum(data["counts"].values()) == 1  # nothing else: the same map, the same cells
    (c,) = data["changes"]
    assert np.hypot(c["centroid"][0] - where[0], c["centroid"][1] - where[1]) < 0.1
    assert c["area_m2"] == pytest.approx(0.6 * 0.4, rel=0.2)
    assert np.allclose(data["alignment"]["T_a_b"], 0.0, atol=0.02)  # the same map: no motion
    # the mask, read as nav2 reads it: A's grid, resolution and origin; 1 on the obstacle, 0 elsewhere
    meta, grid = nav2_raw(out / "changes.yaml")
    a = read_map(demo_map.out / "map.yaml")
    assert grid.shape == a.spec.shape and meta["resolution"] == a.spec.resolution
    assert meta["origin"][:2] == [a.spec.origin_x, a.spec.origin_y]
    rows, cols = np.nonzero(grid == 1)
    assert 0.8 * 96 <= rows.size <= 96 and not (grid == 2).any() and not (grid < 0).any()
    assert abs(a.spec.origin_x + (cols.mean() + 0.5) * a.spec.resolution - where[0]) < 0.1
    # the updated map: the demo map with the obstacle, read back by load_map and as map_server does
    m = semmap.load_map(upd)
    assert m.occupied[rows, cols].all() and m.occupied.sum() == a.occupied.sum() + rows.size
    assert json.loads((upd / "update.json").read_text())["cells_added"] == rows.size
    again = semmap.diff(upd, b_yaml)
    assert sum(again.counts().values()) == 0


@pytest.mark.parametrize("mode", ["raw", "scale"])
def test_a_plain_map_saved_in_another_mode_diffs_as_its_trinary_twin(demo_map, changed, tmp_path, mode):
    """The changed map saved as other tools' savers may write it: ``raw`` (the pixel is the occupancy: 0 free,
    100 occupied, 255 unknown) or ``scale`` with unknown cells transparent. The diff finds the same one new
    obstacle; read as trinary pixels, a raw map's free floor (0, black) would be one large obstacle."""
    b = read_map(changed[0])
    img = np.where(b.occupied, 100, np.where(b.free, 0, 255)).astype(np.uint8)
    if mode == "scale":
        grey = np.where(b.occupied, 0, 254).astype(np.uint8)
        img = np.dstack([grey, grey, grey, np.where(b.unknown, 0, 255).astype(np.uint8)])
    d = tmp_path / mode
    d.mkdir()
    assert cv2.imwrite(str(d / "map.png"), np.flipud(img))
    s = b.spec
    (d / "map.yaml").write_text(f"image: map.png\nmode: {mode}\nresolution: {s.resolution}\n"
                                f"origin: [{s.origin_x}, {s.origin_y}, 0.0]\nnegate: 0\n"
                                "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    again = read_map(d / "map.yaml")
    assert np.array_equal(again.occupied, b.occupied) and np.array_equal(again.free, b.free)
    r = semmap.diff(demo_map.out, d / "map.yaml")
    assert r.counts()["static_added"] == 1 and sum(r.counts().values()) == 1


def test_bad_input_is_one_line_and_leaves_nothing(demo_map, changed, tmp_path, capsys):
    out = tmp_path / "diff"
    assert main(["diff", str(demo_map.out), str(tmp_path / "nowhere"), "--out", str(out)]) == MapFolderError.exit_code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0] and not out.exists()
    # an empty map cannot be aligned: exit 8, one line, no folder
    empty = tmp_path / "empty"
    empty.mkdir()
    m = read_map(changed[0])
    from semmap.io.mapserver import write_map

    write_map(empty / "map.yaml", m.spec, np.zeros(m.spec.shape, bool), known=m.free)
    assert main(["diff", str(demo_map.out), str(empty), "--out", str(out)]) == AlignmentError.exit_code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "too few to align" in err[0] and not out.exists()
    # --update needs a semmap map folder as A
    assert main(["diff", str(changed[0]), str(demo_map.out), "--out", str(out), "--update",
                 str(tmp_path / "u")]) == 2
    assert "--update needs session A" in capsys.readouterr().err
    assert not (tmp_path / "u").exists() and not out.exists()
    # an existing --out without --force
    out.mkdir()
    assert main(["diff", str(demo_map.out), str(changed[0]), "--out", str(out)]) == 4
    assert "already exists" in capsys.readouterr().err


def test_a_copy_of_a_map_folder_has_no_changes(demo_map, tmp_path):
    b = tmp_path / "b"
    shutil.copytree(demo_map.out, b)
    r = semmap.diff(demo_map.out, b)
    assert r.semantic and sum(r.counts().values()) == 0 and not r.mask.any()
    assert r.alignment.inlier_fraction > 0.98 and np.allclose(r.alignment.T_a_b, 0.0, atol=0.02)


def test_the_diff_knows_which_object_holds_each_movable_cell_as_the_build_grouped_them(demo_map, tmp_path):
    from semmap.compare.session import open_session

    s = open_session(demo_map.out)
    assert s.objects and s.object_index is not None
    idx = s.object_index
    assert set(np.unique(idx[s.semi_static]).tolist()) <= set(range(len(s.objects)))
    assert (idx[~s.semi_static] == -1).all()
    for k, o in enumerate(s.objects):  # each object's cells are its own: their count and centre
        rows, cols = np.nonzero(idx == k)
        assert rows.size == o.n_cells
        cx = s.spec.origin_x + (cols.mean() + 0.5) * s.spec.resolution
        cy = s.spec.origin_y + (rows.mean() + 0.5) * s.spec.resolution
        assert abs(cx - o.centroid[0]) < 1e-3 and abs(cy - o.centroid[1]) < 1e-3
    # listed in another order (two objects whose centroids tie in y come out of the build's uncropped
    # grid in the order its last bits give): the same grouping, each cell on its listed object
    b = tmp_path / "reordered"
    shutil.copytree(demo_map.out, b)
    objs = json.loads((b / "semi_static_objects.json").read_text())
    objs["objects"] = objs["objects"][::-1]
    (b / "semi_static_objects.json").write_text(json.dumps(objs))
    s2 = open_session(b)
    assert s2.object_index is not None and len(s.objects) >= 2
    n = len(s.objects)
    assert np.array_equal(s2.object_index, np.where(idx >= 0, n - 1 - idx, -1))
    # an object list edited by hand is not the build's: no grouping, the boxes decide
    b = tmp_path / "edited"
    shutil.copytree(demo_map.out, b)
    objs = json.loads((b / "semi_static_objects.json").read_text())
    objs["objects"] = objs["objects"][1:]
    (b / "semi_static_objects.json").write_text(json.dumps(objs))
    assert open_session(b).object_index is None


def test_three_sessions_give_a_history_folder(demo_map, changed, tmp_path, capsys):
    out = tmp_path / "history"
    assert main(["diff", str(demo_map.out), str(changed[0]), str(demo_map.out), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "change history of 3 sessions" in text
    h = json.loads((out / "history.json").read_text())
    assert [s["counts"]["static_added"] for s in h["steps"]] == [1, 0]
    assert [s["counts"]["static_removed"] for s in h["steps"]] == [0, 1]  # the obstacle is gone again
    (place,) = h["places"]
    assert len(place["changed_in"]) == 2 and (out / "history.md").is_file()
    assert len(list((out / "steps").iterdir())) == 2
    assert main(["diff", str(demo_map.out), str(changed[0]), str(demo_map.out), "--out", str(tmp_path / "x"),
                 "--update", str(tmp_path / "u")]) == 2
    assert "--update takes two sessions" in capsys.readouterr().err


@pytest.mark.parametrize("stage", ["semmap.compare.write._overlay", "semmap.compare.update._picture"])
def test_an_interruption_while_writing_leaves_no_folder(demo_map, changed, tmp_path, monkeypatch, capsys, stage):
    """Ctrl-C (or SIGTERM, raised the same way) while the diff folder or the updated map is being
    written: no output folder, no hidden partial folder, and the signal's exit code."""
    module, name = stage.rsplit(".", 1)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(module + "." + name, interrupted)
    out, upd = tmp_path / "diff", tmp_path / "updated"
    code = main(["diff", str(demo_map.out), str(changed[0]), "--out", str(out), "--update", str(upd)])
    assert code == 130
    assert not out.exists() and not upd.exists()
    assert not list(tmp_path.glob(".*partial*")), "a hidden partial folder was left"


def _big_floor(path, size_m=60.0, seed=3):
    """A floor of rooms of random sizes, with doors and furniture legs, as a map_server map."""
    from semmap.io.mapserver import write_map
    from semmap.records import GridSpec

    rng = np.random.default_rng(seed)
    n = int(size_m / 0.05)
    occ = np.zeros((n, n), np.uint8)
    xs = np.r_[(np.cumsum(np.r_[0, rng.uniform(5, 11, 20)]) / 0.05).astype(int), n - 3]
    xs = xs[xs < n]
    for x in xs:
        cv2.line(occ, (int(x), 0), (int(x), n - 1), 1, 3)
        cv2.line(occ, (0, int(x)), (n - 1, int(x)), 1, 3)
        for k in range(0, n, 200):
            occ[int(x) - 2:int(x) + 3, k + 40:k + 58] = 0  # doors
    for _ in range(300):
        r, c = rng.integers(20, n - 20, 2)
        occ[r, c] = 1
    write_map(path, GridSpec(0.05, 0.0, 0.0, n, n), occ > 0)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_during_a_long_diff_leaves_a_whole_folder_or_none(tmp_path, sig):
    """SIGTERM or Ctrl-C while two 60 m floors are compared: the command ends promptly, with the
    signal's exit code and one line, or (had it already finished) exit 0 and a whole folder; never
    a partial folder, and no process left."""
    _big_floor(tmp_path / "a.yaml")
    _big_floor(tmp_path / "b.yaml")
    out = tmp_path / "diff"
    proc = subprocess.Popen([sys.executable, "-m", "semmap", "diff", str(tmp_path / "a.yaml"),
                             str(tmp_path / "b.yaml"), "--out", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    # semmap's main() running (it catches SIGTERM from then on): on a loaded machine the imports take seconds
    wait_until_catches(proc.pid, signal.SIGTERM)
    time.sleep(1.0)  # the imports, then the alignment
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail("semmap diff did not end within 30 s of the signal")
    assert not list(tmp_path.glob(".*partial*")), "a hidden partial folder was left"
    if proc.returncode == 0:  # it had finished: the folder is whole
        assert (out / "changes.json").is_file() and (out / "overlay.png").is_file()
    else:
        assert proc.returncode == 128 + int(sig) and not out.exists()
        lines = err.strip().splitlines()
        assert len(lines) == 1 and ("terminated" in lines[0] or "interrupted" in lines[0])
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, 0)
        pytest.fail("a process of the diff is still running")


def test_the_overlays_labels_at_one_place_do_not_cover_each_other():
    # two objects gone side by side (two chairs of a ward room): their labels go at different heights
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from semmap.compare.write import _label_placer

    fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
    ax.set_xlim(0, 10)
    ax.set_ylim(0, 10)
    place = _label_placer(ax, fig.dpi)
    offsets = [place((5.0, 5.0), "chair gone", dx=8.0), place((5.1, 5.0), "chair gone", dx=8.0),
               place((5.0, 5.05), "potted plant 1.20 m")]
    heights = [dy for _, dy in offsets]
    assert len(set(heights)) == 3 and min(abs(a - b) for a in heights for b in heights if a != b) >= 9.0
    assert place((1.0, 1.0), "tv 2.29 m") == (4.0, -2.0)  # alone: beside its point
    plt.close(fig)


def test_bare_floor_is_where_many_rays_passed_and_no_beam_ended_in_or_beside_the_cell(demo_map):
    from semmap.compare.session import BARE_MIN_PASSES, open_session

    s = open_session(demo_map.out)
    g = np.load(demo_map.out / "grid.npz")
    hits, free = g["hits"], g["free"]
    assert s.bare is not None and s.bare.shape == hits.shape and s.bare.any()
    assert (free[s.bare] >= BARE_MIN_PASSES).all()
    # no return in the cell or any of its eight neighbours
    near = np.zeros(hits.shape, bool)
    h = hits > 0
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near |= np.roll(np.roll(h, dr, 0), dc, 1)
    assert not (s.bare & near).any() and not (s.bare & s.occupied).any()
    # and every cell so passed and so clear is bare (the edges aside, where roll wraps)
    clear = (free >= BARE_MIN_PASSES) & ~near
    assert np.array_equal(s.bare[1:-1, 1:-1], clear[1:-1, 1:-1])
    # a plain map_server map has no counts: no bare floor
    assert open_session(demo_map.out / "map.yaml").bare is None
