"""objects.moving_min_height_m through a whole run: the runner asks the sensor grid for each
cell's highest return and hands it to the small-group rule. On a real slice with small
decided-moving groups (SemanticKITTI 09: ground points the ground split called obstacles),
two bounds with known outcomes, each checked against runs of their own without the layer:
100 m (every group is lower) decides exactly as the small-group rule alone; 1 mm (no
obstacle return is lower: they start at the 0.3 m ground threshold) spares every small group
with a return of the scan within one cell, so it changes fewer cells than the rule alone —
only the groups that show no height at all (decided moving, no return near them now) —, and
each of its changes is one the rule alone makes too (moving → static)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from evperc.fusion.twin import DECISION_CODES as D

SEQ = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "semantickitti" / "09"
needs_slice = pytest.mark.skipif(
    not (SEQ / "velodyne").is_dir(),
    reason=f"SemanticKITTI slice not found at {SEQ} (the shared data folder is absent)")


def _decisions(tmp_path: Path, name: str, objects: str) -> np.ndarray:
    config = tmp_path / f"{name}.toml"
    # the small-group rule alone: with moving_needs_object every moving cell outside a
    # moving object is static whatever its group (tests/objects/test_moving_needs_object.py)
    config.write_text("[objects]\nmoving_needs_object = false\n" + objects)
    out = tmp_path / name
    result = CliRunner().invoke(cli, ["run", str(SEQ), "--no-map", "--config", str(config),
                                      "--out", str(out)])
    assert result.exit_code == 0, result.output
    return np.stack([f.decision for f in evperc.load(out).frames])


@needs_slice
def test_the_height_bound_reaches_the_small_group_rule(tmp_path: Path) -> None:
    none = _decisions(tmp_path, "none", "moving_min_cluster_cells = 0\n")
    small = _decisions(tmp_path, "small", "moving_min_cluster_cells = 3\n"
                                          "moving_min_height_m = 0.0\n")
    high = _decisions(tmp_path, "high", "moving_min_cluster_cells = 3\n"
                                        "moving_min_height_m = 100.0\n")
    low = _decisions(tmp_path, "low", "moving_min_cluster_cells = 3\n"
                                      "moving_min_height_m = 0.001\n")
    moving, static = D["moving"], D["static"]
    by_rule = none != small
    assert by_rule.any()  # the slice has small moving groups
    assert ((none[by_rule] == moving) & (small[by_rule] == static)).all()
    np.testing.assert_array_equal(high, small)
    by_low = none != low
    assert by_low.sum() < by_rule.sum()  # the layer reached the rule and spared groups
    assert not (by_low & ~by_rule).any()
    np.testing.assert_array_equal(low[by_low], small[by_low])
