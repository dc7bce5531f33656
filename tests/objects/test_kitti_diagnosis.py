"""scripts/kitti_moving_diagnosis.py on the KITTI copy in tests/data (scans 0, 3, 6, 9 of
SemanticKITTI 05): the reasons account for every moving point, and its pooled counts are
those of `evperc evaluate --semantickitti` (evperc.eval.semantickitti, the scorer it does
not use) on the same run."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from evperc.config import load_config
from evperc.eval.semantickitti import evaluate_semantickitti

REPO = Path(__file__).resolve().parents[2]
SMALL = REPO / "tests" / "data" / "semantickitti05"
sys.path.insert(0, str(REPO / "scripts"))
import kitti_moving_diagnosis as diag  # noqa: E402


def test_reasons_cover_every_moving_point_and_counts_match_the_scorer(tmp_path: Path) -> None:
    config = load_config()
    out = tmp_path / "run"
    rec = diag.run_recorded(SMALL, config, out)
    assert rec.numbers == [0, 3, 6, 9]
    result = diag.diagnose(rec, SMALL, config, warmup=1)
    for scan in result["scans"]:
        truth = np.fromfile(SMALL / "labels" / f"{scan['scan']:06d}.label", "<u4") & 0xFFFF
        moving = int(np.isin(truth, range(252, 260)).sum())
        assert scan["moving_points"] == moving
        assert sum(scan["reasons"].values()) == moving
        assert scan["reasons"].get("moving", 0) + scan["reasons"].get("moving-reach", 0) \
            == scan["counts"]["tp"]
    scored = evaluate_semantickitti(out, SMALL, warmup=1)["overall"]
    assert scored["moving_truth"] > 0
    for k in ("tp", "fp", "fn", "tn"):
        assert result["pooled"].get(k, 0) == scored[k]
