"""Real LiDAR quirks, judged per beam: a sector blocked by the robot's body, the driver's "nothing seen"
codes below range_min, and NaN readings.

A beam that has (nearly) never returned anything is masked as blocked: it clears no free space, whatever
``paint.below_range_min`` and ``paint.nan_readings`` say. The same readings on a beam that sees out
follow those settings.
"""

import contextlib
import logging
import math
from itertools import islice
from types import SimpleNamespace

import numpy as np
import pytest

from semmap.classes import load_class_table
from semmap.config import PaintConfig, SyncConfig
from semmap.io.bag import iter_messages
from semmap.io.messages import scan_from_msg
from semmap.paint.painter import Painter, PaintStats
from semmap.pipeline import _warn_about_painting
from semmap.records import Scan

N = 271  # beams from -135° to +135°, one per degree
A0, INC = math.radians(-135.0), math.radians(1.0)
R_MIN, R_MAX = 0.02, 5.6  # a Hokuyo URG-04LX's limits
BLOCKED = slice(0, 15)  # -135° to -121°: the robot's body is in the way
SPORADIC = slice(100, 110)  # beams that see the room, with the odd "nothing seen" code
NAN = slice(200, 210)
NO_CLEAR = 0.0  # a beam that clears nothing: its point stays at the LiDAR


def _painter(**paint) -> Painter:
    return Painter(np.eye(4), None, (), load_class_table(), PaintConfig(**paint), SyncConfig(), 10.0)


def _room() -> np.ndarray:
    """Walls 3 m away all round; the blocked sector reads the URG's 0.019 m."""
    r = np.full(N, 3.0)
    r[BLOCKED] = 0.019
    return r


def _cleared(painter: Painter, ranges: np.ndarray, i: int = 0) -> np.ndarray:
    """Paint one scan: how far each beam clears free space (its point's distance from the LiDAR), m."""
    scan = Scan(i * 100_000_000, "laser", A0, INC, np.asarray(ranges, np.float32), R_MIN, R_MAX)
    p = painter.paint(scan, None, None).painted
    return np.hypot(*(p.points - p.origin).T)


def _tour(painter: Painter, scans: int, odd: tuple[slice, float] | None = None, wall: float = 3.0) -> np.ndarray:
    """Paint ``scans`` scans of the room, walls ``wall`` m away; in every other scan the beams ``odd[0]`` read
    ``odd[1]``. The cleared distances of each scan, (scans, N)."""
    out = []
    for i in range(scans):
        r = _room()
        r[r == 3.0] = wall
        if odd is not None and i % 2:
            r[odd[0]] = odd[1]
        out.append(_cleared(painter, r, painter.stats.scans))
    return np.array(out)


@pytest.mark.parametrize("setting", ["invalid", "no_return"])
def test_a_blocked_sector_clears_nothing_in_any_scan(setting):
    painter = _painter(below_range_min=setting, nan_readings=setting)
    d = _tour(painter, 60)
    assert np.all(d[:, BLOCKED] == NO_CLEAR)  # from the first scan on, never through the walls behind the robot
    assert np.allclose(d[:, 15:], 3.0)
    # NaN on the blocked sector is masked the same way
    r = _room()
    r[BLOCKED] = np.nan
    assert np.all(_cleared(painter, r, 60)[BLOCKED] == NO_CLEAR)


@pytest.mark.parametrize(("setting", "expected"), [("no_return", R_MAX), ("invalid", NO_CLEAR)])
def test_sporadic_codes_below_range_min_follow_the_setting(setting, expected):
    painter = _painter(below_range_min=setting)
    _tour(painter, 5)
    r = _room()
    r[SPORADIC] = 0.006  # the URG's "possibly an object beyond the range"
    d = _cleared(painter, r, 5)
    assert np.allclose(d[SPORADIC], expected)  # no_return: to the range limit, min(range_max, grid limit)
    assert np.all(d[BLOCKED] == NO_CLEAR)


@pytest.mark.parametrize(("setting", "expected"), [("no_return", R_MAX), ("invalid", NO_CLEAR)])
def test_nan_readings_follow_their_own_setting(setting, expected):
    painter = _painter(nan_readings=setting)  # below_range_min stays "invalid"
    _tour(painter, 5)
    r = _room()
    r[NAN] = np.nan
    r[SPORADIC] = 0.006
    d = _cleared(painter, r, 5)
    assert np.allclose(d[NAN], expected)
    assert np.all(d[SPORADIC] == NO_CLEAR)


def test_a_beam_that_has_not_returned_yet_clears_nothing():
    """The first scans are judged conservatively: "nothing seen" clears only once the beam has seen out."""
    painter = _painter(below_range_min="no_return")
    r = _room()
    r[SPORADIC] = 0.006
    assert np.all(_cleared(painter, r, 0)[SPORADIC] == NO_CLEAR)  # the very first scan: unknown yet
    _cleared(painter, _room(), 1)  # the beams return once
    assert np.allclose(_cleared(painter, r, 2)[SPORADIC], R_MAX)


def test_a_blocked_beam_stays_blocked_through_a_spurious_return():
    """Blocked in (nearly) every scan: one return in a hundred scans (paint.blocked_share 1 %) keeps the mask."""
    painter = _painter(below_range_min="no_return")
    _tour(painter, 100)
    r = _room()
    r[3] = 0.03  # a reflection off the robot's body, just above range_min
    _cleared(painter, r, 100)
    d = _tour(painter, 20)
    assert np.all(d[:, BLOCKED] == NO_CLEAR)
    assert painter.stats.blocked_beams == 15


def test_stats_count_blocked_beams_nan_and_sporadic_readings():
    painter = _painter(below_range_min="no_return", blocked_min_scans=50)
    _tour(painter, 49)
    assert painter.stats.blocked == {}  # not judged before paint.blocked_min_scans scans
    r = _room()
    r[SPORADIC] = 0.007
    r[NAN] = np.nan
    _cleared(painter, r, 49)
    s = painter.stats
    assert s.beams == 50 * N
    assert s.below_range_min == 50 * 15 + 10 and s.below_range_min_unblocked == 10
    assert s.nan_readings == 10 and s.nan_unblocked == 10
    (blocked,) = s.blocked.values()
    assert blocked.count == 15 and s.blocked_beams == 15 and blocked.scans == 50
    assert blocked.layout == (A0, INC, N)
    ((first, last, beams),) = blocked.sectors
    assert (math.degrees(first), math.degrees(last), beams) == (pytest.approx(-135.0), pytest.approx(-121.0), 15)
    assert math.degrees(blocked.span) == pytest.approx(15.0)
    _tour(painter, 10)
    assert s.blocked[A0, INC, N].scans == 60


def test_a_sector_across_the_seam_of_a_full_turn_is_one_sector():
    painter = Painter(np.eye(4), None, (), load_class_table(), PaintConfig(blocked_min_scans=1), SyncConfig(), 10.0)
    r = np.full(360, 3.0)
    r[:5] = r[-5:] = 0.0
    painter.paint(Scan(0, "laser", -math.pi, math.radians(1.0), r.astype(np.float32), R_MIN, R_MAX), None, None)
    (blocked,) = painter.stats.blocked.values()
    ((first, last, beams),) = blocked.sectors
    assert (round(math.degrees(first)), round(math.degrees(last)), beams) == (175, -176, 10)


def _warnings(caplog, stats: PaintStats, **paint) -> list[str]:
    tinfo = SimpleNamespace(topics=SimpleNamespace(scan="/scan", image=None))
    run = SimpleNamespace(painter=SimpleNamespace(stats=stats))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="semmap.pipeline"):
        _warn_about_painting(tinfo, SimpleNamespace(paint=PaintConfig(**paint)), run)  # type: ignore[arg-type]
    return [rec.getMessage() for rec in caplog.records]


def test_warnings_name_the_blocked_sector_and_advise_from_the_rest(caplog):
    painter = _painter()
    _tour(painter, 60)  # the blocked sector is 5.5 % of the readings; nothing else is below range_min
    (msg,) = _warnings(caplog, painter.stats)
    assert msg == ("beams -135.0° to -121.0° (15) on /scan read below range_min or NaN in (nearly) every one "
                   "of 60 scans: masked as blocked, they clear no free space")
    # the driver's "nothing seen" on 20 beams that see the walls in every other scan: 3.7 % of the readings
    sporadic = _painter()
    _tour(sporadic, 60, (slice(100, 120), 0.006))
    msgs = _warnings(caplog, sporadic.stats)
    assert len(msgs) == 2 and msgs[1].startswith("4 % of the readings on /scan are below range_min on beams not "
                                                 "blocked")
    assert msgs[1].endswith("set paint.below_range_min: no_return")
    assert len(_warnings(caplog, sporadic.stats, below_range_min="no_return")) == 1


def test_nan_warnings_advise_no_return_only_where_nothing_is_within_range(caplog):
    wide = slice(200, 220)  # 20 beams that read NaN in every other scan: 3.7 % of the readings
    far, near = _painter(), _painter()
    _tour(far, 60, (wide, np.nan), wall=5.0)  # down a corridor: the returns beside the NaN beams are far
    _tour(near, 60, (wide, np.nan), wall=1.0)  # dropouts on a near wall (glass, black paint)
    (_, msg) = _warnings(caplog, far.stats)
    assert msg.startswith("4 % of the readings on /scan are NaN on beams not blocked, and clear no free space")
    assert msg.endswith("set paint.nan_readings: no_return")
    (_, msg) = _warnings(caplog, near.stats)
    assert "dropouts" in msg and "no_return" not in msg
    assert len(_warnings(caplog, far.stats, nan_readings="no_return")) == 1  # the blocked sector only
    (_, msg) = _warnings(caplog, near.stats, nan_readings="no_return")
    assert "consider paint.nan_readings: invalid" in msg


def test_the_hokuyo_bags_blocked_sector_is_found_in_50_scans(data_dir):
    """The URG-04LX on the may9 robot: 44 beams from -135° to -120° read 0.019 m in every scan."""
    bag = data_dir / "hokuyo_odom_bags" / "2018_may9_editted_before1.bag"
    if not bag.is_file():
        pytest.skip(f"{bag} is absent")
    painter = _painter(below_range_min="no_return", nan_readings="no_return")
    with contextlib.closing(iter_messages(bag, ["/scan"])) as msgs:
        for _, _, msg in islice(msgs, 50):
            scan = scan_from_msg(msg)
            p = painter.paint(scan, None, None).painted
            d = np.hypot(*(p.points - p.origin).T)
            deg = np.degrees(scan.angles)
            assert np.all(d[(deg > -135.1) & (deg < -119.8)] == NO_CLEAR)
    s = painter.stats
    (blocked,) = s.blocked.values()
    assert blocked.scans == 50 and blocked.count == 44
    ((first, last, beams),) = blocked.sectors  # none elsewhere
    assert beams == 44
    assert math.degrees(first) == pytest.approx(-135.0, abs=0.05)
    assert math.degrees(last) == pytest.approx(-119.9, abs=0.05)
    assert math.degrees(blocked.span) == pytest.approx(15.5, abs=0.1)
    # the driver's other codes and the NaN readings, on beams that see out, clear to the range limit
    assert 0 < s.below_range_min_unblocked < 0.05 * s.below_range_min
    assert s.nan_unblocked > 0
