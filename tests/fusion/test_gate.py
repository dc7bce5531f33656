"""The motion gate pass (evperc.fusion.gate) against a plain-Python reference written from
its definition (docs/method.md, "The motion gate"), on a window that scrolls; and the
behaviours it exists for: a wall grazed free is never ever-free, a road is."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from evperc.fusion.fused import window_order
from evperc.fusion.gate import NEVER, GateState, gate_step
from evperc.fusion.twin import FusionParams

PARAMS = FusionParams(motion_gate="ever_free", gate_free_s=0.3, gate_revoke_s=0.5,
                      gate_gap_s=0.2, gate_min_free=0.5)
#: the same with the re-hit revocation on (a return back 0.2–0.6 s after the previous one)
REHIT = replace(PARAMS, gate_rehit_s=0.6)
#: ... and only after a gap in which the cell was seen free
REHIT_FREE = replace(REHIT, gate_rehit_gap="seen_free")
#: ... revoking only the cells of its block that held a return within gate_rehit_s
REHIT_RECENT = replace(REHIT_FREE, gate_rehit_revokes="recent_returns")


class Reference:
    """Per window cell dicts in window coordinates; scrolling moves the dicts."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.shape = shape
        self.cells = {(r, c): self.new() for r in range(shape[0]) for c in range(shape[1])}

    @staticmethod
    def new() -> dict:
        return {"run": None, "occ_run": 0.0, "last_occ": None, "ever": False,
                "free_since_occ": False}

    def scroll(self, dr: int, dc: int) -> None:
        old = self.cells
        self.cells = {(r, c): old.get((r + dr, c + dc), self.new())
                      for r in range(self.shape[0]) for c in range(self.shape[1])}

    def step(self, free, occ, dt, p: FusionParams) -> np.ndarray:
        ready, revoke, rehit, recent = {}, {}, {}, {}
        for (r, c), cell in self.cells.items():
            # ages are kept as "seconds since" (None: never)
            since = None if cell["last_occ"] is None else cell["last_occ"] + dt
            cell["last_occ"] = since
            rev = False
            if occ[r, c] > 0:
                if since is not None and since <= p.gate_gap_s + 1e-3:
                    cell["occ_run"] += since
                else:
                    cell["occ_run"] = 0.0
                cell["last_occ"] = 0.0
                cell["run"] = None
                back = since is not None and p.gate_gap_s + 1e-3 < since <= p.gate_rehit_s + 1e-3
                if p.gate_rehit_gap == "seen_free":
                    back = back and cell["free_since_occ"]
                cell["free_since_occ"] = False
                rev = cell["occ_run"] >= p.gate_revoke_s - 1e-3
                if p.gate_rehit_revokes == "recent_returns":
                    rehit[r, c] = back
                else:
                    rev = rev or back
            elif free[r, c] >= p.gate_min_free:
                cell["run"] = 0.0 if cell["run"] is None else cell["run"] + dt
                cell["free_since_occ"] = True
            ready[r, c] = cell["run"] is not None and cell["run"] >= p.gate_free_s - 1e-3
            revoke[r, c] = rev
            # a return within gate_rehit_s, this scan's included
            recent[r, c] = (cell["last_occ"] is not None
                            and cell["last_occ"] <= p.gate_rehit_s + 1e-3)
        gate = np.zeros(self.shape, np.uint8)
        for (r, c), cell in self.cells.items():
            block = [(r + y, c + x) for y in (-1, 0, 1) for x in (-1, 0, 1)]
            if any(revoke.get(b, False) for b in block) or (
                    recent[r, c] and any(rehit.get(b, False) for b in block)):
                cell["ever"] = False
            elif all(ready.get(b, False) for b in block):
                cell["ever"] = True
            gate[r, c] = cell["ever"]
        return gate


def assert_times_equal(state: GateState, ref: Reference, offset: list[int]) -> None:
    """The state's three times (window order) against the reference's cells: a free run's
    length (none: −1), the occupied run's length, the time since the last return (never:
    NEVER). To 1e-4 s: float32 sums of the same dts against float64 ones (about 1e-6 s apart
    over these scenes), a tenth of the 1e-3 s slack of every comparison made on them."""
    times = window_order(state.times, offset)
    want = np.empty_like(times)
    for (r, c), cell in ref.cells.items():
        want[:, r, c] = (-1.0 if cell["run"] is None else cell["run"], cell["occ_run"],
                         NEVER if cell["last_occ"] is None else cell["last_occ"])
    np.testing.assert_allclose(times, want, rtol=0, atol=1e-4)


@pytest.mark.parametrize("params", [PARAMS, REHIT, REHIT_FREE, REHIT_RECENT],
                         ids=["rehit-off", "rehit-on", "rehit-seen-free", "rehit-recent"])
@pytest.mark.parametrize("seed", range(4))
def test_gate_pass_matches_reference(seed: int, params: FusionParams) -> None:
    """Random free / occupied / unseen scans with long free and occupied stretches (so
    that cells become ever-free and are revoked), the window scrolling by 0–2 cells."""
    check_against_reference(seed, (13, 17), with_closed=False, params=params)


# the one-sweep pass (a ring of three row results) has its own first, last and only rows
# and columns: thin windows, and the closed mask (the building margin) applied in the pass
@pytest.mark.parametrize(("seed", "shape"), [(4, (1, 9)), (5, (9, 1)), (6, (2, 5)),
                                             (7, (3, 3)), (8, (23, 41)), (9, (40, 64))])
def test_gate_pass_matches_reference_thin_windows_and_closed_cells(
        seed: int, shape: tuple[int, int]) -> None:
    check_against_reference(seed, shape, with_closed=True,
                            params=(PARAMS, REHIT, REHIT_FREE, REHIT_RECENT)[seed % 4])


def step_both(state: GateState, ref: Reference, free: np.ndarray, occ: np.ndarray, dt: float,
              params: FusionParams, offset: list[int], shift: tuple[int, int],
              closed: np.ndarray | None, frame: int) -> np.ndarray:
    """One scan through :func:`gate_step` and the reference; ``ever`` (unmasked), the times
    and the gate layer (0 where ``closed``) must agree. Returns the gate layer."""
    got = gate_step(state, free, occ, dt, params, offset=tuple(offset), shift=shift,
                    closed=closed)
    want = ref.step(free, occ, dt, params)
    np.testing.assert_array_equal(window_order(state.ever, offset), want)
    assert_times_equal(state, ref, offset)
    if closed is not None:
        want = np.where(closed, 0, want)
    np.testing.assert_array_equal(got, want, err_msg=f"frame {frame}")
    return got


def check_against_reference(seed: int, shape: tuple[int, int], with_closed: bool,
                            params: FusionParams = PARAMS) -> None:
    """:func:`gate_step` against :class:`Reference` over 40 frames (:func:`step_both`; exact:
    both evaluate the same float32 comparisons, the reference in float64 on values that are
    sums of the same dts; the original case has passed so since the gate was written); with
    ``with_closed``, a random closed mask each frame, which zeroes the gate layer only."""
    rng = np.random.default_rng(seed)
    thin = (shape[0] - 2) * (shape[1] - 2) < 20  # too few inner cells to count transitions
    state = GateState.fresh(shape)
    ref = Reference(shape)
    offset = [0, 0]
    base = rng.choice(3, size=shape, p=[0.15, 0.7, 0.15])  # 0 unseen, 1 free, 2 occupied
    opened = revoked = 0
    previous = np.zeros(shape, np.uint8)
    for frame in range(40):
        shift = (int(rng.integers(-1, 2)), int(rng.integers(-2, 3))) if frame % 4 == 3 \
            else (0, 0)
        offset = [(offset[0] + shift[0]) % shape[0], (offset[1] + shift[1]) % shape[1]]
        ref.scroll(*shift)
        flip = rng.random(shape) < 0.08
        kind = np.where(flip, rng.choice(3, size=shape), base)
        if frame % 10 == 0:  # the scene changes now and then
            base = rng.choice(3, size=shape, p=[0.15, 0.7, 0.15])
        free = np.where(kind == 1, rng.choice([0.7, 0.3], size=shape, p=[0.9, 0.1]), 0.0)
        occ = np.where(kind == 2, 0.8, 0.0)
        dt = float(rng.choice([0.1, 0.1, 0.05, 0.3]))
        closed = rng.random(shape) < 0.2 if with_closed else None
        got = step_both(state, ref, free, occ, dt, params, offset, shift, closed, frame)
        opened += int(((got == 1) & (previous == 0)).sum())
        revoked += int(((got == 0) & (previous == 1)).sum())
        previous = got
    if not thin:
        assert opened > 10 and revoked > 5, (opened, revoked)  # both transitions exercised


def run_scene(frames: list[tuple[np.ndarray, np.ndarray]], params: FusionParams = PARAMS
              ) -> list[np.ndarray]:
    state = GateState.fresh(frames[0][0].shape)
    return [gate_step(state, f, o, 0.1, params).copy() for f, o in frames]


def test_road_cell_opens_after_the_burn_in_and_stays_open_under_a_car() -> None:
    shape = (7, 7)
    free = np.full(shape, 0.7, np.float32)
    occ = np.zeros(shape, np.float32)
    car = occ.copy()
    car[3, 3] = 0.8
    gates = run_scene([(free, occ)] * 4 + [(np.where(car > 0, 0, free), car)] * 3)
    # free_s after k free scans is (k − 1) · 0.1: ready at the 4th scan (0.3 s)
    assert gates[2][3, 3] == 0 and gates[3][3, 3] == 1
    assert gates[3][0, 3] == 0  # window edge: neighbours outside count as not free
    assert all(g[3, 3] == 1 for g in gates[4:])  # a car arriving keeps the gate open


def test_wall_is_never_ever_free() -> None:
    """A wall row grazed free now and then, with the building behind it never observed:
    its cells never open (a neighbour is always unseen); the road in front does."""
    shape = (8, 9)
    frames = []
    for k in range(12):
        free = np.zeros(shape, np.float32)
        occ = np.zeros(shape, np.float32)
        free[4:] = 0.7       # road
        if k % 3:            # the wall row: free by grazing rays, then a return
            free[3] = 0.7
        else:
            occ[3] = 0.8
        frames.append((free, occ))
    gates = run_scene(frames)
    assert not any(g[:4].any() for g in gates)
    assert gates[-1][5:7, 1:8].all()


def test_long_occupancy_revokes_the_cell_and_its_neighbours() -> None:
    shape = (7, 7)
    free = np.full(shape, 0.7, np.float32)
    occ = np.zeros(shape, np.float32)
    park = occ.copy()
    park[3, 3] = 0.8
    parked = np.where(park > 0, 0, free)
    gap = (parked, occ)  # one scan without the return: tolerated (0.2 s)
    gates = run_scene([(free, occ)] * 5 + [(parked, park)] * 3 + [gap] + [(parked, park)] * 4)
    assert gates[4][2:5, 2:5].all()
    # occupied at scans 5, 6, 7, (gap), 9, 10: runs of 0, 0.1, 0.2, 0.4, 0.5 s
    assert gates[9][3, 3] == 1
    assert not gates[10][2:5, 2:5].any() and gates[10][1, 1] == 1
    assert not gates[12][2:5, 2:5].any()  # not re-opened while occupied


def pole_scene() -> list[tuple[np.ndarray, np.ndarray]]:
    """A thin pole at (3, 3) in open ground: seen free (through the gap between two beams)
    for 4 scans, hit, free for 3 scans, hit again, free 7 scans, hit again."""
    shape = (7, 7)
    free = np.full(shape, 0.7, np.float32)
    occ = np.zeros(shape, np.float32)
    pole = occ.copy()
    pole[3, 3] = 0.8
    hit = (np.where(pole > 0, 0, free), pole)
    return [(free, occ)] * 4 + [hit] + [(free, occ)] * 3 + [hit] + [(free, occ)] * 7 + [hit]


def test_rehit_within_the_bound_closes_the_gate_for_a_pole_seen_through_gaps() -> None:
    """Without the rule the pole's every return passes the gate (ever-free is kept while
    the cell holds no long occupied run); with gate_rehit_s 0.6 s the first return still
    passes (the cell's history cannot tell a pole from a car yet), the one 0.4 s later
    does not (nor do its neighbours), the one 0.8 s after that does (past the bound)."""
    frames = pole_scene()
    off, on = run_scene(frames), run_scene(frames, REHIT)
    assert [g[3, 3] for g in off][4::4][:3] == [1, 1, 1]  # scans 4, 8, 12 (12: free)
    assert off[8][3, 3] == 1 and off[16][3, 3] == 1
    assert on[4][3, 3] == 1
    assert on[8][3, 3] == 0 and not on[8][2:5, 2:5].any() and on[8][1, 1] == 1
    assert on[16][3, 3] == 1  # 0.8 s after the previous return: past the bound


def test_rehit_spares_a_car_driving_through() -> None:
    """A car's cells are hit on consecutive scans (no gap over gate_gap_s): the rule does
    not fire, the gate stays open ahead of it as it drives a cell a scan."""
    shape = (5, 12)
    free = np.full(shape, 0.7, np.float32)
    frames = [(free, np.zeros(shape, np.float32))] * 4
    for k in range(6):
        occ = np.zeros(shape, np.float32)
        occ[2, 3 + k:5 + k] = 0.8
        frames.append((np.where(occ > 0, 0, free), occ))
    on = run_scene(frames, REHIT)
    for k in range(6):
        assert on[4 + k][2, 4 + k] == 1, k  # the car's front cell: the gate open


def test_rehit_seen_free_still_closes_for_the_pole() -> None:
    """The pole's gaps are free (the beams that miss it cross its cell): with
    gate_rehit_gap "seen_free" its second return revokes as with "any"."""
    frames = pole_scene()
    assert [g[3, 3] for g in run_scene(frames, REHIT_FREE)] == \
        [g[3, 3] for g in run_scene(frames, REHIT)]
    assert run_scene(frames, REHIT_FREE)[8][3, 3] == 0


def test_rehit_seen_free_spares_a_cell_occluded_in_its_gap() -> None:
    """A cell behind a car's near face (a roof return now and then, unknown between: the
    near face hides it) does not revoke its block under "seen_free", so the road cell ahead
    of it, which the car enters next, keeps its gate open; under "any" it is revoked."""
    shape = (5, 7)
    free = np.full(shape, 0.7, np.float32)
    frames = [(free, np.zeros(shape, np.float32))] * 4
    roof = np.zeros(shape, np.float32)
    roof[2, 2] = 0.8
    hidden = free.copy()
    hidden[2, 2] = 0.0  # unobserved: neither free nor occupied
    frames += [(np.where(roof > 0, 0, free), roof), (hidden, np.zeros(shape, np.float32)),
               (hidden, np.zeros(shape, np.float32)), (hidden, np.zeros(shape, np.float32)),
               (np.where(roof > 0, 0, free), roof)]
    any_gap, seen_free = run_scene(frames, REHIT), run_scene(frames, REHIT_FREE)
    assert any_gap[-1][2, 3] == 0  # the re-hit after 0.4 s revoked the block
    assert seen_free[-1][2, 3] == 1  # the gap was not free: nothing revoked


def walker_scene() -> list[tuple[np.ndarray, np.ndarray]]:
    """A one-cell walker on open ground: its return at (3, 3) for a scan, then its cell seen
    free for three (the return fell beside it, in no cell the sensor model marks), then at
    (3, 3) again (a re-hit after a free gap), then one step on, at (3, 4)."""
    shape = (7, 9)
    free = np.full(shape, 0.7, np.float32)
    at = {}
    for cell in ((3, 3), (3, 4)):
        occ = np.zeros(shape, np.float32)
        occ[cell] = 0.8
        at[cell] = (np.where(occ > 0, 0, free), occ)
    empty = (free, np.zeros(shape, np.float32))
    return [empty] * 4 + [at[3, 3]] + [empty] * 3 + [at[3, 3], at[3, 4]]


def test_rehit_recent_returns_spares_the_cell_ahead_of_a_walker() -> None:
    """Under "block" the walker's re-hit at (3, 3) revokes its whole block, so the step into
    (3, 4) meets a closed gate; under "recent_returns" only (3, 3) closes — (3, 4) held no
    return — and the step is seen through an open gate."""
    block, recent = run_scene(walker_scene(), REHIT_FREE), run_scene(walker_scene(),
                                                                       REHIT_RECENT)
    assert block[8][3, 3] == 0 and block[8][3, 4] == 0 and block[9][3, 4] == 0
    assert recent[8][3, 3] == 0 and recent[8][3, 4] == 1 and recent[9][3, 4] == 1
    assert recent[8][2, 2] == 1  # the rest of the block stays open too


def test_rehit_recent_returns_closes_a_pole_and_the_cells_it_spills_into() -> None:
    """A pole whose returns fall in (3, 3) and, now and then, in (3, 4) beside it: a re-hit
    of (3, 3) revokes (3, 4) as well under "recent_returns" (it held a return 0.2 s before),
    as under "block"; a cell of the block never hit stays open."""
    shape = (7, 7)
    free = np.full(shape, 0.7, np.float32)
    empty = (free, np.zeros(shape, np.float32))
    scans = {}
    for name, cells in (("pole", [(3, 3)]), ("spill", [(3, 4)])):
        occ = np.zeros(shape, np.float32)
        for cell in cells:
            occ[cell] = 0.8
        scans[name] = (np.where(occ > 0, 0, free), occ)
    frames = [empty] * 4 + [scans["pole"], empty, scans["spill"], empty, scans["pole"]]
    recent = run_scene(frames, REHIT_RECENT)
    assert recent[8][3, 3] == 0 and recent[8][3, 4] == 0
    assert recent[8][2, 2] == 1


def test_rejects_mismatched_grids() -> None:
    state = GateState.fresh((3, 4))
    with pytest.raises(ValueError, match="sensor grid"):
        gate_step(state, np.zeros((3, 3)), np.zeros((3, 3)), 0.1, PARAMS)


@pytest.mark.parametrize("params", [PARAMS, REHIT_RECENT], ids=["rehit-off", "rehit-recent"])
@pytest.mark.parametrize("seed", range(3))
def test_gate_pass_matches_reference_where_rays_reach_a_moving_part_of_the_window(
        seed: int, params: FusionParams) -> None:
    """Untouched cells beside touched ones: the rays reach a disc that wanders over the
    window (and now and then nothing at all), the window scrolls, so rows hold untouched
    ends, touched cells beyond the disc, and rows with nothing. Exact against the reference,
    the times included; the scene has what it is for (rows starting or ending with 32
    untouched cells: a pass that skipped such cells was measured, docs/performance.md)."""
    rng = np.random.default_rng(100 + seed)
    shape = (31, 150)
    state, ref = GateState.fresh(shape), Reference(shape)
    offset, centre = [0, 0], np.array([15.0, 10.0])
    rows, cols = np.mgrid[:shape[0], :shape[1]]
    opened = revoked = untouched_ends = 0
    previous = np.zeros(shape, np.uint8)
    for frame in range(60):
        shift = (int(rng.integers(-1, 2)), int(rng.integers(-3, 4))) if frame % 5 == 4 \
            else (0, 0)
        offset = [(offset[0] + shift[0]) % shape[0], (offset[1] + shift[1]) % shape[1]]
        ref.scroll(*shift)
        centre = np.clip(centre + rng.normal(0, 3.0, 2) - shift, 0, np.array(shape) - 1)
        radius = 0.0 if frame % 13 == 12 else float(rng.uniform(4, 9))
        seen = (rows - centre[0]) ** 2 + (cols - centre[1]) ** 2 <= radius ** 2
        kind = np.where(rng.random(shape) < 0.85, 1, 2)  # free, or a return
        free = np.where(seen & (kind == 1), 0.7, 0.0)
        occ = np.where(seen & (kind == 2), 0.8, 0.0)
        closed = rng.random(shape) < 0.1
        got = step_both(state, ref, free, occ, 0.1, params, offset, shift, closed, frame)
        untouched = ~seen & (window_order(state.times[0], offset) < 0) & (
            window_order(state.times[2], offset) >= 1e9)
        untouched_ends += int(untouched[:, :32].all(axis=1).sum()
                            + untouched[:, -32:].all(axis=1).sum())
        opened += int(((got == 1) & (previous == 0)).sum())
        revoked += int(((got == 0) & (previous == 1)).sum())
        previous = got
    # both transitions happen (23-117 of each over these seeds), and more than a quarter of
    # the 3,720 row ends start 32 untouched cells (56-62 %)
    assert opened >= 5 and revoked >= 5 and untouched_ends > 930, (opened, revoked, untouched_ends)
