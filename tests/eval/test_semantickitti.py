"""The SemanticKITTI-MOS scorer on hand-made label files, every expected value counted by
hand in the comments."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from evperc.cli import cli
from evperc.errors import LogError, OutputError
from evperc.eval.semantickitti import evaluate_semantickitti

INSTANCE = 7 << 16  # instance ids in the high 16 bits must not change the class

# scan A: (truth, prediction) per point
#   0 unlabeled / 251 -> ignored      1 outlier / 251 -> ignored
#   9 road / 251      -> FP           40 road / 9    -> TN
#   252 moving-car / 251 -> TP        254 moving-person / 0 -> FN
#   10 car (parked) / 251 -> FP       253 moving-bicyclist / 9 -> FN
A = ([0, 1, 9, 40, 252 | INSTANCE, 254, 10 | INSTANCE, 253],
     [251, 251, 251, 9, 251, 0, 251, 9])
# scan B: nothing moving, nothing predicted moving: TN 3
B = ([9, 9, 40], [9, 9, 0])
# scan C: one moving point found, one static point called moving: TP 1, FP 1
C = ([252, 9], [251, 251])


def _write(root: Path, scans: dict[str, tuple[list[int], list[int]]]) -> tuple[Path, Path]:
    run, seq = root / "run", root / "seq"
    (run / "labels").mkdir(parents=True)
    (seq / "labels").mkdir(parents=True)
    for name, (truth, pred) in scans.items():
        np.array(truth, "<u4").tofile(seq / "labels" / f"{name}.label")
        np.array(pred, "<u4").tofile(run / "labels" / f"{name}.label")
    return run, seq


def test_hand_counted_scores(tmp_path: Path) -> None:
    run, seq = _write(tmp_path, {"000000": A, "000001": B, "000002": C})
    r = evaluate_semantickitti(run, seq, warmup=1)
    a, b, c = r["per_scan"]
    assert (a["tp"], a["fp"], a["fn"], a["tn"], a["ignored"]) == (1, 2, 2, 1, 2)
    assert a["iou"] == pytest.approx(1 / 5)          # 1 / (1 + 2 + 2)
    assert a["precision"] == pytest.approx(1 / 3)    # 1 / (1 + 2)
    assert a["recall"] == pytest.approx(1 / 3)       # 1 / (1 + 2)
    assert a["static_as_moving"] == pytest.approx(2 / 3)  # 2 / (2 + 1)
    assert (b["tp"], b["fp"], b["fn"], b["tn"]) == (0, 0, 0, 3)
    assert b["iou"] is None and b["precision"] is None and b["recall"] is None
    assert b["static_as_moving"] == 0.0
    assert (c["iou"], c["precision"], c["recall"], c["static_as_moving"]) == (0.5, 0.5, 1.0, 1.0)
    # warm-up: scan A alone; overall: B + C pooled -> TP 1, FP 1, FN 0, TN 3
    assert r["warmup_scans"] == 1 and r["warmup"]["iou"] == pytest.approx(0.2)
    o = r["overall"]
    assert o["scans"] == 2 and (o["tp"], o["fp"], o["fn"], o["tn"]) == (1, 1, 0, 3)
    assert o["iou"] == 0.5 and o["precision"] == 0.5 and o["recall"] == 1.0
    assert o["static_as_moving"] == pytest.approx(1 / 4)
    # with no warm-up all three pool: TP 2, FP 3, FN 2, TN 4 -> IoU 2/7
    assert evaluate_semantickitti(run, seq, warmup=0)["overall"]["iou"] == pytest.approx(2 / 7)


def test_cli_table_and_json(tmp_path: Path) -> None:
    run, seq = _write(tmp_path, {"000004": A, "000005": C})
    (seq / "labels" / "000006.label").write_bytes(np.zeros(2, "<u4").tobytes())  # not in run
    out = tmp_path / "s.json"
    result = CliRunner().invoke(cli, ["evaluate", str(run), "--semantickitti", str(seq),
                                      "--warmup", "1", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "000004 (w)" in result.output and "all 1" in result.output
    doc = json.loads(out.read_text())
    assert doc["overall"]["iou"] == 0.5 and doc["not_predicted"] == ["000006"]
    assert doc["cell_scores"] is None and "cells" in doc["cell_scores_note"]


def test_errors(tmp_path: Path) -> None:
    run, seq = _write(tmp_path, {"000000": A})
    np.zeros(3, "<u4").tofile(run / "labels" / "000000.label")
    with pytest.raises(LogError, match="3 labels.*has 8"):
        evaluate_semantickitti(run, seq)
    (run / "labels" / "000000.label").unlink()
    with pytest.raises(OutputError, match="--point-labels"):
        evaluate_semantickitti(run, seq)
    result = CliRunner().invoke(cli, ["evaluate", str(run), "--semantickitti", str(seq)])
    assert result.exit_code == 2 and result.output.count("\n") == 1
    result = CliRunner().invoke(cli, ["evaluate", str(run)])
    assert result.exit_code == 2 and "--truth DIR" in result.output
