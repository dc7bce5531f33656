"""simulate → run (map and --no-map) → evaluate, end to end on a short synthetic drive.

Floors are set from measurements (ibeo4, seed 3, 5 s, the default config, i.e. the tuned values
of docs/evaluation.md; the measured value is in each comment) with a margin, so a regression in
the simulator, the fusion or the scoring that loses moving objects, invents free space or stops
using the map fails here. The full study with the numbers of docs/evaluation.md is
scripts/evaluation_study.py.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from evperc.cli import cli

REPO = Path(__file__).resolve().parents[2]
OSM = REPO / "tests" / "data" / "osm"
SEED, SECONDS = 3, 5  # a drive where moving cars are seen from the first second


def invoke_ok(*args: str) -> None:
    """Run the CLI quietly in this process; fail the test on a non-zero exit."""
    result = CliRunner().invoke(cli, ["-q", *args])
    assert result.exit_code == 0, result.output


@pytest.fixture(scope="module")
def scores(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Metrics of the map and no-map runs, both cell sets, as `evperc evaluate --json` wrote."""
    root = tmp_path_factory.mktemp("simeval")
    drive = root / "drive"
    invoke_ok("simulate", "--map", str(OSM / "helsinki_buildings.geojson"), "--roads",
            str(OSM / "helsinki_roads.geojson"), "--profile", "ibeo4", "--seconds", str(SECONDS),
            "--seed", str(SEED), "--out", str(drive))
    invoke_ok("run", str(drive / "drive.mcap"), "--map", str(drive / "map.geojson"),
            "--out", str(root / "map"))
    invoke_ok("run", str(drive / "drive.mcap"), "--no-map", "--out", str(root / "nomap"))
    out: dict[str, Any] = {}
    for cells in ("observed", "visible"):
        path = root / f"{cells}.json"
        invoke_ok("evaluate", str(root / "map"), "--truth", str(drive / "truth"), "--compare",
                str(root / "nomap"), "--cells", cells, "--json", str(path))
        doc = json.loads(path.read_text())
        out[cells] = {"map": doc, "nomap": doc["compare"]}
    return out


def test_every_scan_is_scored(scores: dict[str, Any]) -> None:
    for cells in ("observed", "visible"):
        for run in ("map", "nomap"):
            m = scores[cells][run]
            assert m["frames_matched"] == SECONDS * 10
            assert m["frames_unmatched"] == 0
            assert m["per_class"]["moving"]["support"] > 100  # measured 251 visible cells
    # a cell seen now was seen at this or an earlier scan: visible ⊆ observed
    assert scores["visible"]["map"]["cells"] < scores["observed"]["map"]["cells"]


def test_moving_objects_are_found(scores: dict[str, Any]) -> None:
    visible = scores["visible"]["map"]
    assert visible["per_class"]["moving"]["recall"] >= 0.45  # measured 0.574
    # within one cell (the boundary convention of evperc.eval.metrics): measured P 0.975,
    # R 0.741 since 2026-12-05, fifth session. On this drive a car passing a stopped one
    # merges with it in one cluster for a few frames; without the split of shared clusters
    # (configs/ablation/no_split.toml: P 0.743) the stopped car's track takes the cluster and
    # is reported moving for 10 frames (docs/evaluation.md § Since 2026-12-05, fourth and
    # fifth sessions). The floors: precision 0.90 (the measured value less 0.075, about a
    # false track of 5 frames more; below the fix's 0.975, above the 0.743 without it),
    # recall 0.55 (issue 21's direction with a margin; unchanged)
    tolerant = visible["moving_within_one_cell"]
    assert tolerant["precision"] >= 0.90 and tolerant["recall"] >= 0.55
    latency = visible["latency_frames"]
    assert latency["episodes"] >= 10  # measured 20
    # measured 9 of 20 (11 with the free margin d_s 0.5 m, the default until 2026-12-01,
    # 15 before the motion gate): the 11 missed are pedestrians' episodes of 1-8 frames and
    # a parked car pulling out in the last 5 frames; the floor allows a loss of two more
    assert latency["detected"] >= 0.35 * latency["episodes"]
    assert latency["median"] <= 2  # measured 0 frames


def test_free_space_is_trustworthy(scores: dict[str, Any]) -> None:
    for run in ("map", "nomap"):
        assert scores["observed"][run]["coarse"]["free"]["precision"] >= 0.99  # measured 0.997
        assert scores["visible"][run]["coarse"]["free"]["precision"] >= 0.995  # measured 0.9998


def test_the_map_helps(scores: dict[str, Any]) -> None:
    for cells in ("observed", "visible"):
        with_map, without = scores[cells]["map"], scores[cells]["nomap"]
        # infrastructure is named only with the map (no-map: never, by construction)
        assert with_map["per_class"]["infrastructure"]["recall"] >= 0.5  # measured 0.90 observed
        assert without["per_class"]["infrastructure"]["recall"] == 0.0
        # road / pavement context turns static into stopped: measured 0.41 vs 0.07 observed
        assert (with_map["per_class"]["stopped"]["f1"]
                >= (without["per_class"]["stopped"]["f1"] or 0.0) + 0.1)
        # the map must not cost static F1 (the building margin closes the motion gate only; it
        # no longer widens the prior, which had cost this)
        assert with_map["coarse"]["static"]["f1"] >= without["coarse"]["static"]["f1"]


def test_unmapped_is_decided_with_the_map_only(scores: dict[str, Any]) -> None:
    """The unmapped cue (docs/method.md, "Unmapped infrastructure") relabels thin static
    things off the road; it needs the map's road edge and does nothing without it."""
    for cells, recall, precision in (("observed", 0.221, 0.375), ("visible", 0.159, 0.337)):
        with_map, without = scores[cells]["map"], scores[cells]["nomap"]
        got = with_map["per_class"]["unmapped"]
        assert got["support"] > 300  # measured 1055 observed, 421 visible cells
        assert got["recall"] >= recall / 2, got  # measured values in the tuple above
        assert got["precision"] >= precision / 2, got
        assert without["per_class"]["unmapped"]["recall"] == 0.0
        assert without["per_class"]["unmapped"]["precision"] is None  # never decided
