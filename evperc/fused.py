"""The whole per-frame fusion (SPEC §5 steps 2–8) and decision (SPEC §6) in one pass per cell.

:func:`fused_step` computes what :func:`evperc.pipeline.fusion_step` followed by
:func:`evperc.pipeline.decide` computes, for every option of
:class:`~evperc.pipeline.FusionParams`, but in one compiled loop (numba) over the cells that
updates the state ``pg`` / ``zeta`` in place and writes the conflict parts, betP and the
decision codes into preallocated arrays. It exploits the structure of the inputs instead of
dense 32 × 32 transforms:

- SG' = SG ⊕ GG has at most five focal sets per cell, among eight possible ones
  ({F}, {I}, {S,M}, {U,S,M}, {I,U,S,M}, {F,S,M}, {F,U,S,M}, Ω), built in closed form from
  m({F}), m({O}) and the cell's context label; so c = PG' ∩ SG' is
  Σ_B w_B · (mass at X moved to X ∩ B), 32 multiply-adds per focal set B;
- contextual discounting is one butterfly per class with a non-zero rate
  (mass at A ∌ θ gives α_θ of itself to A ∪ {θ}); classical discounting is a scaling;
- a cell that is vacuous with ζ = 0, not observed and not given the prior stays vacuous:
  it is skipped after one read (its outputs are the vacuous cell's).

Arithmetic is float64 inside the loop; masses, ζ, conflicts and betP are stored as float32.
The decision is taken on the stored (float32) masses, as ``decide`` does on the runner's
float32 grid. Total conflict of SG with GG (only possible with μ = 1 and β = 1) uses the
float32 tolerance of :func:`evperc.dst.total_conflict_tolerance`, as the runner's float32
``fusion_step`` does.

Reachable focal sets (:func:`reachable_focal_sets`): all 31 non-empty subsets with
contextual discounting, 15 with classical discounting. The kernel is not specialised for the
classical case: it loops over all 32 entries either way (an input state may hold any set) and
measured only ~15 % faster with classical discounting, whose scaling is already cheap.

Context labels are those of :mod:`evperc.geo.prior` (0 other, 1 road, 2 building) plus
:data:`NO_MAP` (255): no prior in that cell (``--no-map``: pass ``labels=None``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from evperc.dst import total_conflict_tolerance
from evperc.geo.prior import (
    CONTEXT_BUILDING,
    CONTEXT_OTHER,
    CONTEXT_ROAD,
    FOCAL_BUILDING,
    FOCAL_OTHER,
    FOCAL_ROAD,
)
from evperc.pipeline import DECISION_CODES, FusionParams, scaled_rate

#: context label of a cell without map prior (vacuous GG)
NO_MAP = 255

_F, _I, _U, _S, _M = 1, 2, 4, 8, 16
_O = _I | _U | _S | _M
_OMEGA = 31
_RESIDUAL = {"omega": 0, "empty": 1, "normalise": 2}
_TOL32 = total_conflict_tolerance(5, np.dtype(np.float32))
_TIE = 1e-4  # as evperc.pipeline.decide
_CODE_FREE, _CODE_MOVING, _CODE_STATIC = (DECISION_CODES[k] for k in ("free", "moving", "static"))
_CODE_INFRA, _CODE_UNMAPPED, _CODE_STOPPED = (
    DECISION_CODES[k] for k in ("infrastructure", "unmapped", "stopped"))
_CODE_UNKNOWN = DECISION_CODES["unknown"]
_NO_LABELS = np.zeros(1, dtype=np.uint8)
_NO_OBSERVED = np.zeros(1, dtype=np.bool_)


@dataclass(frozen=True)
class FusedOutputs:
    """Per-frame outputs of :func:`fused_step` (the state itself is updated in place)."""

    conflict: np.ndarray  # float32 (rows, cols, 3): ∅_FO, ∅_OF, ∅_other
    betp: np.ndarray  # float32 (rows, cols, 5): betP of F, I, U, S, M
    decision: np.ndarray  # uint8 (rows, cols): DECISION_CODES

    @staticmethod
    def empty(shape: tuple[int, int]) -> FusedOutputs:
        """Uninitialised outputs for a grid of ``shape``; every cell is written by a step."""
        return FusedOutputs(np.empty((*shape, 3), np.float32), np.empty((*shape, 5), np.float32),
                            np.empty(shape, np.uint8))


def fused_step(pg: np.ndarray, zeta: np.ndarray, free: np.ndarray, occupied: np.ndarray,
               labels: np.ndarray | None, betas: tuple[float, float, float], dt_s: float,
               params: FusionParams, *, observed: np.ndarray | None = None,
               out: FusedOutputs | None = None, skip_vacuous: bool = True) -> FusedOutputs:
    """One frame, in place: ``pg``, ``zeta`` ← PG_t, ζ_t (SPEC §5 steps 2–8), plus SPEC §6.

    ``pg``: float32 C-contiguous ``(rows, cols, 32)``; ``zeta``: float32 ``(rows, cols)``;
    ``free``, ``occupied``: the sensor grid m({F}), m({O}) (SPEC §3); ``labels``: uint8
    context labels (0 other, 1 road, 2 building, :data:`NO_MAP`) or ``None`` for no map;
    ``betas``: ``(beta_building, beta_road, beta_other)`` as in
    :func:`evperc.geo.prior.prior_masses`; ``observed``: cells the scan touched, by default
    ``(free > 0) | (occupied > 0)``. ``out`` receives conflict, betP and decision (allocated
    when ``None``); ``skip_vacuous=False`` forces the full computation in every cell (tests).
    Equal to ``fusion_step`` then ``decide`` to float32 round-off.
    """
    shape = _check_state(pg, zeta)
    cells = shape[0] * shape[1]
    free32 = _grid(free, np.float32, shape, "free")
    occ32 = _grid(occupied, np.float32, shape, "occupied")
    has_map = labels is not None
    lab = _grid(labels, np.uint8, shape, "labels") if has_map else _NO_LABELS
    if has_map:
        bad = (lab > CONTEXT_BUILDING) & (lab != NO_MAP)
        if bad.any():
            raise ValueError(f"unknown context label {int(lab[bad][0])} (expected 0, 1, 2 or "
                             f"{NO_MAP})")
    has_observed = observed is not None
    obs = _grid(observed, np.bool_, shape, "observed") if has_observed else _NO_OBSERVED
    focal_of, beta_of = _label_tables(betas)
    if out is None:
        out = FusedOutputs.empty(shape)
    elif (out.conflict.shape != (*shape, 3) or out.betp.shape != (*shape, 5)
          or out.decision.shape != shape or out.conflict.dtype != np.float32
          or out.betp.dtype != np.float32 or out.decision.dtype != np.uint8
          or not all(a.flags.c_contiguous for a in (out.conflict, out.betp, out.decision))):
        raise ValueError(f"out arrays do not match the grid {shape} (see FusedOutputs.empty)")
    if params.residual_conflict not in _RESIDUAL:
        raise ValueError(f"residual_conflict must be one of {sorted(_RESIDUAL)}")
    if params.discount == "contextual":
        alphas = scaled_rate(params.discount_rates, dt_s, params.discount_period_s)
        alpha_classical = 0.0
    else:
        alphas = np.zeros(5)
        alpha_classical = float(scaled_rate(params.discount_classical, dt_s,
                                            params.discount_period_s))
    _fused_kernel(
        pg.reshape(cells, 32), zeta.reshape(cells), free32.reshape(cells), occ32.reshape(cells),
        obs.reshape(-1), has_observed, lab.reshape(-1), has_map, focal_of, beta_of,
        params.prior_where == "everywhere", params.discount == "contextual",
        np.asarray(alphas, np.float64), alpha_classical, _RESIDUAL[params.residual_conflict],
        params.stopped_target == "stopped", float(params.zeta_increment),
        float(params.zeta_decrement), float(params.gamma_occupied),
        float(params.gamma_conflict), float(params.decision_min_betp),
        float(params.decision_max_ignorance), bool(skip_vacuous), _TOL32,
        out.conflict.reshape(cells, 3), out.betp.reshape(cells, 5), out.decision.reshape(cells))
    return out


def reachable_focal_sets(params: FusionParams) -> frozenset[int]:
    """Subsets (bitmasks) that can hold mass in PG when starting from vacuous cells.

    The closure of {Ω} under the operations of one step with these options: discounting
    (A → A ∪ {θ} for each class whose rate is non-zero; classical: A → Ω), intersection
    with every possible focal set of SG', the rule ⊛ ({M}, Ω, and ∅ when
    ``residual_conflict = "empty"``) and specialisation (A → A ∖ {M}; {M} → {S} or ∅).
    """
    sg_sets = {_F, _O, _OMEGA}
    sg_prime = set(sg_sets)
    for prior in (FOCAL_BUILDING, FOCAL_ROAD, FOCAL_OTHER):
        sg_prime |= {s & prior for s in sg_sets if s & prior}
    if params.discount == "contextual":
        grow = [1 << k for k, a in enumerate(params.discount_rates) if a > 0]
    else:
        grow = []
    keep_empty = params.residual_conflict == "empty"
    sets = {_OMEGA}
    while True:
        new = set(sets) | {_M, _OMEGA}
        for a in sets:
            new |= {a | bit for bit in grow}
            if params.discount == "classical":
                new.add(_OMEGA)
            new |= {a & b for b in sg_prime if a & b or keep_empty}
            if a & _M:
                target = a & ~_M
                new.add(target if target or params.stopped_target == "empty" else _S)
        if new == sets:
            return frozenset(sets)
        sets = new


def _check_state(pg: np.ndarray, zeta: np.ndarray) -> tuple[int, int]:
    if (pg.ndim != 3 or pg.shape[-1] != 32 or pg.dtype != np.float32
            or not pg.flags.c_contiguous or not pg.flags.writeable):
        raise ValueError(f"pg must be a writeable C-contiguous float32 (rows, cols, 32) array, "
                         f"got {pg.dtype} {pg.shape}")
    shape = pg.shape[:2]
    if (zeta.shape != shape or zeta.dtype != np.float32 or not zeta.flags.c_contiguous
            or not zeta.flags.writeable):
        raise ValueError(f"zeta must be a writeable C-contiguous float32 {shape} array, "
                         f"got {zeta.dtype} {zeta.shape}")
    return shape


def _grid(a: np.ndarray, dtype: type, shape: tuple[int, int], name: str) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=dtype)
    if a.shape != shape:
        raise ValueError(f"{name} has shape {a.shape}, the grid is {shape}")
    return a


def _label_tables(betas: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Per label: the focal set of the prior and its mass β (SPEC §4); NO_MAP → β = 0."""
    beta_building, beta_road, beta_other = (float(b) for b in betas)
    if not all(0.0 <= b <= 1.0 for b in (beta_building, beta_road, beta_other)):
        raise ValueError(f"prior masses must be in [0, 1], got {list(betas)}")
    focal = np.full(256, _OMEGA, dtype=np.int64)
    beta = np.zeros(256, dtype=np.float64)
    for label, mask, b in ((CONTEXT_OTHER, FOCAL_OTHER, beta_other),
                           (CONTEXT_ROAD, FOCAL_ROAD, beta_road),
                           (CONTEXT_BUILDING, FOCAL_BUILDING, beta_building)):
        focal[label], beta[label] = mask, b
    return focal, beta


#: 1/|A| per subset A (betP shares); 0 for ∅
_INV_SIZE = np.array([0.0] + [1.0 / bin(a).count("1") for a in range(1, 32)])


@numba.njit(cache=True, nogil=True)
def _add_focal(masks: np.ndarray, weights: np.ndarray, count: int, mask: int,
               weight: float) -> int:
    if weight == 0.0:
        return count
    for j in range(count):
        if masks[j] == mask:
            weights[j] += weight
            return count
    masks[count] = mask
    weights[count] = weight
    return count + 1


@numba.njit(cache=True, nogil=True, inline="always")
def _butterfly(m: np.ndarray, bit: int, alpha: float) -> None:
    """Disjunction with m_θ(∅) = 1 − α, m_θ({θ}) = α for θ = ``bit``: A ∌ θ gives α m(A) to
    A ∪ {θ}."""
    for block in range(0, 32, 2 * bit):
        for j in range(block, block + bit):
            lo = m[j]
            m[j + bit] += alpha * lo
            m[j] = lo - alpha * lo


@numba.njit(cache=True, nogil=True, inline="always")
def _sum_nonempty(m: np.ndarray, step: int) -> float:
    """Σ_{A ≠ ∅} m(A) over A = step, 2·step, … (step 1: all; step 2: the subsets of O),
    in four independent partial sums (a single chain would be latency-bound)."""
    s0, s1, s2, s3 = 0.0, m[step], m[2 * step], m[3 * step]
    for a in range(4 * step, 32, 4 * step):
        s0 += m[a]
        s1 += m[a + step]
        s2 += m[a + 2 * step]
        s3 += m[a + 3 * step]
    return (s0 + s1) + (s2 + s3)


@numba.njit(cache=True, nogil=True, inline="always")
def _sum_with(w: np.ndarray, bit: int) -> float:
    """Σ_{A ∋ θ} w(A) for θ = ``bit``."""
    total = 0.0
    for block in range(bit, 32, 2 * bit):
        for j in range(block, block + bit):
            total += w[j]
    return total


@numba.njit(cache=True, nogil=True)
def _decide_cell(pg: np.ndarray, i: int, w: np.ndarray, bp: np.ndarray, tol: float,
                 min_betp: float, max_ign: float) -> int:
    """betP into ``bp`` and the decision code of cell ``i`` of ``pg`` (SPEC §6, as
    pipeline.decide)."""
    for a in range(32):
        w[a] = pg[i, a]
    norm = _sum_nonempty(w, 1)
    if norm > tol:
        scale = 1.0 / norm
        for a in range(32):
            w[a] *= _INV_SIZE[a] * scale
        bp[0] = _sum_with(w, 1)
        bp[1] = _sum_with(w, 2)
        bp[2] = _sum_with(w, 4)
        bp[3] = _sum_with(w, 8)
        bp[4] = _sum_with(w, 16)
    else:
        for k in range(5):
            bp[k] = 0.0
    free, infra, unmapped, stopped, moving = bp[0], bp[1], bp[2], bp[3], bp[4]
    static = infra + unmapped + stopped
    code, best = _CODE_FREE, free
    if moving > best:
        code, best = _CODE_MOVING, moving
    if static > best:
        code, best = _CODE_STATIC, static
    if code == _CODE_STATIC:
        fine_code, fine_best = _CODE_INFRA, infra
        if unmapped > fine_best:
            fine_code, fine_best = _CODE_UNMAPPED, unmapped
        if stopped > fine_best:
            fine_code, fine_best = _CODE_STOPPED, stopped
        fine_second = static - fine_best - min(infra, unmapped, stopped)
        if fine_best >= 0.5 and fine_best >= 0.5 * static and fine_best - fine_second > _TIE:
            code = fine_code
    if best < min_betp or pg[i, _OMEGA] > max_ign:
        code = _CODE_UNKNOWN
    return code


@numba.njit(cache=True, nogil=True)
def _fused_kernel(pg, zeta, free, occ, observed, has_observed, labels, has_map, focal_of,
                  beta_of, prior_everywhere, contextual, alphas, alpha_classical, residual,
                  stopped_to_s, inc, dec, gamma_o, gamma_c, min_betp, max_ign, skip_vacuous,
                  tol, conflict, betp, decision):  # pragma: no cover - compiled
    n = pg.shape[0]
    m = np.empty(32)
    c = np.empty(32)
    shares = np.empty(32)
    bp = np.empty(5)
    masks = np.empty(8, np.int64)
    weights = np.empty(8)
    # the outcome of a vacuous cell, for the skip path
    vac = np.zeros((1, 32), np.float32)
    vac[0, _OMEGA] = 1.0
    vac_code = _decide_cell(vac, 0, shares, bp, tol, min_betp, max_ign)
    vac_bp = bp.copy()
    skip_ok = skip_vacuous and gamma_o > 0.0
    sg_sets = (_F, _O, _OMEGA)
    for i in range(n):
        f = np.float64(free[i])
        o = np.float64(occ[i])
        obs = observed[i] if has_observed else (f > 0.0 or o > 0.0)
        label = labels[i] if has_map else 255
        beta = beta_of[label]
        use_prior = beta > 0.0 and (obs or prior_everywhere)
        z = np.float64(zeta[i])
        if skip_ok and z == 0.0 and f == 0.0 and o == 0.0 and not use_prior \
                and pg[i, _OMEGA] == 1.0:
            vacuous = True
            for a in range(_OMEGA):
                if pg[i, a] != 0.0:
                    vacuous = False
                    break
            if vacuous:
                conflict[i, 0] = 0.0
                conflict[i, 1] = 0.0
                conflict[i, 2] = 0.0
                for k in range(5):
                    betp[i, k] = vac_bp[k]
                decision[i] = vac_code
                continue
        # 2. SG' = SG ⊕ GG: focal sets of SG (F, O, Ω) and their intersections with the prior
        sg_mass = (f, o, np.float64(np.float32(1.0) - free[i] - occ[i]))
        count = 0
        if use_prior:
            prior = focal_of[label]
            for j in range(3):
                s = sg_mass[j]
                if s != 0.0:
                    count = _add_focal(masks, weights, count, sg_sets[j] & prior, s * beta)
                    count = _add_focal(masks, weights, count, sg_sets[j], s * (1.0 - beta))
            kept = 0.0
            has_empty = False
            for j in range(count):
                if masks[j] == 0:
                    has_empty = True
                else:
                    kept += weights[j]
            if kept <= tol:  # total conflict: the sources cancel, keep SG
                count = 0
            else:
                if has_empty:
                    k = 0
                    for j in range(count):
                        if masks[j] != 0:
                            masks[k] = masks[j]
                            weights[k] = weights[j]
                            k += 1
                    count = k
                for j in range(count):
                    weights[j] /= kept
        if count == 0:
            for j in range(3):
                count = _add_focal(masks, weights, count, sg_sets[j], sg_mass[j])
        # 3. discount PG_{t-1}
        for a in range(32):
            m[a] = pg[i, a]
        if contextual:
            if alphas[0] > 0.0:
                _butterfly(m, 1, alphas[0])
            if alphas[1] > 0.0:
                _butterfly(m, 2, alphas[1])
            if alphas[2] > 0.0:
                _butterfly(m, 4, alphas[2])
            if alphas[3] > 0.0:
                _butterfly(m, 8, alphas[3])
            if alphas[4] > 0.0:
                _butterfly(m, 16, alphas[4])
        elif alpha_classical > 0.0:
            rest = 1.0 - m[_OMEGA]
            for a in range(_OMEGA):
                m[a] *= 1.0 - alpha_classical
            m[_OMEGA] += alpha_classical * rest
        # 4. c = PG' ∩ SG' and the conflict parts
        if count == 1 and masks[0] == _OMEGA:
            w = weights[0]
            for a in range(32):
                c[a] = w * m[a]
        else:
            for a in range(32):
                c[a] = 0.0
            for j in range(count):
                b = masks[j]
                w = weights[j]
                for a in range(32):
                    c[a & b] += w * m[a]
        sg_free = 0.0
        sg_bel_o = 0.0
        for j in range(count):
            if masks[j] == _F:
                sg_free += weights[j]
            elif masks[j] & _F == 0:
                sg_bel_o += weights[j]
        pg_bel_o = _sum_nonempty(m, 2)
        fo = m[_F] * sg_bel_o
        of = pg_bel_o * sg_free
        other = max(c[0] - fo - of, 0.0)
        # 5. rule ⊛
        c[0] = 0.0
        c[_M] += fo
        c[_OMEGA] += of
        if residual == 0:
            c[_OMEGA] += other
        elif residual == 1:
            c[0] = other
        else:
            scale = 1.0 / max(1.0 - other, 1e-300)
            for a in range(32):
                c[a] *= scale
        # 6. accumulator ζ
        bel_o = _sum_nonempty(c, 2)
        dynamic = fo + of
        if bel_o >= gamma_o and dynamic <= gamma_c:
            z = min(1.0, z + inc)
        elif dynamic > gamma_c:
            z = max(0.0, z - dec)
        z32 = np.float32(z)
        zeta[i] = z32
        z = np.float64(z32)
        # 7. specialise by ζ: A ∋ M gives ζ·m(A) to A ∖ {M}; {M} to {S} or ∅
        if z > 0.0:
            for a in range(_M + 1, 32):
                given = c[a] * z
                c[a] -= given
                c[a - _M] += given
            given = c[_M] * z
            c[_M] -= given
            c[_S if stopped_to_s else 0] += given
        # 8. store; decide on the stored masses
        for a in range(32):
            pg[i, a] = c[a]
        conflict[i, 0] = fo
        conflict[i, 1] = of
        conflict[i, 2] = other
        decision[i] = _decide_cell(pg, i, shares, bp, tol, min_betp, max_ign)
        for k in range(5):
            betp[i, k] = bp[k]
