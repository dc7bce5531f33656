"""The whole per-frame fusion (SPEC §5 steps 2–8) and decision (SPEC §6) in one pass per cell.

:func:`fused_step` computes what :func:`evperc.pipeline.fusion_step` followed by
:func:`evperc.pipeline.decide` computes, for every option of
:class:`~evperc.pipeline.FusionParams`, in one compiled loop over the cells, and can read the
previous state from a window shifted by whole cells (the scrolling of SPEC §2), so a frame
reads the state once and writes it once.

Layout: the state is **planar**, ``pg[A, row, col]`` (one contiguous float32 plane per
subset A), and so are the outputs. The per-cell code (:mod:`evperc.fused_kernel`, generated
by :mod:`evperc.fused_codegen`) is straight-line float32 arithmetic on 32 scalars with
selects instead of branches, which LLVM vectorises across the cells of a row (8–16 cells per
instruction with AVX2 / AVX-512). It exploits the structure of the inputs instead of dense
32 × 32 transforms: SG' = SG ⊕ GG is applied as (m ∩ SG) ∩ GG with Dempster's
normalisation of the SG–GG conflict in closed form; contextual discounting is one butterfly
per class (mass at A ∌ θ gives α_θ of itself to A ∪ {θ}), classical discounting a scaling.

Two output kinds: :class:`FusedOutputs` (float32 betP and conflict parts, the decision; for
tests and studies) and :class:`StoredOutputs` (everything quantised to uint8 as the output
format stores it, written straight into the writer's chunk buffer: no float copies).

Arithmetic is float32 (``fastmath``: LLVM may reassociate sums), so results equal the numpy
twin to float32 round-off (~1e-6), not bit for bit. For the vectoriser to prove that the
output planes do not overlap the input planes it needs one run-time check per pair of
pointers, more than LLVM's default limit allows; :func:`_allow_vectorisation` raises that
limit before the kernels are compiled (the compiled kernels are cached, ``cache=True``).
With ``pg_out is pg`` (in place) the checks fail and the scalar loop runs: correct, ~5×
slower; the runner alternates two state buffers instead.

Reachable focal sets (:func:`reachable_focal_sets`): all 31 non-empty subsets with
contextual discounting, 15 with classical discounting; the kernel keeps all 32 entries.

Context labels are those of :mod:`evperc.geo.prior` (0 other, 1 road, 2 building) plus
:data:`NO_MAP` (255): no prior in that cell (``--no-map``: pass ``labels=None``).
"""

from __future__ import annotations

from dataclasses import dataclass

import llvmlite.binding
import numpy as np

from evperc.dst import total_conflict_tolerance
from evperc.geo.prior import (
    CONTEXT_BUILDING,
    FOCAL_BUILDING,
    FOCAL_OTHER,
    FOCAL_ROAD,
)
from evperc.pipeline import DECISION_CODES, FusionParams, decide, scaled_rate, vacuous


def _allow_vectorisation() -> None:
    """Let LLVM's loop vectoriser emit the run-time overlap checks of ~120 planes (default
    limit: 8 checks, which leaves the kernel scalar, ~5× slower)."""
    llvmlite.binding.set_option("evperc", "-runtime-memory-check-threshold=100000")
    llvmlite.binding.set_option("evperc", "-vectorize-memory-check-threshold=100000")
    llvmlite.binding.set_option("evperc", "-memory-check-merge-threshold=10000")


_allow_vectorisation()

from evperc import fused_kernel  # noqa: E402  (after the LLVM options)

#: context label of a cell without map prior (vacuous GG)
NO_MAP = 255

_F, _I, _U, _S, _M = 1, 2, 4, 8, 16
_O = _I | _U | _S | _M
_OMEGA = 31
_RESIDUAL = {"omega": 0, "empty": 1, "normalise": 2}
_TOL32 = total_conflict_tolerance(5, np.dtype(np.float32))
_CODES = tuple(np.float32(DECISION_CODES[k]) for k in (
    "free", "moving", "static", "infrastructure", "unmapped", "stopped", "unknown"))


@dataclass(frozen=True)
class FusedOutputs:
    """Float outputs of :func:`fused_step` (planar; the state is updated separately)."""

    conflict: np.ndarray  # float32 (3, rows, cols): ∅_FO, ∅_OF, ∅_other
    betp: np.ndarray  # float32 (5, rows, cols): betP of F, I, U, S, M
    decision: np.ndarray  # uint8 (rows, cols): DECISION_CODES

    @staticmethod
    def empty(shape: tuple[int, int]) -> FusedOutputs:
        """Uninitialised outputs for a grid of ``shape``; every cell is written by a step."""
        return FusedOutputs(np.empty((3, *shape), np.float32), np.empty((5, *shape), np.float32),
                            np.empty(shape, np.uint8))

    def arrays(self) -> tuple[np.ndarray, ...]:
        return self.betp, self.conflict, self.decision


@dataclass(frozen=True)
class StoredOutputs:
    """uint8 outputs of :func:`fused_step` as the output format stores them
    (``round(255 · x)``, docs/output-format.md): the new masses, betP, conflict parts, ζ
    and the decision, each planar. Usually views into the writer's chunk buffer."""

    masses: np.ndarray  # uint8 (32, rows, cols)
    betp: np.ndarray  # uint8 (5, rows, cols)
    conflict: np.ndarray  # uint8 (3, rows, cols)
    zeta: np.ndarray  # uint8 (rows, cols)
    decision: np.ndarray  # uint8 (rows, cols)

    @staticmethod
    def empty(shape: tuple[int, int]) -> StoredOutputs:
        return StoredOutputs(np.empty((32, *shape), np.uint8), np.empty((5, *shape), np.uint8),
                             np.empty((3, *shape), np.uint8), np.empty(shape, np.uint8),
                             np.empty(shape, np.uint8))

    def arrays(self) -> tuple[np.ndarray, ...]:
        return self.masses, self.betp, self.conflict, self.zeta, self.decision


def fused_step(pg: np.ndarray, zeta: np.ndarray, free: np.ndarray, occupied: np.ndarray,
               labels: np.ndarray | None, betas: tuple[float, float, float], dt_s: float,
               params: FusionParams, *, observed: np.ndarray | None = None,
               out: FusedOutputs | StoredOutputs | None = None,
               flags: np.ndarray | None = None, offset: tuple[int, int] = (0, 0),
               shift: tuple[int, int] = (0, 0)) -> FusedOutputs | StoredOutputs:
    """One frame, in place: ``pg``, ``zeta`` ← PG_t, ζ_t (SPEC §5 steps 2–8); the SPEC §6
    outputs into ``out``.

    ``pg``: planar float32 ``(32, rows, cols)`` state and ``zeta`` its accumulator, held in
    a circular buffer (grid_map's moving grid): window cell ``(r, c)`` lives at buffer cell
    ``((r + offset[0]) % rows, (c + offset[1]) % cols)``. ``shift = (dr, dc)``: window cell
    ``(r, c)`` of this frame was cell ``(r + dr, c + dc)`` of the previous frame's window
    (``new.row0 − old.row0``, ``new.col0 − old.col0``), so a scrolled window keeps its cells
    where they are and only the cells that enter start vacuous (ζ = 0): nothing is copied.
    ``flags``: uint8 ``(rows, cols)`` buffer cells known to be exactly vacuous with ζ = 0,
    kept up to date by the step (``None``: derived from ``pg``, ``zeta`` — slower); blocks
    of such cells that the scan did not touch are skipped (when no prior applies there).

    ``free``, ``occupied``: the sensor grid m({F}), m({O}) (SPEC §3), window order;
    ``labels``: uint8 context labels (0 other, 1 road, 2 building, :data:`NO_MAP`) or
    ``None`` for no map; ``betas``: ``(beta_building, beta_road, beta_other)`` as in
    :func:`evperc.geo.prior.prior_masses`; ``observed``: cells the scan touched, by default
    ``(free > 0) | (occupied > 0)``. ``out``: :class:`FusedOutputs` (allocated when
    ``None``) or :class:`StoredOutputs`, window order.
    Equal to ``fusion_step`` then ``decide`` to float32 round-off.
    """
    shape = _check_state(pg, zeta)
    if flags is None:
        flags = vacuous_flags(pg, zeta)
    elif flags.shape != shape or flags.dtype != np.uint8 or not flags.flags.c_contiguous:
        raise ValueError(f"flags must be a C-contiguous uint8 {shape} array")
    off_r, off_c = (int(v) for v in offset)
    if not (0 <= off_r < shape[0] and 0 <= off_c < shape[1]):
        raise ValueError(f"offset {offset} outside the {shape} buffer")
    free32 = _grid(free, np.float32, shape, "free")
    occ32 = _grid(occupied, np.float32, shape, "occupied")
    if labels is None:
        lab = np.full(shape, NO_MAP, np.uint8)
    else:
        lab = _grid(labels, np.uint8, shape, "labels")
        bad = (lab > CONTEXT_BUILDING) & (lab != NO_MAP)
        if bad.any():
            raise ValueError(f"unknown context label {int(lab[bad][0])} (expected 0, 1, 2 or "
                             f"{NO_MAP})")
    derive_obs = observed is None
    obs = lab if derive_obs else _grid(observed, np.bool_, shape, "observed").view(np.uint8)
    if out is None:
        out = FusedOutputs.empty(shape)
    _check_outputs(out, shape)
    if params.residual_conflict not in _RESIDUAL:
        raise ValueError(f"residual_conflict must be one of {sorted(_RESIDUAL)}")
    beta_b, beta_r, beta_o = _betas(betas)
    if params.discount == "contextual":
        alphas = scaled_rate(np.asarray(params.discount_rates, np.float64), dt_s,
                             params.discount_period_s)
        alpha_c = 0.0
    else:
        alphas = np.zeros(5)
        alpha_c = float(scaled_rate(params.discount_classical, dt_s, params.discount_period_s))
    everywhere = params.prior_where == "everywhere"
    f32 = np.float32
    scalars = (
        derive_obs, everywhere, beta_b, beta_r, beta_o, f32(_TOL32),
        *(f32(a) for a in alphas), f32(1.0 - alpha_c), f32(alpha_c),
        _RESIDUAL[params.residual_conflict], params.stopped_target == "stopped",
        f32(params.zeta_increment), f32(params.zeta_decrement), f32(params.gamma_occupied),
        f32(params.gamma_conflict), f32(params.decision_min_betp),
        f32(params.decision_max_ignorance), *_CODES, _vacuous_code(params),
        # an untouched vacuous cell stays vacuous unless a prior or ζ can move it
        derive_obs and not everywhere and params.gamma_occupied > 0)
    kernel = (fused_kernel.step_float if isinstance(out, FusedOutputs)
              else fused_kernel.step_stored)
    kernel(pg, zeta, flags, off_r, off_c, int(shift[0]), int(shift[1]), free32, occ32, lab, obs,
           *scalars, *out.arrays())
    return out


def vacuous_flags(pg: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """uint8 ``(rows, cols)``: 1 where the cell is exactly vacuous (m(Ω) = 1) with ζ = 0."""
    return ((pg[_OMEGA] == 1.0) & ~pg[:_OMEGA].any(axis=0) & (zeta == 0.0)).astype(np.uint8)


def window_order(buffer: np.ndarray, offset: tuple[int, int]) -> np.ndarray:
    """A circular buffer's ``(..., rows, cols)`` cells in window order (a copy)."""
    return np.roll(buffer, (-int(offset[0]), -int(offset[1])), axis=(-2, -1))


def _vacuous_code(params: FusionParams) -> np.uint8:
    """The decision of a vacuous cell (SPEC §6), as the kernel's skip path writes it."""
    return np.uint8(decide(vacuous((1, 1)), params)[1][0, 0])


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
    if (pg.ndim != 3 or pg.shape[0] != 32 or pg.dtype != np.float32
            or not pg.flags.c_contiguous or not pg.flags.writeable):
        raise ValueError(f"pg must be a writeable C-contiguous float32 (32, rows, cols) "
                         f"array, got {pg.dtype} {pg.shape}")
    shape = pg.shape[1:]
    if (zeta.shape != shape or zeta.dtype != np.float32 or not zeta.flags.c_contiguous
            or not zeta.flags.writeable):
        raise ValueError(f"zeta must be a writeable C-contiguous float32 {shape} array, "
                         f"got {zeta.dtype} {zeta.shape}")
    return shape


def _check_outputs(out: FusedOutputs | StoredOutputs, shape: tuple[int, int]) -> None:
    want = FusedOutputs.empty((1, 1)) if isinstance(out, FusedOutputs) else (
        StoredOutputs.empty((1, 1)))
    for got, model in zip(out.arrays(), want.arrays(), strict=True):
        if (got.shape != (*model.shape[:-2], *shape) or got.dtype != model.dtype
                or not got.flags.c_contiguous or not got.flags.writeable):
            raise ValueError(f"out arrays do not match the grid {shape} (see "
                             f"{type(out).__name__}.empty)")


def _grid(a: np.ndarray, dtype: type, shape: tuple[int, int], name: str) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=dtype)
    if a.shape != shape:
        raise ValueError(f"{name} has shape {a.shape}, the grid is {shape}")
    return a


def _betas(betas: tuple[float, float, float]) -> tuple[np.float32, np.float32, np.float32]:
    """β of the building, road and other priors (SPEC §4)."""
    values = tuple(float(b) for b in betas)
    if len(values) != 3 or not all(0.0 <= b <= 1.0 for b in values):
        raise ValueError(f"prior masses must be in [0, 1], got {list(betas)}")
    return tuple(np.float32(b) for b in values)
