"""One fusion step per scan (method.md §5) and the decision (§6), as pure functions over grids.

State of the perception grid PG: dense masses ``(rows, cols, 32)`` over Ω = {F, I, U, S, M}
(bit0 F … bit4 M) and the accumulator ζ ``(rows, cols)``. No I/O here; the driver that reads a
log and writes the output is :mod:`evperc.runner`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from evperc import dst

F, I, U, S, M = 1, 2, 4, 8, 16
OMEGA = 31
OCCUPIED = I | U | S | M  # O = {I, U, S, M}: the refinement of the sensor's O (method.md §5.1)
N_CLASSES = 5
CLASSES = ("F", "I", "U", "S", "M")

#: decision codes of the output (docs/output-format.md)
DECISION_CODES = {"unknown": 0, "free": 1, "moving": 2, "static": 3, "stopped": 4,
                  "infrastructure": 5, "unmapped": 6}

#: betP differences below this are ties (float32 round-off)
_TIE = 1e-4



@dataclass(frozen=True)
class FusionParams:
    """The ``[fusion]`` and ``[decision]`` keys of the config (method.md §5, §6).

    The field defaults are the untuned values (docs/method.md); ``configs/default.toml``
    (via :meth:`from_config`) holds the defaults of a run, some of them tuned
    (docs/evaluation.md)."""

    prior_where: str = "observed"
    discount: str = "contextual"
    discount_period_s: float = 0.1
    discount_rates: tuple[float, float, float, float, float] = (0.1, 0.0, 0.01, 0.02, 0.1)
    discount_classical: float = 0.1
    residual_conflict: str = "omega"
    stopped_target: str = "stopped"
    zeta_increment: float = 0.1
    zeta_decrement: float = 0.5
    gamma_occupied: float = 0.6
    gamma_conflict: float = 0.2
    decision_min_betp: float = 0.5
    decision_max_ignorance: float = 0.5
    # the motion gate (docs/method.md, "The motion gate"); the defaults here are the paper's
    # rule (∅_FO → {M} everywhere), configs/default.toml turns the gate on
    motion_gate: str = "none"
    gate_closed_target: str = "occupied"
    building_conflict: str = "moving"
    gate_free_s: float = 0.5
    gate_min_free: float = 0.5
    gate_revoke_s: float = 15.0
    gate_gap_s: float = 0.2
    gate_rehit_s: float = 0.0
    gate_rehit_gap: str = "any"
    gate_rehit_revokes: str = "block"
    gate_faded_free: bool = False

    @staticmethod
    def from_config(config: dict[str, Any]) -> FusionParams:
        fu, de = config["fusion"], config["decision"]
        return FusionParams(
            prior_where=fu["prior_where"], discount=fu["discount"],
            discount_period_s=fu["discount_period_s"],
            discount_rates=(fu["discount_free"], fu["discount_infrastructure"],
                            fu["discount_unmapped"], fu["discount_stopped"],
                            fu["discount_moving"]),
            discount_classical=fu["discount_classical"],
            residual_conflict=fu["residual_conflict"], stopped_target=fu["stopped_target"],
            zeta_increment=fu["zeta_increment"], zeta_decrement=fu["zeta_decrement"],
            gamma_occupied=fu["gamma_occupied"], gamma_conflict=fu["gamma_conflict"],
            decision_min_betp=de["min_betp"], decision_max_ignorance=de["max_ignorance"],
            motion_gate=fu["motion_gate"], gate_closed_target=fu["gate_closed_target"],
            building_conflict=fu["building_conflict"], gate_free_s=fu["gate_free_s"],
            gate_min_free=fu["gate_min_free"], gate_revoke_s=fu["gate_revoke_s"],
            gate_gap_s=fu["gate_gap_s"], gate_rehit_s=fu["gate_rehit_s"],
            gate_rehit_gap=fu["gate_rehit_gap"],
            gate_rehit_revokes=fu.get("gate_rehit_revokes", "block"),
            gate_faded_free=fu["gate_faded_free"])

    @property
    def gated(self) -> bool:
        """Whether the motion gate decides where ∅_FO may go to {M} (else: everywhere)."""
        return self.motion_gate != "none"


def scaled_rate(rate: float | np.ndarray, dt_s: float, period_s: float) -> np.ndarray:
    """α(dt) = 1 − (1 − α)^(dt / period): a rate per ``period_s`` applied over ``dt_s``."""
    rate = np.asarray(rate, dtype=np.float64)
    return 1.0 - (1.0 - rate) ** (max(dt_s, 0.0) / period_s)


def vacuous(shape: tuple[int, ...], dtype: np.dtype | type = np.float32) -> np.ndarray:
    """Mass grid with m(Ω) = 1 in every cell (also the prior of ``--no-map``)."""
    return dst.FRAME.vacuous(shape, dtype)


def sensor_masses(free: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """SG refined to Ω (method.md §5.1): {F}→{F}, {O}→{I,U,S,M}, Ω_SG→Ω."""
    m = np.zeros((*free.shape, 32), dtype=np.float32)
    m[..., F] = free
    m[..., OCCUPIED] = occupied
    m[..., OMEGA] = 1.0 - free - occupied
    return m


def belief_occupied(m: np.ndarray) -> np.ndarray:
    """Bel(O) = Σ_{∅≠A⊆{I,U,S,M}} m(A) (method.md §5.4)."""
    return dst.belief_of(m, OCCUPIED)


def conflict_targets(conflict_fo: np.ndarray, gate: np.ndarray | None,
                     building: np.ndarray | None, params: FusionParams
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rule ⊛'s split of ∅_FO (docs/method.md, "The motion gate"): the parts sent to
    {M}, to {I} and to the closed gate's target (O or {I,U,S}), ``(to_m, to_i, to_closed)``.

    With ``building_conflict = "infrastructure"`` a cell with the map's building label sends
    ∅_FO to {I}; elsewhere it goes to {M} where the gate is open (``motion_gate = "none"``:
    open everywhere, the paper's rule) and to the closed target where it is not."""
    zero = np.zeros_like(conflict_fo)
    shape = conflict_fo.shape
    in_building = (np.zeros(shape, bool) if building is None or params.building_conflict
                   != "infrastructure" else np.broadcast_to(np.asarray(building, bool), shape))
    if params.gated:
        if gate is None:
            raise ValueError("motion_gate is on: pass the gate layer (evperc.fusion.gate)")
        open_ = np.broadcast_to(np.asarray(gate) != 0, shape)
    else:
        open_ = np.ones(shape, bool)
    to_i = np.where(in_building, conflict_fo, zero)
    to_m = np.where(~in_building & open_, conflict_fo, zero)
    to_closed = np.where(~in_building & ~open_, conflict_fo, zero)
    return to_m, to_i, to_closed


def faded_free_to_sensor(fused: np.ndarray, pg: np.ndarray, sensor_o: np.ndarray,
                         gate: np.ndarray | None) -> np.ndarray:
    """``fusion.gate_faded_free`` (docs/method.md §5a): where the motion gate is closed, the
    products of a faded free set A of ``pg`` (F ∈ A, A ≠ {F}) with the sensor's O go to O
    (with the map's prior: O ∩ P) instead of A ∩ O ∩ P — a return where the grid believed
    free says "occupied", not which of I, U, S, M the fading left beside F.

    ``fused`` = ``dst.conjunctive(pg, sg')``; ``sensor_o``: the part of sg' = SG ⊕ GG that
    comes from SG's m(O) (sets O ∩ P only). By bilinearity the change on the closed cells is
    − conj(pg_A, sensor_o) + (Σ pg_A) · sensor_o, pg_A the faded free sets of ``pg``."""
    if gate is None:
        raise ValueError("motion_gate is on: pass the gate layer (evperc.fusion.gate)")
    sets = np.arange(32)
    pg_faded = np.where((sets & F != 0) & (sets != F), pg, 0.0)
    rerouted = (fused - dst.conjunctive(pg_faded, sensor_o)
                + pg_faded.sum(axis=-1, keepdims=True) * sensor_o)
    closed = np.broadcast_to(np.asarray(gate) == 0, fused.shape[:-1])
    return np.where(closed[..., None], rerouted, fused).astype(fused.dtype)


def fusion_step(pg: np.ndarray, zeta: np.ndarray, sg: np.ndarray, prior: np.ndarray,
                observed: np.ndarray, dt_s: float, params: FusionParams,
                gate: np.ndarray | None = None, building: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step PG_{t−1}, ζ_{t−1} → PG_t, ζ_t (method.md §5, steps 2–8).

    ``sg``: the refined sensor grid (method.md §5.1); ``prior``: the GIS grid GG; ``observed``:
    cells the scan touched; ``gate``: the motion gate of this scan (non-zero: ∅_FO may go
    to {M}; :mod:`evperc.fusion.gate`), needed when ``params.motion_gate`` is on;
    ``building``: cells with the map's building label (``building_conflict``). Returns
    ``(pg, zeta, conflict)`` with ``conflict[..., k]`` = ∅_FO, ∅_OF, ∅_other of this step.
    """
    # 2. SG' = SG ⊕ GG (Dempster), on observed cells only unless prior_where = everywhere
    sg_prior, conflict_k = dst.dempster(sg, prior)
    # total conflict (only possible with mu = 1 and beta = 1): the sources cancel, keep SG
    use_prior = conflict_k < 1
    if params.prior_where == "observed":
        use_prior &= np.asarray(observed, dtype=bool)
    sg_prior = np.where(use_prior[..., None], sg_prior, sg)
    # 3. discount PG_{t-1}
    if params.discount == "contextual":
        alphas = scaled_rate(params.discount_rates, dt_s, params.discount_period_s)
        pg_disc = dst.contextual_discount(pg, alphas.astype(pg.dtype))
    else:
        alpha = scaled_rate(params.discount_classical, dt_s, params.discount_period_s)
        pg_disc = dst.discount(pg, float(alpha))
    # 4. conjunctive combination and its conflict parts
    fused = dst.conjunctive(pg_disc, sg_prior)
    if params.gated and params.gate_faded_free:
        sensor_o = np.zeros_like(sg)
        sensor_o[..., OCCUPIED] = sg[..., OCCUPIED]
        with np.errstate(divide="ignore", invalid="ignore"):
            o_prior = dst.conjunctive(sensor_o, prior) / (1.0 - conflict_k)[..., None]
        sensor_o = np.where(use_prior[..., None], o_prior, sensor_o)
        fused = faded_free_to_sensor(fused, pg_disc, sensor_o, gate)
    conflict_fo, conflict_of, conflict_other = dst.conflict_parts(
        pg_disc, sg_prior, dst.FRAME, empty_mass=fused[..., 0])
    # 5. modified rule ⊛: ∅_FO → {M} where the gate allows ({I} in buildings, else O or
    # {I,U,S}), ∅_OF → Ω, ∅_other per option
    to_m, to_i, to_closed = conflict_targets(conflict_fo, gate, building, params)
    fused[..., 0] = 0
    fused[..., M] += to_m
    fused[..., I] += to_i
    fused[..., OCCUPIED if params.gate_closed_target == "occupied" else OCCUPIED & ~M] += \
        to_closed
    fused[..., OMEGA] += conflict_of
    if params.residual_conflict == "omega":
        fused[..., OMEGA] += conflict_other
    elif params.residual_conflict == "empty":
        fused[..., 0] = conflict_other
    else:  # normalise
        fused /= np.maximum(1.0 - conflict_other, np.finfo(fused.dtype).tiny)[..., None]
    # 6. accumulator ζ: the conflict that says "something moved" (∅_FO only where it went
    # to {M}; all of it with the paper's rule)
    dynamic = to_m + conflict_of
    grow = (belief_occupied(fused) >= params.gamma_occupied) & (dynamic <= params.gamma_conflict)
    shrink = dynamic > params.gamma_conflict
    zeta = np.where(grow, np.minimum(1.0, zeta + params.zeta_increment),
                    np.where(shrink, np.maximum(0.0, zeta - params.zeta_decrement), zeta))
    zeta = zeta.astype(pg.dtype)
    # 7. specialise by ζ
    pg_new = dst.specialise_by_zeta(fused, zeta, dst.FRAME, stopped_target=params.stopped_target)
    conflict = np.stack([conflict_fo, conflict_of, conflict_other], axis=-1).astype(pg.dtype)
    return pg_new, zeta, conflict


def decide(pg: np.ndarray, params: FusionParams) -> tuple[np.ndarray, np.ndarray]:
    """betP per class and the fine decision code per cell (method.md §6).

    Coarse: free = betP(F), moving = betP(M), static = betP(I)+betP(U)+betP(S); the largest
    wins unless it is below ``decision_min_betp`` or m(Ω) > ``decision_max_ignorance``
    (then unknown). Fine: a static cell becomes infrastructure / unmapped / stopped when the
    largest of betP(I), betP(U), betP(S) is ≥ 0.5 and at least half the static score, and
    strictly the largest (a U/S tie, e.g. an obstacle on a pavement, stays ``static``).
    """
    betp = dst.pignistic(pg)
    free, infra, unmapped, stopped, moving = (betp[..., k] for k in range(N_CLASSES))
    static = infra + unmapped + stopped
    scores = np.stack([free, moving, static], axis=-1)
    winner = np.argmax(scores, axis=-1)
    best = np.take_along_axis(scores, winner[..., None], axis=-1)[..., 0]
    codes = np.array([DECISION_CODES["free"], DECISION_CODES["moving"],
                      DECISION_CODES["static"]], dtype=np.uint8)
    decision = codes[winner]
    fine = np.stack([infra, unmapped, stopped], axis=-1)
    fine_winner = np.argmax(fine, axis=-1)
    fine_best = np.take_along_axis(fine, fine_winner[..., None], axis=-1)[..., 0]
    fine_codes = np.array([DECISION_CODES["infrastructure"], DECISION_CODES["unmapped"],
                           DECISION_CODES["stopped"]], dtype=np.uint8)
    fine_second = static - fine_best - fine.min(axis=-1)
    refine = ((decision == DECISION_CODES["static"]) & (fine_best >= 0.5)
              & (fine_best >= 0.5 * static) & (fine_best - fine_second > _TIE))
    decision = np.where(refine, fine_codes[fine_winner], decision)
    unknown = (best < params.decision_min_betp) | (pg[..., OMEGA] > params.decision_max_ignorance)
    decision = np.where(unknown, np.uint8(DECISION_CODES["unknown"]), decision).astype(np.uint8)
    return betp.astype(np.float32), decision
