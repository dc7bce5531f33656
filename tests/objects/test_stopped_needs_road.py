"""Step 4 of the unmapped pass, `stopped` needs the road or motion
(``objects.stopped_needs_road``, evperc.objects.unmapped): hand-made decision grids with the
expected result worked out in the comments, and the fusion history that makes a façade's
return `stopped` in the first place (the numpy twin of the fused step)."""

from __future__ import annotations

import numpy as np

from evperc.config import load_config
from evperc.fusion.twin import DECISION_CODES as D
from evperc.fusion.twin import FusionParams, decide, fusion_step, sensor_masses, vacuous
from evperc.geo.prior import CONTEXT_BUILDING, CONTEXT_OTHER, CONTEXT_ROAD, prior_masses
from evperc.objects.unmapped import STAT_UNSTOPPED, UnmappedParams, unmapped_enabled
from tests.objects.unmapped_grids import DT, SHAPE, free_window, run_cue, street_labels

ON = UnmappedParams(max_width_m=0.55, min_age_s=0.1, stopped_needs_road=True)
OFF = UnmappedParams(max_width_m=0.55, min_age_s=0.1, stopped_needs_road=False)


def _run(decisions, labels, params=ON, moving_cells=None):
    return run_cue(decisions, labels, params, moving_cells)


def test_facade_strip_off_the_road_is_not_stopped() -> None:
    dec = free_window()
    dec[10, 12:16] = D["stopped"]     # returns along the façade: (10, 15) is 8-next to the
    dec[10, 11] = D["static"]         # building cell (11, 16); one component of 5 cells, no
    # road cell, never moving; near the building, so not unmapped (step 3): step 4 makes
    # its 4 stopped cells static, the static one stays
    (final,), cue = _run([dec], street_labels())
    want = dec.copy()
    want[10, 11:16] = D["static"]
    np.testing.assert_array_equal(final, want)
    (row,) = cue.stats
    assert row[STAT_UNSTOPPED] == 4
    # the rule off: the fusion's decision stands
    (final,), _ = _run([dec], street_labels(), OFF)
    np.testing.assert_array_equal(final, dec)


def test_parked_car_across_the_kerb_stays_stopped() -> None:
    dec = free_window()
    dec[4:8, 2:10] = D["stopped"]     # 2 m x 4 m across the kerb: rows 4-5 are road, so the
    dec[7, 2] = D["static"]           # whole component stays as it is, its pavement rows too
    (final,), _ = _run([dec], street_labels())
    np.testing.assert_array_equal(final, dec)


def test_off_road_thing_seen_moving_stays_stopped() -> None:
    moving, still = free_window(), free_window()
    moving[8:10, 3:8] = D["moving"]   # a car that drove onto the pavement (frame 0) ...
    still[8:10, 3:8] = D["stopped"]   # ... and stopped there: its cells were seen moving
    still[8, 12] = D["stopped"]       # a lone cell never seen moving, age 0 at frame 1 (free
    # at frame 0): too young for unmapped (step 3), so step 4 makes it static; at frame 2
    # (age 0.1 s) step 3 makes it unmapped first
    out, _ = _run([moving, still, still], street_labels())
    want = still.copy()
    want[8, 12] = D["static"]
    np.testing.assert_array_equal(out[1], want)
    want[8, 12] = D["unmapped"]
    np.testing.assert_array_equal(out[2], want)
    # with an object list: motion means being in a moving object, not a moving decision
    cells = [np.array([r * SHAPE[1] + c for r in (8, 9) for c in range(3, 8)]),
             np.zeros(0, np.int64), np.zeros(0, np.int64)]
    out, _ = _run([moving, still, still], street_labels(), moving_cells=cells)
    np.testing.assert_array_equal(out[2], want)
    none = [np.zeros(0, np.int64)] * 3
    out, _ = _run([moving, still, still], street_labels(), moving_cells=none)
    assert (out[1][8:10, 3:8] == D["static"]).all()   # never in a moving object


def test_without_a_map_nothing_changes() -> None:
    dec = free_window()
    dec[10, 12:16] = D["stopped"]
    (final,), _ = _run([dec], None)
    np.testing.assert_array_equal(final, dec)


def test_defaults_turn_the_rule_on_and_the_paper_preset_off() -> None:
    config = load_config()
    assert UnmappedParams.from_config(config).stopped_needs_road
    paper = load_config(preset="kurdej2013")
    assert not paper["objects"]["stopped_needs_road"] and not unmapped_enabled(paper)
    # the rule alone runs the pass (the unmapped cue off)
    config["objects"]["unmapped_cue"] = False
    assert unmapped_enabled(config)
    params = UnmappedParams.from_config(config)
    assert not params.unmapped and params.stopped_needs_road


def _fuse(context: int, history: str, faded_free: bool = False) -> list[int]:
    """Decisions of one cell of ``context`` (the default fusion keys, the motion gate
    closed, a building cell next to it) over ``history``: F a free scan, - no evidence,
    O an occupied return. ``faded_free``: ``fusion.gate_faded_free`` (the default; off: the
    paper's product, what the pass below was made for)."""
    config = load_config()
    config["fusion"]["gate_faded_free"] = faded_free
    params = FusionParams.from_config(config)
    shape = (1, 2)
    labels = np.array([[context, CONTEXT_BUILDING]], np.uint8)
    prior = prior_masses(labels, 0.9, 0.9, 0.8)
    pg, zeta = vacuous(shape), np.zeros(shape, np.float32)
    gate = np.zeros(shape, np.uint8)
    out = []
    for s in history:
        free = np.array([[0.7 if s == "F" else 0.0, 0.0]], np.float32)
        occupied = np.array([[0.8 if s == "O" else 0.0, 0.0]], np.float32)
        pg, zeta, _ = fusion_step(pg, zeta, sensor_masses(free, occupied), prior,
                                  (free + occupied) > 0, DT, params, gate=gate,
                                  building=labels == CONTEXT_BUILDING)
        out.append(int(decide(pg, params)[1][0, 0]))
    return out


def test_a_facade_return_after_free_scans_is_stopped_by_the_fusion_and_static_after() -> None:
    """Why step 4: a pavement cell seen free fades through {F, M} (α_M = 0.1 > α_S, α_U);
    a return there (prior {F,U,S,M} → {U,S,M}) intersects {F, M} to {M} with no conflict,
    so the closed motion gate does not hold it; the cell is `moving` for a few scans, then
    ζ moves {M} to {S} and betP(S) > betP(U): `stopped`. On the road the same history ends
    `stopped` too, rightly (the prior allows only S or M there). With the paper's product
    (``fusion.gate_faded_free`` off); the default's walk is the test below."""
    history = "F" * 5 + "-" * 10 + "O" * 15
    other = _fuse(CONTEXT_OTHER, history)
    road = _fuse(CONTEXT_ROAD, history)
    assert other[-1] == D["stopped"] and road[-1] == D["stopped"]
    assert D["moving"] in other[15:]            # the gate did not stop that
    # the pass over the last frame, the cell 8-next to the building (so not unmapped), in
    # no moving object: static off the road, stopped on it
    for context, want in ((CONTEXT_OTHER, D["static"]), (CONTEXT_ROAD, D["stopped"])):
        labels = np.full(SHAPE, CONTEXT_OTHER, np.uint8)
        labels[5, 5], labels[5, 6] = context, CONTEXT_BUILDING
        dec = free_window()
        dec[5, 5] = (other if context == CONTEXT_OTHER else road)[-1]
        (final,), _ = _run([dec], labels, moving_cells=[np.zeros(0, np.int64)])
        assert final[5, 5] == want


def test_with_faded_free_space_the_closed_gate_holds_the_facade_return() -> None:
    """The default ``fusion.gate_faded_free`` (method.md §5a "Faded free space"): the same
    history, the gate closed — the return's product with the faded {F, M} goes to O (∩ the
    prior) instead of {M}. Worked on the masses: no {M} anywhere, so the pavement cell is
    `static` from its first return on (betP(I) + betP(U) + betP(S) wins, none of the three
    reaches 0.5) and never `moving` or `stopped`; the road cell ({S, M} from the prior, ζ
    growing at once: no dynamic conflict) is `unknown` at the first return (the static
    score 0.49, under min_betp; betP(M) 0.38) and `stopped` after, never `moving`."""
    history = "F" * 5 + "-" * 10 + "O" * 15
    other = _fuse(CONTEXT_OTHER, history, faded_free=True)
    road = _fuse(CONTEXT_ROAD, history, faded_free=True)
    assert other[15:] == [D["static"]] * 15
    assert road[15] == D["unknown"] and road[16:] == [D["stopped"]] * 14
    assert load_config()["fusion"]["gate_faded_free"] is True
