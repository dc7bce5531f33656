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
