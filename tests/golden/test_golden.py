"""`evperc run` on sample_data/ must reproduce tests/golden/ (with and without the map).

A change that alters results fails here with a readable diff; if the change is intended,
run `make golden`, review `git diff tests/golden`, and commit the new files with the reason.
"""

from __future__ import annotations

import difflib
import json
from pathlib import Path

import numpy as np
import pytest

from tests.golden.golden import CASES, compute, dumps, paths

#: betP / ζ may move one storage step (uint8, 1/255); decisions must not move
ARRAY_ATOL = 1 / 255
NUMBER_RTOL = 1e-3


def _close(a, b) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float):
        return bool(np.isclose(a, b, rtol=NUMBER_RTOL, atol=1e-3))
    return a == b


@pytest.mark.parametrize("case", sorted(CASES))
def test_sample_run_matches_golden(case: str, tmp_path: Path) -> None:
    json_path, npz_path = paths(case)
    assert json_path.exists() and npz_path.exists(), (
        f"golden file {json_path.name} missing: run `make golden` and commit it")
    summary, arrays = compute(case, tmp_path / case)
    expected = json.loads(json_path.read_text())
    if not _close(summary, expected):
        diff = "".join(difflib.unified_diff(
            dumps(expected).splitlines(keepends=True), dumps(summary).splitlines(keepends=True),
            fromfile=f"golden/{json_path.name}", tofile="this run", n=2))
        pytest.fail("summary differs from the golden file (first 80 lines):\n"
                    + "".join(diff.splitlines(keepends=True)[:80]))
    with np.load(npz_path) as golden:
        assert sorted(golden.files) == sorted(arrays)
        for key in golden.files:
            want, got = golden[key], arrays[key]
            if key.startswith("decision"):
                changed = int((want != got).sum())
                assert changed == 0, f"{key}: {changed} of {want.size} cells changed decision"
            else:
                worst = float(np.abs(want - got).max())
                assert worst <= ARRAY_ATOL, f"{key}: max difference {worst:.4g}"
