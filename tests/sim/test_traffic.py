"""No simulated agent drives through the ego vehicle (evperc.sim.traffic): hand-made traffic on
a straight road, the expected fate of each agent worked out by hand, and the simulated
drives' own agents against the ego's body."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from evperc.config import load_config
from evperc.sim.drive import SimRequest, plan
from evperc.sim.scene import BOX, read_map_layers
from evperc.sim.traffic import (
    EGO_BODY_M,
    LANE_OFFSET_M,
    STEP_S,
    Agents,
    Trajectory,
    _drop_through_ego,
    ego_bodies,
)

DATA = Path(__file__).resolve().parents[1] / "data" / "osm"


def _straight_ego(speed: float = 5.0, seconds: float = 10.0) -> Trajectory:
    """Along +x from the origin in the right-hand lane: y = −LANE_OFFSET_M, heading 0."""
    t = np.arange(0.0, seconds + STEP_S / 2, STEP_S)
    return Trajectory(np.array([[0.0, 0.0], [1000.0, 0.0]]), t, speed * t,
                      np.full_like(t, LANE_OFFSET_M))


def _cars(xs: np.ndarray, ys: np.ndarray, headings: np.ndarray) -> Agents:
    """4.5 m x 1.8 m cars at ``xs``, ``ys`` (frames, agents)."""
    n = xs.shape[1]
    return Agents(np.full(n, BOX, np.int8), np.full(n, 4.5), np.full(n, 1.8), np.full(n, 1.5),
                  np.array(["car"] * n), xs, ys, headings, np.zeros_like(xs))


def test_an_agent_driving_through_the_ego_is_dropped() -> None:
    ego = _straight_ego()
    t = np.arange(100) / 10.0                        # 10 s of scans; the ego at x = 5 t
    lane = -LANE_OFFSET_M                           # the ego's lane centre (right of +x)
    xs = np.column_stack([
        -20.0 + 10.0 * t,    # 0: same lane, 10 m/s from 20 m behind: meets the ego at 4 s
        30.0 + 5.0 * t,      # 1: same lane, 30 m ahead, the ego's speed: never meets it
        60.0 - 8.0 * t,      # 2: oncoming lane (3.2 m left): passes beside, 3.2 − 0.9 − 0.85 > 0
        np.full_like(t, 20.0),   # 3: parked 1.9 m right of the lane centre: 0.9 + 0.85 < 1.9
        np.full_like(t, 25.0),   # 4: parked 1.6 m right of it, into the lane: 1.75 > 1.6
    ])
    ys = np.column_stack([np.full_like(t, lane), np.full_like(t, lane),
                          np.full_like(t, lane + 2 * LANE_OFFSET_M),
                          np.full_like(t, lane - 1.9), np.full_like(t, lane - 1.6)])
    headings = np.zeros_like(xs)
    headings[:, 2] = np.pi
    kept = _drop_through_ego(_cars(xs, ys, headings), ego, t)
    assert sorted(kept.x[0].tolist()) == [20.0, 30.0, 60.0]   # agents 3, 1, 2
    assert kept.x.shape == (100, 3)


def test_the_ego_body_holds_the_lidar_mounts() -> None:
    """The body the agents must stay out of is the car the lidars sit on (ibeo4 at the front
    bumper, x = 3.7 m; hdl64 on the roof, x = 1.5 m: docs of evperc.sim.lidar)."""
    (body,) = ego_bodies(_straight_ego(), np.array([0.0]))
    rear, front, half = EGO_BODY_M
    assert body.covers(shapely.points([[3.7, -LANE_OFFSET_M], [1.5, -LANE_OFFSET_M]])).all()
    assert shapely.area(body) == pytest.approx((front - rear) * 2 * half)


@pytest.mark.parametrize(("profile", "seconds", "seed"), [("ibeo4", 20.0, 16),
                                                          ("hdl64", 10.0, 14)])
def test_simulated_agents_never_overlap_the_ego(profile: str, seconds: float, seed: int
                                                ) -> None:
    """Drives of the evaluation whose traffic drove a car through the ego before (ibeo4
    seed 16: 254 visible cell-frames of it; hdl64 seed 14: 1,228)."""
    cfg = load_config()
    req = SimRequest(DATA / "helsinki_buildings.geojson", Path("unused"), cfg,
                     roads_path=DATA / "helsinki_roads.geojson", profile=profile,
                     seconds=seconds, seed=seed)
    layers = read_map_layers(req.map_path, req.roads_path)
    drive = plan(req, layers)
    assert len(drive.agents) > 10
    for k, body in enumerate(ego_bodies(drive.ego, drive.t_scan)):
        assert not shapely.intersects(drive.agents.at(k).polygons(), body).any(), k
