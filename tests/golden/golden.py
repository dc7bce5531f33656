"""Golden outputs of `evperc run` on sample_data/ (with and without the map).

``compute(case, out_dir)`` runs the real command and reduces its output to what is kept
under tests/golden/: a key-sorted, rounded JSON summary and a few selected frames (NPZ).
``python -m tests.golden.update`` (``make golden``) rewrites them; CI never does.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from click.testing import CliRunner

import evperc
from evperc.cli import cli

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
SAMPLE = ROOT / "sample_data"
CASES = {
    "map": ["--map", str(SAMPLE / "map.geojson")],
    "nomap": ["--no-map"],
    # the paper's method: its golden files were first written by commit e996c3d (before the
    # preset and issue 20's mechanisms existed) with `--config` holding SPEC's values of the
    # four tuned keys; `--preset kurdej2013` must keep reproducing them. Since output
    # format_version 4 their betP entries (mean_betp, betp_*) are the betP of the stored
    # masses (rewritten alone: within 0.0082 of e996c3d's stored betP, every cell inside the
    # rounding bound of docs/output-format.md); every other entry is still e996c3d's
    "kurdej2013": ["--map", str(SAMPLE / "map.geojson"), "--preset", "kurdej2013"],
}
END_S = 6.0               # the first 6 s of the drive keep the test short
SELECTED = (9, 29, 59)    # frames stored as arrays
DECIMALS = 4


def compute(case: str, out_dir: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    result = CliRunner().invoke(cli, ["-q", "run", str(SAMPLE / "drive.mcap"), *CASES[case],
                                      "--end", str(END_S), "--out", str(out_dir)])
    if result.exit_code != 0:
        raise RuntimeError(f"evperc run failed: {result.output}")
    run = evperc.load(out_dir)
    codes = run.decision_codes
    names = sorted(codes, key=codes.get)
    per_frame = []
    arrays: dict[str, np.ndarray] = {}
    for frame in run.frames:
        counts = np.bincount(frame.decision.ravel(), minlength=len(names))
        per_frame.append({
            "stamp_ns": frame.stamp_ns,
            "pose": [round(float(v), DECIMALS) for v in frame.pose],
            "origin": list(frame.origin),
            "decisions": {n: int(counts[codes[n]]) for n in names},
            "mean_betp": [round(float(v), DECIMALS) for v in frame.betp.mean(axis=(0, 1))],
            "mean_zeta": round(float(frame.zeta.mean()), DECIMALS),
            "conflict_sum": [round(float(v), 2) for v in frame.conflict.sum(axis=(0, 1))],
        })
        if frame.index in SELECTED:
            arrays[f"decision_{frame.index}"] = frame.decision
            arrays[f"betp_{frame.index}"] = frame.betp
            arrays[f"zeta_{frame.index}"] = frame.zeta
    summary = {"case": case, "frame_count": len(run), "crs": run.crs,
               "resolution_m": run.resolution_m, "shape": list(run.shape),
               "frames": per_frame}
    return summary, arrays


def paths(case: str) -> tuple[Path, Path]:
    return HERE / f"sample_{case}.json", HERE / f"sample_{case}_frames.npz"


def dumps(summary: dict[str, Any]) -> str:
    return json.dumps(summary, indent=1, sort_keys=True) + "\n"
