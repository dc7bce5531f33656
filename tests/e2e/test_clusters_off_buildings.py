"""Clusters kept off the façades' static cells (``objects.clusters_off_buildings``,
docs/method.md §8 step 1), end to end: the defaults against
configs/ablation/clusters_on_buildings.toml.

simulate (vlp16, tuning seed 2, 10 s) → run with each → evaluate against the simulator's
truth (visible cells). On this drive a person stands against a wall whose returns fall one
cell outside the map's building outline and are decided stopped; the person's cluster took
in the 12 m strip, and the track reported it moving on the wall's evidence. Measured
(docs/evaluation.md § "Since 2026-12-05, second session"): moving precision within one cell
0.859 → 0.966, recall within one cell 0.883 → 0.883. The floors: the gain must be at least
+0.05 (half of it; without the rule there is none), and recall may not fall by more than
0.01 (no tuning set lost recall within one cell to the rule; one hundredth is the noise of
one frame of one agent on this drive).

The height condition (``objects.off_buildings_max_height_m``, 2.2 m) against
configs/ablation/facade_fragments_any_height.toml: simulate (hdl64, tuning seed 10, 10 s).
On this drive a small fragment of a façade, kept whole while it was at most 2 m across and
trimmed when it joined a larger group, made a track whose centroid jumped; a person walks
along a wall within the building margin (the reason for the small-group exception).
Measured (docs/evaluation.md § "Since 2026-12-05, third session"): moving precision within
one cell 0.843 → 0.896, recall 0.568 → 0.568. Floors: +0.025 (half the gain) and −0.01 (as
above: the walker must stay found — at 1.5 m, under the simulated people's 1.5–1.9 m, the
hdl64 tuning drives lost recall within one cell 0.846 → 0.824).
"""

from __future__ import annotations

from typing import Any

import pytest

from tests.e2e.paired_runs import moving_within_one_cell
from tests.e2e.test_sim_eval import REPO


@pytest.fixture(scope="module")
def within_one_cell(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return moving_within_one_cell(tmp_path_factory.mktemp("vlp16"), "vlp16", 2,
                                  REPO / "configs" / "ablation" / "clusters_on_buildings.toml")


def test_the_wall_is_no_longer_tracked(within_one_cell: dict[str, Any]) -> None:
    now, before = within_one_cell["now"], within_one_cell["before"]
    assert before["support"] > 300   # moving truth cells in view: the drive has movers
    assert now["precision"] >= before["precision"] + 0.05, (now, before)


def test_the_person_is_still_found(within_one_cell: dict[str, Any]) -> None:
    now, before = within_one_cell["now"], within_one_cell["before"]
    assert now["recall"] >= before["recall"] - 0.01, (now, before)


@pytest.fixture(scope="module")
def with_height_bound(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return moving_within_one_cell(tmp_path_factory.mktemp("hdl64"), "hdl64", 10,
                                  REPO / "configs" / "ablation" /
                                  "facade_fragments_any_height.toml")


def test_a_tall_fragment_of_the_facade_is_not_tracked(with_height_bound: dict[str, Any]
                                                      ) -> None:
    now, before = with_height_bound["now"], with_height_bound["before"]
    assert before["support"] > 200   # moving truth cells in view
    assert now["precision"] >= before["precision"] + 0.025, (now, before)


def test_the_walker_along_the_wall_is_still_found(with_height_bound: dict[str, Any]) -> None:
    now, before = with_height_bound["now"], with_height_bound["before"]
    assert now["recall"] >= before["recall"] - 0.01, (now, before)
