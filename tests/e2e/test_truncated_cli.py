"""`evperc run` on a log cut short (a recorder killed mid-drive, issue 22 item 1): every scan
whose poses were read is fused, whatever the cut and however the writer laid out its chunks.

The expectation is computed from the full file with the mcap library alone (which chunks end
before the cut, which messages they hold), not with evperc's reader: a scan is expected when
its chunk is complete before the cut and its stamp lies within the stamps of the pose
messages in such chunks (the street drive's poses are 0.1 s apart, within max_pose_gap_s)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from evperc.cli import cli

from .scenes import write_street_drive

SMALL = "[grid]\nwindow_size_m = 30.0\n[output]\nchunk_frames = 4\n"


def chunk_layout(path: Path) -> list[tuple[int, int, list[tuple[str, int]]]]:
    """(start offset, end offset, [(topic, log time)]) of each chunk of a complete file."""
    chunks, channels = [], {}
    with path.open("rb") as f:
        for_offsets = StreamReader(f, emit_chunks=True).records
        while True:
            start = f.tell()
            record = next(for_offsets, None)
            if record is None:
                break
            if not isinstance(record, Chunk):
                continue
            messages = []
            for item in breakup_chunk(record):
                if hasattr(item, "topic"):
                    channels[item.id] = item.topic
                elif isinstance(item, Message):
                    messages.append((channels[item.channel_id], item.log_time))
            chunks.append((start, f.tell(), messages))
    return chunks


def expected_stamps(chunks: list, cut: int) -> list[int]:
    readable = [m for start, end, messages in chunks if end <= cut for m in messages]
    poses = [t for topic, t in readable if topic == "/odom"]
    if not poses:
        return []
    return sorted(t for topic, t in readable
                  if topic == "/scan" and min(poses) <= t <= max(poses))


def cut_points(chunks: list, size: int) -> list[int]:
    """Every chunk's start and end (and one byte after it), its middle, and a
    point inside the summary section after the last chunk."""
    points = set()
    for start, end, _ in chunks:
        points.update({start, (start + end) // 2, end, end + 1})
    points.add((chunks[-1][1] + size) // 2)
    return sorted(p for p in points if 0 < p < size)


@pytest.mark.parametrize("poses_first", [False, True], ids=["log-time-order", "poses-first"])
def test_every_scan_with_poses_read_is_fused_at_every_cut(tmp_path: Path,
                                                          poses_first: bool) -> None:
    full = write_street_drive(tmp_path / "full.mcap", n_scans=40, beams=180,
                              chunk_size=6000, poses_first=poses_first)
    chunks = chunk_layout(full)
    # 4 s of drive: longer than the reader's wait for poses (max_pose_gap_s + 1 s), so a
    # reader that took the file order for log-time order would have let the early poses go
    assert len(chunks) >= 5, len(chunks)  # the test needs several chunks to cut between
    data = full.read_bytes()
    config = tmp_path / "small.toml"
    config.write_text(SMALL)
    seen_partial = 0
    for cut in cut_points(chunks, len(data)):
        cut_path = tmp_path / f"cut_{cut}.mcap"
        cut_path.write_bytes(data[:cut])
        out = tmp_path / f"out_{cut}"
        result = CliRunner().invoke(cli, ["run", str(cut_path), "--no-map", "--config",
                                          str(config), "--out", str(out)])
        expected = expected_stamps(chunks, cut)
        if not expected:
            # nothing to fuse ("no scan could be fused", or "no lidar topic" when the cut
            # comes before the scans' channel): one line naming the log, exit 2 (bad input),
            # no output left
            assert result.exit_code == 2, (cut, result.output)
            errors = [line for line in result.output.splitlines()
                      if line.startswith("evperc: error")]
            assert len(errors) == 1 and str(cut_path) in errors[0], (cut, result.output)
            assert not out.exists(), cut
            continue
        assert result.exit_code == 0, (cut, result.output)
        manifest = json.loads((out / "manifest.json").read_text())
        assert manifest["complete"] is True
        import evperc

        stamps = [frame.stamp_ns for frame in evperc.load(out).frames]
        assert stamps == expected, (cut, len(stamps), len(expected))
        seen_partial += 0 < len(expected) < 40
    assert seen_partial >= 3  # the cuts did land between scans
