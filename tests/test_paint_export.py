"""`semmap paint`: every beam of a tour painted without and with the occlusion filter, and Fig. 6."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from semmap.cli.main import main
from semmap.errors import OutputExistsError
from semmap.io.bag import message_count
from semmap.paint.export import EXPORT_COLUMNS, export_painted
from semmap.paint.figure import ImagePicker
from semmap.records import Mobility

# the demo tour's LiDAR: 270° at 0.5° is 541 beams
BEAMS = 541


@pytest.fixture(scope="module")
def exported(tmp_path_factory, short_demo_world):
    """The 8 s demo tour (ROS1) exported to NPZ through the library, with two pickers watching."""
    from semmap.sim.tour import simulate

    tour = simulate(short_demo_world, tmp_path_factory.mktemp("tour") / "demo", seed=3)
    out = tmp_path_factory.mktemp("paint") / "painted.npz"
    seen: list[tuple[int, int, int | None]] = []  # scan stamp, relabelled, image stamp
    most, at = ImagePicker(), ImagePicker(at=0)

    def watch(pair):
        seen.append((pair.scan.stamp_ns, pair.relabelled, None if pair.view is None else pair.view.stamp_ns))
        most.offer(pair)
        at.offer(pair)

    result = export_painted(tour.out, out, on_pair=watch)
    return tour, result, np.load(out), seen, most, at


def test_npz_has_one_row_per_beam_of_every_scan(exported):
    tour, result, data, seen, _, _ = exported
    scans = message_count(tour.bag, "/scan")
    assert result.scans == scans == len(seen) == 120
    assert result.beams == scans * BEAMS
    assert set(EXPORT_COLUMNS) <= set(data.files)
    for c in EXPORT_COLUMNS:
        assert data[c].shape == (scans * BEAMS,), c
    assert np.array_equal(data["beam"][:BEAMS], np.arange(BEAMS))
    assert np.unique(data["stamp_ns"]).size == scans
    # the scans were painted: the camera saw people, furniture and walls
    raw = data["mobility_raw"]
    for m in (Mobility.STATIC, Mobility.SEMI_STATIC, Mobility.DYNAMIC):
        assert np.count_nonzero(raw == m) > 50, m.label
    assert result.scans_painted >= scans - 2  # 5 Hz images, 15 Hz scans: all but the first scans pair up


def test_filter_only_ever_makes_points_unknown(exported):
    _, result, data, seen, _, _ = exported
    changed = data["mobility"] != data["mobility_raw"]
    assert np.all(data["mobility"][changed] == Mobility.UNKNOWN)
    assert np.all(data["class"][changed] == -1)
    assert np.all(data["mobility_raw"][changed] != Mobility.UNKNOWN)
    assert np.all(data["class"][~changed] == data["class_raw"][~changed])
    assert result.relabelled == int(changed.sum()) == sum(n for _, n, _ in seen)
    assert result.relabelled_max_per_scan == max(n for _, n, _ in seen)
    # no return: no point, nothing to paint
    no_point = ~np.isfinite(data["x"])
    assert np.all(data["mobility_raw"][no_point] == Mobility.UNKNOWN)


def test_picker_keeps_the_scan_with_most_relabelled_points(exported):
    _, _, _, seen, most, at = exported
    painted = [s for s in seen if s[2] is not None]
    assert most.best is not None and most.best.relabelled == max(n for _, n, _ in painted)
    assert at.best is not None and at.best.scan.stamp_ns == painted[0][0]  # at=0: the earliest painted scan
    assert most.images_seen == len({s[2] for s in painted})


def test_cli_writes_csv_and_picture_and_refuses_to_overwrite(exported, tmp_path, capsys):
    tour, _, data, _, _most, _ = exported
    table, png = tmp_path / "painted.csv", tmp_path / "fig6.png"
    assert main(["paint", str(tour.out), "--out", str(table), "--picture", str(png), "-q"]) == 0
    with open(table, newline="") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == EXPORT_COLUMNS
    assert len(rows) - 1 == data["beam"].size
    # the CSV says in names what the NPZ says in numbers
    names = [m.label for m in Mobility]
    assert [r[5] for r in rows[1:]] == [names[m] for m in data["mobility_raw"]]
    assert [r[7] for r in rows[1:]] == [names[m] for m in data["mobility"]]
    # Fig. 6 of the scan with the most relabelled points: three panels side by side
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] > 2.5 * img.shape[0]

    capsys.readouterr()
    before = table.read_bytes()
    assert main(["paint", str(tour.out), "--out", str(table)]) == OutputExistsError.exit_code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("semmap paint: error:") and "--force" in err[0]
    assert table.read_bytes() == before
    assert main(["paint", str(tour.out), "--picture", str(png)]) == OutputExistsError.exit_code


def test_cli_draws_a_chosen_image(exported, tmp_path, capsys):
    tour = exported[0]
    png = tmp_path / "image3.png"
    assert main(["paint", str(tour.out), "--picture", str(png), "--image", "3"]) == 0
    out = capsys.readouterr().out
    assert "picture" in out and "over the RGB image" in out
    assert cv2.imread(str(png)) is not None
    assert main(["paint", str(tour.out), "--picture", str(tmp_path / "none.png"), "--frame", "999", "-q"]) == 2
    assert "image 999" in capsys.readouterr().err
    assert not (tmp_path / "none.png").exists()
