"""ROS1 bags recorded by 2010-era rosbag read as ROS's own tools read them; damaged ones fail in one line.

A user's 2010 bag crashed ``semmap info`` and ``semmap build`` with ``internal error: AssertionError``
(exit 70) inside rosbags: its index data records carry a wrong data length (C Turtle's rosbag wrote
one; ROS's reader ignores it). Re-indexed, its message definitions name ``roslib/Header`` and rosbags
failed again. We do not have that bag: ``legacy_bag`` rewrites a bag rosbags wrote the way old
writers laid theirs out, and these tests check that semmap reads it as ``rosbag`` does (the same
messages, the same map) and that a bag damaged beyond repair ends in one line naming the file.
"""

from __future__ import annotations

import json
import logging
import struct
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from legacy_bag import (
    OP_CHUNK,
    OP_CONNECTION,
    OP_INDEX,
    header_fields,
    make_legacy_bag,
    read_bag,
    write_bag,
)

from semmap.cli.main import main
from semmap.io.bag import bag_info, iter_messages, open_bag, topic_types

SCAN_T = "sensor_msgs/msg/LaserScan"


@pytest.fixture(scope="module")
def scans_bag(tmp_path_factory):
    """A LiDAR-only ROS1 bag: the /scan of a 3 s simulated tour, in chunks of about 16 kB (several)."""
    from rosbags.rosbag1 import Writer

    from semmap.sim.scenarios import demo
    from semmap.sim.tour import simulate

    root = tmp_path_factory.mktemp("legacy")
    small_camera = {"camera": {"width": 80, "height": 60, "K": [[75.2, 0, 41.0], [0, 75.0, 30.05], [0, 0, 1]]}}
    tour = simulate(replace(demo().world, duration_s=3.0), root / "tour", fmt="ros1", seed=2, config=small_camera)
    return _lidar_only(tour.bag, root / "scans.bag", Writer)


def _lidar_only(src: Path, dst: Path, writer_cls, compression=None, chunk_bytes=16 * 1024) -> Path:
    with open_bag(src) as reader:
        writer = writer_cls(dst)
        writer.chunk_threshold = chunk_bytes
        if compression:
            writer.set_compression(compression)
        with writer:
            conns = [c for c in reader.connections if c.topic == "/scan"]
            out = writer.add_connection("/scan", SCAN_T, msgdef=conns[0].msgdef.data, md5sum=conns[0].digest,
                                        callerid="/urg_node")
            for _, t, raw in reader.messages(connections=conns):
                writer.write(out, t, raw)
    return dst


def _scans(bag: Path) -> list[tuple[int, int, str, bytes]]:
    """(bag time, header stamp, frame, ranges) of every scan, as semmap streams them."""
    out = []
    for _, t, msg in iter_messages(bag, ["/scan"]):
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        out.append((t, stamp, msg.header.frame_id, np.asarray(msg.ranges).tobytes()))
    return out


def _rosbags_opens(bag: Path) -> str:
    """What rosbags itself says on opening the bag ("ok", or the exception)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    try:
        with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)):
            return "ok"
    except Exception as exc:
        return f"{type(exc).__name__}: {exc}"


def _one_line_error(capsys, code: int, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert code == 3, err  # BagError
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err and "internal error" not in err
    for needle in needles:
        assert needle in err, err
    return err


# -- the helper makes what old writers made --------------------------------------------------------


def test_helper_rewrites_a_bag_byte_for_byte_when_asked_for_nothing(scans_bag, tmp_path):
    same = make_legacy_bag(scans_bag, tmp_path / "same.bag", index_data_length=None, field_order="as is",
                           roslib_header=False)
    assert same.read_bytes() == scans_bag.read_bytes()


def test_the_legacy_bag_is_what_rosbags_cannot_read(scans_bag, tmp_path):
    """The two failures the user reported, reproduced: rosbags asserts on the index data length, and
    once that is right, does not know roslib/Header. The md5sums are the ones ROS wrote."""
    old = make_legacy_bag(scans_bag, tmp_path / "old.bag", roslib_header=False)
    assert _rosbags_opens(old).startswith("AssertionError")
    reindexed = make_legacy_bag(scans_bag, tmp_path / "reindexed.bag", index_data_length=None)
    assert "std_msgs/msg/Header' is unknown" in _rosbags_opens(reindexed)
    conns = [header_fields(r.data) for r in read_bag(reindexed) if r.op == OP_CONNECTION]
    definition = dict(conns[0])[b"message_definition"].decode()
    assert "MSG: roslib/Header" in definition and "std_msgs/Header" not in definition
    assert dict(conns[0])[b"md5sum"] == b"90c7ef2dc6895d81024acba2ac42f369"  # LaserScan, since 2010


# -- reading them as ROS does ------------------------------------------------------------------------


@pytest.mark.parametrize("length", [
    pytest.param(lambda count: count * 12 + 4, id="count*12+4"),
    pytest.param(lambda count: 0, id="zero"),
    pytest.param(lambda count: count * 8, id="count*8"),
    pytest.param(lambda count: 0xFFFFFFFF, id="0xffffffff"),
])
def test_wrong_index_data_lengths_are_ignored_as_ros_does(scans_bag, tmp_path, length):
    old = make_legacy_bag(scans_bag, tmp_path / "old.bag", index_data_length=length, pad_index_headers=True)
    assert _scans(old) == _scans(scans_bag)
    info = bag_info(old)
    assert info.topic("/scan").count == 45 and info.topic("/scan").msgtype == SCAN_T
    assert "read its own index as ROS's reader does" in info.index_note
    assert "roslib/Header" in info.index_note


def test_info_on_a_2010_bag(scans_bag, tmp_path, capsys):
    old = make_legacy_bag(scans_bag, tmp_path / "old.bag")
    assert main(["info", str(old), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert main(["info", str(scans_bag), "--json"]) == 0
    want = json.loads(capsys.readouterr().out)
    assert got["topics"] == want["topics"]  # counts, rates, first and last times: all the same
    assert got["topics"][0]["count"] == 45 and got["topics"][0]["rate_hz"] == pytest.approx(15.0, rel=0.02)
    assert "wrong data length" in got["index_note"] and "index_note" not in want
    assert main(["info", str(old)]) == 0
    out = capsys.readouterr().out
    assert "index:" in out and "roslib/Header" in out


def test_roslib_header_reads_as_std_msgs_header(scans_bag, tmp_path):
    old = make_legacy_bag(scans_bag, tmp_path / "old.bag")
    assert topic_types(old) == {"/scan": SCAN_T}
    with open_bag(old) as reader:
        conn = reader.connections[0]
        _, _, raw = next(reader.messages(connections=[conn]))
        msg = reader.deserialize(raw, conn.msgtype)
    assert msg.header.__msgtype__ == "std_msgs/msg/Header"
    assert msg.header.frame_id == "laser" and msg.header.stamp.sec > 1_700_000_000
    assert _scans(old) == _scans(scans_bag)  # every stamp, frame and range, in the same order


def test_build_from_a_2010_bag_makes_the_same_map(scans_bag, tmp_path, capsys):
    """A LaserScan-only 2010 bag builds a LiDAR-only map, the one its modern copy builds."""
    cfg = tmp_path / "build.yaml"
    cfg.write_text("workers: false\n")
    old = make_legacy_bag(scans_bag, tmp_path / "old.bag", pad_index_headers=True)
    maps = {}
    for name, bag in (("old", old), ("new", scans_bag)):
        out = tmp_path / f"map_{name}"
        assert main(["build", str(bag), "--out", str(out), "--config", str(cfg), "-q"]) == 0, capsys.readouterr().err
        maps[name] = out
        assert (out / "map.yaml").is_file()
    summary = json.loads((maps["old"] / "summary.json").read_text())
    assert summary["counts"]["scans"] == 45
    assert (maps["old"] / "map.pgm").read_bytes() == (maps["new"] / "map.pgm").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["build.yaml", "map_new", "map_old", "old.bag"]


@pytest.mark.parametrize("name", ["leg_tracker/negative_2.bag", "hokuyo_odom_bags/2019_jan17_expt08.bag",
                                  "hokuyo_odom_bags/2018_may9_editted_after1.bag"])
def test_real_bags_laid_out_the_2010_way_read_the_same(data_dir, tmp_path, name):
    """Bags ROS itself wrote (C++ rosbag: header fields in std::map order; Python rosbag: in its own
    order), their comments and all, given 2010 index records and roslib/Header, or left unindexed."""
    src = data_dir / name
    if not src.is_file():
        pytest.skip(f"{src} not found")
    want = {t.name: (t.count, t.msgtype, t.first_ns, t.last_ns) for t in bag_info(src).topics}
    for variant in ({"pad_index_headers": True}, {"unindexed": True}):
        bag = make_legacy_bag(src, tmp_path / "old.bag", **variant)
        assert _rosbags_opens(bag) != "ok"
        assert {t.name: (t.count, t.msgtype, t.first_ns, t.last_ns) for t in bag_info(bag).topics} == want


# -- rebuilding the index from the chunks, as `rosbag reindex` does ---------------------------------------


@pytest.mark.parametrize("compression", [None, "bz2", "lz4"])
def test_unindexed_bags_are_reindexed_from_their_chunks(scans_bag, tmp_path, compression):
    """A recording never closed (index_pos 0, no index): its chunks, decompressed where they are
    compressed, give every message back. Nothing is written beside the bag."""
    from rosbags.rosbag1 import Writer

    src = scans_bag
    if compression:
        src = _lidar_only(scans_bag, tmp_path / "packed.bag", Writer,
                          compression=Writer.CompressionFormat[compression.upper()])
    bag = make_legacy_bag(src, tmp_path / "never_closed.bag", unindexed=True)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert "not indexed" in _rosbags_opens(bag)
    assert _scans(bag) == _scans(scans_bag)
    info = bag_info(bag)
    assert info.message_count == 45 and "rebuilt its index from its chunks" in info.index_note
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_never_closed_bag_keeps_its_complete_chunks(scans_bag, tmp_path):
    """Cut inside its last chunk, a never-closed bag loses that chunk, as with `rosbag reindex`."""
    bag = make_legacy_bag(scans_bag, tmp_path / "never_closed.bag", unindexed=True)
    records = read_bag(bag)
    last = [r for r in records if r.op == OP_CHUNK][-1]
    data = bag.read_bytes()
    bag.write_bytes(data[:last.pos + 100])
    info = bag_info(bag)
    kept = _scans(bag)
    assert 30 < info.message_count == len(kept) < 45
    assert kept == _scans(scans_bag)[:len(kept)]
    assert "dropped its unfinished end" in info.index_note


def test_a_never_closed_bag_without_a_complete_chunk_is_truncated(scans_bag, tmp_path, capsys):
    bag = make_legacy_bag(scans_bag, tmp_path / "never_closed.bag", unindexed=True)
    first = next(r for r in read_bag(bag) if r.op == OP_CHUNK)
    bag.write_bytes(bag.read_bytes()[:first.pos + 100])
    code = main(["info", str(bag)])
    _one_line_error(capsys, code, str(bag), "bag is truncated: it was never closed, and no chunk in it is complete",
                    f"the chunk at byte {first.pos} needs")


def test_an_index_that_leads_astray_is_rebuilt_while_reading(scans_bag, tmp_path, caplog):
    """An index that adds up but points one message at the wrong bytes: rosbags opens the bag and fails
    mid-read; semmap goes on through an index rebuilt from the chunks, without losing or repeating a scan."""
    records = read_bag(scans_bag)
    idx = [r for r in records if r.op == OP_INDEX][3]
    entries = bytearray(idx.data)
    struct.pack_into("<I", entries, 8, struct.unpack_from("<I", entries, 8 + 12)[0] + 1)  # first entry -> garbage
    idx.data = bytes(entries)
    bad = tmp_path / "astray.bag"
    write_bag(bad, records)
    assert _rosbags_opens(bad) == "ok"
    want = _scans(scans_bag)
    with caplog.at_level(logging.DEBUG, logger="semmap.io.bag"):
        got = _scans(bad)
    assert "reading through its index failed" in caplog.text  # ... after the first chunks' scans
    assert got == want
    info = bag_info(bad)
    assert info.topic("/scan").count == 45
    assert "rebuilt its index from its chunks" in info.index_note and "its own index failed" in info.index_note


def test_chunks_out_of_order_are_reindexed(scans_bag, tmp_path):
    """Two chunks (each with its index data) swapped in the file, the index left as it was: the index
    no longer leads to the chunks, the chunks themselves still hold every message."""
    records = read_bag(scans_bag)
    chunks = [i for i, r in enumerate(records) if r.op == OP_CHUNK]
    a, b = chunks[2], chunks[5]
    group_a, group_b = records[a:a + 2], records[b:b + 2]  # a chunk and its one index data record
    assert [r.op for r in group_a + group_b] == [OP_CHUNK, OP_INDEX] * 2
    swapped = records[:a] + group_b + records[a + 2:b] + group_a + records[b + 2:]
    data = b"".join(r.encode() for r in swapped[1:])
    head = scans_bag.read_bytes()[:swapped[1].pos]  # magic and file header, unchanged (index_pos too)
    bag = tmp_path / "reordered.bag"
    bag.write_bytes(head + data)
    assert _rosbags_opens(bag) != "ok"
    assert _scans(bag) == _scans(scans_bag)  # in time order, as before
    assert "rebuilt its index from its chunks" in bag_info(bag).index_note


def test_healthy_bags_take_rosbags_own_path(scans_bag):
    with open_bag(scans_bag) as reader:
        assert reader.paths == [scans_bag]  # the bag itself, not a rebuilt view
    assert bag_info(scans_bag).index_note is None


# -- damaged beyond repair: one line naming the file and what is wrong --------------------------------------


def _damage_chunk(bag: Path, out: Path, chunk, at: int, value: bytes) -> Path:
    """A copy of ``bag`` with ``value`` written ``at`` bytes into the record ``chunk``."""
    data = bytearray(bag.read_bytes())
    data[chunk.pos + at:chunk.pos + at + len(value)] = value
    out.write_bytes(bytes(data))
    return out


def test_a_bag_damaged_beyond_repair_is_one_clear_line(scans_bag, tmp_path, capsys):
    """Its index is of no use (never closed) and a chunk is garbled: exit 3, the file and the place."""
    bag = make_legacy_bag(scans_bag, tmp_path / "never_closed.bag", unindexed=True)
    chunk = [r for r in read_bag(bag) if r.op == OP_CHUNK][1]
    hlen = struct.unpack_from("<I", bag.read_bytes(), chunk.pos)[0]
    # its first record's header
    broken = _damage_chunk(bag, tmp_path / "broken.bag", chunk, 4 + hlen + 4 + 2, b"\xff\xff")
    code = main(["info", str(broken)])
    err = _one_line_error(capsys, code, str(broken), f"chunk at byte {chunk.pos}", "bag is damaged")
    assert err.startswith("semmap info: error: ")
    cfg = tmp_path / "build.yaml"
    cfg.write_text("workers: false\n")
    out = tmp_path / "map"
    code = main(["build", str(broken), "--out", str(out), "--config", str(cfg), "-q"])
    _one_line_error(capsys, code, str(broken), "bag is damaged")
    assert not out.exists() and not [p for p in tmp_path.iterdir() if "partial" in p.name]


def test_an_undecompressable_chunk_is_one_clear_line(scans_bag, tmp_path, capsys):
    from rosbags.rosbag1 import Writer

    packed = _lidar_only(scans_bag, tmp_path / "packed.bag", Writer, compression=Writer.CompressionFormat.BZ2)
    bag = make_legacy_bag(packed, tmp_path / "never_closed.bag", unindexed=True)
    chunk = [r for r in read_bag(bag) if r.op == OP_CHUNK][2]
    hlen = struct.unpack_from("<I", bag.read_bytes(), chunk.pos)[0]
    broken = _damage_chunk(bag, tmp_path / "broken.bag", chunk, 4 + hlen + 4 + 40, b"\x00" * 8)
    code = main(["info", str(broken)])
    _one_line_error(capsys, code, str(broken), f"the chunk at byte {chunk.pos} cannot be decompressed (bz2")


def test_a_closed_bag_cut_short_is_truncated(scans_bag, tmp_path, capsys):
    data = scans_bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    code = main(["info", str(cut)])
    _one_line_error(capsys, code, str(cut), "bag is truncated: its index should start at byte")


def test_not_a_bag(tmp_path, capsys):
    for name, data, needle in (("empty.bag", b"", "the file is empty"),
                               ("text.bag", b"hello\n" * 100, "not a ROS1 bag"),
                               ("v12.bag", b"#ROSBAG V1.2\n" + bytes(100), "bag format 1.2 is not supported")):
        bag = tmp_path / name
        bag.write_bytes(data)
        code = main(["info", str(bag)])
        _one_line_error(capsys, code, str(bag), needle)
