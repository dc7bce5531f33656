"""objects.centroid = "returns" through the object stage: a person walking a tenth of a
0.5 m cell a scan, seen as one or two cells. The oracle is the walker's own motion, set by the
test: 1 m/s along x. With the returns' mean for a centroid the tracker's constant-velocity
fit finds that speed exactly (the mean moves with the walker); with the cell centres' mean
it sees a staircase (the centroid stands, then jumps half a cell) and the fit is off."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import evperc
from evperc.cli import cli
from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.geo.window import Window
from evperc.objects.stage import ObjectStage
from evperc.objects.tracking import TrackerState

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data"
RES = 0.5
SHAPE = (20, 40)
WINDOW = Window(RES, SHAPE[0], SHAPE[1], 0, 0)
SPEED = 1.0       # m/s along x, the walker's truth
DT_NS = 100_000_000
Y = 5.1           # the walker's y: row 10 (5.0-5.5 m)
#: the walker's returns: offsets (m) from its centre along x, a 0.3 m wide body
BODY = np.array([-0.15, -0.05, 0.05, 0.15])


def _walk(centroid: str, frames: int = 12, max_cells: int = 0, sigma_m: float = 0.25,
          min_returns: int = 0, returns_sigma_m: float = 0.0, heights: bool = False
          ) -> TrackerState:
    """The walker through the object stage. ``heights``: the sensor grid's way — the sums
    written with the heights (valid where a cell's height is > 0), every other cell of the
    block holding another scan's sums, which must not be read."""
    config = load_config(overrides={"objects.centroid": centroid,
                                    "objects.centroid_max_cells": max_cells,
                                    "objects.centroid_sigma_m": sigma_m,
                                    "objects.centroid_min_returns": min_returns,
                                    "objects.centroid_returns_sigma_m": returns_sigma_m,
                                    "objects.min_cluster_cells": 1})
    stage = ObjectStage(config, SHAPE)
    state = TrackerState()
    zeros = np.zeros(SHAPE, np.uint8)
    for k in range(frames):
        x = 5.02 + SPEED * k * DT_NS / 1e9 + BODY
        decision = np.full(SHAPE, D["free"], np.uint8)
        occupied = np.zeros(SHAPE, np.bool_)
        sums = np.zeros((*SHAPE, 3), np.float32)
        if heights:  # stale sums of another scan wherever this one has no return
            sums[:] = (0.2, -0.2, 7.0)
        top = np.zeros(SHAPE, np.float32)
        for px in x:
            r, c = int(Y // RES), int(px // RES)
            decision[r, c] = D["static"]
            occupied[r, c] = True
            if top[r, c] == 0:
                sums[r, c] = 0.0
            top[r, c] = 1.5  # the walker's head above the ground
            sums[r, c] += (px - (c + 0.5) * RES, Y - (r + 0.5) * RES, 1.0)
        if heights:  # the cell behind it decided moving, no return of this scan in it: it
            # joins the walker's cluster (a cell decided moving grows it), its sums are stale
            decision[int(Y // RES), int((x[0] - RES) // RES)] = D["moving"]
        stage.step(state, decision, zeros, zeros, WINDOW, k * DT_NS, occupied_now=occupied,
                   heights=top if heights else None, return_sums=sums)
    assert len(state) == 1  # one track followed the walker all along
    return state


def _floor(sigma_m: float, history: int = 10) -> float:
    """The velocity's standard deviation at the noise floor: σ₀ / √Σ(tᵢ − t̄)²."""
    t = np.arange(history) * 0.1
    return sigma_m / float(np.sqrt(((t - t.mean()) ** 2).sum()))


@pytest.mark.parametrize("sigma_m", [0.25, 0.1])
def test_the_returns_mean_gives_the_walkers_speed(sigma_m):
    state = _walk("returns", sigma_m=sigma_m)
    # the fit over the last history_frames centroids of a walker at constant speed: exact
    # but for float32 sums of the offsets (1e-7 m over 0.9 s)
    np.testing.assert_allclose(state.velocity[0], [SPEED, 0.0], atol=1e-5)
    # its noise is the floor: the residuals are zero
    assert state.sigma[0] == pytest.approx(_floor(sigma_m), rel=1e-6)


def test_the_cell_centres_mean_is_a_staircase():
    # the same walker: the fit of the last ten centroids is off by 6 % (0.94 m/s; far more
    # than the float32 rounding of the above) ...
    state = _walk("cells")
    assert abs(state.velocity[0, 0] - SPEED) > 0.05
    # ... with its noise at the floor all the same: the staircase's residuals are smaller
    assert state.sigma[0] == pytest.approx(_floor(0.25), rel=1e-6)


def test_clusters_larger_than_max_cells_keep_the_cell_centres():
    # the walker is one or two cells: a bound of one cell leaves the two-cell frames, and
    # so the fit, to the cell centres
    assert abs(_walk("returns", max_cells=1).velocity[0, 0] - SPEED) > 1e-3
    np.testing.assert_allclose(_walk("returns", max_cells=2).velocity[0], [SPEED, 0.0],
                               atol=1e-5)


def test_the_stage_asks_for_the_sums_only_for_returns():
    assert not ObjectStage(load_config(overrides={"objects.centroid": "cells"}),
                           SHAPE).needs_return_sums
    assert ObjectStage(load_config(overrides={"objects.centroid": "returns"}),
                       SHAPE).needs_return_sums
    assert ObjectStage(load_config(), SHAPE).needs_return_sums  # the default since 2026-12-07


def test_the_sums_are_read_only_where_a_cell_holds_a_return():
    # the sensor grid's block: this scan's sums where the height is > 0, another scan's
    # elsewhere (an uncleared block), and the walker's cluster holds a cell without a return
    # (decided moving behind it): the fit is the exact speed only if that cell's stale sums
    # were left alone
    state = _walk("returns", heights=True)
    np.testing.assert_allclose(state.velocity[0], [SPEED, 0.0], atol=1e-5)


@pytest.mark.parametrize("min_returns, exact", [(4, True), (5, False)])
def test_clusters_with_fewer_returns_keep_the_cell_centres(min_returns, exact):
    # the walker holds 4 returns a scan (BODY): a bound of 5 leaves it to the staircase
    vx = _walk("returns", min_returns=min_returns).velocity[0, 0]
    assert bool(abs(vx - SPEED) < 1e-5) == exact
    if not exact:
        assert vx == pytest.approx(_walk("cells").velocity[0, 0], abs=1e-12)


@pytest.mark.parametrize("min_returns, floor_m", [(4, 0.1), (5, 0.25)])
def test_a_returns_mean_takes_its_own_noise_floor(min_returns, floor_m):
    # centroid_returns_sigma_m 0.1 for the returns' means, centroid_sigma_m 0.25 for the
    # cells' means: the fit's noise is the floor of the centroid its track has (the
    # residuals of both are under the floors, test_the_cell_centres_mean_is_a_staircase)
    state = _walk("returns", min_returns=min_returns, returns_sigma_m=0.1)
    assert state.sigma[0] == pytest.approx(_floor(floor_m), rel=1e-6)


def test_a_run_hands_the_returns_to_the_tracker(tmp_path):
    """Through ``evperc run`` (the sample drive's first 6 s): the sensor grid's sums reach
    the object stage (the object lists change), the fusion does not (the masses and ζ are
    the same: the object stage writes nothing back), and every record's centroid lies in
    its cells' bounding box (a mean of returns that lie in those cells)."""
    runs = {}
    for name, centroid in (("cells", "cells"), ("returns", "returns")):
        config = tmp_path / f"{name}.toml"
        config.write_text(f'[objects]\ncentroid = "{centroid}"\ncentroid_sigma_m = 0.1\n'
                          'centroid_min_returns = 0\ncentroid_returns_sigma_m = 0.0\n')
        out = tmp_path / name
        result = CliRunner().invoke(cli, ["run", str(SAMPLE / "drive.mcap"), "--map",
                                          str(SAMPLE / "map.geojson"), "--end", "6",
                                          "--config", str(config), "--out", str(out)])
        assert result.exit_code == 0, result.output
        runs[name] = evperc.load(out).frames
    changed = 0
    for a, b in zip(runs["cells"], runs["returns"], strict=True):
        np.testing.assert_array_equal(a.masses, b.masses)
        np.testing.assert_array_equal(a.zeta, b.zeta)
        for record in b.objects:
            x, y = record["centroid_m"]
            xmin, ymin, xmax, ymax = record["bbox_m"]
            assert xmin <= x <= xmax and ymin <= y <= ymax
        centroids = lambda f: sorted(map(tuple, f.objects["centroid_m"].tolist()))  # noqa: E731
        changed += centroids(a) != centroids(b)
    assert changed > 0  # the returns reached the tracker
