"""Evaluator on hand-made grids with hand-computed scores."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from evperc.cli import cli
from evperc.config import load_config
from evperc.eval.metrics import evaluate
from evperc.geo.window import Window
from evperc.output.writer import RunWriter
from evperc.sim.truth import TruthFrame, TruthWriter, load_truth

CODES = {"unknown": 0, "free": 1, "moving": 2, "static": 3, "stopped": 4,
         "infrastructure": 5, "unmapped": 6}
F, M, S, I, U = 1, 2, 4, 5, 6   # truth codes (docs/truth-format.md)
UNK, FREE, MOV, STA, STO, INF, UNM = range(7)


def write_truth(tmp: Path, frames: list[dict], agents: int = 0) -> Path:
    w = TruthWriter(tmp / "truth", 2, 0.5, "EPSG:32635",
                    {"agents": [{"id": i + 1} for i in range(agents)]}, chunk_frames=2)
    for k, f in enumerate(frames):
        classes = np.array(f["classes"], dtype=np.uint8)
        rows, cols = classes.shape
        origin = f.get("origin", (0, 0))
        w.manifest["rows"], w.manifest["cols"] = rows, cols
        w.add(TruthFrame(k, f["stamp"], origin, Window(0.5, rows, cols, *origin),
                         np.zeros(3), classes,
                         np.array(f.get("observed", np.ones_like(classes)), dtype=bool),
                         np.array(f.get("visible", np.ones_like(classes)), dtype=bool),
                         np.array(f.get("agent", np.zeros_like(classes)), dtype=np.int32)))
    w.close()
    return tmp / "truth"


def fake_run(frames: list[dict]) -> SimpleNamespace:
    return SimpleNamespace(decision_codes=CODES, frames=[
        SimpleNamespace(stamp_ns=f["stamp"], origin=f.get("origin", (0, 0)),
                        decision=np.array(f["decision"], dtype=np.uint8)) for f in frames])


def test_per_class_and_coarse_scores_by_hand(tmp_path: Path) -> None:
    truth = load_truth(write_truth(tmp_path, [{
        "stamp": 100, "classes": [[F, F, I], [S, M, U]],
        "observed": [[1, 1, 1], [1, 1, 0]]}]))
    run = fake_run([{"stamp": 100, "decision": [[FREE, MOV, INF], [STA, MOV, UNM]]},
                    {"stamp": 150, "decision": [[FREE, FREE, FREE], [FREE, FREE, FREE]]}])
    m = evaluate(run, truth)
    # evaluated: F→free ✓, F→moving ✗, I→infrastructure ✓, S→static (miss), M→moving ✓;
    # the U cell is unobserved
    assert m["cells"] == 5 and m["frames_matched"] == 1 and m["frames_unmatched"] == 1
    pc = m["per_class"]
    assert pc["free"] == pytest.approx({"precision": 1.0, "recall": 0.5, "f1": 2 / 3,
                                        "support": 2})
    assert pc["infrastructure"] == {"precision": 1.0, "recall": 1.0, "f1": 1.0, "support": 1}
    assert pc["stopped"] == {"precision": None, "recall": 0.0, "f1": None, "support": 1}
    assert pc["moving"] == pytest.approx({"precision": 0.5, "recall": 1.0, "f1": 2 / 3,
                                          "support": 1})
    assert pc["unmapped"] == {"precision": None, "recall": None, "f1": None, "support": 0}
    co = m["coarse"]
    assert co["static"] == {"precision": 1.0, "recall": 1.0, "f1": 1.0, "support": 2}
    assert co["free"]["recall"] == 0.5 and co["moving"]["precision"] == 0.5
    assert m["accuracy"] == pytest.approx(3 / 5) and m["coarse_accuracy"] == pytest.approx(4 / 5)
    conf = np.array(m["confusion"]["counts"])
    assert m["confusion"]["decision"] == list(CODES)
    assert conf[3, STA] == 1 and conf[0, MOV] == 1 and conf.sum() == 5
    assert m["stopped_vs_moving"]["stopped"]["static"] == 1
    assert m["stopped_vs_moving"]["moving"]["moving"] == 1


def test_moving_within_one_cell_by_hand(tmp_path: Path) -> None:
    # truth: a 2-cell moving footprint in row 1, columns 1-2; the top-left cell unevaluated
    truth = load_truth(write_truth(tmp_path, [{
        "stamp": 7,
        "classes": [[F, F, F, F, F], [F, M, M, F, F], [F, F, F, F, F], [F, F, F, F, I]],
        "visible": [[0, 1, 1, 1, 1], [1, 1, 1, 1, 1], [1, 1, 1, 1, 1], [1, 1, 1, 1, 1]]}]))
    run = fake_run([{"stamp": 7, "decision": [
        [FREE, FREE, FREE, MOV, FREE],   # (0,3): diagonal to truth (1,2): correct
        [FREE, FREE, FREE, FREE, MOV],   # (1,4): two columns off: wrong
        [FREE, FREE, FREE, FREE, FREE],
        [MOV, FREE, FREE, FREE, FREE]]}])  # (3,0): far off: wrong
    m = evaluate(run, truth, cells="visible")
    tol = m["moving_within_one_cell"]
    # decided moving 3, correct 1 (0,3); truth M 2: (1,2) has the decided (0,3) as a
    # neighbour, (1,1) has none of them
    assert (tol["decided"], tol["correct"], tol["support"], tol["found"]) == (3, 1, 2, 1)
    assert tol["precision"] == pytest.approx(1 / 3) and tol["recall"] == pytest.approx(0.5)
    assert tol["f1"] == pytest.approx(0.4)
    # strict: no decided moving cell is truth M
    assert m["per_class"]["moving"]["precision"] == 0.0
    # a decided cell at the window's edge whose neighbour is unevaluated truth M still counts
    run2 = fake_run([{"stamp": 7, "decision": [[MOV, FREE, FREE, FREE, FREE],
                                               [FREE] * 5, [FREE] * 5, [FREE] * 5]}])
    tol2 = evaluate(run2, truth, cells="visible")["moving_within_one_cell"]
    assert (tol2["decided"], tol2["correct"]) == (0, 0)  # (0,0) itself unevaluated: not scored
    run3 = fake_run([{"stamp": 7, "decision": [[FREE, FREE, FREE, FREE, FREE],
                                               [MOV, FREE, FREE, FREE, FREE],
                                               [FREE] * 5, [FREE] * 5]}])
    tol3 = evaluate(run3, truth, cells="visible")["moving_within_one_cell"]
    assert (tol3["decided"], tol3["correct"], tol3["found"]) == (1, 1, 1)


def test_stopped_within_one_cell_by_hand(tmp_path: Path) -> None:
    # truth: a parked car of 2 cells (row 1, columns 1-2) beside a moving one (row 3, col 4)
    truth = load_truth(write_truth(tmp_path, [{
        "stamp": 7,
        "classes": [[F, F, F, F, F], [F, S, S, F, F], [F, F, F, F, F], [F, F, F, F, M]]}]))
    run = fake_run([{"stamp": 7, "decision": [
        [FREE, STO, FREE, FREE, FREE],   # (0,1): above truth (1,1): correct
        [FREE, FREE, FREE, FREE, STO],   # (1,4): two columns off (1,2): wrong
        [FREE, FREE, FREE, FREE, FREE],
        [FREE, FREE, FREE, FREE, MOV]]}])
    m = evaluate(run, truth, cells="visible")
    tol = m["stopped_within_one_cell"]
    # decided stopped 2, correct 1; truth S 2, both next to (0,1): (1,1) below, (1,2) diagonal
    assert (tol["decided"], tol["correct"], tol["support"], tol["found"]) == (2, 1, 2, 2)
    assert tol["precision"] == pytest.approx(0.5) and tol["recall"] == pytest.approx(1.0)
    assert m["per_class"]["stopped"]["precision"] == 0.0  # strict: none of them is truth S
    # the moving class is scored apart: its one decided cell is on its one truth cell
    mov = m["moving_within_one_cell"]
    assert (mov["decided"], mov["correct"], mov["support"], mov["found"]) == (1, 1, 1, 1)


def test_windows_compared_where_both_cover(tmp_path: Path) -> None:
    truth = load_truth(write_truth(tmp_path, [{"stamp": 5, "classes": [[F, I, I], [F, F, M]]}]))
    # run window shifted one column east: its columns 0, 1 are the truth's columns 1, 2
    run = fake_run([{"stamp": 5, "origin": (0, 1), "decision": [[INF, FREE, UNK],
                                                                 [FREE, MOV, UNK]]}])
    m = evaluate(run, truth)
    assert m["cells"] == 4
    assert m["per_class"]["infrastructure"] == pytest.approx(
        {"precision": 1.0, "recall": 0.5, "f1": 2 / 3, "support": 2})
    assert m["per_class"]["moving"]["recall"] == 1.0
    assert m["per_class"]["free"]["recall"] == 1.0


def test_latency_per_moving_episode(tmp_path: Path) -> None:
    # agent 1 moves in frames 0-3, first seen at frame 1, decided moving at frame 3: 2 frames;
    # agent 2 moves in frames 0-3, seen at 0, never decided moving: missed
    frames, run = [], []
    for k in range(4):
        frames.append({"stamp": 10 * k, "classes": [[M, M]], "agent": [[1, 2]],
                       "visible": [[k >= 1, True]]})
        run.append({"stamp": 10 * k, "decision": [[MOV if k == 3 else FREE, STO]]})
    m = evaluate(fake_run(run), load_truth(write_truth(tmp_path, frames, agents=2)))
    lat = m["latency_frames"]
    assert (lat["episodes"], lat["detected"], lat["missed"]) == (2, 1, 1)
    assert lat["mean"] == 2.0 and lat["max"] == 2
    ep = [e for e in lat["per_episode"] if e["agent"] == 1][0]
    assert ep["onset_frame"] == 1 and ep["latency_s"] == pytest.approx(20e-9)
    assert sorted(e["visible_frames"] for e in lat["per_episode"]) == [3, 4]
    assert lat["by_visible_frames"] == {"1-4": {"episodes": 2, "missed": 1},
                                        "5-9": {"episodes": 0, "missed": 0},
                                        "10+": {"episodes": 0, "missed": 0}}


def test_missed_episodes_by_frames_visible(tmp_path: Path) -> None:
    # 12 frames, three agents moving throughout: agent 1 visible in all but frames 3 and 7
    # (10 frames) and decided moving at frame 5; agent 2 visible in frames 4-9 (6), never
    # decided moving; agent 3 visible in frame 11 only (1), never decided moving
    frames, run = [], []
    for k in range(12):
        frames.append({"stamp": 10 * k, "classes": [[M, M, M]], "agent": [[1, 2, 3]],
                       "visible": [[k not in (3, 7), 4 <= k <= 9, k == 11]]})
        run.append({"stamp": 10 * k, "decision": [[MOV if k == 5 else STA, STA, STA]]})
    lat = evaluate(fake_run(run), load_truth(write_truth(tmp_path, frames, agents=3)))[
        "latency_frames"]
    assert {e["agent"]: e["visible_frames"] for e in lat["per_episode"]} == {1: 10, 2: 6, 3: 1}
    assert lat["by_visible_frames"] == {"1-4": {"episodes": 1, "missed": 1},
                                        "5-9": {"episodes": 1, "missed": 1},
                                        "10+": {"episodes": 1, "missed": 0}}


def write_run(out: Path, decision: np.ndarray, stamp: int) -> None:
    rows, cols = decision.shape
    w = RunWriter(out, load_config(), {"decision_codes": CODES, "resolution_m": 0.5,
                                       "rows": rows, "cols": cols, "crs": "EPSG:32635"})
    w.add(stamp, np.zeros(3), (0, 0), np.zeros((rows, cols, 32)), np.zeros((rows, cols, 5)),
          decision, np.zeros((rows, cols)), np.zeros((rows, cols, 3)))
    w.close({})


def test_evaluate_cli_json_and_compare(tmp_path: Path) -> None:
    truth = write_truth(tmp_path, [{"stamp": 7, "classes": [[F, I], [S, M]]}])
    write_run(tmp_path / "map", np.array([[FREE, INF], [STO, MOV]], dtype=np.uint8), 7)
    write_run(tmp_path / "nomap", np.array([[FREE, STA], [STA, FREE]], dtype=np.uint8), 7)
    res = CliRunner().invoke(cli, ["evaluate", str(tmp_path / "map"), "--truth", str(truth),
                                   "--compare", str(tmp_path / "nomap"), "--json",
                                   str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    assert "infrastructure" in res.output and "nomap" in res.output
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["per_class"]["infrastructure"]["recall"] == 1.0
    assert doc["per_class"]["moving"]["f1"] == 1.0
    assert doc["compare"]["per_class"]["infrastructure"]["recall"] == 0.0
    assert doc["compare"]["per_class"]["moving"]["recall"] == 0.0
    assert doc["compare"]["coarse"]["static"]["recall"] == 1.0
    assert set(doc["per_class"]) == {"free", "infrastructure", "unmapped", "stopped", "moving"}
    assert "confusion" in doc and "latency_frames" in doc


def test_evaluate_cli_missing_truth_is_one_line(tmp_path: Path) -> None:
    write_run(tmp_path / "run", np.zeros((2, 2), dtype=np.uint8), 1)
    res = CliRunner().invoke(cli, ["evaluate", str(tmp_path / "run"), "--truth",
                                   str(tmp_path / "nothing")])
    assert res.exit_code == 2
    assert res.output.count("\n") == 1 and "truth" in res.output


def test_visible_cells_only(tmp_path: Path) -> None:
    """``cells="visible"`` scores only the cells seen in the frame itself."""
    truth = load_truth(write_truth(tmp_path, [{
        "stamp": 100, "classes": [[F, F, I], [S, M, U]],
        "observed": [[1, 1, 1], [1, 1, 1]], "visible": [[1, 0, 1], [0, 1, 0]]}]))
    run = fake_run([{"stamp": 100, "decision": [[FREE, UNK, INF], [UNK, MOV, UNK]]}])
    seen = evaluate(run, truth, cells="visible")
    assert seen["cells"] == 3
    assert seen["per_class"]["free"]["recall"] == 1.0
    assert seen["per_class"]["moving"]["recall"] == 1.0
    remembered = evaluate(run, truth, cells="observed")
    assert remembered["cells"] == 6
    assert remembered["per_class"]["free"]["recall"] == 0.5
    with pytest.raises(Exception, match="visible"):
        evaluate(run, truth, cells="everything")


def _objects_frame(stamp: int, decision: list, objects: list[tuple[int, int, list[int]]]
                   ) -> SimpleNamespace:
    """A run frame with an object list: (track id, state, flat cell indices) each."""
    from evperc.output.objects import OBJECT_DTYPE, object_labels

    dec = np.array(decision, dtype=np.uint8)
    recs = np.zeros(len(objects), OBJECT_DTYPE)
    for k, (tid, state, cells) in enumerate(objects):
        recs[k]["track_id"], recs[k]["state"], recs[k]["cell_count"] = tid, state, len(cells)
    cells = np.array([c for _, _, cs in objects for c in cs], dtype=np.uint32)
    frame = SimpleNamespace(stamp_ns=stamp, origin=(0, 0), decision=dec, objects=recs,
                            object_cells=cells)
    frame.object_labels = lambda: object_labels(recs, cells, dec.shape)
    return frame


def test_object_precision_recall_and_track_switches_by_hand(tmp_path: Path) -> None:
    classes, agent = [[M, M, F, M, M, F]], [[1, 1, 0, 2, 2, 0]]
    truth = load_truth(write_truth(tmp_path, [
        {"stamp": 0, "classes": classes, "agent": agent},
        {"stamp": 1, "classes": classes, "agent": agent},
        {"stamp": 2, "classes": classes, "agent": agent, "visible": [[1, 1, 1, 0, 0, 1]]}],
        agents=2))
    dec = [[MOV, MOV, FREE, MOV, MOV, FREE]]
    run = SimpleNamespace(decision_codes=CODES, frames=[
        # track 5 on agent 1 (match); track 6 on a free cell (false)
        _objects_frame(0, dec, [(5, 1, [0, 1]), (6, 1, [2])]),
        # agent 1 now matched by track 7: one switch; track 5 stopped on agent 2: not scored
        _objects_frame(1, dec, [(5, 2, [3]), (7, 1, [0, 1])]),
        # agent 2 not visible: matched by track 8 (precision) but not a true one (recall)
        _objects_frame(2, dec, [(8, 1, [3, 4])])])
    obj = evaluate(run, truth)["objects"]
    # reported moving 2 + 1 + 1 = 4, matched 1 + 1 + 1 = 3; true visible 2 + 2 + 1 = 5,
    # found 1 + 1 + 0 = 2
    assert obj["moving_reported"] == 4 and obj["moving_matched"] == 3
    assert obj["moving_truth"] == 5 and obj["moving_found"] == 2
    assert obj["precision"] == 0.75 and obj["recall"] == 0.4
    assert obj["track_switches"] == 1
    assert obj["identity_switches"] == 1 and obj["duplicate_matches"] == 0
    # a run without object lists has no object scores
    assert evaluate(fake_run([{"stamp": 0, "decision": dec}]), truth)["objects"] is None


def test_identity_switches_and_duplicates_by_hand(tmp_path: Path) -> None:
    """Two tracks on one agent count a track switch per frame in record order, but no
    identity switch while the kept track still matches it (CLEAR MOT's IDSW)."""
    classes, agent = [[M, M, M, M, F]], [[1, 1, 1, 1, 0]]
    truth = load_truth(write_truth(tmp_path, [
        {"stamp": k, "classes": classes, "agent": agent} for k in range(5)], agents=1))
    dec = [[MOV, MOV, MOV, MOV, FREE]]
    run = SimpleNamespace(decision_codes=CODES, frames=[
        _objects_frame(0, dec, [(5, 1, [0, 1])]),                # kept 5
        _objects_frame(1, dec, [(5, 1, [0, 1]), (6, 1, [2, 3])]),  # 6 after 5: switch; kept 5
        _objects_frame(2, dec, [(6, 1, [2, 3]), (5, 1, [0, 1])]),  # 5 after 6: switch; kept 5
        _objects_frame(3, dec, [(5, 1, [0, 1])]),                # 5 alone: no switch
        _objects_frame(4, dec, [(7, 1, [0, 1, 2])])])            # a new track: both count
    obj = evaluate(run, truth)["objects"]
    # last-match switches: frames 1, 2, 4 -> 3; identity: frame 4 -> 1 (a rule keeping the
    # first match of a frame would switch at frames 2, 3 and 4);
    # agent-frames matched twice: frames 1, 2 -> 2
    assert obj["track_switches"] == 3
    assert obj["identity_switches"] == 1
    assert obj["duplicate_matches"] == 2
    assert obj["moving_reported"] == 7 and obj["moving_matched"] == 7


def test_objects_and_episodes_within_one_cell_by_hand(tmp_path: Path) -> None:
    """A one-cell person reported in the cell beside its footprint: no match strictly, a
    match within one cell; two cells away: no match either way; a missed episode strictly
    is detected within one cell when a cell decided moving touches the agent's."""
    # row of 7 cells: agent 1 (a person) at cell 1, agent 2 at cell 5
    classes, agent = [[F, M, F, F, F, M, F]], [[0, 1, 0, 0, 0, 2, 0]]
    truth = load_truth(write_truth(tmp_path, [
        {"stamp": 0, "classes": classes, "agent": agent},
        {"stamp": 1, "classes": classes, "agent": agent}], agents=2))
    run = SimpleNamespace(decision_codes=CODES, frames=[
        # track 5 at cell 2 (beside agent 1), track 6 at cell 3 (two cells from both)
        _objects_frame(0, [[FREE, FREE, MOV, MOV, FREE, FREE, FREE]],
                       [(5, 1, [2]), (6, 1, [3])]),
        # track 5 at cell 0 (beside agent 1 on the other side); agent 2's own cell moving
        _objects_frame(1, [[MOV, FREE, FREE, FREE, FREE, MOV, FREE]],
                       [(5, 1, [0]), (7, 1, [5])])])
    m = evaluate(run, truth)
    obj = m["objects"]
    # strictly: reported 2 + 2, matched 0 + 1 (track 7), true 2 + 2, found 0 + 1
    assert (obj["moving_reported"], obj["moving_matched"]) == (4, 1)
    assert (obj["moving_truth"], obj["moving_found"]) == (4, 1)
    near = obj["within_one_cell"]
    # within one cell: track 5 matches agent 1 in both frames, track 6 never (cells 2 and 4
    # beside it are not M), track 7 agent 2: matched 1 + 2, found 1 (agent 1) + 2
    assert (near["moving_matched"], near["moving_found"]) == (3, 3)
    assert near["precision"] == 0.75 and near["recall"] == 0.75
    # episodes: agent 1 never has its own cell decided moving (missed strictly), but has a
    # moving neighbour in frame 0 (latency 0 within one cell); agent 2 detected at frame 1
    lat, lat_near = m["latency_frames"], m["latency_frames_within_one_cell"]
    assert (lat["episodes"], lat["detected"], lat["missed"]) == (2, 1, 1)
    assert (lat_near["episodes"], lat_near["detected"], lat_near["missed"]) == (2, 2, 0)
    assert sorted(e["latency_frames"] for e in lat_near["per_episode"]) == [0, 1]
