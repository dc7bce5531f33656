"""Ego vehicle and agents (cars, pedestrians) moving along the road graph.

Every agent follows a random walk on the road graph at a lateral offset: moving cars in the
right-hand lane, parked cars at the kerb, pedestrians on the pavement. Its speed follows a
target profile ``v(t) = v_cruise`` except during one pause ``[a, b)`` where it is 0,
smoothed by a moving average of ``ACCEL_WINDOW_S`` (about 2–3 m/s² for cars). An agent is
S (stopped) at an instant when its speed is at most ``STOP_SPEED_M_S``, else M (moving).
Parked cars that leave have the pause ``(−∞, t_leave)`` and steer from the kerb to the lane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from evperc.sim.roads import pose_along
from evperc.sim.scene import (
    BOX,
    CYLINDER,
    MOVING,
    STOPPED,
    Scene,
    Solids,
    kerb_offset_m,
)

LANE_OFFSET_M = 1.6        # right-hand lane centre from the centre line
PAVEMENT_EXTRA_M = 2.6     # pedestrians walk this far beyond the parked cars' centres
STOP_SPEED_M_S = 0.1
ACCEL_WINDOW_S = 2.0
STEP_S = 0.05
#: the ego vehicle's body in base_link (x forward from the rear axle, y left), metres: rear,
#: front, half width (a 4.6 m x 1.7 m car; the lidar mounts lie on it: ibeo4 at the front
#: bumper, x = 3.7, hdl64 on the roof, x = 1.5)
EGO_BODY_M = (-0.9, 3.7, 0.85)


@dataclass(frozen=True)
class Trajectory:
    """A body following ``path`` with arc length ``s(t)`` and offset ``d(t)`` on a time grid."""

    path: np.ndarray    # (V, 2)
    t: np.ndarray       # (T,) seconds from the drive start
    s: np.ndarray       # (T,)
    d: np.ndarray       # (T,)

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``x, y, heading, speed`` at times ``t`` (linear interpolation of s and d)."""
        t = np.asarray(t, dtype=np.float64)
        s = np.interp(t, self.t, self.s)
        d = np.interp(t, self.t, self.d)
        x, y, heading = pose_along(self.path, s, d)
        speed = np.interp(t, self.t[:-1] + STEP_S / 2, np.diff(self.s) / STEP_S)
        return x, y, heading, speed


@dataclass(frozen=True)
class Agents:
    """Agents sampled at the scan times: arrays ``(F, A)`` of pose, speed and class."""

    kind: np.ndarray      # (A,) BOX (vehicle) or CYLINDER (pedestrian)
    length: np.ndarray    # (A,)
    width: np.ndarray
    height: np.ndarray
    role: np.ndarray      # (A,) "car", "parked", "pedestrian"
    x: np.ndarray         # (F, A)
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray

    @property
    def label(self) -> np.ndarray:
        """(F, A) truth class: MOVING above the stop speed, else STOPPED."""
        return np.where(np.abs(self.speed) > STOP_SPEED_M_S, MOVING, STOPPED).astype(np.uint8)

    def at(self, frame: int) -> Solids:
        """The agents at scan ``frame`` as solids."""
        return Solids(self.kind, self.x[frame], self.y[frame], self.heading[frame],
                      self.length, self.width, self.height, self.label[frame])

    def __len__(self) -> int:
        return len(self.kind)


def speed_profiles(t: np.ndarray, v_cruise: np.ndarray, pause_start: np.ndarray,
                   pause_end: np.ndarray) -> np.ndarray:
    """(A, T) smoothed speeds: ``v_cruise`` outside ``[pause_start, pause_end)``, else 0."""
    paused = (t[None, :] >= pause_start[:, None]) & (t[None, :] < pause_end[:, None])
    target = np.where(paused, 0.0, v_cruise[:, None])
    w = max(1, int(round(ACCEL_WINDOW_S / STEP_S)))
    padded = np.concatenate([np.repeat(target[:, :1], w, axis=1), target], axis=1)
    c = np.cumsum(padded, axis=1)
    return (c[:, w:] - c[:, :-w]) / w


def time_grid(seconds: float) -> np.ndarray:
    return np.arange(0.0, seconds + 1.0 + STEP_S, STEP_S)


def plan_ego(scene: Scene, seconds: float, max_speed: float, rng: np.random.Generator,
             start_xy: tuple[float, float] | None) -> Trajectory:
    """The ego route: from the main-road node nearest ``start_xy`` (default: a random one
    near the map's centre), cruising at 60–100 % of ``max_speed`` with a 30 % chance of one
    stop of 2–6 s (a traffic light) after the first two seconds."""
    g = scene.graph
    wide = np.zeros(len(g.xy), dtype=bool)
    np.logical_or.at(wide, np.repeat(np.arange(len(g.xy)), g.degree), g.width_m >= 7.0)
    candidates = np.flatnonzero(wide & (g.degree >= 1))
    if len(candidates) == 0:
        candidates = np.flatnonzero(g.degree >= 1)
    if start_xy is None:
        centre = g.xy[candidates].mean(axis=0)
        near = candidates[np.argsort(np.hypot(*(g.xy[candidates] - centre).T))[:50]]
        start = int(rng.choice(near))
    else:
        start = int(candidates[np.argmin(np.hypot(*(g.xy[candidates] - start_xy).T))])
    t = time_grid(seconds)
    v_cruise = rng.uniform(0.6, 1.0) * max_speed
    stops = rng.random() < 0.3
    a = rng.uniform(2.0, max(2.0, seconds - 2.0)) if stops else np.inf
    b = a + rng.uniform(2.0, 6.0)
    v = speed_profiles(t, np.array([v_cruise]), np.array([a]), np.array([b]))[0]
    v[:] = np.maximum(v, 0.0)
    path, _ = g.random_walk(start, v_cruise * (seconds + 1.0) + 50.0, rng)
    s = np.concatenate([[0.0], np.cumsum(v[:-1]) * STEP_S])
    return Trajectory(path, t, s, np.full_like(t, LANE_OFFSET_M))


def populate(scene: Scene, ego: Trajectory, stamps_s: np.ndarray, rng: np.random.Generator,
             moving_cars: int, pedestrians: int, parked_spacing_m: float, radius_m: float
             ) -> Agents:
    """Moving cars, parked cars (some leave) and pedestrians near the ego route, sampled at
    ``stamps_s``."""
    g = scene.graph
    ex, ey, _, _ = ego.pose(ego.t)
    route = shapely.LineString(np.column_stack([ex, ey]))
    near_nodes = np.flatnonzero(
        (shapely.distance(shapely.points(g.xy), route) < radius_m) & (g.degree >= 1))
    if len(near_nodes) == 0:
        near_nodes = np.flatnonzero(g.degree >= 1)
    route_len = float(route.length) + 2 * radius_m
    n_parked = int(rng.poisson(2.0 * route_len / parked_spacing_m))
    t = time_grid(float(stamps_s[-1]) if len(stamps_s) else 0.0)
    horizon = float(t[-1])

    specs = []  # (role, kind, L, W, H, v_cruise, pause_a, pause_b, d0, d1, t_steer)
    for _ in range(moving_cars):
        stop = rng.random() < 0.4
        a = rng.uniform(0.0, horizon) if stop else np.inf
        specs.append(("car", BOX, *_car_dims(rng), rng.uniform(5.0, 13.0), a,
                      a + rng.uniform(2.0, 6.0), LANE_OFFSET_M, LANE_OFFSET_M, np.inf))
    for _ in range(n_parked):
        leaves = rng.random() < 0.2
        t_leave = rng.uniform(0.0, horizon) if leaves else np.inf
        kerb = 3.5
        specs.append(("parked", BOX, *_car_dims(rng), 5.0 if leaves else 0.0, -np.inf,
                      t_leave, kerb, LANE_OFFSET_M, t_leave))
    for _ in range(pedestrians):
        mode = rng.integers(3)     # walking, standing then walking, standing throughout
        a = (np.inf, -np.inf, -np.inf)[mode]
        b = (np.inf, rng.uniform(0.0, horizon), np.inf)[mode]
        side = rng.choice([-1.0, 1.0])
        specs.append(("pedestrian", CYLINDER, 0.6, 0.6, rng.uniform(1.5, 1.9),
                      rng.uniform(0.8, 1.6), a, b, side, side, np.inf))
    if not specs:
        return _empty_agents(len(stamps_s))
    cols = list(zip(*specs, strict=True))
    role = np.array(cols[0])
    v_cruise, pa, pb = (np.array(c, dtype=np.float64) for c in cols[5:8])
    v = speed_profiles(t, v_cruise, pa, pb)
    xs, ys, hs, vs = [], [], [], []
    for i in range(len(specs)):  # one random walk per agent (a graph walk is sequential)
        start = int(rng.choice(near_nodes))
        path, widths = g.random_walk(start, v_cruise[i] * horizon + 80.0, rng)
        if len(path) < 2:
            path = np.vstack([g.xy[start], g.xy[start] + [1.0, 0.0]])
            widths = np.array([7.0])
        kerb = float(kerb_offset_m(widths[:1])[0])
        s0 = rng.uniform(0.0, min(40.0, _length(path) / 2))
        s = s0 + np.concatenate([[0.0], np.cumsum(v[i, :-1]) * STEP_S])
        d = _offsets(role[i], cols, i, kerb, t)
        traj = Trajectory(path, t, s, d)
        x, y, h, sp = traj.pose(stamps_s)
        xs.append(x)
        ys.append(y)
        hs.append(h)
        vs.append(sp)
    agents = Agents(np.array(cols[1], dtype=np.int8), *(np.array(c, dtype=np.float64)
                                                         for c in cols[2:5]), role,
                    np.stack(xs, 1), np.stack(ys, 1), np.stack(hs, 1), np.stack(vs, 1))
    return _drop_clashes(_drop_through_ego(agents, ego, stamps_s), scene)


def _offsets(role: str, cols: list, i: int, kerb: float, t: np.ndarray) -> np.ndarray:
    d0, d1, t_steer = cols[8][i], cols[9][i], cols[10][i]
    if role == "parked":
        ramp = np.clip((t - t_steer) / 3.0, 0.0, 1.0) if np.isfinite(t_steer) else 0.0 * t
        return kerb + (d1 - kerb) * ramp
    if role == "pedestrian":
        return np.full_like(t, d0 * (kerb + PAVEMENT_EXTRA_M))
    return np.full_like(t, d0)


def _car_dims(rng: np.random.Generator) -> tuple[float, float, float]:
    if rng.random() < 0.15:
        return (rng.uniform(5.2, 6.0), 2.0, rng.uniform(2.1, 2.5))   # van
    return (rng.uniform(4.0, 4.8), rng.uniform(1.7, 1.9), rng.uniform(1.4, 1.6))


def _length(path: np.ndarray) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def _empty_agents(frames: int) -> Agents:
    z = np.zeros(0)
    zz = np.zeros((frames, 0))
    return Agents(z.astype(np.int8), z, z, z, z.astype(str), zz, zz, zz, zz)


def ego_bodies(ego: Trajectory, stamps_s: np.ndarray) -> np.ndarray:
    """The ego's body (:data:`EGO_BODY_M`) at each of ``stamps_s``: shapely polygons."""
    x, y, h, _ = ego.pose(np.asarray(stamps_s, np.float64))
    rear, front, half = EGO_BODY_M
    u = np.array([rear, front, front, rear])
    w = np.array([-half, -half, half, half])
    c, s = np.cos(h)[:, None], np.sin(h)[:, None]
    return shapely.polygons(np.stack([x[:, None] + c * u - s * w,
                                      y[:, None] + s * u + c * w], axis=-1))


def _drop_through_ego(agents: Agents, ego: Trajectory, stamps_s: np.ndarray) -> Agents:
    """Drop the agents whose footprint overlaps the ego's body at a scan time. Agents follow
    their walks blind to the ego: a car in the ego's lane at another speed drove through it,
    and the truth called the cells around the lidar — inside a car whose faces the rays,
    starting within it, never hit — visible and moving (up to 1,228 such cell-frames in a
    10 s drive)."""
    if len(agents) == 0 or len(stamps_s) == 0:
        return agents
    bad = np.zeros(len(agents), dtype=bool)
    for k, body in enumerate(ego_bodies(ego, stamps_s)):
        bad[shapely.intersects(agents.at(k).polygons(), body)] = True
    return _keep(agents, ~bad)


def _keep(agents: Agents, keep: np.ndarray) -> Agents:
    return Agents(agents.kind[keep], agents.length[keep], agents.width[keep],
                  agents.height[keep], agents.role[keep], agents.x[:, keep], agents.y[:, keep],
                  agents.heading[:, keep], agents.speed[:, keep])


def _drop_clashes(agents: Agents, scene: Scene) -> Agents:
    """Drop agents that start inside a building or unmapped object, parked cars within 10 m
    of a junction, and parked cars that overlap an earlier vehicle (first come, first kept)."""
    first = agents.at(0)
    shapes = first.polygons()
    obstacles = np.concatenate([scene.buildings, scene.furniture.polygons()])
    tree = shapely.STRtree(obstacles)
    bad = np.zeros(len(agents), dtype=bool)
    bad[np.unique(tree.query(shapes, predicate="intersects")[0])] = True
    vehicle = agents.kind == BOX
    pairs = shapely.STRtree(shapes).query(shapes, predicate="intersects")
    i, j = pairs
    clash = (i > j) & vehicle[i] & vehicle[j] & (agents.role[i] == "parked")
    bad[i[clash]] = True
    junctions = scene.graph.xy[scene.graph.degree >= 3]
    if len(junctions):
        gap = np.hypot(first.x[:, None] - junctions[None, :, 0],
                       first.y[:, None] - junctions[None, :, 1]).min(axis=1)
        bad |= (agents.role == "parked") & (gap < 10.0)
    return _keep(agents, ~bad)
