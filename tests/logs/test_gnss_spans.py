"""A long log is geo-referenced from the GNSS fixes of a few spans of it, not from all of it
(evperc.logs.message_log.LogReader.gnss_spans; docs/performance.md, "Start-up")."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest

from evperc.config import load_config
from evperc.logs import message_log
from evperc.logs.factory import open_log
from evperc.runner import geo_reference
from tests.logs.reference import S0
from tests.mcap_writers import transform, write_ros2_mcap

MS = 1_000_000
UTM35 = "EPSG:32635"
#: where the log's world origin lies in UTM 35N, and the grid angle of its x axis
ORIGIN_E, ORIGIN_N, HEADING = 385_000.0, 6_672_000.0, math.radians(37.0)


def _drive(tmp_path, seconds: float, rate_hz: float = 10.0, fix_every: int = 1):
    """A log of ``seconds``: odometry in a local frame along a quarter circle of 300 m
    radius, and noise-free fixes of the body at the same stamps (every ``fix_every``-th),
    placed by the known origin and heading (pyproj inverse: an oracle independent of the
    fit)."""
    n = int(seconds * rate_hz)
    stamps = [S0 + round(i * 1e9 / rate_hz) for i in range(n)]
    arc = np.linspace(0.0, math.pi / 2, n)
    x, y = 300.0 * np.sin(arc), 300.0 * (1.0 - np.cos(arc))
    odometry = [(s, transform(x=float(a), y=float(b), yaw=float(t)))
                for s, a, b, t in zip(stamps, x, y, arc, strict=True)]
    c, s_ = math.cos(HEADING), math.sin(HEADING)
    east, north = ORIGIN_E + c * x - s_ * y, ORIGIN_N + s_ * x + c * y
    lon, lat = pyproj.Transformer.from_crs(UTM35, "EPSG:4326", always_xy=True).transform(
        east, north)
    fixes = [(s, float(b), float(a), 10.0)
             for s, a, b in zip(stamps, lon, lat, strict=True)][::fix_every]
    clouds = [(stamps[0], np.array([[5.0, 0.0, 0.5]]), "base_link"),
              (stamps[-1], np.array([[5.0, 0.0, 0.5]]), "base_link")]
    path = write_ros2_mcap(tmp_path / "long.mcap", clouds=clouds, odometry=odometry,
                           fixes=fixes, chunk_size=8 * 1024)
    return path, n


def _counting(reader):
    """``reader`` whose source counts the messages it yields per topic."""
    counts: dict[str, int] = {}
    iter_raw = reader.source.iter_raw

    def counted(topics=None, start_ns=None, end_ns=None):
        for raw in iter_raw(topics, start_ns, end_ns):
            counts[raw.topic] = counts.get(raw.topic, 0) + 1
            yield raw

    reader.source.iter_raw = counted
    return counts


def test_spans_of_a_long_log(tmp_path):
    path, n = _drive(tmp_path, 100.0)
    reader = open_log(path)
    spans = reader.gnss_spans()
    width = int(message_log.GNSS_SPAN_S * 1e9)
    assert len(spans) == message_log.GNSS_SPANS
    assert all(b - a == width for a, b in spans)
    # from the first message to the last, evenly spaced (to the nanosecond's rounding)
    assert spans[0][0] == reader.source.start_ns
    assert abs(spans[-1][1] - reader.source.end_ns) <= 1
    steps = np.diff([a for a, _ in spans])
    assert steps.max() - steps.min() <= 1 and steps.min() > width


def test_a_short_log_is_read_whole(tmp_path):
    path, _ = _drive(tmp_path, message_log.GNSS_SPANS * message_log.GNSS_SPAN_S)
    assert open_log(path).gnss_spans() == [(None, None)]


def test_a_source_that_cannot_seek_is_read_whole(tmp_path):
    """An unindexed file is read from its start for every span: one pass instead."""
    path, _ = _drive(tmp_path, 100.0)
    reader = open_log(path)
    assert reader.source.seeks
    reader.source.seeks = False
    assert reader.gnss_spans() == [(None, None)]


@pytest.mark.parametrize("kind", ["rosbag1", "rosbag2_sqlite"])
def test_bags_are_geo_referenced_from_their_spans(tmp_path, kind):
    """A ROS 1 bag (its index by time in memory) and a ROS 2 sqlite3 bag (a query per span)
    seek by time: the same spans, the same fit, from a fraction of the fixes."""
    from tests.bag_writers import write_rosbag1, write_rosbag2_sqlite

    src, n = _drive(tmp_path, 400.0, rate_hz=5.0)
    bag = (write_rosbag1(src, tmp_path / "long.bag") if kind == "rosbag1"
           else write_rosbag2_sqlite(src, tmp_path / "long_bag"))
    reader = open_log(bag)
    assert reader.source.seeks
    assert len(reader.gnss_spans()) == message_log.GNSS_SPANS
    counts = _counting(reader)
    georef = geo_reference(reader, load_config(overrides={"map.crs": UTM35}), need_crs=True)
    assert abs(georef.heading_rad - HEADING) < 1e-7
    np.testing.assert_allclose(georef.T_crs_world[:2, 3], [ORIGIN_E, ORIGIN_N], atol=1e-3)
    assert counts["/fix"] <= message_log.GNSS_SPANS * (_read_s() * 5 + 1)


def _read_s() -> float:
    """Seconds of log one span's read takes (LogReader.gnss_span: the fixes and poses
    together, from max_pose_gap_s + 1 s of slack before the span to its end)."""
    return message_log.GNSS_SPAN_S + load_config()["input"]["max_pose_gap_s"] + 1.0


def test_a_ros2_bag_with_mcap_storage_is_read_whole(tmp_path):
    """rosbags scans an MCAP storage file from its start when it has no chunk index, and
    does not say which: such a bag is not taken to seek."""
    from tests.mcap_writers import write_rosbags_mcap

    t = [S0 + i * 100 * MS for i in range(3)]
    write_rosbags_mcap(tmp_path / "bag", clouds=[(s, np.array([[5.0, 0.0, 0.5]]), "base_link")
                                                  for s in t],
                       odometry=[(s, transform(x=0.1 * i)) for i, s in enumerate(t)])
    reader = open_log(tmp_path / "bag")
    assert not reader.source.seeks
    assert reader.gnss_spans() == [(None, None)]


def test_long_log_geo_reference_from_its_spans(tmp_path):
    path, n = _drive(tmp_path, 400.0, rate_hz=5.0)
    reader = open_log(path)
    counts = _counting(reader)
    config = load_config(overrides={"map.crs": UTM35})
    georef = geo_reference(reader, config, need_crs=True)
    # noise-free fixes: the fit recovers the placement to float round-off; 1 mm and 1e-7 rad
    # are far above that (~1e-9 m from pyproj's round trip) and far below a cell
    assert abs(georef.heading_rad - HEADING) < 1e-7
    np.testing.assert_allclose(georef.T_crs_world[:2, 3], [ORIGIN_E, ORIGIN_N], atol=1e-3)
    # what was read: the spans only — each from max_pose_gap_s + 1 s of slack before it to
    # its end, fixes and poses in one read, then the poses after it to the first after its
    # last fix
    spans = message_log.GNSS_SPANS
    assert counts["/fix"] <= spans * (_read_s() * 5 + 1)
    assert counts["/odom"] <= spans * (_read_s() + 0.2) * 5 + 1  # + the body frame's first
    assert counts["/odom"] < n / 3


def test_short_log_geo_reference_reads_every_fix(tmp_path):
    path, n = _drive(tmp_path, 20.0)
    reader = open_log(path)
    counts = _counting(reader)
    georef = geo_reference(reader, load_config(overrides={"map.crs": UTM35}), need_crs=True)
    assert abs(georef.heading_rad - HEADING) < 1e-7
    assert counts["/fix"] == n


def test_the_summary_is_parsed_once(tmp_path, monkeypatch):
    """The geo-reference's ~35 time-range reads reuse the summary read at open (each parse
    walks every chunk index: O(log length) per read otherwise)."""
    from mcap.reader import SeekingReader

    path, _ = _drive(tmp_path, 400.0, rate_hz=5.0)
    parse = SeekingReader.get_summary
    parses = []

    def counted(self):
        parses.append(1)
        return parse(self)

    monkeypatch.setattr(SeekingReader, "get_summary", counted)
    reader = open_log(path)
    assert len(parses) == 1
    geo_reference(reader, load_config(overrides={"map.crs": UTM35}), need_crs=True)
    assert len(parses) == 1


def test_a_sparse_gnss_topic_falls_back_to_every_fix(tmp_path):
    """Fixes every 10 s: the 2 s spans hold fewer than one a span, so every fix is read."""
    path, n = _drive(tmp_path, 400.0, rate_hz=5.0, fix_every=50)
    reader = open_log(path)
    assert len(reader.gnss_spans()) == message_log.GNSS_SPANS
    counts = _counting(reader)
    georef = geo_reference(reader, load_config(overrides={"map.crs": UTM35}), need_crs=True)
    assert abs(georef.heading_rad - HEADING) < 1e-7
    assert counts["/fix"] >= n // 50  # the spans' few, then all of them


@pytest.mark.parametrize("seconds", [400.0, 20.0])
def test_one_read_of_a_span_gives_what_two_reads_give(tmp_path, seconds):
    """LogReader.gnss_span (the fixes and poses of a span in one read) against the two reads
    it replaces, gnss_fixes then positions_at (which a long log read whole still takes):
    the same fixes and the same positions, bit for bit, span by span — a long log's 16
    spans, and a short log as one span — and when the poses it holds do not reach (a fix
    stamped before them; none held), it reads the rest as positions_at does."""
    from dataclasses import replace

    path, _ = _drive(tmp_path, seconds, rate_hz=5.0)
    reader = open_log(path)
    spans = reader.gnss_spans()
    if spans == [(None, None)]:
        spans = [(reader.start_ns, reader.end_ns + 1)]
    assert len(spans) == (message_log.GNSS_SPANS if seconds > 40 else 1)
    for a, b in spans:
        span = reader.gnss_span(a, b)
        fixes = reader.gnss_fixes(a, b)
        assert len(fixes) > 0
        np.testing.assert_array_equal(span.fixes, fixes)
        frame = reader.gnss_antenna_frame()
        want = reader.positions_at(fixes[:, 0].astype(np.int64), frame)
        assert not np.isnan(want).any()
        np.testing.assert_array_equal(span.positions(frame), want)
        late = replace(span, read_from_ns=span.read_from_ns + 10**9)
        np.testing.assert_array_equal(late.positions(frame), want)
        empty = replace(span, poses=[], read_to_ns=span.read_from_ns)
        np.testing.assert_array_equal(empty.positions(frame), want)


def test_geo_reference_from_one_read_equals_two_reads(tmp_path):
    """The placement geo_reference fits from the spans read once each is the one the two
    reads give (gnss_fixes and positions_at per span, fitted by georef.from_gnss): the same
    numbers, not within a tolerance."""
    from evperc.geo import georef as georef_mod
    from evperc.geo.crs import working_crs

    path, _ = _drive(tmp_path, 400.0, rate_hz=5.0)
    config = load_config(overrides={"map.crs": UTM35})
    got = geo_reference(open_log(path), config, need_crs=True)
    reader = open_log(path)
    fixes = [reader.gnss_fixes(a, b) for a, b in reader.gnss_spans()]
    frame = reader.gnss_antenna_frame()
    xy = np.concatenate([reader.positions_at(f[:, 0].astype(np.int64), frame)[:, :2]
                         for f in fixes])
    every = np.concatenate(fixes)
    crs = working_crs(UTM35, (float(every[0, 2]), float(every[0, 1])))
    want = georef_mod.from_gnss(xy, every[:, [2, 1]], crs)
    assert got.heading_rad == want.heading_rad
    np.testing.assert_array_equal(got.T_crs_world, want.T_crs_world)
