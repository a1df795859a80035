"""Reading a bag costs memory that does not grow with the bag.

rosbags' ROS1 reader keeps one Python record per message of *every* topic while a bag is open (about
180 bytes per bag message: 58 MB for a 30-minute tour, in each of the readers a build holds open).
semmap reads a ROS1 bag whose index is as ROS writes it through a table of its chunks instead, and
reads a chunk's index only when the stream gets there. These tests write bags with many messages on a
topic nobody reads (``/tf``) beside a few scans, and measure (tracemalloc) what opening the bag,
counting the scans and streaming them costs (ROS1, MCAP and sqlite3); and check that the messages come in
rosbags' own order where chunks overlap in time, where messages share a time, and in compressed chunks.
"""

from __future__ import annotations

import gc
import itertools
import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from semmap.io.bag import BagWriter, iter_messages, message_count, open_bag
from semmap.records import Scan

SCANS = 100
FEW, MANY = 5_000, 50_000  # messages on /tf
#: what a message nobody reads may cost while the bag is open and streamed (rosbags' ROS1 reader: ~140 B)
BYTES_PER_UNWANTED = 2.0


def _tour(path: Path, fmt: str, unwanted: int) -> Path:
    """``SCANS`` scans at 15 Hz, ``unwanted`` small /tf messages between them."""
    ident = np.eye(4)
    per = unwanted // SCANS
    with BagWriter(path, fmt) as w:
        for i in range(SCANS):
            t0 = 1_700_000_000 * 10**9 + i * 66_666_666
            w.scan("/scan", t0, Scan(stamp_ns=t0, frame_id="laser", angle_min=-1.0, angle_increment=0.01,
                                     ranges=np.ones(200, np.float32), range_min=0.1, range_max=10.0))
            for j in range(per):
                t = t0 + 1000 * (j + 1)
                w.transforms("/tf", t, [(t, "odom", "base_link", ident)])
    return path


def _cost(bag: Path) -> tuple[int, int, int, int]:
    """(bytes held by the open bag, peak bytes while it is opened, counted and its scans streamed, scans
    counted, scans read), as a build reads its scans: one reader, counted, then streamed."""
    import semmap.io.fastbag as fastbag

    getattr(fastbag, "_TABLES", {}).clear()  # measure the first open of the bag, not a cached one
    gc.collect()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    with open_bag(bag) as reader:
        held = tracemalloc.get_traced_memory()[0] - base
        counted = message_count(bag, "/scan", reader)
        read = sum(1 for _ in iter_messages(bag, ["/scan"], reader=reader))
        peak = tracemalloc.get_traced_memory()[1] - base
    return held, peak, counted, read


@pytest.mark.parametrize("fmt", ["ros1", "mcap", "sqlite3"])
def test_memory_does_not_grow_with_messages_nobody_reads(tmp_path, fmt):
    suffix = ".bag" if fmt == "ros1" else ""
    few = _tour(tmp_path / f"few{suffix}", fmt, FEW)
    many = _tour(tmp_path / f"many{suffix}", fmt, MANY)
    tracemalloc.start()
    try:
        _cost(few)  # the first bag opened pays for imports and type stores
        held_few, peak_few, counted, read = _cost(few)
        assert counted == read == SCANS
        held_many, peak_many, counted, read = _cost(many)
        assert counted == read == SCANS
    finally:
        tracemalloc.stop()
    extra = MANY - FEW
    assert held_many - held_few < BYTES_PER_UNWANTED * extra, (held_few, held_many)
    assert peak_many - peak_few < BYTES_PER_UNWANTED * extra, (peak_few, peak_many)
    assert held_many < 1 << 20 and peak_many < 4 << 20, (held_many, peak_many)  # under 1 MB and 4 MB


# -- the same messages as rosbags, in its order ------------------------------------------------------------


def _tangled(path: Path, compression: str | None) -> Path:
    """A ROS1 bag in chunks of about 1 kB that overlap in time (messages written out of time order), with
    messages that share a time on one topic and across topics; each message's data is its serial number."""
    from rosbags.rosbag1 import Writer

    from semmap.io.bag import _typestore

    rng = np.random.default_rng(7)
    store = _typestore("ros1")
    writer = Writer(path)
    writer.chunk_threshold = 1024
    if compression:
        writer.set_compression(Writer.CompressionFormat[compression.upper()])
    with writer:
        conns = [writer.add_connection(topic, "std_msgs/msg/UInt32", typestore=store, callerid=node)
                 for topic, node in (("/a", "/one"), ("/b", "/one"), ("/c", "/one"), ("/a", "/two"))]  # /a: two
        base = 1_700_000_000 * 10**9
        for serial in range(3000):
            t = base + int(rng.integers(0, 400)) * 10**7 + (serial // 50) * 10**8  # drifts forward, jumps back
            writer.write(conns[int(rng.integers(0, 4))], t, struct.pack("<I", serial))
    return path


def _theirs(bag: Path, topics: list[str] | None, start=None, stop=None, reverse=False):
    """(topic, bag time, bytes) as rosbags' own reader gives them."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        conns = conns[::-1] if reverse else conns
        return ([(c.topic, t, bytes(raw)) for c, t, raw in reader.messages(connections=conns, start=start, stop=stop)],
                [(c.id, c.topic, c.msgcount) for c in reader.connections],
                (reader.start_time, reader.end_time, reader.message_count),
                {name: info.msgcount for name, info in reader.topics.items()})


@pytest.mark.parametrize("compression", [None, "bz2", "lz4"])
def test_overlapping_chunks_read_in_rosbags_order(tmp_path, monkeypatch, compression):
    import semmap.io.fastbag as fastbag
    from semmap.io.fastbag import Ros1Reader, ros1_records

    bag = _tangled(tmp_path / "tangled.bag", compression)
    with open_bag(bag) as reader:
        assert isinstance(reader.readers[0], Ros1Reader)  # no per-message index
        table = reader.readers[0].table
        assert len(table.t_min) > 20 and np.any(table.t_min[1:] < table.t_max[:-1])  # chunks do overlap
        start, end = reader.start_time, reader.end_time
    monkeypatch.setattr(fastbag, "_SPARSE_MIN_BYTES", 0)  # record by record wherever the chunks allow it
    monkeypatch.setattr(fastbag, "_RELEASE_BYTES", 4096)
    mid = (start + end) // 2
    for topics, lo, hi, reverse in ((None, None, None, False), (["/a"], None, None, False),
                                    (["/a", "/c"], None, None, True),
                                    (["/b", "/c"], mid, mid + 10**9, False), (None, start, mid, True)):
        want, conns, times, counts = _theirs(bag, topics, lo, hi, reverse)
        with open_bag(bag) as reader:
            assert [(c.id, c.topic, c.msgcount) for c in reader.connections] == conns
            assert (reader.start_time, reader.end_time, reader.message_count) == times
            assert {name: info.msgcount for name, info in reader.topics.items()} == counts
            mine = [c for c in reader.connections if topics is None or c.topic in topics]
            mine = mine[::-1] if reverse else mine
            got = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages(connections=mine, start=lo, stop=hi)]
            assert got == want
            records = ros1_records(reader, mine)
            assert (records is None) == (compression is not None)
            if records is not None and lo is None:
                kept = list(records)  # views of the mapped bag, held while pages read past are handed back
                assert all(isinstance(raw, memoryview) for _, _, raw in kept)
                assert [(c.topic, t, bytes(raw)) for c, t, raw in kept] == want
    want = [(topic, t, struct.unpack("<I", raw)[0]) for topic, t, raw in _theirs(bag, ["/a", "/b"])[0]]
    assert len(want) > 1000
    assert [(topic, t, msg.data) for topic, t, msg in iter_messages(bag, ["/a", "/b"])] == want


def _tangled_mcap(path: Path) -> Path:
    """An MCAP bag in several 1 MiB chunks that overlap in time, messages sharing times across topics."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from semmap.io.bag import _typestore

    rng = np.random.default_rng(11)
    store = _typestore("mcap")
    string_t = store.types["std_msgs/msg/String"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = [writer.add_connection(topic, "std_msgs/msg/String", typestore=store) for topic in ("/a", "/b", "/c")]
        base = 1_700_000_000 * 10**9
        for serial in range(2500):
            t = base + int(rng.integers(0, 200)) * 10**7 + (serial // 100) * 10**9
            raw = store.serialize_cdr(string_t(data=f"{serial:06d}" + "x" * 4000), "std_msgs/msg/String")
            writer.write(conns[int(rng.integers(0, 3))], t, raw)
    return path


def test_mcap_chunks_read_in_rosbags_order(tmp_path, monkeypatch):
    """MCAP messages read record by record, each chunk's index read when the stream reaches it: rosbags'
    order where chunks overlap in time."""
    import semmap.io.fastbag as fastbag
    from semmap.io.fastbag import mcap_records

    bag = _tangled_mcap(tmp_path / "tangled")
    monkeypatch.setattr(fastbag, "_SPARSE_MIN_BYTES", 0)
    for topics in (["/a"], ["/a", "/c"], ["/c", "/b", "/a"]):
        want = _theirs(bag, topics)[0]
        with open_bag(bag) as reader:
            chunks = reader.readers[0].storage.storages[0].chunks
            assert len(chunks) > 5
            assert any(b.message_start_time < a.message_end_time for a, b in itertools.pairwise(chunks))
            conns = [c for c in reader.connections if c.topic in topics]
            records = mcap_records(reader, conns)
            assert records is not None
            assert [(c.topic, t, bytes(raw)) for c, t, raw in records] == want
