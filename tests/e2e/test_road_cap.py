"""A 16-layer scanner's far cars on the road (configs/vlp16.toml: the ground chain's gap capped
on the mapped road, docs/method.md §3 "The chain's gap on the road"), end to end.

simulate (vlp16, tuning seed 7, 10 s) → run with the 16-layer preset a 16-layer log takes
and with the cap off (``ground_chain_gap_m = 0``, the preset before) → evaluate against the
simulator's truth. Measured (docs/evaluation.md § "Since 2026-12-07, eleventh session"):
moving recall within one cell 0.375 → 0.827 on this drive, precision within one cell 0.813 →
0.876. The floors: the gain must be at least +0.2 (less than half of it: a change that stops
the run's map from reaching the ground split, or caps nothing, loses all of it), and
precision may not fall by more than 0.02.

The reach of the road (``sensor.ground_chain_gap_road_reach_m = 2``, an option: the returns
within 2 m of a mapped road capped too — the pavements' people 40–60 m away; docs/evaluation.md
§ "Since 2026-12-08"), on the same drive: recall within one cell 0.827 → 0.892, precision
0.876 → 0.873. The floor: at least half the gain, +0.03 (a reach that reaches no return, or
a rasteriser that is not handed to the ground split, gains nothing), precision within 0.02.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.e2e.paired_runs import paired_scores

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def within_one_cell(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("vlp16-road-cap")
    before = root / "before.toml"
    before.write_text("[sensor]\nground_chain_gap_m = 0.0\n")
    reach = root / "reach.toml"
    reach.write_text((REPO / "configs" / "vlp16.toml").read_text().replace(
        "[sensor]\n", "[sensor]\nground_chain_gap_road_reach_m = 2.0\n", 1))
    scores = paired_scores(root, "vlp16", 7, {"now": None, "before": before, "reach": reach})
    return {name: s["moving_within_one_cell"] for name, s in scores.items()}


def test_the_road_cap_finds_the_far_cars(within_one_cell: dict[str, Any]) -> None:
    now, before = within_one_cell["now"], within_one_cell["before"]
    assert before["support"] > 1000   # moving truth cells in view: the drive has movers
    assert now["recall"] >= before["recall"] + 0.2, (now, before)


def test_without_losing_precision(within_one_cell: dict[str, Any]) -> None:
    now, before = within_one_cell["now"], within_one_cell["before"]
    assert now["precision"] >= before["precision"] - 0.02, (now, before)


def test_the_roads_reach_finds_the_pavements_people(within_one_cell: dict[str, Any]) -> None:
    now, reach = within_one_cell["now"], within_one_cell["reach"]
    assert reach["recall"] >= now["recall"] + 0.03, (reach, now)
    assert reach["precision"] >= now["precision"] - 0.02, (reach, now)
