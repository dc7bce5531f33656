"""Behaviour of the fusion step with the default parameters on single cells (method.md §6).

Scans are given as sequences of per-cell sensor states: 'f' free, 'o' occupied, '-' unseen.
The motion gate is open (a cell amid free road, ever-free: tests/fusion/test_gate.py
decides where it is); its rule is tested in tests/fusion/test_fused.py.
"""

from __future__ import annotations

import numpy as np

from evperc.config import load_config
from evperc.fusion.twin import (
    DECISION_CODES,
    FusionParams,
    decide,
    fusion_step,
    sensor_masses,
    vacuous,
)
from evperc.geo.prior import CONTEXT_BUILDING, CONTEXT_OTHER, CONTEXT_ROAD, prior_masses

CONFIG = load_config()
PARAMS = FusionParams.from_config(CONFIG)
CODE_NAMES = {v: k for k, v in DECISION_CODES.items()}
DT = 0.1


def prior_for(context: int | None) -> np.ndarray:
    if context is None:  # --no-map
        return vacuous((1, 1))
    m = CONFIG["map"]
    return prior_masses(np.full((1, 1), context, np.uint8), m["beta_building"], m["beta_road"],
                        m["beta_other"])


def play(sequence: str, context: int | None) -> list[str]:
    """Decisions after each scan of ``sequence`` on one cell."""
    pg, zeta = vacuous((1, 1)), np.zeros((1, 1), np.float32)
    prior = prior_for(context)
    out = []
    mu_f, mu_o = CONFIG["sensor"]["mu_free"], CONFIG["sensor"]["mu_occupied"]
    for state in sequence:
        free = np.full((1, 1), mu_f if state == "f" else 0.0, np.float32)
        occ = np.full((1, 1), mu_o if state == "o" else 0.0, np.float32)
        pg, zeta, _ = fusion_step(pg, zeta, sensor_masses(free, occ), prior, state != "-", DT,
                                  PARAMS, gate=np.ones((1, 1), np.uint8),
                                  building=np.full((1, 1), context == CONTEXT_BUILDING))
        assert np.isclose(pg.sum(), 1.0, atol=1e-5)
        _, decision = decide(pg, PARAMS)
        out.append(CODE_NAMES[int(decision[0, 0])])
    return out


def test_car_arriving_on_road_is_moving_then_stopped_then_gone() -> None:
    decisions = play("fffff" + "o" * 15 + "fff", CONTEXT_ROAD)
    assert decisions[:5] == ["free"] * 5
    assert decisions[5] == "moving"  # within one scan of its arrival
    first_stopped = decisions.index("stopped")
    assert 6 <= first_stopped <= 10  # about half a second of staying put (ζ)
    assert decisions[first_stopped:20] == ["stopped"] * (20 - first_stopped)
    assert "free" in decisions[20:22]  # free again within a scan or two after it left
    assert decisions[22] == "free"


def test_building_is_infrastructure_only_with_the_map() -> None:
    assert play("ooooo", CONTEXT_BUILDING)[-1] == "infrastructure"
    no_map = play("o" * 30, None)
    assert "infrastructure" not in no_map
    assert no_map[-1] == "static"


def test_pole_on_pavement_is_static_not_moving() -> None:
    """On a pavement the prior {F,U,S,M} allows both U and S and no cue of the method tells
    them apart: the cell is 'static' (U/S undecided), as docs/method.md states."""
    with_map = play("o" * 20, CONTEXT_OTHER)
    assert with_map[-1] == "static"
    assert "moving" not in with_map[1:]
    assert play("o" * 20, None)[-1] == "static"


def test_pole_seen_arriving_on_pavement_is_moving_first() -> None:
    assert play("fff" + "o", CONTEXT_OTHER)[-1] == "moving"


def test_unseen_free_cell_fades_to_unknown() -> None:
    decisions = play("fffff" + "-" * 40, CONTEXT_ROAD)
    assert decisions[5:15] == ["free"] * 10  # still free one second after the last scan
    fade = decisions.index("unknown")
    assert 15 <= fade <= 35  # unknown after about two seconds (1–3 s)
    assert set(decisions[fade:]) == {"unknown"}


def test_vacuous_cell_is_unknown_not_static() -> None:
    _, decision = decide(vacuous((2, 2)), PARAMS)
    assert np.all(decision == DECISION_CODES["unknown"])
