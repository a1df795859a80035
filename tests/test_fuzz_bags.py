"""Mutated bags (bytes flipped, cut short, records reordered): every case ends in a map or in one clear
line naming the file, with one of semmap's exit codes, never a traceback, an internal error or a hang.

A short simulated tour in each storage (ROS1, MCAP, sqlite3) is mutated by hypothesis, derandomised so CI
runs the same cases every time; ``semmap info`` and ``semmap build`` (in one process: ``workers: false``)
then run on it in this process. Raise the number of cases for a long local run with
``SEMMAP_FUZZ_EXAMPLES=200``; ``SEMMAP_FUZZ_LOG=FILE`` appends what each case ended in to FILE.
"""

from __future__ import annotations

import contextlib
import faulthandler
import io
import os
import random
import re
import shutil
import signal
import struct
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parent))
from legacy_bag import MAGIC, OP_CHUNK, read_record

from semmap.cli.main import main

FORMATS = ["ros1", "mcap", "sqlite3"]
#: cases per storage: ``semmap info`` is cheap, a build that succeeds takes a few seconds
INFO_EXAMPLES = int(os.environ.get("SEMMAP_FUZZ_EXAMPLES", "30"))
BUILD_EXAMPLES = max(1, INFO_EXAMPLES * 3 // 10)
#: wall-clock bound of one command on one mutated bag (a build of this tour takes about 2 s)
CASE_SECONDS = 60
SEMMAP_CODES = {1, 2, 3, 4, 5}


def _settings(n: int) -> settings:
    return settings(max_examples=n, deadline=None, derandomize=True, database=None, print_blob=False,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                           HealthCheck.data_too_large])


@pytest.fixture(scope="module")
def tours(tmp_path_factory):
    """A 3 s demo tour (small camera images, so a mutation often lands in structure) in every storage."""
    from semmap.sim.scenarios import demo
    from semmap.sim.tour import simulate

    world = replace(demo().world, duration_s=3.0)
    small_camera = {"camera": {"width": 80, "height": 60, "K": [[75.2, 0, 41.0], [0, 75.0, 30.05], [0, 0, 1]]}}
    root = tmp_path_factory.mktemp("fuzz_tours")
    out = {fmt: simulate(world, root / fmt, fmt=fmt, seed=5, config=small_camera) for fmt in FORMATS}
    cfg = root / "build.yaml"
    cfg.write_text("workers: false\n")
    return out, cfg


def _storage_file(bag: Path) -> Path:
    """The file holding the messages: the .bag itself, or the .mcap / .db3 in a ROS2 bag folder."""
    if bag.is_file():
        return bag
    return next(f for f in sorted(bag.iterdir()) if f.suffix in (".mcap", ".db3"))


# -- what a storage is made of: records to reorder, and offsets where structure is --------------------


def _ros1_layout(data: bytes) -> tuple[list[tuple[int, int]], list[int]]:
    """(start, end) of every top-level record after the magic line; where the records inside
    (uncompressed) chunks, and their data, start."""
    units, hot, pos = [], [], len(MAGIC)
    while pos < len(data):
        rec, end = read_record(data, pos)
        units.append((pos, end))
        if rec.op == OP_CHUNK and rec.get(b"compression") == b"none":
            base = end - len(rec.data)
            inner = 0
            while inner < len(rec.data):
                (hlen,) = struct.unpack_from("<I", rec.data, inner)
                hot += [base + inner, base + inner + 8 + hlen]  # its header, its data (a message's fields)
                _, inner = read_record(rec.data, inner)
        pos = end
    return units, hot


def _mcap_layout(data: bytes) -> tuple[list[tuple[int, int]], list[int]]:
    """(start, end) of every MCAP record between the leading and the trailing magic; where the records
    inside uncompressed chunks, and a message's data, start."""
    units, hot, pos = [], [], 8
    while pos + 9 <= len(data) - 8:
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        units.append((pos, pos + 9 + length))
        if data[pos] == 0x06:  # chunk: times, sizes, crc, compression, records
            (clen,) = struct.unpack_from("<I", data, pos + 9 + 28)
            if clen == 0:
                inner = pos + 9 + 32 + 8
                while inner < pos + 9 + length:
                    (ilen,) = struct.unpack_from("<Q", data, inner + 1)
                    hot += [inner, inner + 9 + 22] if data[inner] == 0x05 else [inner]
                    inner += 9 + ilen
        pos += 9 + length
    return units, hot


def _sqlite_layout(data: bytes) -> tuple[list[tuple[int, int]], list[int]]:
    """(start, end) of every database page; the database header."""
    (size,) = struct.unpack_from(">H", data, 16)
    size = 65536 if size == 1 else size
    pages = [(i, min(i + size, len(data))) for i in range(0, len(data), size)]
    return pages, [0]


LAYOUT = {"ros1": _ros1_layout, "mcap": _mcap_layout, "sqlite3": _sqlite_layout}


# -- mutations --------------------------------------------------------------------------------------


def mutations(data: bytes, units: list[tuple[int, int]], hot: list[int]) -> st.SearchStrategy:
    """Lists of mutations of ``data``: byte flips (anywhere, or near where a record or a message's fields
    start), a cut, a swap of two records (ROS1: chunks and index records alike).

    Hypothesis draws a seed and the mutations follow from it at random: its own small examples come
    first and would otherwise all be cuts at byte 0 and flips of byte 0; a failing case prints the
    mutations it made.
    """
    near = sorted({s for s, _ in units} | set(hot))

    def from_seed(seed: int) -> list[tuple[str, int, int]]:
        rng = random.Random(seed)
        ops = []
        for _ in range(rng.choice((1, 1, 2, 3))):
            kind = rng.choices(("flip", "cut", "swap"), weights=(6, 1, 2))[0]
            if kind == "flip":
                at = rng.randrange(len(data)) if rng.random() < 0.4 else \
                    min(rng.choice(near) + rng.randrange(64), len(data) - 1)
                ops.append(("flip", at, rng.randrange(1, 256)))
            elif kind == "cut":
                ops.append(("cut", rng.randrange(len(data)), 0))
            else:
                ops.append(("swap", rng.randrange(len(units)), rng.randrange(len(units))))
        return ops

    return st.integers(0, 2**32 - 1).map(from_seed)


def _mutate(data: bytes, units: list[tuple[int, int]], ops) -> bytes:
    buf = bytearray(data)
    for kind, a, b in ops:
        if kind == "swap" and a != b and len(buf) == len(data):  # reorder whole records (ROS1: chunks too)
            (s1, e1), (s2, e2) = sorted([units[a], units[b]])
            buf = buf[:s1] + buf[s2:e2] + buf[e1:s2] + buf[s1:e1] + buf[e2:]
        elif kind == "flip" and a < len(buf):
            buf[a] ^= b
        elif kind == "cut":
            buf = buf[:a]
    return bytes(buf)


class Hang(BaseException):
    """A command ran past its wall-clock bound (not an Exception: semmap's CLI must not catch it)."""


@contextlib.contextmanager
def bounded(seconds: int):
    """Fail the case if it runs longer than ``seconds``; kill the process (with every thread's stack on
    stderr) if even that does not end it, e.g. a hang in native code."""
    def on_alarm(signum, frame):
        raise Hang(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(seconds)
    faulthandler.dump_traceback_later(2 * seconds, exit=True, file=sys.__stderr__)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _run(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with bounded(CASE_SECONDS), contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(argv)
    return code, err.getvalue()


#: a line semmap's log handler wrote (``LEVEL logger: message``), e.g. a damaged transform left out
_LOG_LINE = re.compile(r"^(DEBUG|INFO|WARNING|ERROR|CRITICAL) [\w.]+: ")


def _check(command: str, code: int, err: str, bag: Path) -> None:
    """A map (exit 0), or exit 1-5 and one line ``semmap COMMAND: error: ...`` naming the file.

    The error is the one line that is not a log record: warnings logged before the failure (a
    damaged field left out, say) are log lines of their own, in the log's format.
    """
    if os.environ.get("SEMMAP_FUZZ_LOG"):  # what each case ended in, for a look at a long run
        with open(os.environ["SEMMAP_FUZZ_LOG"], "a", encoding="utf-8") as f:
            f.write(f"{command}\t{code}\t{err.strip().replace(str(bag.parent), '<tmp>')}\n")
    assert "Traceback" not in err, err
    assert code == 0 or code in SEMMAP_CODES, f"exit {code}: {err}"
    if code != 0:
        lines = [line for line in err.strip().splitlines() if not _LOG_LINE.match(line)]
        assert len(lines) == 1, err
        assert lines[0].startswith(f"semmap {command}: error: "), err
        assert str(bag.parent) in lines[0], err  # it names the file (the bag, or the calibration beside it)


def _mutated_copy(tour, ops, workdir: Path) -> Path:
    """A copy of the tour's bag with the mutations applied to its storage file."""
    bag = workdir / tour.bag.name
    if tour.bag.is_file():
        shutil.copy2(tour.bag, bag)
    else:
        shutil.copytree(tour.bag, bag)
    target = _storage_file(bag)
    data = target.read_bytes()
    target.write_bytes(_mutate(data, LAYOUT[tour.format](data)[0], ops))
    return bag


def _cases(tours, fmt):
    tour = tours[0][fmt]
    data = _storage_file(tour.bag).read_bytes()
    return tour, mutations(data, *LAYOUT[fmt](data))


@pytest.mark.parametrize("fmt", FORMATS)
def test_info_on_mutated_bags(tours, fmt):
    tour, strategy = _cases(tours, fmt)

    @_settings(INFO_EXAMPLES)
    @given(ops=strategy)
    def case(ops):
        with tempfile.TemporaryDirectory(prefix="semmap-fuzz-") as tmp:
            bag = _mutated_copy(tour, ops, Path(tmp))
            code, err = _run(["info", str(bag)])
            _check("info", code, err, bag)

    case()


@pytest.mark.parametrize("fmt", FORMATS)
def test_build_on_mutated_bags(tours, fmt):
    tour, strategy = _cases(tours, fmt)
    cfg = tours[1]

    @_settings(BUILD_EXAMPLES)
    @given(ops=strategy)
    def case(ops):
        with tempfile.TemporaryDirectory(prefix="semmap-fuzz-") as tmp:
            bag = _mutated_copy(tour, ops, Path(tmp))
            shutil.copy2(tour.out / "calibration.yaml", Path(tmp) / "calibration.yaml")
            out = Path(tmp) / "map"
            code, err = _run(["build", str(bag), "--out", str(out), "--config", str(cfg), "-q"])
            _check("build", code, err, bag)
            if code == 0:
                assert (out / "map.yaml").is_file() and (out / "map.pgm").is_file()
            else:
                assert not out.exists(), "a failed build left its output folder"
            assert not [p.name for p in Path(tmp).iterdir() if "partial" in p.name], "a .partial folder was left"

    case()


def test_mutations_are_applied():
    """The mutations do what they say: a swap keeps the bytes and moves records, a cut shortens."""
    data = bytes(range(100))
    units = [(0, 10), (10, 30), (30, 100)]
    assert _mutate(data, units, [("swap", 0, 2)]) == data[30:] + data[10:30] + data[:10]
    assert _mutate(data, units, [("cut", 40, 0)]) == data[:40]
    assert _mutate(data, units, [("flip", 5, 1)])[5] == 4


# -- what the fuzzer found, kept as plain cases ----------------------------------------------------------


def _hdr():
    from types import SimpleNamespace as NS

    return NS(stamp=NS(sec=5, nanosec=7), frame_id="laser")


def _laserscan(**fields):
    from types import SimpleNamespace as NS

    msg = {"header": _hdr(), "angle_min": -2.0, "angle_increment": 0.01, "time_increment": 1e-4, "scan_time": 0.1,
           "range_min": 0.05, "range_max": 30.0, "ranges": np.full(401, 2.0, np.float32),
           "intensities": np.zeros(0, np.float32)}
    msg.update(fields)
    return NS(**msg)


def test_absurd_laserscan_fields_are_made_harmless():
    """A flipped exponent byte makes range_max 1e30 (then a 1e20 m reading counted as a hit made the grid
    allocate beyond memory) or time_increment 1e9 s (an integer overflow in motion compensation)."""
    from semmap.io.messages import MAX_RANGE_M, scan_from_msg

    ranges = np.full(401, 2.0, np.float32)
    ranges[7] = 1e20
    scan = scan_from_msg(_laserscan(range_max=1e30, ranges=ranges), "/scan")
    assert scan.range_max == MAX_RANGE_M and scan.ranges[7] > scan.range_max  # REP-117: invalid
    assert scan_from_msg(_laserscan(range_max=float("inf"))).range_max == MAX_RANGE_M
    assert scan_from_msg(_laserscan(time_increment=1e9)).time_increment == 0.0
    assert scan_from_msg(_laserscan(time_increment=float("nan"), scan_time=float("inf"))).scan_time == 0.0
    assert scan_from_msg(_laserscan(time_increment=-1e-4)).time_increment == -1e-4  # clockwise LiDARs
    assert scan_from_msg(_laserscan(angle_min=float("nan"))).ranges.size == 0  # a bad scan, skipped by builds
    assert scan_from_msg(_laserscan(angle_increment=1.0)).ranges.size == 0  # 400 rad: not a 2D scan
    assert scan_from_msg(_laserscan(intensities=np.ones(3, np.float32))).intensities is None
    assert scan_from_msg(_laserscan(range_min=float("nan"))).range_min == 0.0
    real = scan_from_msg(_laserscan())
    assert (real.range_max, real.time_increment, real.ranges.size) == (30.0, 1e-4, 401)


def test_absurd_odometry_and_transforms_are_not_used():
    from types import SimpleNamespace as NS

    from semmap.io.messages import odometry_from_msg, transforms_from_msg

    def odom(x):
        pose = NS(position=NS(x=x, y=0.0, z=0.0), orientation=NS(x=0.0, y=0.0, z=0.0, w=1.0))
        return NS(header=_hdr(), child_frame_id="base_link", pose=NS(pose=pose))

    assert np.all(np.isnan(odometry_from_msg(odom(1e30), "/odom")[3]))
    assert odometry_from_msg(odom(12.5))[3][0] == 12.5

    def tf(translation, rotation):
        t = NS(header=NS(stamp=NS(sec=1, nanosec=0), frame_id="base_link"), child_frame_id="laser",
               transform=NS(translation=NS(x=translation[0], y=translation[1], z=translation[2]),
                            rotation=NS(x=rotation[0], y=rotation[1], z=rotation[2], w=rotation[3])))
        return NS(transforms=[t])

    assert len(transforms_from_msg(tf((0.3, 0.0, 0.1), (0, 0, 0, 1)))) == 1
    assert transforms_from_msg(tf((float("nan"), 0.0, 0.1), (0, 0, 0, 1)), "/tf_static") == []
    assert transforms_from_msg(tf((0.3, 0.0, 0.1), (0, 0, 0, 0))) == []  # scipy raised on a zero quaternion
    assert transforms_from_msg(tf((1e30, 0.0, 0.1), (0, 0, 0, 1))) == []


def test_images_that_do_not_fit_their_size_name_the_topic_and_field():
    from types import SimpleNamespace as NS

    from semmap.errors import BagError
    from semmap.io.messages import image_from_msg

    def image(**fields):
        msg = {"header": _hdr(), "height": 4, "width": 3, "encoding": "mono8", "is_bigendian": 0, "step": 3,
               "data": np.zeros(12, np.uint8)}
        msg.update(fields)
        return NS(**msg)

    assert image_from_msg(image()).data.shape == (4, 3)
    for fields, needle in (({"height": 0}, "3x0 pixels"),
                           ({"data": np.zeros(11, np.uint8)}, "shorter than height x step"),
                           ({"step": 2}, "step 2 is shorter than a row"),
                           ({"height": 2**31}, "shorter than height x step")):
        with pytest.raises(BagError, match=needle) as err:
            image_from_msg(image(**fields), "/camera/labels")
        assert "/camera/labels" in str(err.value)


def test_a_tour_with_damaged_messages_still_builds(tours, tmp_path, capsys):
    """Damaged fields in a few scans and odometry messages (as the fuzzer made them): a map, exit 0."""
    from rosbags.rosbag1 import Writer

    from semmap.io.bag import _typestore, open_bag

    tour, cfg = tours[0]["ros1"], tours[1]
    store = _typestore("ros1")
    damage = {
        ("/scan", 5): lambda m: (setattr(m, "range_max", 1e30),
                                 setattr(m, "ranges", np.full(m.ranges.size, 1e20, np.float32))),
        ("/scan", 9): lambda m: setattr(m, "time_increment", 1e9),
        ("/scan", 12): lambda m: setattr(m, "angle_min", float("nan")),
        ("/odom", 40): lambda m: setattr(m.pose.pose.position, "x", 1e30),
    }
    bag = tmp_path / "damaged.bag"
    seen: dict[str, int] = {}
    with open_bag(tour.bag) as reader, Writer(bag) as writer:
        out = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
               for c in reader.connections}
        for conn, t, raw in reader.messages():
            seen[conn.topic] = seen.get(conn.topic, 0) + 1
            edit = damage.get((conn.topic, seen[conn.topic]))
            if edit is not None:
                msg = store.deserialize_ros1(raw, conn.msgtype)
                edit(msg)
                raw = store.serialize_ros1(msg, conn.msgtype)
            writer.write(out[conn.id], t, raw)
    shutil.copy2(tour.out / "calibration.yaml", tmp_path / "calibration.yaml")
    code = main(["build", str(bag), "--out", str(tmp_path / "map"), "--config", str(cfg), "-q"])
    assert code == 0, capsys.readouterr().err
    assert (tmp_path / "map" / "map.yaml").is_file()
