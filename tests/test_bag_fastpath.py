"""semmap's own bag record reader (io/fastbag.py): used only with the rosbags versions it was tested with,
it leaves a bag it does not understand to rosbags' reader (same messages, and a log line saying so), and
never takes a bug of semmap's for a bag it cannot read."""

from __future__ import annotations

import logging
import struct

import numpy as np
import pytest

import semmap.io.fastbag as fastbag
from semmap.io.bag import BagWriter, iter_messages, open_bag
from semmap.records import Scan


@pytest.fixture
def scans_bag(tmp_path):
    """A ROS1 bag of 40 scans (a new file per test: no table of it is cached yet)."""
    path = tmp_path / "scans.bag"
    n = 91
    with BagWriter(path, "ros1") as w:
        for k in range(40):
            t = 100_000_000_000 + k * 100_000_000
            w.scan("/scan", t, Scan(t, "laser", -1.5, 3.0 / (n - 1), np.full(n, 1.0 + k, np.float32), 0.05, 60.0,
                                    0.0, 0.1))
    return path


@pytest.fixture
def fresh_version_check():
    fastbag.usable.cache_clear()
    yield
    fastbag.usable.cache_clear()


def _ranges(path):
    return [float(msg.ranges[0]) for _, _, msg in iter_messages(path, ["/scan"])]


def test_a_healthy_bag_is_read_by_semmaps_reader(scans_bag, fresh_version_check):
    assert fastbag.usable()  # the rosbags installed is one it was tested with
    with open_bag(scans_bag) as reader:
        assert fastbag.reads(reader)
    assert _ranges(scans_bag) == [1.0 + k for k in range(40)]


def test_a_bag_it_does_not_understand_goes_to_rosbags_with_a_log_line(scans_bag, monkeypatch, caplog):
    def unusual(fd, size):
        raise struct.error("unpack requires a buffer of 4 bytes")  # as a cut record gives it

    monkeypatch.setattr(fastbag, "_scan_ros1", unusual)
    with caplog.at_level(logging.INFO, logger="semmap.io"):
        with open_bag(scans_bag) as reader:
            assert not fastbag.reads(reader)
        assert _ranges(scans_bag) == [1.0 + k for k in range(40)]
    assert "read through rosbags' reader, not a table of its chunks (unpack requires" in caplog.text


def test_a_record_it_cannot_read_midway_goes_to_rosbags_with_a_log_line(scans_bag, monkeypatch, caplog):
    from rosbags.rosbag1 import ReaderError

    real = fastbag._message_at
    calls = []

    def fails_on_the_tenth(buf, pos, end):
        calls.append(pos)
        if len(calls) == 10:
            raise ReaderError("Expected to find message data.")
        return real(buf, pos, end)

    monkeypatch.setattr(fastbag, "_message_at", fails_on_the_tenth)
    with caplog.at_level(logging.INFO, logger="semmap.io"):
        assert _ranges(scans_bag) == [1.0 + k for k in range(40)]  # none lost, none repeated
    assert "reading through its index failed" in caplog.text and "rosbags' reader" in caplog.text


@pytest.mark.parametrize("where", ["_scan_ros1", "_message_at"])
def test_a_bug_in_semmaps_reader_is_raised_not_hidden_by_the_fallback(scans_bag, monkeypatch, where):
    def bug(*args):
        raise TypeError("unsupported operand type(s) for +: 'int' and 'NoneType'")

    monkeypatch.setattr(fastbag, where, bug)
    with pytest.raises(TypeError, match="unsupported operand"):
        _ranges(scans_bag)


def test_outside_the_tested_rosbags_versions_rosbags_reads_every_bag(scans_bag, monkeypatch, caplog,
                                                                    fresh_version_check):
    monkeypatch.setattr(fastbag, "_rosbags_version", lambda: "0.12.1")
    with caplog.at_level(logging.INFO, logger="semmap.io"):
        with open_bag(scans_bag) as reader:
            assert not fastbag.reads(reader)
            assert fastbag.ros1_records(reader, list(reader.connections)) is None
        assert _ranges(scans_bag) == [1.0 + k for k in range(40)]
    lines = [r for r in caplog.records if "is not a version semmap's own bag reader was tested with" in r.message]
    assert len(lines) == 1 and lines[0].levelno == logging.WARNING  # once, however often bags are opened
    assert "rosbags 0.12.1" in lines[0].message and "0.10.4 to before 0.12" in lines[0].message


def test_the_tested_range_matches_the_dependency_bound():
    """pyproject.toml's bound on rosbags and the reader's tested range say the same."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    lo, hi = fastbag.TESTED_ROSBAGS
    assert f'"rosbags>={".".join(map(str, lo))},<{".".join(map(str, hi))}"' in text


def test_a_build_opens_its_bag_once(short_tour, tmp_path, monkeypatch):
    """The tour's topics, frames, transforms and calibration, the scan count and the scan and odometry
    stream all come from one opened bag; the camera stream, read beside it, opens its own."""
    import semmap.io.bag as bag_module
    from semmap.pipeline import build

    opened = []
    real = bag_module._open_reader

    def counting(p):
        opened.append(p)
        return real(p)

    monkeypatch.setattr(bag_module, "_open_reader", counting)
    build(short_tour.out, tmp_path / "lidar", overrides={"workers": False, "topics": {"labels": "none"}})
    assert opened == [short_tour.bag]
    opened.clear()
    res = build(short_tour.out, tmp_path / "map", overrides={"workers": False})
    assert res.summary.painting.scans_painted > 0
    assert opened == [short_tour.bag, short_tour.bag]  # the tour, and its label images (InProcessImages)


def test_a_recording_split_into_two_bags_is_refused_with_how_to_join_them(tmp_path):
    # rosbag record --split writes a recording as several files: semmap reads one bag, and says how to
    # join the parts (rosbags, which it reads bags with, installs rosbags-convert); the joined bag holds
    # every scan of both, in time order
    import shlex
    import subprocess
    import sys

    from semmap.errors import BagError
    from semmap.io.bag import resolve_bag_path

    n = 91
    for part in range(2):
        with BagWriter(tmp_path / f"tour_{part}.bag", "ros1") as w:
            for k in range(20):
                t = 100_000_000_000 + (20 * part + k) * 100_000_000
                w.scan("/scan", t, Scan(t, "laser", -1.5, 3.0 / (n - 1), np.full(n, 1.0 + 20 * part + k, np.float32),
                                        0.05, 60.0, 0.0, 0.1))
    with pytest.raises(BagError) as err:
        resolve_bag_path(tmp_path)
    msg = str(err.value)
    assert "tour_0.bag, tour_1.bag" in msg and "rosbags-convert" in msg
    command = shlex.split(msg[msg.index("rosbags-convert"):])
    assert command[:4] == ["rosbags-convert", "--src", "tour_0.bag", "tour_1.bag"]
    joined = tmp_path / "joined"
    joined.mkdir()
    run = subprocess.run([sys.executable, "-c", "import sys; from rosbags.convert.cli import main; sys.exit(main())",
                          *command[1:-1], str(joined / command[-1])], cwd=tmp_path, capture_output=True, text=True,
                         check=False)
    assert run.returncode == 0, run.stderr
    assert _ranges(resolve_bag_path(joined)) == [1.0 + k for k in range(40)]
