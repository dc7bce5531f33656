"""`evperc render` on real output folders: PNG frames, GIF, --frames, --compare, errors."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from click.testing import CliRunner

from evperc.cli import cli
from evperc.errors import UsageError
from evperc.render.run_render import parse_frames
from tests.render.conftest import CODES, make_frame, write_run

ROWS, COLS = 20, 20       # auto scale: 400 // 20 = 20 px per cell


def drive(n: int, first_stamp: int = 1_000_000_000) -> list:
    """n frames, 0.1 s apart, window moving one column east per frame; frame k has one
    moving cell at window (5, 5 + k % 3) and ego far outside."""
    frames = []
    for k in range(n):
        f = make_frame(ROWS, COLS, col0=k, stamp_ns=first_stamp + k * 100_000_000, index=k,
                       pose=(-500.0, -500.0, 0.0))
        f.decision[5, 5 + k % 3] = CODES["moving"]
        f.betp[5, 5 + k % 3] = [0, 0, 0, 0, 1]
        frames.append(f)
    return frames


def invoke(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def cell_centre(row: int, col: int, left: int, top: int, px: int = 20) -> tuple[int, int]:
    return top + (ROWS - 1 - row) * px + px // 2, left + col * px + px // 2


def test_png_frames_show_the_moving_cell(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", drive(5))
    dest = tmp_path / "png"
    result = invoke("render", str(out), "--dest", str(dest), "--layers", "decision,betp")
    assert result.exit_code == 0, result.output
    names = sorted(p.name for p in dest.iterdir())
    assert names == [f"frame_{k:05d}.png" for k in range(5)]
    image = iio.imread(dest / "frame_00004.png")
    # layout: margin 8, title 16 → panel 0 at (left 8, top 24), panel 1 at left 8+400+10
    y, x = cell_centre(5, 5 + 4 % 3, 8, 24)
    assert tuple(image[y, x]) == (255, 0, 0)
    y, x = cell_centre(5, 5, 8, 24)
    assert tuple(image[y, x]) == (0, 255, 0)
    y, x = cell_centre(5, 5 + 4 % 3, 418, 24)
    assert tuple(image[y, x]) == (255, 0, 0)


def test_gif_has_the_selected_frames(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", drive(7))
    gif = tmp_path / "drive.gif"
    result = invoke("render", str(out), "--gif", str(gif), "--frames", "1:7:2", "--fps", "5",
                    "--layers", "decision")
    assert result.exit_code == 0, result.output
    frames = iio.imread(gif, index=None)
    assert frames.shape[0] == 3                          # frames 1, 3, 5
    meta = iio.immeta(gif, index=0)
    assert meta.get("duration") == 200
    # frame 1 (second picture would be 3): moving cell at column 5 + 1
    y, x = cell_centre(5, 6, 8, 24)
    assert np.abs(frames[0][y, x, :3].astype(int) - (255, 0, 0)).max() <= 8


def test_trace_survives_the_scroll_in_the_run(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", drive(3))
    dest = tmp_path / "png"
    assert invoke("render", str(out), "--dest", str(dest), "--layers", "trace").exit_code == 0
    image = iio.imread(dest / "frame_00002.png")
    # moving at global columns 0+5, 1+6, 2+7 = 5, 7, 9; frame 2's window starts at column 2
    for global_col in (5, 7, 9):
        y, x = cell_centre(5, global_col - 2, 8, 24)
        assert tuple(image[y, x]) == (255, 0, 0), global_col
    y, x = cell_centre(5, 6 - 2, 8, 24)
    assert tuple(image[y, x]) != (255, 0, 0)


def test_trace_includes_frames_not_drawn(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", drive(3))
    dest = tmp_path / "png"
    args = ("render", str(out), "--dest", str(dest), "--layers", "trace", "--frames", "2")
    assert invoke(*args).exit_code == 0
    assert [p.name for p in dest.iterdir()] == ["frame_00002.png"]
    image = iio.imread(dest / "frame_00002.png")
    for global_col in (5, 7, 9):                       # frames 0 and 1 were not drawn
        y, x = cell_centre(5, global_col - 2, 8, 24)
        assert tuple(image[y, x]) == (255, 0, 0), global_col


def test_compare_matches_frames_by_stamp(tmp_path: Path) -> None:
    a = write_run(tmp_path / "map", drive(4))
    b_frames = [f for f in drive(4) if f.index != 2]           # stamp of frame 2 missing
    for f in b_frames:
        f.decision[:] = CODES["unknown"]
    b = write_run(tmp_path / "nomap", b_frames)
    dest = tmp_path / "cmp"
    result = invoke("render", str(a), "--compare", str(b), "--dest", str(dest),
                    "--layers", "decision")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in dest.iterdir()) == [
        "frame_00000.png", "frame_00001.png", "frame_00003.png"]
    image = iio.imread(dest / "frame_00003.png")
    assert image.shape[1] == 8 + 400 + 10 + 400 + 8           # two panels side by side
    y, x = cell_centre(10, 10, 8, 24)
    assert tuple(image[y, x]) == (0, 255, 0)                  # run A: free
    y, x = cell_centre(10, 10, 418, 24)
    assert tuple(image[y, x]) == (0, 0, 0)                    # run B: unknown


def test_usage_errors_are_one_line_exit_2(tmp_path: Path) -> None:
    out = write_run(tmp_path / "run", drive(2))
    result = invoke("render", str(out))
    assert result.exit_code == 2 and "--out" in result.output
    result = invoke("render", str(out), "--dest", str(tmp_path / "d"), "--layers", "betp,foo")
    assert result.exit_code == 2 and "foo" in result.output
    dest = tmp_path / "again"
    assert invoke("render", str(out), "--dest", str(dest)).exit_code == 0
    result = invoke("render", str(out), "--dest", str(dest))
    assert result.exit_code == 2 and "--overwrite" in result.output
    assert invoke("render", str(out), "--dest", str(dest), "--overwrite").exit_code == 0
    result = invoke("render", str(tmp_path / "nothing"), "--dest", str(dest))
    assert result.exit_code == 2 and "not an evperc output" in result.output


@pytest.mark.parametrize(("text", "expected"), [
    (None, slice(None)), ("0:100:5", slice(0, 100, 5)), (":10", slice(None, 10)),
    ("5:", slice(5, None)), ("3", slice(3, 4)), ("-1", slice(-1, None)),
    ("::2", slice(None, None, 2)),
])
def test_parse_frames(text: str | None, expected: slice) -> None:
    assert parse_frames(text) == expected


@pytest.mark.parametrize("text", ["a:b", "1:2:3:4", "0:10:0", "0:10:-1"])
def test_parse_frames_rejects(text: str) -> None:
    with pytest.raises(UsageError, match="--frames"):
        parse_frames(text)


def test_too_big_gif_is_refused_before_writing(tmp_path: Path, monkeypatch) -> None:
    import evperc.render.run_render as rr

    monkeypatch.setattr(rr, "GIF_MAX_BYTES", 1000)
    out = write_run(tmp_path / "run", drive(2))
    gif = tmp_path / "big.gif"
    result = invoke("render", str(out), "--gif", str(gif))
    assert result.exit_code == 2 and "--frames" in result.output
    assert not gif.exists()


def test_unknown_decision_code_name_is_drawn_in_the_unnamed_colour() -> None:
    from evperc.render.frame import FrameRenderer

    codes = {**CODES, "mystery": 9}
    frame = make_frame(2, 2, pose=(-99.0, -99.0, 0.0))
    frame.decision[0, 0] = 9
    renderer = FrameRenderer(("decision", "decision6"), codes, cell_px=4)
    image = renderer.render(frame)
    for j in (0, 1):
        left, top = renderer.layout.panel_origin(0, j)
        assert tuple(image[top + 4 + 2, left + 2]) == (255, 255, 128)
