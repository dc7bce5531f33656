"""A message's payload read where it lies in its decompressed chunk
(``evperc.logs.mcap_source._ChunkBytes``, and ``_ChunkView`` for a chunk decompressed into a
buffer the reading thread keeps): the reads are those of ``io.BytesIO`` (the oracle), long
ones are views of the chunk, a kept buffer is never reused while a view of it lives, and
every decoder still gets what it decodes."""

from __future__ import annotations

import io

import mcap.stream_reader
import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st

from evperc.logs import mcap_source
from evperc.logs.factory import open_log
from evperc.logs.mcap_source import (
    CHUNK_BUFFERS,
    VIEW_MIN_BYTES,
    McapSource,
    _chunk_stream,
    _ChunkBuffers,
    _ChunkBytes,
    _ChunkView,
    _decompress,
)
from tests.bag_writers import write_ros1_mcap
from tests.logs.reference import S0
from tests.mcap_writers import transform, write_json_mcap, write_ros2_mcap

MS = 1_000_000
#: a read size: -1 / None (the rest), 0, short, about the view threshold, past the end
_SIZES = st.one_of(st.none(), st.just(-1), st.integers(0, 64),
                   st.integers(VIEW_MIN_BYTES - 2, VIEW_MIN_BYTES + 2),
                   st.integers(0, 3 * VIEW_MIN_BYTES))


@pytest.mark.parametrize("stream", [_ChunkBytes,  # a chunk mcap decompressed (bytes)
                                    lambda data: _ChunkView(memoryview(bytearray(data)))],
                         ids=["bytes", "kept buffer"])
@settings(max_examples=60, deadline=None)
@given(size=st.integers(0, 3 * VIEW_MIN_BYTES), reads=st.lists(_SIZES, max_size=8),
       seed=st.integers(0, 2**32 - 1))
def test_reads_are_bytesio_reads(stream, size, reads, seed):
    data = np.random.default_rng(seed).integers(0, 256, size, np.uint8).tobytes()
    ours, oracle = stream(data), io.BytesIO(data)
    for n in reads:
        got, want = ours.read(n), oracle.read(n)
        assert bytes(got) == want
        assert ours.tell() == oracle.tell()
        long_read = n is not None and n >= VIEW_MIN_BYTES
        assert isinstance(got, memoryview) is long_read
        assert isinstance(got, bytes) is not long_read
    assert ours.read() == oracle.read()


def test_a_chunk_decompressed_into_a_kept_buffer_is_zstds():
    """The kept buffer holds what ``zstandard.decompress`` gives (several frames, as a
    stream of them, too), a free buffer is reused, a viewed one is not, and a chunk whose
    record gives the wrong size is an error, as it is for mcap's own decompression."""
    rng = np.random.default_rng(1)
    pieces = [rng.integers(0, 7, n, np.uint8).tobytes() for n in (300_000, 120_000)]
    buffers = _ChunkBuffers()
    for data in (pieces[0], pieces[1], pieces[0] + pieces[1]):
        frame = zstandard.compress(data)
        assert buffers.decompress(frame, len(data)).tobytes() == data
    assert len(buffers.buffers) == 1  # each view dropped before the next chunk
    two_frames = zstandard.compress(pieces[0]) + zstandard.compress(pieces[1])
    held = buffers.decompress(two_frames, len(pieces[0]) + len(pieces[1]))
    other = buffers.decompress(zstandard.compress(pieces[1]), len(pieces[1]))
    assert len(buffers.buffers) == 2 and held.obj is not other.obj
    assert held.tobytes() == pieces[0] + pieces[1] and other.tobytes() == pieces[1]
    with pytest.raises(zstandard.ZstdError):
        buffers.decompress(zstandard.compress(pieces[1]), len(pieces[1]) + 1)
    with pytest.raises(zstandard.ZstdError):
        buffers.decompress(zstandard.compress(pieces[1]), len(pieces[1]) - 1)


def test_every_kept_buffer_viewed_gives_bytes_of_their_own():
    buffers = _ChunkBuffers()
    data = bytes(range(256)) * 100
    views = [buffers.decompress(zstandard.compress(data), len(data))
             for _ in range(CHUNK_BUFFERS)]
    assert buffers.decompress(zstandard.compress(data), len(data)) is None
    assert len({id(v.obj) for v in views}) == CHUNK_BUFFERS
    mcap_source._views.on = True
    try:
        got = _decompress(zstandard.compress(data), len(data))
    finally:
        mcap_source._views.on = False
    assert isinstance(got, bytes | memoryview) and bytes(got) == data
    assert _decompress(zstandard.compress(data), len(data)) == data  # outside iter_raw


@pytest.mark.parametrize(("held", "compression"), [(2, "zstd"), (40, "zstd"), (2, "lz4"),
                                                   (2, "none")])
def test_payloads_kept_across_many_chunks_stay_those_written(tmp_path, held, compression):
    """A reader that keeps the payloads it was handed (views of kept buffers: the chunks'
    records read from the file, and zstd's decompressed chunks) while mcap reads the next
    chunks: each still holds what mcap's own reader reads, with a few kept (buffers
    reused) and with more kept than there are buffers (bytes of their own past them); lz4
    and uncompressed chunks, whose records are kept buffers too, alike."""
    from mcap.reader import make_reader

    path = write_ros2_mcap(tmp_path / "d.mcap", clouds=_clouds(40, 6000, seed=11),
                           odometry=_odometry(80), chunk_size=64 * 1024,
                           compression=compression)
    with path.open("rb") as f:
        theirs = [bytes(m.data) for _, _, m in make_reader(f).iter_messages(
            topics=["/points"])]
    kept: list = []
    seen = 0
    for raw in McapSource.open(path).iter_raw(["/points"]):
        kept.append(raw.message.data)
        kept = kept[-held:]
        seen += 1
        assert [bytes(k) for k in kept] == theirs[seen - len(kept):seen]
    assert seen == len(theirs) == 40
    in_kept_buffer = any(isinstance(k, memoryview) and isinstance(k.obj, bytearray)
                         for k in kept)
    assert in_kept_buffer is (compression != "lz4")  # lz4 decompresses into bytes


def test_a_chunk_record_is_read_into_a_kept_buffer_and_short_at_the_end(tmp_path):
    """``_RecordFile``: a long read fills a kept buffer with the file's bytes (a view of
    it), a short one is the file's own ``bytes``, a read past the end is as short as the
    file's, and at the end it is empty."""
    data = np.random.default_rng(4).integers(0, 256, 3 * VIEW_MIN_BYTES, np.uint8).tobytes()
    path = tmp_path / "f.bin"
    path.write_bytes(data)
    with path.open("rb") as f:
        ours = mcap_source._RecordFile(f)
        head = ours.read(10)
        assert isinstance(head, bytes) and head == data[:10]
        body = ours.read(2 * VIEW_MIN_BYTES)
        assert isinstance(body, memoryview) and isinstance(body.obj, bytearray)
        assert body.tobytes() == data[10:10 + 2 * VIEW_MIN_BYTES]
        assert ours.tell() == 10 + 2 * VIEW_MIN_BYTES
        rest = ours.read(2 * VIEW_MIN_BYTES)
        assert rest.tobytes() == data[10 + 2 * VIEW_MIN_BYTES:]
        assert ours.read(VIEW_MIN_BYTES) == b""
        ours.seek(5)
        assert bytes(ours.read(VIEW_MIN_BYTES)) == data[5:5 + VIEW_MIN_BYTES]


def test_mcap_decompresses_into_the_kept_buffers():
    assert mcap.stream_reader.zstandard.decompress is _decompress


def test_a_written_stream_is_a_plain_bytesio():
    stream = _ChunkBytes(bytes(2 * VIEW_MIN_BYTES))
    stream.seek(10)
    stream.write(b"\x07" * 5)
    stream.seek(0)
    data = stream.read(2 * VIEW_MIN_BYTES)
    assert isinstance(data, bytes) and data[8:17] == b"\x00\x00" + b"\x07" * 5 + b"\x00\x00"


def test_mcap_wraps_its_chunks_in_it_for_evperc_only(tmp_path):
    """The hand-over is in place (mcap 1.6 makes a chunk's stream in
    ``get_chunk_data_stream``: if a newer mcap stops, this says so), and mcap read by anyone
    else in the process (here mcap's own reader, beside a read of ours in flight) gives bytes,
    as mcap's decoders expect."""
    from mcap.reader import make_reader

    assert mcap.stream_reader.BytesIO is _chunk_stream
    path = write_ros2_mcap(tmp_path / "d.mcap", clouds=_clouds(2, 6000),
                           odometry=_odometry(6))
    ours = McapSource.open(path).iter_raw(["/points"])
    assert isinstance(next(ours).message.data, memoryview)
    with path.open("rb") as f:
        theirs = [m.data for _, _, m in make_reader(f).iter_messages(topics=["/points"])]
    assert len(theirs) == 2 and all(isinstance(d, bytes) for d in theirs)
    assert isinstance(next(ours).message.data, memoryview)


def _clouds(n, points, seed=3):
    rng = np.random.default_rng(seed)
    return [(S0 + i * 100 * MS, rng.uniform(-40, 40, (points, 3)), "velodyne")
            for i in range(n)]


def _odometry(n):
    return [(S0 - 50 * MS + i * 50 * MS, transform(x=0.5 * i, yaw=0.01 * i)) for i in range(n)]


def test_a_long_payload_is_a_view_and_decodes_the_same(tmp_path):
    """An hdl64-sized ROS 2 cloud (6,000 points × 16 bytes, zstd chunks) comes as a view of
    its chunk; a short pose message as bytes; the scans' points are those written."""
    clouds = _clouds(4, 6000)
    path = write_ros2_mcap(tmp_path / "d.mcap", clouds=clouds, odometry=_odometry(12),
                           tf_static=[("base_link", "velodyne", np.eye(4))])
    source = McapSource.open(path)
    kinds = {}
    for raw in source.iter_raw():
        kinds.setdefault(raw.topic, set()).add(type(raw.message.data))
    assert kinds["/points"] == {memoryview} and kinds["/odom"] == {bytes}
    scans = list(open_log(path).scans())
    assert len(scans) == 4
    for scan, (_, pts, _) in zip(scans, clouds, strict=True):
        np.testing.assert_array_equal(scan.points, pts.astype(np.float32))


def test_ros1_and_json_decoders_get_long_payloads_as_bytes(tmp_path):
    """The decoders that take bytes (mcap-ros1's genpy, json) read long payloads as before:
    the same points from a ROS 1 MCAP written from the ROS 2 one, and from a JSON cloud of
    6,000 points (~97 kB of text, its data base64)."""
    clouds = _clouds(3, 6000)
    ros2 = write_ros2_mcap(tmp_path / "d.mcap", clouds=clouds, odometry=_odometry(10),
                           tf_static=[("base_link", "velodyne", np.eye(4))])
    ros1 = write_ros1_mcap(ros2, tmp_path / "ros1.mcap")
    want = [s.points for s in open_log(ros2).scans()]
    got = [s.points for s in open_log(ros1).scans()]
    assert len(got) == 3
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
    json_clouds = _clouds(2, 6000, seed=5)
    poses = [(S0 - 20 * MS + i * 90 * MS, transform(x=-1.0 * i)) for i in range(4)]
    path = write_json_mcap(tmp_path / "j.mcap", clouds=json_clouds, poses=poses)
    assert max(len(r.message.data) for r in McapSource.open(path).iter_raw()
               if r.topic == "/lidar") >= VIEW_MIN_BYTES
    scans = list(open_log(path).scans())
    assert len(scans) == 2
    for scan, (_, pts, _) in zip(scans, json_clouds, strict=True):
        np.testing.assert_allclose(scan.points, pts.astype(np.float32), rtol=1e-6)


def test_no_buffer_is_kept_where_reference_counts_cannot_tell_a_view(tmp_path, monkeypatch):
    """This CPython tells a viewed buffer from a free one (the probe at import), and where
    a Python could not, a record is read into ``bytes`` of its own, as mcap reads it."""
    assert mcap_source._refcounts_tell_views() and mcap_source._KEEP_BUFFERS
    monkeypatch.setattr(mcap_source, "_KEEP_BUFFERS", False)
    path = tmp_path / "f.bin"
    path.write_bytes(bytes(2 * VIEW_MIN_BYTES))
    with path.open("rb") as f:
        assert isinstance(mcap_source._RecordFile(f).read(2 * VIEW_MIN_BYTES), bytes)
