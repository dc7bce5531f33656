"""scripts/trace_missed.py's agent speeds from the simulator's plan of a drive, checked against
the drive's truth files, which the simulator wrote as it cast the scans: an agent's cells are
M exactly where its speed is above the stop speed (docs/truth-format.md). The drive is
simulated here, with the default configuration, as the script assumes."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from evperc.config import load_config
from evperc.sim.drive import SimRequest, simulate
from evperc.sim.traffic import STOP_SPEED_M_S
from evperc.sim.truth import load_truth

REPO = Path(__file__).resolve().parents[2]
OSM = REPO / "tests" / "data" / "osm"
sys.path.insert(0, str(REPO / "scripts"))

import trace_missed  # noqa: E402


@pytest.fixture(scope="module")
def truth_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "drive"
    simulate(SimRequest(OSM / "helsinki_buildings.geojson", out, load_config(),
                        roads_path=OSM / "helsinki_roads.geojson", profile="ibeo4",
                        seconds=5.0, seed=7))
    return out / "truth"


def test_planned_speeds_are_the_truths_moving_and_stopped_agents(truth_dir: Path):
    truth = load_truth(truth_dir)
    speeds = trace_missed.planned_speeds(truth)
    assert speeds is not None and len(speeds) == len(truth.agents)
    m_code, s_code = truth.class_codes["moving"], truth.class_codes["stopped"]
    checked = moving = 0
    for t in truth.frames:
        for a in np.unique(t.agent[t.agent > 0]).tolist():
            classes = np.unique(t.classes[t.agent == a])
            assert len(classes) == 1  # an agent is one class in a frame
            planned_moving = speeds[a][t.index] > STOP_SPEED_M_S
            assert classes[0] == (m_code if planned_moving else s_code), (t.index, a)
            checked += 1
            moving += int(planned_moving)
    # the drive holds both kinds, in numbers (763 agent-frames, 221 moving): the check is
    # not vacuous
    assert checked > 500 and 100 < moving < checked - 100


def test_a_plan_of_another_drive_is_refused(truth_dir: Path, tmp_path: Path):
    # the same truth frames with another seed in the manifest: the plan's agents are not
    # the truth's, and the cells' estimate stands (None)
    copy = tmp_path / "truth"
    shutil.copytree(truth_dir, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["seed"] = manifest["seed"] + 1
    (copy / "manifest.json").write_text(json.dumps(manifest))
    assert trace_missed.planned_speeds(load_truth(copy)) is None


@pytest.mark.parametrize("v, bucket", [(None, "speed ?"), (0.0, "< 0.5 m/s"),
                                       (0.49, "< 0.5 m/s"), (0.5, "0.5-1 m/s"),
                                       (1.0, ">= 1 m/s")])
def test_speed_buckets(v, bucket):
    assert trace_missed._speed_bucket(v, 0.5) == bucket


def test_isolation_breakers_name_the_truth_of_the_still_cells_around_a_group():
    """A one-cell group at (2, 2) of a 6 x 6 run window, reach 1: the still cells around it
    are a cell the same agent's truth covers, one of another agent, a free cell decided
    static (a cell the walker left), a static truth cell and one outside the truth; a cell
    decided free or moving, one beyond the reach and the group's own cell are not named."""
    D = trace_missed.DECISION_CODES
    names = {0: "free", 3: "static", 6: "unmapped"}
    decision = np.full((6, 6), D["free"], np.uint8)
    agent = np.zeros((6, 6), np.int64)
    classes = np.zeros((6, 6), np.int64)  # truth free
    decision[2, 2] = D["static"]  # the group itself
    agent[2, 2] = 7
    decision[1, 1] = D["stopped"]
    agent[1, 1] = 7  # the same agent
    decision[1, 2] = D["unmapped"]
    agent[1, 2] = 9  # another one
    decision[1, 3] = D["static"]  # truth free: a left cell
    decision[3, 1] = D["infrastructure"]
    classes[3, 1] = 3
    decision[3, 3] = D["static"]
    classes[3, 3] = -1  # no truth there
    decision[3, 2] = D["moving"]  # not still
    decision[0, 0] = D["static"]  # beyond one cell
    classes[0, 0] = 6
    got = trace_missed.isolation_breakers(np.array([2 * 6 + 2]), decision, 1, 7, agent,
                                          classes, names)
    assert got == ["another agent", "free", "outside", "same agent", "static"]
    assert trace_missed.isolation_breakers(np.array([2 * 6 + 2]), decision, 2, 7, agent,
                                           classes, names) == sorted([*got, "unmapped"])
    decision[1, 3] = D["free"]
    assert "free" not in trace_missed.isolation_breakers(np.array([14]), decision, 1, 7,
                                                         agent, classes, names)
    group = np.array([35])  # at a corner: neighbours outside the window are left out
    assert trace_missed.isolation_breakers(group, decision, 1, 7, agent, classes,
                                           names) == []
