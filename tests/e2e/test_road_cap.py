"""A 16-layer scanner's far cars on the road (configs/vlp16.toml: the ground chain's gap capped
on the mapped road, docs/method.md §3 "The chain's gap on the road"), end to end.

simulate (vlp16, tuning seed 7, 10 s) → run with the 16-layer preset a 16-layer log takes
and with the cap off (``ground_chain_gap_m = 0``, the preset before) → evaluate against the
simulator's truth. Measured (docs/evaluation.md § "Since 2026-12-07, eleventh session"):
moving recall within one cell 0.375 → 0.827 on this drive, precision within one cell 0.813 →
0.876. The floors: the gain must be at least +0.2 (less than half of it: a change that stops
the run's map from reaching the ground split, or caps nothing, loses all of it), and
precision may not fall by more than 0.02.
"""

from __future__ import annotations

from typing import Any

import pytest

from tests.e2e.paired_runs import moving_within_one_cell


@pytest.fixture(scope="module")
def within_one_cell(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("vlp16-road-cap")
    before = root / "before.toml"
    before.write_text("[sensor]\nground_chain_gap_m = 0.0\n")
    return moving_within_one_cell(root, "vlp16", 7, before)


def test_the_road_cap_finds_the_far_cars(within_one_cell: dict[str, Any]) -> None:
    now, before = within_one_cell["now"], within_one_cell["before"]
    assert before["support"] > 1000   # moving truth cells in view: the drive has movers
    assert now["recall"] >= before["recall"] + 0.2, (now, before)


def test_without_losing_precision(within_one_cell: dict[str, Any]) -> None:
    now, before = within_one_cell["now"], within_one_cell["before"]
    assert now["precision"] >= before["precision"] - 0.02, (now, before)
